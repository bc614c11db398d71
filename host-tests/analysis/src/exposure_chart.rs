//! The exposure chart: the tracker's attitude accuracy (cross-boresight and roll, 1 sigma)
//! against the exposure at a set of body rates, from the SIL over the sky turning during
//! each exposure, the same run as `startrack sil --sky --rate-deg-s 0,R,0 --exposure-ms E`.
//!
//! Each point is one seeded attitude of [`FRAMES`] frames, exposures back to back (the
//! frame period equal to the exposure: the frame-transfer sensor integrates while the last
//! frame is read), the flight configuration's tracker told the exposure, the star signal
//! the sky's photometric model scaled to the exposure ([`startrack_sim::sky::scene`]). A
//! solved frame is wrong as in [`crate::sil_rates`]; the RMS errors are over the solved
//! frames that are not wrong. A point whose stars would trail more than [`MAX_TRAIL_PX`] in
//! one exposure is not run (written with no frames): the tracker loses such stars already
//! at 13.6 px (docs/tracker.md, "At body rate") and rendering trails that long costs minutes
//! a frame. Cost: a run is what its frames cost in the SIL (~1 s an acquisition frame in
//! release, ~0.02 s a tracking frame).

use crate::sil_rates::{self, RateCase};
use rand::SeedableRng;
use startrack_homes::sil::{self, SilConfig, SilReport};
use startrack_sim::sky::field::random_attitude;
use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
use startrack_sim::sky::scene::SkyScene;

/// Exposures of the chart, ms.
pub const EXPOSURES_MS: [u32; 6] = [25, 50, 100, 200, 500, 1000];

/// Body rates of the chart, deg/s, across the boresight (about the camera's y axis).
pub const RATES_DEG_S: [f64; 6] = [0.0, 0.5, 1.0, 2.0, 3.0, 5.0];

/// Frames a point.
pub const FRAMES: u32 = 6;

/// Longest trail in one exposure a point is run at, px.
pub const MAX_TRAIL_PX: f64 = 30.0;

/// A star's trail across the boresight at the field's centre, px per (deg/s x s): 6.8 px at
/// 1 deg/s in 100 ms (the 15 degree camera's 68 px a degree).
pub const PX_PER_DEG: f64 = 68.0;

const ARCSEC_PER_RAD: f64 = 206_264.806;

/// The SIL configuration of the point (`rate_deg_s`, `exposure_ms`), seed `seed`.
pub fn config(rate_deg_s: f64, exposure_ms: u32, seed: u64, frames: u32) -> SilConfig {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x4558_504f);
    let q0 = random_attitude(&mut rng);
    let case = RateCase {
        motion: "cross",
        rate_deg_s,
    };
    let profile = RateProfile::constant(case.vector_deg_s().map(f64::to_radians));
    let exposure_s = f64::from(exposure_ms) * 1e-3;
    // Valid by construction: a finite rate, the exposure equal to the period.
    let motion = ExposureMotion::new(profile, exposure_s, exposure_s)
        .unwrap_or_else(|e| unreachable!("{e}"));
    let mut tracker = SilConfig::default().tracker;
    tracker.exposure_ms = exposure_ms;
    SilConfig {
        frames,
        seed,
        tracker,
        sky: Some(SkyScene::ccd47_15deg_moving(q0, motion)),
        period_us: u64::from(exposure_ms) * 1000,
        ..SilConfig::default()
    }
}

/// One point of the chart.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExposurePoint {
    /// Body rate, deg/s.
    pub rate_deg_s: f64,
    /// Exposure, ms.
    pub exposure_ms: u32,
    /// A star's trail in one exposure, px.
    pub trail_px: f64,
    /// Frames run (0: not run, the trail longer than [`MAX_TRAIL_PX`]).
    pub frames: usize,
    /// Frames with an attitude.
    pub solved: usize,
    /// Solved frames that are wrong.
    pub wrong: usize,
    /// RMS cross-boresight error of the solved frames not wrong, arcsec (1 sigma).
    pub cross_arcsec: f64,
    /// RMS roll error of the same frames, arcsec (1 sigma).
    pub roll_arcsec: f64,
    /// RMS of their reported cross-boresight bound, arcsec.
    pub bound_cross_arcsec: f64,
    /// RMS of their reported roll bound, arcsec.
    pub bound_roll_arcsec: f64,
}

/// The point's trail, px.
pub fn trail_px(rate_deg_s: f64, exposure_ms: u32) -> f64 {
    rate_deg_s * f64::from(exposure_ms) * 1e-3 * PX_PER_DEG
}

/// The point from a SIL report.
pub fn point_of(rate_deg_s: f64, exposure_ms: u32, report: &SilReport) -> ExposurePoint {
    let mut p = ExposurePoint {
        rate_deg_s,
        exposure_ms,
        trail_px: trail_px(rate_deg_s, exposure_ms),
        ..ExposurePoint::default()
    };
    let mut sums = [0.0f64; 4];
    let mut n = 0usize;
    for f in &report.frames {
        p.frames += 1;
        let Some(c) = &f.attitude else { continue };
        let (Ok(fix), Some(e)) = (c.fix.as_ref(), c.error_rad()) else {
            continue;
        };
        p.solved += 1;
        let a = &fix.attitude;
        if sil_rates::is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad()) {
            p.wrong += 1;
            continue;
        }
        sums[0] += e[0] * e[0] + e[1] * e[1];
        sums[1] += e[2] * e[2];
        sums[2] += a.boresight_sigma_rad().powi(2);
        sums[3] += a.roll_sigma_rad().powi(2);
        n += 1;
    }
    if n > 0 {
        let rms = |v: f64| (v / n as f64).sqrt() * ARCSEC_PER_RAD;
        p.cross_arcsec = rms(sums[0]);
        p.roll_arcsec = rms(sums[1]);
        p.bound_cross_arcsec = rms(sums[2]);
        p.bound_roll_arcsec = rms(sums[3]);
    }
    p
}

/// Runs the point (`rate_deg_s`, `exposure_ms`) with seed `seed`, or returns it unrun when
/// its trail is longer than [`MAX_TRAIL_PX`].
pub fn run_point(
    rate_deg_s: f64,
    exposure_ms: u32,
    seed: u64,
    frames: u32,
) -> Result<ExposurePoint, String> {
    if trail_px(rate_deg_s, exposure_ms) > MAX_TRAIL_PX {
        return Ok(ExposurePoint {
            rate_deg_s,
            exposure_ms,
            trail_px: trail_px(rate_deg_s, exposure_ms),
            ..ExposurePoint::default()
        });
    }
    let report = sil::run(&config(rate_deg_s, exposure_ms, seed, frames))?;
    Ok(point_of(rate_deg_s, exposure_ms, &report))
}

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "rate_deg_s,exposure_ms,trail_px,frames,solved,wrong,cross_arcsec,roll_arcsec,bound_cross_arcsec,bound_roll_arcsec";

/// The points as CSV, after `comment` lines (each prefixed `# `); the errors of a point
/// without a solved frame are empty.
pub fn csv(points: &[ExposurePoint], comment: &[&str]) -> String {
    let mut out = crate::figures::csv::csv_head(comment, CSV_HEADER);
    for p in points {
        let v = |x: f64| {
            if p.solved > p.wrong {
                format!("{x:.3}")
            } else {
                String::new()
            }
        };
        out.push_str(&format!(
            "{},{},{:.1},{},{},{},{},{},{},{}\n",
            p.rate_deg_s,
            p.exposure_ms,
            p.trail_px,
            p.frames,
            p.solved,
            p.wrong,
            v(p.cross_arcsec),
            v(p.roll_arcsec),
            v(p.bound_cross_arcsec),
            v(p.bound_roll_arcsec),
        ));
    }
    out
}

/// The chart's PNG: cross-boresight (solid) and roll (dashed) error against the exposure,
/// one colour a rate, both axes logarithmic; points without an attitude are left out.
pub fn plot(
    points: &[ExposurePoint],
    out: &std::path::Path,
    name: &str,
) -> Result<crate::figures::Written, String> {
    use crate::figures::Written;
    use crate::figures::plot::{Chart, Series, lines};
    let mut series = Vec::new();
    for (i, &rate) in RATES_DEG_S.iter().enumerate() {
        let of = |f: fn(&ExposurePoint) -> f64| -> Vec<(f64, f64)> {
            points
                .iter()
                .filter(|p| p.rate_deg_s == rate && p.solved > p.wrong)
                .map(|p| (f64::from(p.exposure_ms), f(p)))
                .collect()
        };
        series.push(Series::solid(
            format!("{rate} deg/s cross-boresight"),
            of(|p| p.cross_arcsec),
            i,
        ));
        series.push(Series {
            dashed: true,
            ..Series::solid(format!("{rate} deg/s roll"), of(|p| p.roll_arcsec), i)
        });
    }
    let chart = Chart {
        title: "Attitude error against exposure (SIL, 1 sigma)".into(),
        x_label: "exposure, ms".into(),
        y_label: "error, arcsec".into(),
        log_x: true,
        log_y: true,
    };
    let mut written = Written::default();
    lines(out, name, &chart, &series, &mut written).map_err(|e| format!("{e:?}"))?;
    Ok(written)
}
