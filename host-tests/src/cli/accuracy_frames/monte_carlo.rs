//! Accuracy end to end on whole simulated frames of mixed PSF widths, as a user runs the
//! pipeline: per frame `startrack simulate` (each star's width drawn from a list, its eq. 8
//! SNR from a range, DSNU, PRNU, hot pixels listed), `calib build` from the simulator's true
//! maps and hot-pixel list with the command's defaults, `process` with its defaults (the
//! flight method, the width not told); every reported star matched to the truth.
//!
//! With `field_a_px` the width is instead a smooth function of the star's place (`simulate
//! --psf-a-field`, what a field PSF model describes), and the stars are binned by the
//! nearest width of the list.
//!
//! Two configurations run on the same frames: the table without a field PSF model, and the
//! table with one (`calib psf-model` fitted to the `stars.csv` of one more frame processed
//! with defaults, then `calib build --psf-model`), so that the flight code's use of the model
//! can be judged on the same stars.
//!
//! # What is measured, per PSF width and SNR bin
//! Stars with another true star closer than [`CROWD_PX`] are left out (a pair is the failure
//! maps' subject, not this one's) and counted. Of the rest:
//! - `missed`: no reported star within [`MATCH_PX`] of the truth;
//! - `bad`: matched but flagged as no clean position ([`BAD_POSITION`]: degenerate, not
//!   converged, poor fit, an excluded or saturated pixel, clipped, blended...), and of
//!   those `poor_fit`, flagged `POOR_FIT` and nothing else of it (their RMS / CRLB is
//!   printed apart: what a user who ignores the flag gets);
//! - of the others (`used`), the RMS over both axes of `error / CRLB`, each star against its
//!   own bound ([`crlb_x_px`] on a 9 x 9 window: its true width, signal, the local true dark
//!   as background, the read noise) and against its width-unknown bound
//!   ([`crlb_x_width_free_px`]); the pull, RMS of `error / reported sigma`, over all used
//!   stars and over those without `SIGMA_UNRELIABLE`; the share flagged `SIGMA_UNRELIABLE`;
//!   the mean reported width `psf_a_px`.
//!
//! Each ratio is an RMS over `2 used` axes: relative standard error `1 / sqrt(4 used)`
//! ([`rms_relative_se`]), printed with it.
//!
//! Cost: per frame one simulated full readout (the render dominates: about 2 s in release,
//! 3 s in the dev profile), one `calib build` and one `process` per configuration, and
//! four 9 x 9 Fisher sums per star. The files of each frame (18 MB) are deleted once the
//! frame is measured.

use crate::cli::calib_models::{PsfModelArgs, run_psf_model};
use crate::cli::process::{ProcessArgs, measure};
use crate::cli::simulate::{SceneMix, SimFiles, SimulateArgs, params};
use crate::cli::{CliError, LabError};
use startrack_analysis::accuracy::{crlb_x_px, crlb_x_width_free_px, rms_relative_se};
use startrack_core::tracker::{StarFlags, StarRecord};
use startrack_homes::home::write_csv;
use startrack_lab::table_build::{CalibBuildArgs, build};
use startrack_sim::sim::Simulator;
use startrack_sim::sim::psf::sigma_of_a;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A reported star within this distance of a true star is its measurement, px.
pub const MATCH_PX: f64 = 1.0;
/// A true star with another closer than this is crowded and left out, px (the flight
/// window is 7 px: beyond 8 px the neighbour's core is outside it).
pub const CROWD_PX: f64 = 8.0;
/// The SNR bins' edges: 10-30, 30-100, 100-200 (a star at exactly 200 is in the last).
pub const SNR_EDGES: [f64; 4] = [10.0, 30.0, 100.0, 200.0];

/// The flags that say a reported position is not a clean measurement.
pub const BAD_POSITION: StarFlags = StarFlags::DETECT_SATURATED
    .union(StarFlags::DETECT_EDGE)
    .union(StarFlags::DETECT_BLENDED)
    .union(StarFlags::DETECT_TRUNCATED)
    .union(StarFlags::SATURATED)
    .union(StarFlags::EDGE_CLIPPED)
    .union(StarFlags::EXCLUDED_PIXEL)
    .union(StarFlags::LOW_SNR)
    .union(StarFlags::DEGENERATE)
    .union(StarFlags::NOT_CONVERGED)
    .union(StarFlags::CLAMPED)
    .union(StarFlags::RING_LOST)
    .union(StarFlags::CALIB_FAILED)
    .union(StarFlags::POOR_FIT);

/// The experiment.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMc {
    /// Frames (each its own sensor, field and noise: seeds `seed .. seed + frames`).
    pub frames: usize,
    /// Stars per frame.
    pub stars: usize,
    /// Seed of the first frame.
    pub seed: u64,
    /// The PSF widths (80 %-energy radius) drawn from, px; with `field_a_px`, the bins'
    /// centres (each star in the bin of the nearest).
    pub widths_a_px: Vec<f64>,
    /// Instead of drawing from the list: the width a smooth function of the place, from the
    /// centre's to the corners' (`simulate --psf-a-field`), px.
    pub field_a_px: Option<[f64; 2]>,
    /// The eq. 8 SNR range, log-uniform.
    pub snr_range: [f64; 2],
    /// Dark signal non-uniformity (relative sigma).
    pub dsnu: f64,
    /// Photo-response non-uniformity (relative sigma).
    pub prnu: f64,
    /// Share of hot pixels.
    pub hot_fraction: f64,
    /// Mean dark, e- (the background).
    pub dark_e: f64,
    /// Read noise, e- RMS.
    pub read_noise_e: f64,
    /// Folder for the frames' files (each frame's deleted once measured).
    pub work_dir: PathBuf,
}

impl FrameMc {
    /// The full table's experiment: 20 frames of 300 stars, seed 1, widths 0.6, 0.8, 1,
    /// 1.5, 2 px, SNR 10-200, DSNU 0.25, PRNU 0.02, 2e-4 hot pixels, 250 e- dark, 5 e- read
    /// noise.
    pub fn full(work_dir: PathBuf) -> Self {
        Self {
            frames: 20,
            stars: 300,
            seed: 1,
            widths_a_px: vec![0.6, 0.8, 1.0, 1.5, 2.0],
            field_a_px: None,
            snr_range: [10.0, 200.0],
            dsnu: 0.25,
            prnu: 0.02,
            hot_fraction: 2e-4,
            dark_e: 250.0,
            read_noise_e: 5.0,
            work_dir,
        }
    }
}

/// What became of one true star in one configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StarOutcome {
    /// True width, px.
    pub a_px: f64,
    /// The width bin: the nearest of the experiment's widths, px.
    pub a_bin: f64,
    /// Eq. 8 SNR (5 x 5 box, mean dark and read noise).
    pub snr: f64,
    /// Another true star closer than [`CROWD_PX`].
    pub crowded: bool,
    /// The matched report, `None` when missed.
    pub record: Option<StarRecord>,
    /// Error (reported minus true), px, x and y.
    pub error_px: [f64; 2],
    /// Own Cramer-Rao bound, x and y, px.
    pub crlb_px: [f64; 2],
    /// Own width-unknown bound, x and y, px.
    pub crlb_width_free_px: [f64; 2],
}

impl StarOutcome {
    /// Matched with a clean position.
    pub fn used(&self) -> bool {
        self.record
            .is_some_and(|r| !r.flags.intersects(BAD_POSITION))
    }

    /// Matched, flagged `POOR_FIT` and nothing else of [`BAD_POSITION`].
    pub fn poor_fit_only(&self) -> bool {
        self.record
            .is_some_and(|r| (r.flags & BAD_POSITION) == StarFlags::POOR_FIT)
    }
}

/// The statistics of one width and SNR bin.
#[derive(Clone, Debug, PartialEq)]
pub struct BinStats {
    /// Configuration: `"no model"` or `"psf model"`.
    pub config: &'static str,
    /// True width, px.
    pub a_px: f64,
    /// SNR bin, lower and upper edge.
    pub snr: [f64; 2],
    /// Isolated true stars in the bin.
    pub stars: usize,
    /// Crowded stars left out.
    pub crowded: usize,
    /// Not found within [`MATCH_PX`].
    pub missed: usize,
    /// Matched, flagged [`BAD_POSITION`].
    pub bad: usize,
    /// Of the bad: flagged `POOR_FIT` and nothing else of [`BAD_POSITION`].
    pub poor_fit: usize,
    /// Used (matched, clean position).
    pub used: usize,
    /// Of the used: flagged `SIGMA_UNRELIABLE`.
    pub sigma_flagged: usize,
    /// RMS of error / own CRLB.
    pub rms_crlb: f64,
    /// RMS of error / own width-unknown bound.
    pub rms_crlb_width_free: f64,
    /// RMS of error / own CRLB over the used stars and the `poor_fit` ones (what a user who
    /// ignores `POOR_FIT` gets).
    pub rms_crlb_with_poor_fit: f64,
    /// RMS of error / reported sigma (all used).
    pub pull: f64,
    /// The pull of the used stars without `SIGMA_UNRELIABLE` (NaN when none).
    pub pull_clean: f64,
    /// Mean reported width of the used stars, px (0: the method does not report one).
    pub mean_psf_a_px: f64,
    /// Relative standard error of the RMS ratios.
    pub rel_se: f64,
}

/// The whole run: every star's outcome per configuration and the bins.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameMcRun {
    /// Outcomes without the model.
    pub no_model: Vec<StarOutcome>,
    /// Outcomes with the model.
    pub psf_model: Vec<StarOutcome>,
    /// The bins, no-model rows then model rows.
    pub bins: Vec<BinStats>,
    /// What `calib psf-model` printed about the model.
    pub model_note: String,
}

fn sim_args(mc: &FrameMc, seed: u64, out: PathBuf) -> SimulateArgs {
    SimulateArgs {
        out,
        seed,
        stars: mc.stars,
        dark_e: mc.dark_e,
        read_noise_e: mc.read_noise_e,
        dsnu: mc.dsnu,
        prnu: mc.prnu,
        psf_a_px: None,
        measured_frames: 0,
        mix: SceneMix {
            psf_a_list: if mc.field_a_px.is_some() {
                Vec::new()
            } else {
                mc.widths_a_px.clone()
            },
            psf_a_field: mc.field_a_px.map(|f| f.to_vec()).unwrap_or_default(),
            snr_range: mc.snr_range.to_vec(),
            hot_fraction: mc.hot_fraction,
        },
    }
}

/// `calib build` of the simulated truth maps and hot list, every other option at the
/// command's default.
pub fn build_args(f: &SimFiles, out: PathBuf, psf_model: Option<PathBuf>) -> CalibBuildArgs {
    CalibBuildArgs {
        bias: Some(f.bias.clone()),
        dark: Some(f.dark.clone()),
        flat: Some(f.flat.clone()),
        hot: Some(f.hot.clone()),
        psf_model,
        ..CalibBuildArgs::with_defaults(out)
    }
}

/// `process` with every option at its default.
pub fn process_args(frame: &Path, table: &Path) -> ProcessArgs {
    ProcessArgs {
        frame: frame.to_path_buf(),
        calib: table.to_path_buf(),
        method: None,
        window: None,
        psf_sigma: None,
        psf_a_px: None,
        exposure_s: None,
        temperature_k: None,
        background_stride: None,
        out: None,
    }
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> CliError + '_ {
    move |e| {
        LabError::Io {
            path: path.to_path_buf(),
            msg: e.to_string(),
        }
        .into()
    }
}

/// Builds the table of `files` (with `model` if given), processes the frame with defaults.
fn build_and_process(
    files: &SimFiles,
    dir: &Path,
    name: &str,
    model: Option<&Path>,
) -> Result<Vec<StarRecord>, CliError> {
    let table = dir.join(name);
    let (bytes, _) = build(&build_args(
        files,
        table.clone(),
        model.map(Path::to_path_buf),
    ))?;
    std::fs::write(&table, bytes).map_err(io_err(&table))?;
    Ok(measure(&process_args(&files.frame, &table))?.stars)
}

/// The truth rows of `truth.csv`: x, y, signal, a.
fn read_truth(path: &Path) -> Result<Vec<[f64; 4]>, CliError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    text.lines()
        .enumerate()
        .skip(1)
        .map(|(i, l)| {
            let v: Vec<f64> = l.split(',').filter_map(|x| x.parse().ok()).collect();
            match v.as_slice() {
                &[x, y, s, a] => Ok([x, y, s, a]),
                _ => Err(LabError::Csv {
                    path: path.to_path_buf(),
                    line: i + 1,
                    msg: "need x_px,y_px,signal_e,a_px".into(),
                }
                .into()),
            }
        })
        .collect()
}

/// The eq. 8 SNR (5 x 5 box, all the signal in it) of `signal_e` on per-pixel variance
/// `var_e2`: the inverse of [`startrack_analysis::accuracy::flux_for_snr`].
pub fn snr_of(signal_e: f64, var_e2: f64) -> f64 {
    signal_e / (signal_e + 25.0 * var_e2).sqrt()
}

/// Matches `records` to the truth of one frame and computes each star's bounds.
fn outcomes(
    truth: &[[f64; 4]],
    records: &[StarRecord],
    sim: &Simulator,
    mc: &FrameMc,
) -> Vec<StarOutcome> {
    let var = mc.dark_e + mc.read_noise_e * mc.read_noise_e;
    let g = sim.params.geometry;
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    truth
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let [x, y, signal, a] = *t;
            let crowded = truth
                .iter()
                .enumerate()
                .any(|(k, o)| k != i && (o[0] - x).hypot(o[1] - y) < CROWD_PX);
            let d = |r: &StarRecord| (f64::from(r.x_px) - x).hypot(f64::from(r.y_px) - y);
            let record = records
                .iter()
                .filter(|r| d(r) < MATCH_PX)
                .min_by(|p, q| d(p).total_cmp(&d(q)))
                .copied();
            let error_px =
                record.map_or([0.0; 2], |r| [f64::from(r.x_px) - x, f64::from(r.y_px) - y]);
            // The local background: the true dark's mean over the 9 x 9 window.
            let (cx, cy) = (x.round() as i64, y.round() as i64);
            let (mut sum, mut n) = (0.0, 0.0);
            for yy in (cy - 4)..=(cy + 4) {
                for xx in (cx - 4)..=(cx + 4) {
                    if (0..cols as i64).contains(&xx) && (0..rows as i64).contains(&yy) {
                        let col = g.raw_col_of_x(xx as usize);
                        sum += mc.dark_e * sim.dark_rel(col, yy as usize);
                        n += 1.0;
                    }
                }
            }
            let bg = if n > 0.0 { sum / n } else { mc.dark_e };
            let (fx, fy) = (4.0 + x - cx as f64, 4.0 + y - cy as f64);
            let s = sigma_of_a(a);
            let r = mc.read_noise_e;
            let a_bin = mc
                .widths_a_px
                .iter()
                .copied()
                .min_by(|p, q| (p - a).abs().total_cmp(&(q - a).abs()))
                .unwrap_or(a);
            StarOutcome {
                a_px: a,
                a_bin,
                snr: snr_of(signal, var),
                crowded,
                record,
                error_px,
                crlb_px: [
                    crlb_x_px(9, 9, fx, fy, s, signal, bg, r),
                    crlb_x_px(9, 9, fy, fx, s, signal, bg, r),
                ],
                crlb_width_free_px: [
                    crlb_x_width_free_px(9, 9, fx, fy, s, signal, bg, r),
                    crlb_x_width_free_px(9, 9, fy, fx, s, signal, bg, r),
                ],
            }
        })
        .collect()
}

/// Simulates frame `seed` into `dir`: its files, its truth and its simulator (for the
/// local dark).
fn simulate_frame(
    mc: &FrameMc,
    seed: u64,
    dir: &Path,
) -> Result<(SimFiles, Vec<[f64; 4]>, Simulator), CliError> {
    let args = sim_args(mc, seed, dir.to_path_buf());
    let files = crate::cli::simulate::run(&args)?;
    let truth = read_truth(&files.truth)?;
    let sim = Simulator::new(params(&args)?, Vec::new());
    Ok((files, truth, sim))
}

/// Runs the experiment: the model's frame first (seed `seed + frames`), then every frame in
/// both configurations.
pub fn run(mc: &FrameMc) -> Result<FrameMcRun, CliError> {
    if mc.frames == 0 || mc.widths_a_px.is_empty() {
        return Err(CliError::Usage(
            "need at least one frame and one width".into(),
        ));
    }
    std::fs::create_dir_all(&mc.work_dir).map_err(io_err(&mc.work_dir))?;
    // The field PSF model from one more frame, processed with defaults as a user would.
    let model_dir = mc.work_dir.join("model-frame");
    let (files, _, _) = simulate_frame(mc, mc.seed + mc.frames as u64, &model_dir)?;
    let stars = build_and_process(&files, &model_dir, "table.bin", None)?;
    let stars_csv = model_dir.join("stars.csv");
    let mut buf = Vec::new();
    write_csv(&mut buf, &stars).map_err(io_err(&stars_csv))?;
    std::fs::write(&stars_csv, buf).map_err(io_err(&stars_csv))?;
    let model = mc.work_dir.join("psf_model.json");
    let fit = run_psf_model(&PsfModelArgs {
        stars: vec![stars_csv],
        out: model.clone(),
        degree: 2,
    })?;
    let model_note = format!(
        "PSF model degree {} from {} stars ({} rejected), scatter {:.3} px",
        fit.degree, fit.stars, fit.rejected, fit.scatter_px
    );
    let _ = std::fs::remove_dir_all(&model_dir);

    let (mut no_model, mut with_model) = (Vec::new(), Vec::new());
    for f in 0..mc.frames {
        let dir = mc.work_dir.join(format!("frame-{f}"));
        let (files, truth, sim) = simulate_frame(mc, mc.seed + f as u64, &dir)?;
        let plain = build_and_process(&files, &dir, "table.bin", None)?;
        let modelled = build_and_process(&files, &dir, "table-model.bin", Some(&model))?;
        no_model.extend(outcomes(&truth, &plain, &sim, mc));
        with_model.extend(outcomes(&truth, &modelled, &sim, mc));
        let _ = std::fs::remove_dir_all(&dir);
    }
    let mut bins = stats("no model", &no_model, &mc.widths_a_px);
    bins.extend(stats("psf model", &with_model, &mc.widths_a_px));
    Ok(FrameMcRun {
        no_model,
        psf_model: with_model,
        bins,
        model_note,
    })
}

/// The bins of `outcomes`: per width of `widths`, per SNR bin of [`SNR_EDGES`].
pub fn stats(config: &'static str, outcomes: &[StarOutcome], widths: &[f64]) -> Vec<BinStats> {
    let mut out = Vec::new();
    for &a in widths {
        for e in SNR_EDGES.windows(2) {
            let &[lo, hi] = e else { continue };
            let last = hi == SNR_EDGES[SNR_EDGES.len() - 1];
            let in_bin = |o: &&StarOutcome| {
                o.a_bin == a && o.snr >= lo && (o.snr < hi || (last && o.snr <= hi))
            };
            let all: Vec<&StarOutcome> = outcomes.iter().filter(in_bin).collect();
            let isolated: Vec<&StarOutcome> = all.iter().copied().filter(|o| !o.crowded).collect();
            let used: Vec<&StarOutcome> = isolated.iter().copied().filter(|o| o.used()).collect();
            let with_poor: Vec<&StarOutcome> = isolated
                .iter()
                .copied()
                .filter(|o| o.used() || o.poor_fit_only())
                .collect();
            let rms_of = |set: &[&StarOutcome], f: &dyn Fn(&StarOutcome, usize) -> Option<f64>| {
                let v: Vec<f64> = set
                    .iter()
                    .flat_map(|o| (0..2).filter_map(|k| f(o, k)))
                    .collect();
                if v.is_empty() {
                    f64::NAN
                } else {
                    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
                }
            };
            let rms = |f: &dyn Fn(&StarOutcome, usize) -> Option<f64>| rms_of(&used, f);
            let sigma = |o: &StarOutcome, k: usize| {
                o.record
                    .map(|r| f64::from(if k == 0 { r.sigma_x_px } else { r.sigma_y_px }))
            };
            let flagged = |o: &StarOutcome| {
                o.record
                    .is_some_and(|r| r.flags.contains(StarFlags::SIGMA_UNRELIABLE))
            };
            let psf_sum: f64 = used
                .iter()
                .filter_map(|o| o.record.map(|r| f64::from(r.psf_a_px)))
                .sum();
            out.push(BinStats {
                config,
                a_px: a,
                snr: [lo, hi],
                stars: isolated.len(),
                crowded: all.len() - isolated.len(),
                missed: isolated.iter().filter(|o| o.record.is_none()).count(),
                bad: isolated
                    .iter()
                    .filter(|o| o.record.is_some() && !o.used())
                    .count(),
                poor_fit: isolated.iter().filter(|o| o.poor_fit_only()).count(),
                used: used.len(),
                sigma_flagged: used.iter().filter(|o| flagged(o)).count(),
                rms_crlb: rms(&|o, k| Some(o.error_px[k] / o.crlb_px[k])),
                rms_crlb_width_free: rms(&|o, k| Some(o.error_px[k] / o.crlb_width_free_px[k])),
                rms_crlb_with_poor_fit: rms_of(&with_poor, &|o, k| {
                    Some(o.error_px[k] / o.crlb_px[k])
                }),
                pull: rms(&|o, k| sigma(o, k).map(|s| o.error_px[k] / s)),
                pull_clean: rms(&|o, k| {
                    (!flagged(o)).then_some(())?;
                    sigma(o, k).map(|s| o.error_px[k] / s)
                }),
                mean_psf_a_px: if used.is_empty() {
                    f64::NAN
                } else {
                    psf_sum / used.len() as f64
                },
                rel_se: rms_relative_se(2 * used.len()),
            });
        }
    }
    out
}

/// The bins as CSV (one row per configuration, width and SNR bin).
pub fn csv(bins: &[BinStats]) -> String {
    let mut s = String::from(
        "config,a_px,snr_lo,snr_hi,stars,crowded,missed,bad,poor_fit,used,sigma_flagged,rms_crlb,rms_crlb_width_free,rms_crlb_with_poor_fit,pull,pull_clean,mean_psf_a_px,rel_se\n",
    );
    for b in bins {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
            b.config,
            b.a_px,
            b.snr[0],
            b.snr[1],
            b.stars,
            b.crowded,
            b.missed,
            b.bad,
            b.poor_fit,
            b.used,
            b.sigma_flagged,
            b.rms_crlb,
            b.rms_crlb_width_free,
            b.rms_crlb_with_poor_fit,
            b.pull,
            b.pull_clean,
            b.mean_psf_a_px,
            b.rel_se
        );
    }
    s
}

/// One bin as the docs' table cell text.
fn cell(b: &BinStats) -> String {
    let pct = |k: usize| 100.0 * k as f64 / b.stars.max(1) as f64;
    // No unflagged star, no pull of the rest.
    let clean = if b.pull_clean.is_nan() {
        String::new()
    } else {
        format!(" ({:.2})", b.pull_clean)
    };
    format!(
        "{:.2} / {:.2} / pull {:.2}, {:.0} % flagged{clean}; {} stars, {:.0} % poor fit ({:.2}), {:.0} % lost",
        b.rms_crlb,
        b.rms_crlb_width_free,
        b.pull,
        100.0 * b.sigma_flagged as f64 / b.used.max(1) as f64,
        b.stars,
        pct(b.poor_fit),
        b.rms_crlb_with_poor_fit,
        pct(b.missed + b.bad - b.poor_fit)
    )
}

/// The bins as a markdown table: one row per configuration and width, one column per SNR
/// bin; each cell `RMS/CRLB / RMS/width-unknown bound / pull, share of used stars flagged
/// SIGMA_UNRELIABLE (pull of the rest); isolated stars, share flagged POOR_FIT alone (RMS /
/// CRLB with them counted), share missed or flagged otherwise`.
pub fn markdown(bins: &[BinStats]) -> String {
    let mut s = String::from("| configuration | a | ");
    let heads: Vec<String> = SNR_EDGES
        .windows(2)
        .map(|e| format!("SNR {}-{}", e[0], e[1]))
        .collect();
    let _ = writeln!(s, "{} |", heads.join(" | "));
    let _ = writeln!(s, "|---|---|{}", "---|".repeat(heads.len()));
    for row in bins.chunks(heads.len()) {
        let Some(first) = row.first() else { continue };
        let cells: Vec<String> = row.iter().map(cell).collect();
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            first.config,
            first.a_px,
            cells.join(" | ")
        );
    }
    s
}

/// The bins of a CSV written by [`csv`] (the committed table's source); `None` on a row
/// that is not one of its rows.
pub fn from_csv(text: &str) -> Option<Vec<BinStats>> {
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            let f = |i: usize| v.get(i).and_then(|s| s.parse::<f64>().ok());
            let n = |i: usize| v.get(i).and_then(|s| s.parse::<usize>().ok());
            let config = match v.first().copied() {
                Some("no model") => "no model",
                Some("psf model") => "psf model",
                _ => return None,
            };
            Some(BinStats {
                config,
                a_px: f(1)?,
                snr: [f(2)?, f(3)?],
                stars: n(4)?,
                crowded: n(5)?,
                missed: n(6)?,
                bad: n(7)?,
                poor_fit: n(8)?,
                used: n(9)?,
                sigma_flagged: n(10)?,
                rms_crlb: f(11)?,
                rms_crlb_width_free: f(12)?,
                rms_crlb_with_poor_fit: f(13)?,
                pull: f(14)?,
                pull_clean: f(15)?,
                mean_psf_a_px: f(16)?,
                rel_se: f(17)?,
            })
        })
        .collect()
}
