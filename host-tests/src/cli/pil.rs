//! `startrack pil`: the flight firmware on QEMU's `mps2-an500` fed by the simulated sensor
//! ([`startrack_homes::pil`]). Prints a line per frame (mode, stars, attitude, emulated time), then the
//! boot-to-first-attitude figure and the stack's high-water mark; `--attitude FILE` writes
//! the CSV of `startrack sil --attitude`.
//!
//! The image is `--elf PATH`, else the one `cargo pil-fw` builds
//! (`target/pil/thumbv7em-none-eabihf/release/startrack-firmware`), built first unless
//! `--no-build`.

use super::sil::{SceneArgs, SilArgs};
use super::{CliError, LabError};
use startrack_homes::pil::{self, PilConfig, PilFrame, PilReport};
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

/// Options of `startrack pil`.
#[derive(Clone, Debug, clap::Args)]
#[command(mut_arg("frames", |a| a.default_value("5")))]
pub struct PilArgs {
    /// The scene, as `startrack sil`'s (with `--sky` the catalog is loaded into the emulated
    /// flash and the firmware's attitude stage runs).
    #[command(flatten)]
    pub scene: SceneArgs,
    /// With `--sky`: attitude CSV (one row per frame), as `startrack sil --attitude`.
    #[arg(long, requires = "sky")]
    pub attitude: Option<PathBuf>,
    /// The link (the emulated UART0) on TCP 127.0.0.1:PORT, for `startrack gse --port PORT`.
    #[arg(long)]
    pub port: Option<u16>,
    /// The firmware image for mps2-an500 (default: the one `cargo pil-fw` builds).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// Do not run `cargo pil-fw` first.
    #[arg(long)]
    pub no_build: bool,
    /// QEMU's working directory (pipes, bank image, catalog, the defmt log `defmt.bin`).
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Run the SIL on the same scene with the firmware's table too, and compare: stars and
    /// attitudes bit for bit, and the largest differences.
    #[arg(long)]
    pub compare: bool,
    /// The run's figures as CSV (`name,value`; the ones of docs/hardware.md's PIL table come
    /// from `--frames 4 --sky --compare`).
    #[arg(long)]
    pub figures: Option<PathBuf>,
    /// Make the firmware hang at frame N of its first boot (the watchdog's test: a reset with
    /// the cause watchdog, 2, must follow).
    #[arg(long, conflicts_with = "panic_at_frame")]
    pub hang_at_frame: Option<u32>,
    /// Make the firmware panic at frame N of its first boot (a reset with the cause other, 5,
    /// must follow).
    #[arg(long)]
    pub panic_at_frame: Option<u32>,
    /// Power on with the bank image left in `--dir` by a previous run (a power cut's test:
    /// the firmware writes the bank through to it), not a fresh one with the SIL's table.
    #[arg(long, requires = "dir")]
    pub keep_bank: bool,
    /// Longest run, wall-clock seconds.
    #[arg(long, default_value_t = 600)]
    pub timeout_s: u64,
}

/// The workspace root (this crate's parent).
fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(PathBuf::from)
        .unwrap_or_default()
}

/// The image `cargo pil-fw` builds.
pub fn default_elf() -> PathBuf {
    workspace().join("target/pil/thumbv7em-none-eabihf/release/startrack-firmware")
}

fn elf_of(args: &PilArgs) -> Result<PathBuf, CliError> {
    if let Some(e) = &args.elf {
        return Ok(e.clone());
    }
    if !args.no_build {
        let status = std::process::Command::new(std::env::var("CARGO").unwrap_or("cargo".into()))
            .arg("pil-fw")
            .current_dir(workspace())
            .status()
            .map_err(|e| CliError::Usage(format!("cargo pil-fw: {e}")))?;
        if !status.success() {
            return Err(CliError::Usage(format!("cargo pil-fw failed: {status}")));
        }
    }
    let elf = default_elf();
    if elf.exists() {
        Ok(elf)
    } else {
        Err(CliError::Usage(format!(
            "{} missing: build it with `cargo pil-fw`",
            elf.display()
        )))
    }
}

/// The frame's line.
pub fn frame_line(f: &PilFrame, previous_counts: u64) -> String {
    let attitude = match &f.attitude {
        None => "no attitude stage".to_string(),
        Some(None) => "no attitude".to_string(),
        Some(Some(fix)) => format!(
            "attitude {} ({} of {} stars) q = [{:.9}, {:.9}, {:.9}, {:.9}]",
            if fix.lost_in_space {
                "lost in space"
            } else {
                "tracking"
            },
            fix.matched,
            fix.used,
            fix.q[0],
            fix.q[1],
            fix.q[2],
            fix.q[3]
        ),
    };
    format!(
        "frame {}: {}, {} stars, {}; emulated {:.6} s (frame {:.6} s), {} instructions since boot",
        f.frame,
        f.mode.name(),
        f.stars.len(),
        attitude,
        f.time_s(),
        (f.counts.saturating_sub(previous_counts) * pil::NS_PER_COUNT) as f64 * 1e-9,
        pil::instructions(f.busy_counts)
    )
}

/// Runs `startrack pil`.
pub fn run(args: &PilArgs) -> Result<PilReport, CliError> {
    let sil_args = SilArgs::of_scene(args.scene.clone())?;
    let sil = super::sil::config_of(&sil_args)?;
    let elf = elf_of(args)?;
    let dir = args.dir.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("startrack-pil-{}", std::process::id()))
    });
    let config = PilConfig {
        sil: sil.clone(),
        elf,
        dir,
        port: args.port,
        timeout: Duration::from_secs(args.timeout_s),
        inject: args
            .hang_at_frame
            .map(|n| (n, pil::Fault::Hang))
            .or(args.panic_at_frame.map(|n| (n, pil::Fault::Panic))),
        keep_bank: args.keep_bank,
    };
    if let Some(p) = args.port {
        eprintln!("startrack pil: link on 127.0.0.1:{p}");
    }
    let last = std::cell::Cell::new(0u64);
    let report = pil::run(
        &config,
        &mut |b| {
            println!(
                "boot: reset cause {}, start-up {} instructions",
                b.cause,
                pil::instructions(u64::from(b.startup_counts))
            );
            last.set(0);
        },
        &mut |f| {
            println!("{}", frame_line(f, last.get()));
            last.set(f.counts);
        },
    )
    .map_err(CliError::Usage)?;
    match report.boot_to_first_attitude() {
        Some((n, f)) => println!(
            "boot to first attitude: {n} instructions (frame {}), {:.4} s at 480 MHz counting one instruction a cycle; {:.4} s emulated with the exposures",
            f.frame,
            pil::board_seconds(n),
            f.time_s()
        ),
        None => println!(
            "boot to first attitude: none in {} frames",
            report.frames.len()
        ),
    }
    println!(
        "stack high-water mark: {} bytes of 131072 (all tasks share the one stack of the thread-mode executor)",
        report.stack_used_b()
    );
    let mut comparison = None;
    if args.compare {
        // The firmware's frame period: its tracking frames' mean, to the microsecond.
        let n = report.frames.len().max(2) as u64 - 1;
        let span = match (report.frames.first(), report.frames.last()) {
            (Some(a), Some(b)) => b.counts.saturating_sub(a.counts),
            _ => 0,
        };
        let period_us = span * pil::NS_PER_COUNT / 1000 / n;
        let c = pil::compare(&sil, &report, period_us.max(1)).map_err(CliError::Usage)?;
        println!(
            "sil against pil ({} frames, sil period {period_us} us): {} frames differ in mode or star count; {} of {} stars bit for bit, largest difference {:.3e} px, flux {:.3e} relative; {} of {} attitudes bit for bit, largest difference {:.3e} arcsec",
            c.frames,
            c.frames_differing,
            c.stars_identical,
            c.stars,
            c.max_position_px,
            c.max_flux_rel,
            c.attitudes_identical,
            c.attitudes,
            c.max_attitude_arcsec
        );
        comparison = Some(c);
    }
    if let Some(p) = &args.figures {
        let io = |e: std::io::Error| LabError::Io {
            path: p.clone(),
            msg: e.to_string(),
        };
        let mut f = std::fs::File::create(p)
            .map(std::io::BufWriter::new)
            .map_err(io)?;
        write_figures(&mut f, &report, comparison.as_ref())
            .and_then(|()| f.flush())
            .map_err(io)?;
    }
    if let (Some(p), Some(sky)) = (&args.attitude, sil.sky) {
        let mut f = std::fs::File::create(p)
            .map(std::io::BufWriter::new)
            .map_err(|e| LabError::Io {
                path: p.clone(),
                msg: e.to_string(),
            })?;
        write_attitude(&mut f, &report, &sky)
            .and_then(|()| f.flush())
            .map_err(|e| LabError::Io {
                path: p.clone(),
                msg: e.to_string(),
            })?;
    }
    Ok(report)
}

/// Writes the attitude CSV of a PIL run, in `startrack sil --attitude`'s columns (errors
/// against the scene's truth).
pub fn write_attitude(
    out: &mut dyn Write,
    report: &PilReport,
    sky: &startrack_sim::sky::scene::SkyScene,
) -> std::io::Result<()> {
    const ARCSEC: f64 = 206_264.806;
    writeln!(
        out,
        "frame,solved,solve_mode,used,matched,qw,qx,qy,qz,error_boresight_arcsec,error_roll_arcsec,sigma_boresight_arcsec,sigma_roll_arcsec,false_probability"
    )?;
    for f in &report.frames {
        match &f.attitude {
            Some(Some(fix)) => {
                let e = startrack_core::attitude::Quat(fix.q).error_vector(sky.attitude(f.frame));
                let [w, x, y, z] = fix.q;
                writeln!(
                    out,
                    "{},1,{},{},{},{w:.9},{x:.9},{y:.9},{z:.9},{:.3},{:.3},{:.3},{:.3},{:.2e}",
                    f.frame,
                    if fix.lost_in_space {
                        "lost_in_space"
                    } else {
                        "tracking"
                    },
                    fix.used,
                    fix.matched,
                    e[0].hypot(e[1]) * ARCSEC,
                    e[2].abs() * ARCSEC,
                    fix.sigma_boresight_rad * ARCSEC,
                    fix.sigma_roll_rad * ARCSEC,
                    fix.false_probability
                )?;
            }
            Some(None) => writeln!(out, "{},0,,,,,,,,,,,,", f.frame)?,
            None => {}
        }
    }
    Ok(())
}

/// Instructions of each tracking frame after the first frame (busy counts between two
/// outcomes of the same boot).
pub fn tracking_frame_instructions(report: &PilReport) -> Vec<u64> {
    report
        .frames
        .windows(2)
        .filter(|w| w[1].mode == startrack_core::tracker::Mode::Tracking && w[1].frame > w[0].frame)
        .map(|w| pil::instructions(w[1].busy_counts.saturating_sub(w[0].busy_counts)))
        .collect()
}

/// Writes the run's figures, `name,value`.
pub fn write_figures(
    out: &mut dyn Write,
    report: &PilReport,
    comparison: Option<&pil::Comparison>,
) -> std::io::Result<()> {
    writeln!(out, "name,value")?;
    if let Some(b) = report.boots.first() {
        writeln!(
            out,
            "startup_instructions,{}",
            pil::instructions(u64::from(b.startup_counts))
        )?;
    }
    if let Some((n, _)) = report.boot_to_first_attitude() {
        writeln!(out, "boot_to_first_attitude_instructions,{n}")?;
    }
    let tracking = tracking_frame_instructions(report);
    if let (Some(lo), Some(hi)) = (tracking.iter().min(), tracking.iter().max()) {
        writeln!(out, "tracking_frame_instructions_min,{lo}")?;
        writeln!(out, "tracking_frame_instructions_max,{hi}")?;
    }
    writeln!(out, "stack_high_water_b,{}", report.stack_used_b())?;
    if let Some(c) = comparison {
        writeln!(out, "stars_compared,{}", c.stars)?;
        writeln!(out, "stars_identical,{}", c.stars_identical)?;
        writeln!(out, "attitudes_compared,{}", c.attitudes)?;
        writeln!(out, "attitudes_identical,{}", c.attitudes_identical)?;
    }
    Ok(())
}
