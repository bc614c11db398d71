//! The end-to-end demo on the simulated sensor: simulate a CCD47-20 frame of a star field,
//! stream it line by line through the core's level measurement, calibrate a window around
//! each star, and compare with the simulator's truth.
//!
//! Stars are found by the core's streaming detector on the calibrated lines; each detected
//! star's window is centred on its brightest pixel, as on the MCU.

use crate::sim::truth::TruthSections;
use crate::sim::{SensorParams, Simulator, Star};
use rand::{RngExt, SeedableRng};
use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::detect::{DetectConfig, Detection, DetectionFlags, LineDetector};
use startrack_core::table::CalibTable;
use startrack_core::units::{Electrons, Kelvin};
use startrack_core::window::Rect;

/// Window side, px.
pub const WINDOW_PX: u16 = 7;
/// Candidate list capacity on the host (the firmware keeps 32): room for any demo field, so
/// that a miss is a detection miss, not a full list; losses are still counted.
pub const MAX_CANDIDATES: usize = 1024;
/// A detection within this distance of a simulated star is that star, px.
pub const MATCH_PX: f64 = 2.0;

/// What the demo measured for one star.
#[derive(Clone, Debug)]
pub struct StarReport {
    /// The star as simulated.
    pub star: Star,
    /// What the detector found there.
    pub detection: Detection,
    /// The window calibrated around it.
    pub rect: Rect,
    /// True star electrons in the window (before the flat: what calibration must recover).
    pub true_flux_e: f64,
    /// Window sum with every correction, e-.
    pub flux_e: f64,
    /// Window sum with gains and over-scan bias only, e-.
    pub flux_gains_only_e: f64,
    /// Sum over the window of (calibrated - truth)^2 / expected noise variance.
    pub chi2: f64,
    /// The same with gains and over-scan bias only.
    pub chi2_gains_only: f64,
    /// Flags raised by calibration.
    pub flags: PixelFlags,
}

/// What the demo measured.
#[derive(Clone, Debug)]
pub struct DemoReport {
    /// Per star.
    pub stars: Vec<StarReport>,
    /// Dark scale measured on the covered columns, e-.
    pub dark_scale_e: f64,
    /// The simulator's true mean covered dark, e-.
    pub true_dark_scale_e: f64,
    /// Mean bias level measured per output over all lines, ADU.
    pub mean_bias_adu: [f64; 2],
    /// Pixels calibrated in total (in the star windows).
    pub pixels: usize,
    /// Simulated stars the detector did not find.
    pub missed: usize,
    /// Simulated stars merged with a neighbour into one detection flagged blended.
    pub in_blends: usize,
    /// Detections with no simulated star within [`MATCH_PX`].
    pub false_detections: usize,
    /// Candidates lost because the list was full.
    pub dropped: u32,
}

impl DemoReport {
    /// chi^2 per pixel of all windows: about 1 when calibration leaves only noise.
    pub fn chi2_per_pixel(&self, gains_only: bool) -> f64 {
        let sum: f64 = self
            .stars
            .iter()
            .map(|s| {
                if gains_only {
                    s.chi2_gains_only
                } else {
                    s.chi2
                }
            })
            .sum();
        sum / self.pixels as f64
    }
}

/// A seeded star field kept clear of the edges.
pub fn star_field(seed: u64, n: usize, params: &SensorParams) -> Vec<Star> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5354_4152);
    let g = params.geometry;
    let margin = 20.0;
    (0..n)
        .map(|_| Star {
            x_px: r.random_range(margin..f64::from(g.active_cols) - margin),
            y_px: r.random_range(margin..f64::from(g.active_rows) - margin),
            signal_e: 10f64.powf(r.random_range(3.7..5.3)),
            a_px: r.random_range(0.8..2.0),
        })
        .collect()
}

/// Runs the demo: `n_stars` stars on the default sensor with `seed`.
pub fn run(seed: u64, n_stars: usize) -> Result<DemoReport, String> {
    let params = SensorParams {
        seed,
        ..SensorParams::default()
    };
    let stars = star_field(seed, n_stars, &params);
    let sim = Simulator::new(params.clone(), stars.clone());
    let g = params.geometry;
    let full = sim
        .truth_table(TruthSections::ALL)
        .map_err(|e| e.to_string())?;
    let bare = sim
        .truth_table(TruthSections::NONE)
        .map_err(|e| e.to_string())?;
    let full = CalibTable::parse(&full).map_err(|e| e.to_string())?;
    let bare = CalibTable::parse(&bare).map_err(|e| e.to_string())?;

    // Scan pass: every line streams through the level measurement, as on the MCU.
    let mut line = vec![0u16; g.line_len()];
    let mut levels = Vec::with_capacity(usize::from(g.lines));
    let mut raw_lines = Vec::with_capacity(usize::from(g.lines));
    let (mut est_full, mut est_bare) = (DarkScaleEstimator::new(), DarkScaleEstimator::new());
    let mut bias_sum = [0.0; 2];
    for y in 0..usize::from(g.lines) {
        sim.render_line(y, &mut line);
        let lv = LineLevels::measure(&g, &line).map_err(|e| e.to_string())?;
        est_full
            .add_line(&full, &line, &lv)
            .map_err(|e| e.to_string())?;
        est_bare
            .add_line(&bare, &line, &lv)
            .map_err(|e| e.to_string())?;
        for (s, b) in bias_sum.iter_mut().zip(lv.bias_adu) {
            *s += b.to_num::<f64>();
        }
        levels.push(lv);
        raw_lines.push(line.clone());
    }
    let cond = |est: &DarkScaleEstimator| FrameConditions {
        dark_scale_e: est.estimate().unwrap_or(Electrons::ZERO),
        exposure_ms: 1000,
        temperature_k: Kelvin::from_num(293),
    };
    let cal_full = FrameCalibration::new(full, cond(&est_full));
    let cal_bare = FrameCalibration::new(bare, cond(&est_bare));

    // Detection pass: each active line calibrated and streamed through the detector. (The
    // dark scale is this frame's, measured above; the firmware uses the previous frame's.)
    let mut detector =
        LineDetector::<MAX_CANDIDATES>::new(DetectConfig::default(), g.active_cols, g.active_rows);
    let mut e_line = vec![Electrons::ZERO; usize::from(g.active_cols)];
    let mut f_line = vec![PixelFlags::empty(); e_line.len()];
    for (y, (raw, lv)) in raw_lines
        .iter()
        .zip(&levels)
        .enumerate()
        .take(usize::from(g.active_rows))
    {
        cal_full
            .calibrate_span(y as u16, 0, raw, lv, &mut e_line, &mut f_line)
            .map_err(|e| e.to_string())?;
        detector
            .push_line(y as u16, &e_line, &f_line)
            .map_err(|e| e.to_string())?;
    }
    detector.finish();
    let near = |d: &Detection, s: &Star| {
        (f64::from(d.x_px) - s.x_px).hypot(f64::from(d.y_px) - s.y_px) < MATCH_PX
    };
    let false_detections = detector
        .candidates()
        .iter()
        .filter(|d| !stars.iter().any(|s| near(d, s)))
        .count();

    let mut reports = Vec::new();
    let mut pixels = 0;
    let (mut missed, mut in_blends) = (0, 0);
    for star in &stars {
        let Some(det) = detector
            .candidates()
            .iter()
            .find(|d| near(d, star))
            .copied()
        else {
            // A star merged with a neighbour into one flagged blob is accounted for.
            let blend = detector.candidates().iter().any(|d| {
                d.flags.contains(DetectionFlags::BLENDED)
                    && (f64::from(d.x_px) - star.x_px).hypot(f64::from(d.y_px) - star.y_px)
                        < 3.0 * MATCH_PX
            });
            if blend {
                in_blends += 1;
            } else {
                missed += 1;
            }
            continue;
        };
        let (rect, _) = Rect::centred_clipped(
            det.peak_x,
            det.peak_y,
            WINDOW_PX,
            g.active_cols,
            g.active_rows,
        );
        let raw = sim.render_window(rect);
        let lv = &levels[usize::from(rect.y0)..usize::from(rect.y0 + rect.height)];
        let calibrate = |cal: &FrameCalibration<'_>| {
            let mut e = vec![Electrons::ZERO; rect.len()];
            let mut f = vec![PixelFlags::empty(); rect.len()];
            cal.calibrate_window(rect, &raw, lv, &mut e, &mut f)
                .map(|flags| (e, flags))
        };
        let (e_full, flags) = calibrate(&cal_full).map_err(|e| e.to_string())?;
        let (e_bare, _) = calibrate(&cal_bare).map_err(|e| e.to_string())?;
        let mut r = StarReport {
            star: *star,
            detection: det,
            rect,
            true_flux_e: 0.0,
            flux_e: 0.0,
            flux_gains_only_e: 0.0,
            chi2: 0.0,
            chi2_gains_only: 0.0,
            flags,
        };
        for (i, (ef, eb)) in e_full.iter().zip(&e_bare).enumerate() {
            let x = usize::from(rect.x0) + i % usize::from(rect.width);
            let y = usize::from(rect.y0) + i / usize::from(rect.width);
            let truth = sim.star_e(x, y);
            let var = expected_variance(&sim, x, y, truth);
            let (ef, eb) = (ef.to_num::<f64>(), eb.to_num::<f64>());
            r.true_flux_e += truth;
            r.flux_e += ef;
            r.flux_gains_only_e += eb;
            r.chi2 += (ef - truth).powi(2) / var;
            r.chi2_gains_only += (eb - truth).powi(2) / var;
        }
        pixels += rect.len();
        reports.push(r);
    }
    Ok(DemoReport {
        stars: reports,
        dark_scale_e: est_full.estimate().map_or(0.0, |v| v.to_num()),
        true_dark_scale_e: params.dark_mean_e * sim.covered_dark_mean(),
        mean_bias_adu: bias_sum.map(|s| s / f64::from(g.lines)),
        pixels,
        missed,
        in_blends,
        false_detections,
        dropped: detector.dropped(),
    })
}

/// Noise variance of a perfectly calibrated pixel, e-^2: photon, dark and read noise through
/// the flat, ADC rounding, and the relative dark map's 1/64 quantisation.
fn expected_variance(sim: &Simulator, x: usize, y: usize, star_e: f64) -> f64 {
    let p = &sim.params;
    let g = p.geometry;
    let col = g.raw_col_of_x(x);
    let flat = sim.flat(x, y);
    let gain = p.gain_e_per_adu[usize::from(g.output_of_col(col).0)];
    let dark = p.dark_mean_e * sim.dark_rel(col, y);
    let shot_read = star_e * flat + dark + p.read_noise_e.powi(2) + gain * gain / 12.0;
    let map_q = (p.dark_mean_e / 64.0).powi(2) / 12.0;
    shot_read / (flat * flat) + map_q
}

/// Prints the report as a table.
pub fn print(report: &DemoReport) {
    println!(
        "startrack demo: simulated CCD47-20 frame (1072 x 1033 raw, both outputs), {} stars",
        report.stars.len() + report.missed + report.in_blends
    );
    println!(
        "bias from over-scan: output 0 {:.2} ADU, output 1 {:.2} ADU; dark scale from covered columns {:.2} e- (true {:.2} e-)",
        report.mean_bias_adu[0],
        report.mean_bias_adu[1],
        report.dark_scale_e,
        report.true_dark_scale_e
    );
    println!(
        "detection (streaming, calibrated lines): {} found, {} in flagged blends, {} missed, {} false, {} lost to a full list; windows {WINDOW_PX}x{WINDOW_PX} on the peaks",
        report.stars.len(),
        report.in_blends,
        report.missed,
        report.false_detections,
        report.dropped
    );
    println!(
        "{:>8} {:>8} {:>5} {:>8} {:>8} {:>6} {:>10} {:>10} {:>8} {:>12} {:>8}",
        "true_x",
        "true_y",
        "a_px",
        "det_x",
        "det_y",
        "snr",
        "true_e",
        "calib_e",
        "chi2/px",
        "gains_only_e",
        "chi2/px"
    );
    for s in &report.stars {
        let n = s.rect.len() as f64;
        println!(
            "{:>8.2} {:>8.2} {:>5.2} {:>8.2} {:>8.2} {:>6.0} {:>10.0} {:>10.0} {:>8.2} {:>12.0} {:>8.2}",
            s.star.x_px,
            s.star.y_px,
            s.star.a_px,
            s.detection.x_px,
            s.detection.y_px,
            s.detection.snr,
            s.true_flux_e,
            s.flux_e,
            s.chi2 / n,
            s.flux_gains_only_e,
            s.chi2_gains_only / n
        );
    }
    println!(
        "chi2 per pixel against truth: full calibration {:.3} (1.0 = noise only), gains and over-scan only {:.3}",
        report.chi2_per_pixel(false),
        report.chi2_per_pixel(true)
    );
}
