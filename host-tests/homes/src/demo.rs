//! The end-to-end demo on the simulated sensor: simulate a CCD47-20 frame of a star field,
//! run it through the core's tracker application as `startrack process` does (a standby
//! frame for the dark scale, then an acquisition frame: over-scan levels, covered-column
//! dark scale, the pre-filtered streaming detection, a centroid on a window at each star's
//! peak) and compare with the simulator's truth: calibrated electrons (chi^2 per pixel,
//! with full calibration and with gains and over-scan only) and centroid positions (RMS
//! error against the reported sigmas). With the sky scene ([`DemoScene::Sky`], `startrack
//! demo --sky`) the frame holds the catalog's stars at a seeded attitude, and the star list
//! also goes through the core's attitude stage: the printout ends with the attitude's error
//! against the truth.

use crate::home::frame_levels;
use crate::home::{HOST_CAPACITY, process_frame};
use rand::{RngExt, SeedableRng};
use startrack_core::calib::{FrameCalibration, FrameConditions, PixelFlags};
use startrack_core::table::CalibTable;
use startrack_core::tracker::{StarFlags, StarRecord, TrackerConfig};
use startrack_core::units::Electrons;
use startrack_core::window::Rect;
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator, Star};

/// A reported star within this distance of a simulated star is that star, px.
pub const MATCH_PX: f64 = 2.0;
/// The PSF width the demo's tracker is configured with, px: `a` at the middle of the
/// field's a = 0.8..2.0 px (sigma 0.78 px).
pub const PSF_A_PX: f32 = 1.4;

/// The demo's tracker configuration: the flight one, room for every star, the field's
/// middle PSF width.
pub fn tracker_config() -> TrackerConfig {
    TrackerConfig {
        max_stars: HOST_CAPACITY as u16,
        psf_a_px: PSF_A_PX,
        ..TrackerConfig::FLIGHT
    }
}

/// What the demo measured for one star.
#[derive(Clone, Debug)]
pub struct StarReport {
    /// The star as simulated.
    pub star: Star,
    /// The tracker's record of it.
    pub record: StarRecord,
    /// The centroid window around it, calibrated here for the comparison with the truth.
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

impl StarReport {
    /// Centroid minus true position (x, y), px.
    pub fn error_px(&self) -> (f64, f64) {
        (
            f64::from(self.record.x_px) - self.star.x_px,
            f64::from(self.record.y_px) - self.star.y_px,
        )
    }

    /// True when the star carries no flag at all (no blend, saturation, clipping,
    /// convergence or defect caveat on its position or sigma).
    pub fn clean(&self) -> bool {
        self.record.flags.is_empty()
    }
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
    /// Simulated stars the tracker did not report.
    pub missed: usize,
    /// Simulated stars merged with a neighbour into one star flagged blended.
    pub in_blends: usize,
    /// Reported stars with no simulated star within [`MATCH_PX`].
    pub false_detections: usize,
    /// Candidates lost because the list was full.
    pub dropped: u32,
    /// The attitude stage's result against the truth (sky scene only).
    pub attitude: Option<crate::sil::AttitudeCheck>,
}

/// What the demo's frame shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DemoScene {
    /// This many seeded random stars (3.7 <= log10 e- < 5.3, a = 0.8..2.0 px).
    Random(usize),
    /// The on-board catalog's stars seen by the 15 degree camera at a seeded random attitude,
    /// PSF `a` = [`PSF_A_PX`].
    Sky,
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

    /// Stars with an unflagged centroid.
    pub fn clean_stars(&self) -> impl Iterator<Item = &StarReport> {
        self.stars.iter().filter(|s| s.clean())
    }

    /// RMS over unflagged stars of the centroid error per axis, px.
    pub fn centroid_rms_px(&self) -> f64 {
        let (sum, n) = self.clean_stars().fold((0.0, 0usize), |(a, n), s| {
            let (ex, ey) = s.error_px();
            (a + ex * ex + ey * ey, n + 2)
        });
        if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
    }

    /// RMS over the same stars of the reported sigmas, px: what the error should be.
    pub fn reported_sigma_rms_px(&self) -> f64 {
        let (sum, n) = self.clean_stars().fold((0.0, 0usize), |(a, n), s| {
            let (sx, sy) = (
                f64::from(s.record.sigma_x_px),
                f64::from(s.record.sigma_y_px),
            );
            (a + sx * sx + sy * sy, n + 2)
        });
        if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
    }

    /// Sum over unflagged stars and both axes of (error / reported sigma)^2, and its number
    /// of terms: chi^2 with that many degrees of freedom when the sigmas are right.
    pub fn centroid_chi2(&self) -> (f64, usize) {
        self.clean_stars().fold((0.0, 0), |(a, n), s| {
            let (ex, ey) = s.error_px();
            let (sx, sy) = (
                f64::from(s.record.sigma_x_px),
                f64::from(s.record.sigma_y_px),
            );
            (a + (ex / sx).powi(2) + (ey / sy).powi(2), n + 2)
        })
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

/// The whole raw frame of `sim`, row-major.
pub fn render_frame(sim: &Simulator) -> Vec<u16> {
    let g = sim.params.geometry;
    let mut raw = vec![0u16; usize::from(g.lines) * g.line_len()];
    for (y, line) in raw.chunks_exact_mut(g.line_len()).enumerate() {
        sim.render_line(y, line);
    }
    raw
}

/// Runs the demo: `n_stars` stars on the default sensor with `seed`.
pub fn run(seed: u64, n_stars: usize) -> Result<DemoReport, String> {
    run_scene(seed, DemoScene::Random(n_stars))
}

/// Runs the demo on `scene` with `seed`.
pub fn run_scene(seed: u64, scene: DemoScene) -> Result<DemoReport, String> {
    use startrack_core::solver::{Solver, SolverConfig};
    let params = SensorParams {
        seed,
        ..SensorParams::default()
    };
    let catalog_bytes = match scene {
        DemoScene::Sky => startrack_sim::sky::scene::committed_catalog()?,
        DemoScene::Random(_) => Vec::new(),
    };
    let sky = match scene {
        DemoScene::Sky => {
            let cat = startrack_core::catalog::Catalog::parse(&catalog_bytes)
                .map_err(|e| format!("catalog: {e}"))?;
            let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x534b_5900);
            let q = startrack_sim::sky::field::random_attitude(&mut r);
            Some((
                cat,
                startrack_sim::sky::scene::SkyScene::ccd47_15deg(q, [0.0; 3]),
            ))
        }
        DemoScene::Random(_) => None,
    };
    let stars = match (&sky, scene) {
        (Some((cat, sc)), _) => sc.stars(cat, 0, f64::from(PSF_A_PX)),
        (None, DemoScene::Random(n)) => star_field(seed, n, &params),
        (None, DemoScene::Sky) => Vec::new(),
    };
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
    let raw = render_frame(&sim);

    let config = tracker_config();
    let result = process_frame(full, &raw, config, None)?;
    // The windows calibrated again, with every correction and with gains and over-scan
    // only, to show what the maps are worth.
    let levels_full = frame_levels(&full, &raw).map_err(|e| e.to_string())?;
    let levels_bare = frame_levels(&bare, &raw).map_err(|e| e.to_string())?;
    let conditions = |dark: Option<Electrons>, table: &CalibTable<'_>| FrameConditions {
        dark_scale_e: dark.unwrap_or(Electrons::ZERO),
        exposure_ms: config.exposure_ms,
        temperature_k: table.hot_pixels().reference_temperature_k(),
    };
    let cal_full = FrameCalibration::new(full, conditions(levels_full.dark_scale_e, &full));
    let cal_bare = FrameCalibration::new(bare, conditions(levels_bare.dark_scale_e, &bare));

    let mut bias_sum = [0.0; 2];
    for lv in &levels_full.lines {
        for (s, b) in bias_sum.iter_mut().zip(lv.bias_adu) {
            *s += b.to_num::<f64>();
        }
    }
    let dist =
        |r: &StarRecord, s: &Star| (f64::from(r.x_px) - s.x_px).hypot(f64::from(r.y_px) - s.y_px);
    let false_detections = result
        .stars
        .iter()
        .filter(|r| !stars.iter().any(|s| dist(r, s) < MATCH_PX))
        .count();

    let mut reports = Vec::new();
    let mut pixels = 0;
    let (mut missed, mut in_blends) = (0, 0);
    for star in &stars {
        let Some(record) = result
            .stars
            .iter()
            .find(|r| dist(r, star) < MATCH_PX)
            .copied()
        else {
            // A star merged with a neighbour into one flagged blob is accounted for.
            let blend = result.stars.iter().any(|r| {
                r.flags.contains(StarFlags::DETECT_BLENDED) && dist(r, star) < 3.0 * MATCH_PX
            });
            if blend {
                in_blends += 1;
            } else {
                missed += 1;
            }
            continue;
        };
        let (rect, _) = Rect::centred_clipped(
            record.x_px.round().clamp(0.0, f32::from(g.active_cols - 1)) as u16,
            record.y_px.round().clamp(0.0, f32::from(g.active_rows - 1)) as u16,
            config.window_px,
            g.active_cols,
            g.active_rows,
        );
        let (e_full, _, flags) = levels_full
            .calibrate_window(&cal_full, &raw, rect)
            .map_err(|e| e.to_string())?;
        let (e_bare, _, _) = levels_bare
            .calibrate_window(&cal_bare, &raw, rect)
            .map_err(|e| e.to_string())?;
        let mut r = StarReport {
            star: *star,
            record,
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
        dark_scale_e: result.summary.dark_scale_e.map_or(0.0, |v| v.to_num()),
        true_dark_scale_e: params.dark_mean_e * sim.covered_dark_mean(),
        mean_bias_adu: bias_sum.map(|s| s / f64::from(g.lines)),
        pixels,
        missed,
        in_blends,
        false_detections,
        dropped: result.summary.candidates_dropped,
        attitude: sky.map(|(cat, sc)| {
            let mut solver = Solver::new(
                cat,
                SolverConfig::for_camera(sc.camera, crate::sil::SOLVER_SIGMA_PX),
            );
            crate::sil::AttitudeCheck {
                t_mid_s: 0.0,
                truth: sc.attitude(0),
                true_rate_rad_s: [0.0; 3],
                fix: solver.update(&result.stars, 0),
                report: None,
                true_time_s: None,
                identified: 0,
            }
        }),
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
        "detection (the tracker's acquisition frame): {} found, {} in flagged blends, {} missed, {} false, {} lost to a full list; {w}x{w} windows on the peaks",
        report.stars.len(),
        report.in_blends,
        report.missed,
        report.false_detections,
        report.dropped,
        w = tracker_config().window_px
    );
    println!(
        "{:>8} {:>8} {:>5} {:>8} {:>8} {:>6} {:>10} {:>10} {:>8} {:>12} {:>8}",
        "true_x",
        "true_y",
        "a_px",
        "cen_x",
        "cen_y",
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
            "{:>8.3} {:>8.3} {:>5.2} {:>8.3} {:>8.3} {:>6.0} {:>10.0} {:>10.0} {:>8.2} {:>12.0} {:>8.2}",
            s.star.x_px,
            s.star.y_px,
            s.star.a_px,
            s.record.x_px,
            s.record.y_px,
            s.record.snr,
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
    let (chi2, dof) = report.centroid_chi2();
    let c = tracker_config();
    let w = c.window_px;
    println!(
        "centroids ({}, a {} px, {w}x{w}) on {} unflagged stars: RMS error {:.4} px per axis, reported sigma RMS {:.4} px, chi2/dof {:.2}",
        c.acquisition_method.name(),
        c.psf_a_px,
        report.clean_stars().count(),
        report.centroid_rms_px(),
        report.reported_sigma_rms_px(),
        if dof == 0 { 0.0 } else { chi2 / dof as f64 }
    );
    if let Some(c) = &report.attitude {
        const ARCSEC: f64 = 206_264.806;
        match (&c.fix, c.error_rad()) {
            (Ok(fix), Some(e)) => {
                let a = &fix.attitude;
                println!(
                    "attitude (lost in space from {} usable stars, {} identified, false-match bound {:.1e}): error cross-boresight {:.2} arcsec (1-sigma bound {:.2}), roll {:.2} arcsec (bound {:.2})",
                    fix.used,
                    fix.matched,
                    fix.false_probability,
                    e[0].hypot(e[1]) * ARCSEC,
                    a.boresight_sigma_rad() * ARCSEC,
                    e[2].abs() * ARCSEC,
                    a.roll_sigma_rad() * ARCSEC,
                );
            }
            (Err(e), _) => println!("attitude: none ({e})"),
            (Ok(_), None) => println!("attitude: none"),
        }
    }
}
