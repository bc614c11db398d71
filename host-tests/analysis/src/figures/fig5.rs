//! Figure 5: the paper's dark non-uniformity experiment, with the core's calibration and
//! centroid code, and our improvement.
//!
//! # The experiment
//! A CCD47-20 with mean dark 250 e- per pixel and per-pixel relative dark `1 + DSNU N(0,1)`
//! (a fixed pattern), read noise 5 e-, no PRNU or column bias (so only the dark matters).
//! One star of 80 % radius [`Fig5Params::a_px`] per trial, at a random position over a
//! 128 x 128 region (so the trials see different dark patterns) and a random phase; its
//! signal is chosen so that eq. 8 gives `snr0` in the 5x5 box without DSNU
//! (`S = SNR^2/2 + sqrt(SNR^4/4 + SNR^2 25 (250 + 25))` in the box). A 7x7 window around the
//! star's pixel is rendered by the simulator (Poisson star and dark, read noise, ADC) and
//! calibrated by the core ([`FrameCalibration::calibrate_window`]) with each line's bias from
//! its over-scan ([`LineLevels::measure`]) and the frame's dark scale from the covered
//! columns of the window's lines ([`DarkScaleEstimator`]). Then the core's CoG (power 1 and
//! 2, 5x5 box on the brightest pixel) with the background from the mean of the window's
//! perimeter (the 24 border pixels), as the paper. A star is detected when the measured SNR
//! (eq. 8 with the perimeter's variance) exceeds 3 and the centroid is not degenerate; the
//! error is the RMS over detected trials of both axes, `sqrt(mean((dx^2+dy^2)/2))`.
//!
//! # The two methods (same rendered pixels, paired)
//! - `perimeter`: the paper's processing: the table has no dark map, so only a uniform dark
//!   comes off and the pattern stays in the pixels.
//! - `precalc`: the dark pre-calculation: the table carries a relative dark map measured from
//!   [`Fig5Params::dark_frames`] simulated dark frames ([`startrack_sim::sim::measured`]), the core
//!   subtracts `map x dark scale` per pixel, and the background is then known rather than
//!   measured: level 0 with the variance of dark shot noise, read noise and the map's own
//!   noise ([`Background::Given`]). The dark scale comes from the covered columns of
//!   `DARK_LINES` fixed lines, and the map is normalised to the covered pixels of the same
//!   lines (the firmware uses the whole frame for both). The perimeter's
//!   24 pixels would add their own level error (`25/24` of the background variance in the
//!   5x5 box's eq. 8 noise), which is what keeps `perimeter`'s measured SNR of an SNR-5 star
//!   near 3.5 even without DSNU (the `mean SNR` that `cargo test -p startrack-host --test
//!   figures_dark -- --nocapture` prints).
//!
//! Cost: ~1600 rendered samples per trial (49 window pixels, 48 reference elements on each of
//! `DARK_LINES` lines);
//! the measured maps cost `dark_frames x 128^2` samples per DSNU value.

use super::{Effort, FigureError, FigureFiles, Written, plot};
use indicatif::{ProgressBar, ProgressStyle};
use rand::{RngExt, SeedableRng};
use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::table::CalibTable;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::units::{Electrons, Kelvin};
use startrack_core::window::{Rect, Window};
use startrack_sim::sim::{SensorParams, Simulator, Star};
use std::path::Path;

/// Parameters of the experiment.
#[derive(Clone, Debug, PartialEq)]
pub struct Fig5Params {
    /// SNR without DSNU (eq. 8, 5x5 box).
    pub snr0: Vec<f64>,
    /// DSNU values (sigma / mean of the dark).
    pub dsnu: Vec<f64>,
    /// Trials (frames) per (snr0, dsnu) point.
    pub trials: usize,
    /// Dark frames averaged into the measured dark map.
    pub dark_frames: u32,
    /// 80 % radius of the star, px.
    pub a_px: f64,
    /// Seed of everything.
    pub seed: u64,
}

/// Mean dark, e- per pixel (the paper's 250).
pub const DARK_MEAN_E: f64 = 250.0;
/// Read noise, e-.
pub const READ_NOISE_E: f64 = 5.0;
/// Centroid box side.
pub const BOX_PX: u8 = 5;
/// Window side (box plus a one-pixel perimeter).
pub const WINDOW_PX: u16 = 7;
/// Detection threshold on the measured SNR (the paper's 3).
pub const DETECT_SNR: f32 = 3.0;
/// Lines whose covered columns give a trial's dark scale (1024 samples: its error, 0.5 e-
/// per pixel at 250 e-, adds ~2 % to the flux variance of an SNR-10 star in the 5x5 box).
const DARK_LINES: usize = 32;

/// The lines of the dark scale, the same for every trial and for the map's normalisation.
fn dark_lines() -> std::ops::Range<usize> {
    let y0 = usize::from(REGION_X0 + REGION_PX / 2) - DARK_LINES / 2;
    y0..y0 + DARK_LINES
}
/// Corner of the region the stars are spread over, px.
const REGION_X0: u16 = 400;
/// Side of that region, px.
const REGION_PX: u16 = 128;
/// First frame number of the dark frames (the trials use frames below it).
const DARK_FRAME0: u32 = 3_000_000_000;

impl Fig5Params {
    /// The paper's grid: SNR 3, 5, 10; DSNU 0..0.25 in steps of 0.05 (quick) or 0.025.
    pub fn for_effort(effort: Effort) -> Self {
        let (trials, step) = match effort {
            Effort::Quick => (300, 0.05f64),
            Effort::Full => (2000, 0.025),
        };
        let n = (0.25 / step).round() as usize;
        Self {
            snr0: vec![3.0, 5.0, 10.0],
            dsnu: (0..=n).map(|i| i as f64 * step).collect(),
            trials,
            dark_frames: 32,
            a_px: 1.5,
            seed: 5,
        }
    }
}

/// How the dark is handled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DarkMethod {
    /// The paper's: background from the window's perimeter only.
    Perimeter,
    /// Dark pre-calculated from the covered pixels and a measured relative dark map.
    Precalc,
}

impl DarkMethod {
    /// The CSV name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Perimeter => "perimeter",
            Self::Precalc => "precalc",
        }
    }
}

/// One point of Figure 5.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fig5Point {
    /// SNR without DSNU.
    pub snr0: f64,
    /// DSNU.
    pub dsnu: f64,
    /// CoG power.
    pub power: u8,
    /// Dark handling.
    pub method: DarkMethod,
    /// RMS error over detected trials, px (0 when none was detected).
    pub rms_px: f64,
    /// Fraction of trials detected.
    pub detect_rate: f64,
    /// Trials.
    pub trials: usize,
    /// Mean measured SNR over all trials.
    pub mean_snr: f64,
}

/// The experiment's result.
#[derive(Clone, Debug)]
pub struct Fig5Result {
    /// Its parameters.
    pub params: Fig5Params,
    /// Every (snr0, dsnu, power, method) point.
    pub points: Vec<Fig5Point>,
}

/// Star signal (total, e-) giving `snr0` in the 5x5 box by eq. 8 without DSNU, for a star
/// centred on a pixel.
pub fn signal_for_snr(snr0: f64, a_px: f64) -> f64 {
    let n2 = f64::from(BOX_PX) * f64::from(BOX_PX);
    let var = DARK_MEAN_E + READ_NOISE_E * READ_NOISE_E;
    let s_box = snr0 * snr0 / 2.0 + (snr0.powi(4) / 4.0 + snr0 * snr0 * n2 * var).sqrt();
    let s = startrack_sim::sim::psf::sigma_of_a(a_px);
    let h = f64::from(BOX_PX / 2);
    let f1: f64 = (-(h as i32)..=h as i32)
        .map(|i| startrack_sim::sim::psf::pixel_fraction(f64::from(i), 0.0, s))
        .sum();
    s_box / (f1 * f1)
}

/// The sensor of the experiment at `dsnu`.
pub fn sensor(dsnu: f64, seed: u64) -> SensorParams {
    SensorParams {
        seed,
        dark_mean_e: DARK_MEAN_E,
        read_noise_e: READ_NOISE_E,
        dsnu,
        prnu: 0.0,
        column_bias_sigma_adu: 0.0,
        ..SensorParams::default()
    }
}

#[derive(Default, Clone, Copy)]
struct Acc {
    sq: f64,
    detected: usize,
    snr_sum: f64,
}

/// Runs the experiment; `progress` draws a progress bar on stderr.
pub fn run(p: &Fig5Params, progress: bool) -> Fig5Result {
    let total = (p.dsnu.len() * p.snr0.len() * p.trials) as u64;
    let bar = if progress {
        let b = ProgressBar::new(total);
        if let Ok(style) =
            ProgressStyle::with_template("fig5/6 {bar:40} {pos}/{len} trials, eta {eta}")
        {
            b.set_style(style);
        }
        b
    } else {
        ProgressBar::hidden()
    };
    let mut points = Vec::new();
    for &dsnu in &p.dsnu {
        let params = sensor(dsnu, p.seed);
        let dark_sim = Simulator::new(params.clone(), Vec::new());
        let region = Rect {
            x0: REGION_X0,
            y0: REGION_X0,
            width: REGION_PX,
            height: REGION_PX,
        };
        let map = dark_sim
            .measure_dark_map(p.dark_frames, DARK_FRAME0, region, dark_lines())
            .ok();
        let bare_bytes = dark_sim.table_from_maps(false, None, None).ok();
        let pre_bytes = map
            .as_ref()
            .and_then(|m| dark_sim.table_from_maps(false, Some(&m.values), None).ok());
        let bare = bare_bytes
            .as_deref()
            .and_then(|b| CalibTable::parse(b).ok());
        let pre = pre_bytes.as_deref().and_then(|b| CalibTable::parse(b).ok());
        for (si, &snr0) in p.snr0.iter().enumerate() {
            let signal_e = signal_for_snr(snr0, p.a_px);
            // [method][power]
            let mut acc = [[Acc::default(); 2]; 2];
            for t in 0..p.trials {
                bar.inc(1);
                let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(p.seed ^ 0xF165);
                r.set_stream(((si as u64) << 32) | t as u64);
                let margin = f64::from(WINDOW_PX);
                let lo = f64::from(REGION_X0) + margin;
                let hi = f64::from(REGION_X0 + REGION_PX) - margin;
                let star = Star {
                    x_px: r.random_range(lo..hi),
                    y_px: r.random_range(lo..hi),
                    signal_e,
                    a_px: p.a_px,
                };
                let frame = (si * p.trials + t) as u32;
                let sim = Simulator {
                    frame,
                    ..Simulator::new(params.clone(), vec![star])
                };
                let methods = [(DarkMethod::Perimeter, &bare), (DarkMethod::Precalc, &pre)];
                for (mi, (method, table)) in methods.into_iter().enumerate() {
                    let Some(table) = table else { continue };
                    for (pi, power) in [CogPower::One, CogPower::Two].into_iter().enumerate() {
                        let Some(a) = acc.get_mut(mi).and_then(|m| m.get_mut(pi)) else {
                            continue;
                        };
                        if let Some((dx, dy, snr)) =
                            trial(&sim, &star, (method, table, p.dark_frames), power)
                        {
                            a.snr_sum += snr;
                            if snr > f64::from(DETECT_SNR) {
                                a.detected += 1;
                                a.sq += 0.5 * (dx * dx + dy * dy);
                            }
                        }
                    }
                }
            }
            for (mi, method) in [DarkMethod::Perimeter, DarkMethod::Precalc]
                .into_iter()
                .enumerate()
            {
                for (pi, power) in [1u8, 2].into_iter().enumerate() {
                    let a = acc
                        .get(mi)
                        .and_then(|m| m.get(pi))
                        .copied()
                        .unwrap_or_default();
                    points.push(Fig5Point {
                        snr0,
                        dsnu,
                        power,
                        method,
                        rms_px: if a.detected == 0 {
                            0.0
                        } else {
                            (a.sq / a.detected as f64).sqrt()
                        },
                        detect_rate: a.detected as f64 / p.trials.max(1) as f64,
                        trials: p.trials,
                        mean_snr: a.snr_sum / p.trials.max(1) as f64,
                    });
                }
            }
        }
    }
    bar.finish_and_clear();
    Fig5Result {
        params: p.clone(),
        points,
    }
}

/// One trial: render, calibrate with `table`, centroid; (dx, dy, measured SNR), with SNR 0
/// for a degenerate centroid; `None` if the window could not be calibrated.
fn trial(
    sim: &Simulator,
    star: &Star,
    (method, table, dark_frames): (DarkMethod, &CalibTable<'_>, u32),
    power: CogPower,
) -> Option<(f64, f64, f64)> {
    let g = sim.params.geometry;
    let (rect, _) = Rect::centred_clipped(
        star.x_px.round() as u16,
        star.y_px.round() as u16,
        WINDOW_PX,
        g.active_cols,
        g.active_rows,
    );
    let raw = sim.render_window(rect);
    let mut line = vec![0u16; g.line_len()];
    let mut levels = Vec::with_capacity(usize::from(rect.height));
    let mut est = DarkScaleEstimator::new();
    // The dark scale from the covered columns of the DARK_LINES lines the map is normalised
    // to (the firmware uses the whole frame; see the module docs).
    for y in dark_lines() {
        sim.render_reference_line(y, &mut line);
        let lv = LineLevels::measure(&g, &line).ok()?;
        est.add_line(table, &line, &lv).ok()?;
    }
    for y in rect.y0..rect.y0 + rect.height {
        sim.render_reference_line(usize::from(y), &mut line);
        levels.push(LineLevels::measure(&g, &line).ok()?);
    }
    let dark_scale_e = est.estimate().unwrap_or(Electrons::ZERO);
    let cal = FrameCalibration::new(
        *table,
        FrameConditions {
            dark_scale_e,
            exposure_ms: 1000,
            temperature_k: Kelvin::from_num(293),
        },
    );
    let mut e = vec![Electrons::ZERO; rect.len()];
    let mut f = vec![PixelFlags::empty(); rect.len()];
    cal.calibrate_window(rect, &raw, &levels, &mut e, &mut f)
        .ok()?;
    let background = match method {
        DarkMethod::Perimeter => Background::PerimeterMean,
        DarkMethod::Precalc => {
            // Dark shot noise at this frame's dark level, read noise, and the measured map's
            // own noise (per pixel, relative sqrt((dark + read^2) / N) / dark).
            let d = dark_scale_e.to_num::<f64>().max(0.0);
            let r2 = sim.params.read_noise_e * sim.params.read_noise_e;
            let map_var = (d + r2) / f64::from(dark_frames.max(1));
            Background::Given {
                level_e: 0.0,
                variance_e2: (d + r2 + map_var) as f32,
            }
        }
    };
    let w = Window::new(rect, &e)?;
    let c = cog(
        &CentroidInput::new(w).with_pixel_flags(&f),
        &CogParams {
            power,
            box_side: BOX_PX,
            anchor: Anchor::Peak,
            background,
        },
    );
    if c.flags.contains(CentroidFlags::DEGENERATE) {
        return Some((0.0, 0.0, 0.0));
    }
    Some((
        f64::from(c.x_px) - star.x_px,
        f64::from(c.y_px) - star.y_px,
        f64::from(c.snr),
    ))
}

/// The CSV header lines of Figures 5 and 6.
pub fn header(p: &Fig5Params) -> Vec<String> {
    vec![
        format!(
            "dark non-uniformity experiment: mean dark {DARK_MEAN_E} e-, read noise {READ_NOISE_E} e-, relative dark 1 + DSNU N(0,1), no PRNU, no column bias"
        ),
        format!(
            "star a = {} px at a random position and phase over a {REGION_PX} px square region; signal from eq. 8 with n = {BOX_PX}: {}",
            p.a_px,
            p.snr0
                .iter()
                .map(|s| format!("SNR {s} -> {:.1} e-", signal_for_snr(*s, p.a_px)))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        format!(
            "core calibration (over-scan bias, covered-column dark scale), core CoG {BOX_PX}x{BOX_PX} box on the peak in a {WINDOW_PX}x{WINDOW_PX} window"
        ),
        format!(
            "detected: measured SNR (eq. 8) > {DETECT_SNR}; rms_px over detected trials, sqrt(mean((dx^2+dy^2)/2)); {} trials per point, seed {}",
            p.trials, p.seed
        ),
        format!(
            "perimeter: no dark map (the paper), background from the perimeter; precalc: relative dark map measured from {} simulated dark frames, subtracted as map x covered dark scale ({DARK_LINES} lines), background known (0 e-, variance dark + read^2 + map noise)",
            p.dark_frames
        ),
    ]
}

/// Writes fig5.csv and fig5.png.
pub fn write(out: &Path, res: &Fig5Result, written: &mut Written) -> Result<(), FigureError> {
    let lines: Vec<String> = res
        .points
        .iter()
        .map(|q| {
            format!(
                "{},{:.3},{},{},{:.6},{:.6}",
                q.snr0,
                q.dsnu,
                q.power,
                q.method.name(),
                q.rms_px,
                q.detect_rate
            )
        })
        .collect();
    let mut header = header(&res.params);
    header.insert(
        0,
        "Figure 5: centroid error against dark non-uniformity".into(),
    );
    FigureFiles {
        number: 5,
        header,
        columns: "snr0,dsnu,power,method,rms_px,detect_rate",
        rows: lines,
        chart: plot::Chart {
            title: "Fig. 5: position error vs DSNU (perimeter = paper, precalc = ours)".into(),
            x_label: "DSNU (dark sigma / mean)".into(),
            y_label: "RMS error, px".into(),
            log_x: false,
            log_y: true,
        },
        series: dsnu_series(res, &[1, 2], |q| q.rms_px),
    }
    .write(out, written)
}

/// The curves of Figures 5 and 6: `y` of each point against its DSNU, one curve per
/// (method, SNR, CoG power in `powers`), in that nesting order. Colour: SNR and power;
/// solid: the paper's perimeter; dashed: our precalc. The power is in the label only when
/// `powers` has more than one.
pub fn dsnu_series(res: &Fig5Result, powers: &[u8], y: fn(&Fig5Point) -> f64) -> Vec<plot::Series> {
    let mut series = Vec::new();
    for method in [DarkMethod::Perimeter, DarkMethod::Precalc] {
        for (si, &snr0) in res.params.snr0.iter().enumerate() {
            for (pi, &power) in powers.iter().enumerate() {
                let label = if powers.len() > 1 {
                    format!("SNR {snr0}, pow {power}, {}", method.name())
                } else {
                    format!("SNR {snr0}, {}", method.name())
                };
                series.push(plot::Series {
                    label,
                    points: res
                        .points
                        .iter()
                        .filter(|q| q.method == method && q.snr0 == snr0 && q.power == power)
                        .map(|q| (q.dsnu, y(q)))
                        .collect(),
                    color: powers.len() * si + pi,
                    dashed: method == DarkMethod::Precalc,
                });
            }
        }
    }
    series
}
