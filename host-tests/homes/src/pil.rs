//! Processor in the loop: the flight firmware's application, built for QEMU's
//! `mps2-an500` (Cortex-M7; `cargo pil-fw`, `firmware/src/board/mps2_an500/`), run under
//! `-icount` and fed by the host's simulated CCD47-20 exactly as the SIL is fed
//! ([`crate::home::SimLines`]: only what each frame's readout request reads is rendered).
//!
//! [`run`] prepares QEMU's working directory (the two named pipes of the firmware's host
//! channel, the table store's bank with the SIL's table in its flash form, the catalog for a
//! sky scene), starts QEMU, answers every request with its lines and collects every frame's
//! outcome ([`PilFrame`]) until `frames` frames are done. The link is QEMU's first serial
//! port: a TCP server on 127.0.0.1:`port` for `startrack gse --port`, or nothing.
//!
//! Time: `-icount shift=1` makes every instruction 2 ns of emulated time (500 M a second,
//! close to the H743's 480 MHz at one instruction a cycle), so the firmware's timeouts fall
//! as on the board; `sleep=off` lets the emulated clock jump over the core's sleeps (the
//! exposures) at once. Each line reaches the firmware when the flight sequencer would have
//! read it out ([`readout_times`]: after the exposure, at its last sample in the program the
//! H7 compiles for that frame's plan), so a frame's emulated time is its exposure, frame
//! transfer and readout. The firmware reports SysTick counts (40 ns each) since its time base
//! started, and of them the counts its executor was busy: busy counts x 40 ns / 2 ns are the
//! instructions it ran (the rest it slept). They are instructions, not cycles: QEMU models no
//! pipeline, cache or wait state.
//!
//! Cost: the host renders what the SIL renders (~1 s a full frame in release), the emulated
//! M7 runs the tracker at QEMU's speed (tens of M instructions a second).

use crate::home::SimLines;
use crate::sil::{self, SilConfig};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, CompileError, Limits, LineJobs, PinMap, ReadoutPlan, Step, Timing, compile,
};
use startrack_core::tracker::{Integration, LineSource, Mode};
use startrack_core::window::Rect;
use startrack_sim::sim::{SensorParams, Simulator};
use startrack_sim::sky::scene::committed_catalog;
use std::collections::HashMap;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// QEMU's `-icount` shift: 2^1 ns an instruction.
pub const ICOUNT_SHIFT: u32 = 1;
/// Emulated ns an instruction.
pub const NS_PER_INSTRUCTION: u64 = 1 << ICOUNT_SHIFT;
/// Emulated ns a SysTick count (QEMU's 25 MHz processor clock).
pub const NS_PER_COUNT: u64 = 40;
/// The flight board's clock, Hz, for the seconds a count of instructions takes at one
/// instruction a cycle.
pub const BOARD_HZ: f64 = 480e6;
/// Where the firmware expects the catalog (its memory map's `CATALOG`).
pub const CATALOG_ADDRESS: u32 = 0x0020_0000;
/// Samples a line, as the firmware reads them.
const LINE_LEN: usize = 1072;
/// The line header's end of frame.
const END_OF_FRAME: u16 = 0xFFFF;

/// What a PIL run runs.
#[derive(Clone, Debug)]
pub struct PilConfig {
    /// The scene, the frames and the tracker's configuration, as for the SIL (its `period_us`
    /// is not used: the firmware keeps its own time).
    pub sil: SilConfig,
    /// The firmware image built for `mps2-an500`.
    pub elf: PathBuf,
    /// QEMU's working directory (pipes, bank, catalog, the defmt log `defmt.bin`).
    pub dir: PathBuf,
    /// The link's TCP port (none: no link).
    pub port: Option<u16>,
    /// Longest run, wall clock.
    pub timeout: Duration,
    /// A fault to make the firmware commit at a frame of its first boot (instead of that
    /// frame's lines).
    pub inject: Option<(u32, Fault)>,
    /// Power on with the bank image a previous run left in `dir` (the firmware writes every
    /// erase and program through to it, so a killed QEMU leaves it as a power cut would),
    /// instead of a fresh bank with the SIL's table; a fresh one when there is none.
    pub keep_bank: bool,
}

/// A fault the firmware commits on request (its line header), to test its safe states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// Its thread-mode loop spins for ever: the watchdog must reset it.
    Hang,
    /// It panics: the panic handler must reset it.
    Panic,
}

impl Fault {
    const fn header(self) -> u16 {
        match self {
            Self::Hang => 0xFFFD,
            Self::Panic => 0xFFFC,
        }
    }
}

/// A reported star.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PilStar {
    /// Position, px.
    pub x_px: f32,
    /// Position, px.
    pub y_px: f32,
    /// Flux, e-.
    pub flux_e: f32,
    /// The `StarFlags` bits.
    pub flags: u32,
}

/// A frame's attitude as the firmware reported it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PilFix {
    /// Lost in space (else tracking).
    pub lost_in_space: bool,
    /// Stars matched.
    pub matched: u8,
    /// Stars used.
    pub used: u8,
    /// ICRS to camera, scalar first.
    pub q: [f64; 4],
    /// 1-sigma cross-boresight, rad.
    pub sigma_boresight_rad: f64,
    /// 1-sigma roll, rad.
    pub sigma_roll_rad: f64,
    /// The identification's false-match probability.
    pub false_probability: f64,
}

/// One frame as the firmware reported it.
#[derive(Clone, Debug, PartialEq)]
pub struct PilFrame {
    /// The tracker's frame number.
    pub frame: u32,
    /// Its mode.
    pub mode: Mode,
    /// Its stars.
    pub stars: Vec<PilStar>,
    /// `None`: no attitude stage (no catalog); `Some(None)`: refused; else the fix.
    pub attitude: Option<Option<PilFix>>,
    /// SysTick counts since the firmware's time base started, at the frame's end.
    pub counts: u64,
    /// Of them, the counts the executor was busy.
    pub busy_counts: u64,
    /// The stack's high-water mark, bytes.
    pub stack_used_b: u32,
    /// The frame's integration on the firmware's clock; `None` when its line source gave
    /// none.
    pub integration: Option<Integration>,
}

impl PilFrame {
    /// Emulated seconds since the time base started.
    pub fn time_s(&self) -> f64 {
        (self.counts * NS_PER_COUNT) as f64 * 1e-9
    }
}

/// A boot of the firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PilBoot {
    /// The reset cause's code (1 power-on, 2 watchdog, 3 software, 4 pin, 5 other).
    pub cause: u8,
    /// SysTick counts of the start-up before `main` (RAM zeroed, `.data` copied, the stack
    /// painted).
    pub startup_counts: u32,
}

/// What a run gave.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PilReport {
    /// Every boot, in order.
    pub boots: Vec<PilBoot>,
    /// Every frame, in order (frames of all boots).
    pub frames: Vec<PilFrame>,
}

impl PilReport {
    /// Instructions from the reset to the end of the first frame with an attitude (the
    /// start-up's counts are all busy), and that frame; `None` without one.
    pub fn boot_to_first_attitude(&self) -> Option<(u64, &PilFrame)> {
        let boot = self.boots.first()?;
        let f = self
            .frames
            .iter()
            .find(|f| matches!(f.attitude, Some(Some(_))))?;
        let counts = u64::from(boot.startup_counts) + f.busy_counts;
        Some((counts * NS_PER_COUNT / NS_PER_INSTRUCTION, f))
    }

    /// The stack's high-water mark over the run, bytes.
    pub fn stack_used_b(&self) -> u32 {
        self.frames
            .iter()
            .map(|f| f.stack_used_b)
            .max()
            .unwrap_or(0)
    }
}

/// Instructions in `counts` SysTick counts.
pub fn instructions(counts: u64) -> u64 {
    counts * NS_PER_COUNT / NS_PER_INSTRUCTION
}

/// Seconds `n` instructions take at [`BOARD_HZ`], one instruction a cycle.
pub fn board_seconds(n: u64) -> f64 {
    n as f64 / BOARD_HZ
}

/// Kills QEMU when dropped.
struct Qemu(Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn mkfifo(path: &Path) -> Result<(), String> {
    let _ = std::fs::remove_file(path);
    let status = Command::new("mkfifo")
        .arg(path)
        .status()
        .map_err(|e| format!("mkfifo: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("mkfifo {} failed", path.display()))
    }
}

/// Writes the bank image: an erased H7 bank 2 with the SIL's table (its flash form) uploaded
/// through the core's store, as the SIL's flash home brings it up.
fn write_bank(config: &SilConfig, params: &SensorParams, dir: &Path) -> Result<(), String> {
    let table = crate::flash_home::flash_table(config, params)?;
    let flash_file = dir.join("bank.flash");
    let _ = std::fs::remove_file(&flash_file);
    let home =
        crate::flash_home::FlashHome::open(&flash_file, params.geometry, Some(table.as_slice()))?;
    std::fs::write(dir.join("pil-bank.bin"), home.store().flash().bytes())
        .map_err(|e| format!("pil-bank.bin: {e}"))
}

/// Runs the firmware for `config.sil.frames` frames; `on_frame` sees each frame as it comes,
/// `on_boot` each boot.
pub fn run(
    config: &PilConfig,
    on_boot: &mut dyn FnMut(&PilBoot),
    on_frame: &mut dyn FnMut(&PilFrame),
) -> Result<PilReport, String> {
    let dir = &config.dir;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let params = SensorParams {
        seed: config.sil.seed,
        ..SensorParams::default()
    };
    if !(config.keep_bank && dir.join("pil-bank.bin").exists()) {
        write_bank(&config.sil, &params, dir)?;
    }
    let catalog_bytes = match config.sil.sky {
        Some(_) => committed_catalog()?,
        None => Vec::new(),
    };
    let catalog = match config.sil.sky {
        Some(_) => Some(
            startrack_core::catalog::Catalog::parse(&catalog_bytes)
                .map_err(|e| format!("catalog: {e}"))?,
        ),
        None => None,
    };
    if config.sil.sky.is_some() {
        std::fs::write(dir.join("pil-catalog.bin"), &catalog_bytes)
            .map_err(|e| format!("pil-catalog.bin: {e}"))?;
    }
    let req_path = dir.join("pil-req");
    let lines_path = dir.join("pil-lines");
    mkfifo(&req_path)?;
    mkfifo(&lines_path)?;

    let mut qemu = Command::new("qemu-system-arm");
    qemu.current_dir(dir)
        .args([
            "-M",
            "mps2-an500",
            "-cpu",
            "cortex-m7",
            "-nographic",
            "-monitor",
            "none",
        ])
        .args(["-icount", &format!("shift={ICOUNT_SHIFT},sleep=off")])
        .args(["-semihosting-config", "enable=on,target=native"]);
    match config.port {
        Some(p) => qemu.args(["-serial", &format!("tcp:127.0.0.1:{p},server,nowait")]),
        None => qemu.args(["-serial", "null"]),
    };
    if config.sil.sky.is_some() {
        qemu.args([
            "-device",
            &format!("loader,file=pil-catalog.bin,addr={CATALOG_ADDRESS:#x},force-raw=on"),
        ]);
    }
    // The firmware's defmt log: semihosting's console is QEMU's standard output.
    let log =
        std::fs::File::create(dir.join("defmt.bin")).map_err(|e| format!("defmt.bin: {e}"))?;
    qemu.arg("-kernel")
        .arg(&config.elf)
        .stdin(Stdio::null())
        .stdout(log);
    let mut child = Qemu(qemu.spawn().map_err(|e| format!("qemu-system-arm: {e}"))?);
    // For a test that cuts the emulated board's power (kills QEMU) mid-run.
    std::fs::write(dir.join("qemu.pid"), child.0.id().to_string())
        .map_err(|e| format!("qemu.pid: {e}"))?;

    // The firmware opens pil-req, then pil-lines: open them in that order, off this thread,
    // so that a QEMU that never gets there is seen exiting.
    let (rp, lp) = (req_path.clone(), lines_path.clone());
    let opener = std::thread::spawn(move || -> std::io::Result<_> {
        let req = std::fs::File::open(&rp)?;
        let lines = std::fs::OpenOptions::new().write(true).open(&lp)?;
        Ok((req, lines))
    });
    let started = Instant::now();
    while !opener.is_finished() {
        if let Ok(Some(status)) = child.0.try_wait() {
            return Err(format!("qemu-system-arm exited at start-up: {status}"));
        }
        if started.elapsed() > config.timeout {
            return Err("the firmware did not open its host channel".into());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let (req, lines) = opener
        .join()
        .map_err(|_| "host channel opener panicked".to_string())?
        .map_err(|e| format!("host channel: {e}"))?;
    let mut req = BufReader::new(req);
    let mut lines = BufWriter::new(lines);

    let sky = config.sil.sky.zip(catalog);
    let base = sil::scene(&config.sil, &params);
    let stars_of =
        |frame: u32| sil::frame_stars(&config.sil, &base, sky.as_ref().map(|(_, c)| c), frame);
    let mut source = SimLines::new(|frame| Simulator {
        frame,
        ..Simulator::new(params.clone(), stars_of(frame))
    });
    let mut report = PilReport::default();
    while report.frames.len() < config.sil.frames as usize {
        if started.elapsed() > config.timeout {
            return Err(format!(
                "timeout after {} frames ({:?})",
                report.frames.len(),
                config.timeout
            ));
        }
        let tag = match read_u8(&mut req) {
            Ok(t) => t,
            Err(e) => {
                let status = child.0.try_wait().ok().flatten();
                return Err(format!("host channel closed ({e}); qemu: {status:?}"));
            }
        };
        match tag {
            b'B' => {
                let cause = read_u8(&mut req)?;
                let startup_counts = read_u32(&mut req)?;
                let boot = PilBoot {
                    cause,
                    startup_counts,
                };
                on_boot(&boot);
                report.boots.push(boot);
            }
            b'Q' => {
                let inject = config
                    .inject
                    .filter(|_| report.boots.len() == 1)
                    .map(|(frame, fault)| (frame, fault.header()));
                serve_request(&mut req, &mut lines, &mut source, inject)?;
            }
            b'R' => {
                let frame = read_outcome(&mut req)?;
                on_frame(&frame);
                report.frames.push(frame);
            }
            t => return Err(format!("host channel: unknown record {t:#04x}")),
        }
    }
    Ok(report)
}

fn read_exact<const N: usize>(r: &mut impl Read) -> Result<[u8; N], String> {
    let mut b = [0u8; N];
    r.read_exact(&mut b)
        .map_err(|e| format!("host channel: {e}"))?;
    Ok(b)
}

fn read_u8(r: &mut impl Read) -> Result<u8, String> {
    Ok(read_exact::<1>(r)?[0])
}

fn read_u16(r: &mut impl Read) -> Result<u16, String> {
    Ok(u16::from_le_bytes(read_exact(r)?))
}

fn read_u32(r: &mut impl Read) -> Result<u32, String> {
    Ok(u32::from_le_bytes(read_exact(r)?))
}

fn read_u64(r: &mut impl Read) -> Result<u64, String> {
    Ok(u64::from_le_bytes(read_exact(r)?))
}

fn read_f32(r: &mut impl Read) -> Result<f32, String> {
    Ok(f32::from_le_bytes(read_exact(r)?))
}

fn read_f64(r: &mut impl Read) -> Result<f64, String> {
    Ok(f64::from_le_bytes(read_exact(r)?))
}

/// The flight sequencer's pixel rate (`firmware/src/board/stm32h743/sequencer.rs`).
pub const PIXEL_RATE_HZ: u32 = 1_000_000;

/// When the flight sequencer reads each line of a request out: the request compiled as the
/// H7's sequencer compiles it (the core's plan and compiler, 1 MHz pixels, both outputs; a
/// refused plan read as a full frame, as there), then each line's last-sample tick, us from
/// the program's start (its frame transfer, at the end of the exposure); with the program's
/// readout end (`Cost::frame_time_ns` after the frame transfer).
pub fn readout_times(
    request: &ReadoutRequest<'_>,
    exposure_us: u32,
) -> Result<(HashMap<u16, u32>, u32), String> {
    let geometry = ReadoutGeometry::CCD47_20_DUAL;
    let plan = ReadoutPlan::new(geometry, *request, Binning::X1, exposure_us)
        .or_else(|_| {
            ReadoutPlan::new(
                geometry,
                ReadoutRequest::FullFrame,
                Binning::X1,
                exposure_us,
            )
        })
        .map_err(|e| format!("readout plan: {e}"))?;
    let ticks = Timing::at_pixel_rate(PIXEL_RATE_HZ)
        .validate(&Limits::CCD47_20)
        .map_err(|e| format!("sequencer timing: {e}"))?;
    let pins = PinMap::IN_ORDER;
    let (mut words, mut steps) = (vec![0u32; 1024], vec![Step::EMPTY; 1024]);
    loop {
        match compile(&plan, &ticks, &pins, &mut words, &mut steps) {
            Ok(_) => break,
            Err(CompileError::Words { needed }) => words.resize(needed, 0),
            Err(CompileError::Steps { needed }) => steps.resize(needed, Step::EMPTY),
            Err(e) => return Err(format!("sequencer compile: {e}")),
        }
    }
    let program = compile(&plan, &ticks, &pins, &mut words, &mut steps)
        .map_err(|e| format!("sequencer compile: {e}"))?;
    let tick_ps = u64::from(program.tick_ps());
    let us = |tick: u64| u32::try_from(tick * tick_ps / 1_000_000).unwrap_or(u32::MAX);
    let times = LineJobs::new(&program)
        .map(|j| (j.line, us(j.end_tick)))
        .collect::<HashMap<_, _>>();
    let cost = startrack_core::sequencer::Cost::of(&program);
    let end_ns =
        cost.segment_ns(startrack_core::sequencer::SegmentId::FrameTransfer) + cost.frame_time_ns();
    Ok((times, u32::try_from(end_ns / 1000).unwrap_or(u32::MAX)))
}

/// A request record (after its tag): the lines it reads, rendered and written, the last one
/// marked, each with the instant the flight sequencer reads it out ([`readout_times`]); an
/// end-of-frame header, at the readout's end, when it reads none.
fn serve_request<F: FnMut(u32) -> Simulator>(
    req: &mut impl Read,
    out: &mut impl Write,
    source: &mut SimLines<F>,
    inject: Option<(u32, u16)>,
) -> Result<(), String> {
    let frame = read_u32(req)?;
    let exposure_us = read_u32(req)?;
    let windowed = read_u8(req)? != 0;
    let n = read_u16(req)?;
    let mut rects = Vec::with_capacity(usize::from(n));
    for _ in 0..n {
        rects.push(Rect {
            x0: read_u16(req)?,
            y0: read_u16(req)?,
            width: read_u16(req)?,
            height: read_u16(req)?,
        });
    }
    let request = if windowed {
        ReadoutRequest::Windows(&rects)
    } else {
        ReadoutRequest::FullFrame
    };
    let io = |e: std::io::Error| format!("host channel: {e}");
    if let Some((at, header)) = inject
        && at == frame
    {
        let [a, b] = header.to_le_bytes();
        out.write_all(&[a, b, 0, 0, 0, 0, 0, 0]).map_err(io)?;
        return out.flush().map_err(io);
    }
    let (ready_us, end_us) = readout_times(&request, exposure_us)?;
    let Ok(()) = crate::home::block_on(source.start_frame(frame, &request));
    // One line held back, to mark the last.
    let mut held: Option<(u16, Vec<u16>)> = None;
    let mut written = 0usize;
    loop {
        let Ok(next) = crate::home::block_on(source.next_line());
        let next = next.map(|l| (l.line, l.samples.to_vec()));
        if let Some((line, samples)) = held.take() {
            let at_us = ready_us.get(&line).copied().unwrap_or(end_us);
            write_line(out, line, next.is_none(), at_us, &samples).map_err(io)?;
            written += 1;
        }
        match next {
            Some(l) => held = Some(l),
            None => break,
        }
    }
    if written == 0 {
        // No line at all (no window): the end of the frame.
        let [a, b] = END_OF_FRAME.to_le_bytes();
        let [c, d, e, f] = end_us.to_le_bytes();
        out.write_all(&[a, b, 0, 0, c, d, e, f]).map_err(io)?;
    }
    out.flush().map_err(io)
}

fn write_line(
    out: &mut impl Write,
    line: u16,
    last: bool,
    ready_us: u32,
    samples: &[u16],
) -> std::io::Result<()> {
    let mut b = Vec::with_capacity(8 + 2 * LINE_LEN);
    b.extend_from_slice(&line.to_le_bytes());
    b.push(u8::from(last));
    b.push(0);
    b.extend_from_slice(&ready_us.to_le_bytes());
    for i in 0..LINE_LEN {
        b.extend_from_slice(&samples.get(i).copied().unwrap_or(0).to_le_bytes());
    }
    out.write_all(&b)
}

/// An outcome record (after its tag).
fn read_outcome(r: &mut impl Read) -> Result<PilFrame, String> {
    let frame = read_u32(r)?;
    let mode = match read_u8(r)? {
        0 => Mode::Standby,
        1 => Mode::Acquisition,
        2 => Mode::Tracking,
        m => return Err(format!("host channel: mode {m}")),
    };
    let n = read_u16(r)?;
    let counts = read_u64(r)?;
    let busy_counts = read_u64(r)?;
    let stack_used_b = read_u32(r)?;
    let att = read_u8(r)?;
    let solve_mode = read_u8(r)?;
    let matched = read_u8(r)?;
    let used = read_u8(r)?;
    let mut q = [0.0; 4];
    for v in &mut q {
        *v = read_f64(r)?;
    }
    let sigma_boresight_rad = read_f64(r)?;
    let sigma_roll_rad = read_f64(r)?;
    let false_probability = read_f64(r)?;
    let integration = match (read_u64(r)?, read_u64(r)?) {
        (u64::MAX, u64::MAX) => None,
        (start_us, end_us) => Some(Integration { start_us, end_us }),
    };
    let mut stars = Vec::with_capacity(usize::from(n));
    for _ in 0..n {
        stars.push(PilStar {
            x_px: read_f32(r)?,
            y_px: read_f32(r)?,
            flux_e: read_f32(r)?,
            flags: read_u32(r)?,
        });
    }
    let attitude = match att {
        0 => None,
        1 => Some(Some(PilFix {
            lost_in_space: solve_mode == 1,
            matched,
            used,
            q,
            sigma_boresight_rad,
            sigma_roll_rad,
            false_probability,
        })),
        _ => Some(None),
    };
    Ok(PilFrame {
        frame,
        mode,
        stars,
        attitude,
        counts,
        busy_counts,
        stack_used_b,
        integration,
    })
}

/// A PIL run against the SIL on the same scene and the same table (the bank's, in its flash
/// form), frame by frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Comparison {
    /// Frames compared (both runs have them).
    pub frames: usize,
    /// Frames whose mode or star count differ.
    pub frames_differing: usize,
    /// Stars compared (same frame, same index).
    pub stars: usize,
    /// Of them, equal bit for bit in x, y, flux and flags.
    pub stars_identical: usize,
    /// Largest position difference, px.
    pub max_position_px: f64,
    /// Largest relative flux difference.
    pub max_flux_rel: f64,
    /// Frames with an attitude in both runs.
    pub attitudes: usize,
    /// Of them, equal bit for bit.
    pub attitudes_identical: usize,
    /// Largest angle between the two attitudes, arcsec.
    pub max_attitude_arcsec: f64,
}

/// Runs the SIL with the PIL's table and frame period (`period_us`, the firmware's frame
/// time rounded), each frame integrating when the firmware's did (the tracker's rate, its
/// predicted windows and trails follow the frames' instants), and compares it with `report`.
pub fn compare(
    config: &SilConfig,
    report: &PilReport,
    period_us: u64,
) -> Result<Comparison, String> {
    let params = SensorParams {
        seed: config.seed,
        ..SensorParams::default()
    };
    let table = crate::flash_home::flash_table(config, &params)?;
    let sil_config = SilConfig {
        period_us,
        integrations: report.frames.iter().map(|f| f.integration).collect(),
        ..config.clone()
    };
    let sil = sil::run_with_table(&sil_config, &table)?;
    let mut c = Comparison::default();
    for (p, s) in report.frames.iter().zip(&sil.frames) {
        c.frames += 1;
        if p.mode != s.summary.mode || p.stars.len() != s.stars.len() {
            c.frames_differing += 1;
        }
        for (a, b) in p.stars.iter().zip(&s.stars) {
            let b = &b.star;
            c.stars += 1;
            let same = a.x_px.to_bits() == b.x_px.to_bits()
                && a.y_px.to_bits() == b.y_px.to_bits()
                && a.flux_e.to_bits() == b.flux_e.to_bits()
                && a.flags == b.flags.bits();
            c.stars_identical += usize::from(same);
            let d = f64::from(a.x_px - b.x_px).hypot(f64::from(a.y_px - b.y_px));
            c.max_position_px = c.max_position_px.max(d);
            let rel = f64::from((a.flux_e - b.flux_e).abs()) / f64::from(b.flux_e.abs()).max(1.0);
            c.max_flux_rel = c.max_flux_rel.max(rel);
        }
        if let (Some(Some(pf)), Some(sc)) = (&p.attitude, &s.attitude)
            && let Ok(sf) = &sc.fix
        {
            c.attitudes += 1;
            let sq = sf.attitude.q.0;
            c.attitudes_identical += usize::from(
                pf.q.iter()
                    .zip(&sq)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
            );
            let e = startrack_core::attitude::Quat(pf.q).error_vector(sf.attitude.q);
            let angle = e.iter().map(|v| v * v).sum::<f64>().sqrt() * 206_264.806;
            c.max_attitude_arcsec = c.max_attitude_arcsec.max(angle);
        }
    }
    Ok(c)
}
