//! The tracker's attitude at body rate: the SIL over the sky turning during each exposure
//! ([`startrack_sim::sky::motion`]) at a set of rates, each over seeded attitudes, with per
//! rate the frames that got an attitude, the wrong ones, and the cross-boresight error
//! against its reported bound.
//!
//! A solved frame is **wrong** when its total error exceeds [`WRONG_ARCSEC`] or either part
//! exceeds [`WRONG_SIGMAS`] times its own 1-sigma bound (cross-boresight: the error's x, y
//! against `boresight_sigma_rad`; roll: z against `roll_sigma_rad`). The RMS error and the
//! RMS bound are over the solved frames that are not wrong.
//!
//! The scene: 100 ms exposures every 100 ms (the frame-transfer sensor integrating while
//! the last frame is read), the flight configuration's tracker told that exposure, the
//! SIL's sensor; run `k` of
//! a rate uses seed `seed0 + k` for the attitude and the sensor. Cost: a run is what its
//! frames cost in the SIL ([`startrack_homes::sil`]: ~1 s an acquisition frame in release, ~0.02 s a
//! tracking frame), so a rate that keeps losing its stars costs most.

use rand::SeedableRng;
use startrack_homes::sil::{self, SilConfig, SilFrame, SilReport};
use startrack_sim::sim::Star;
use startrack_sim::sky::field::random_attitude;
use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
use startrack_sim::sky::scene::SkyScene;

/// Another true star within this distance makes a star an unresolved blend, px (the
/// scene's doubles: its seed-5 field holds one 0.47 px apart).
pub const BLEND_PX: f64 = 5.0;

/// Whether the true star `t` of frame `f` has another true star within [`BLEND_PX`].
pub fn blended(f: &SilFrame, t: &Star) -> bool {
    f.truth
        .iter()
        .any(|u| u != t && (u.x_px - t.x_px).hypot(u.y_px - t.y_px) < BLEND_PX)
}

/// A solved frame off by more than this in total is wrong, arcsec.
pub const WRONG_ARCSEC: f64 = 60.0;

/// A solved frame off by more than this many of its own sigmas (cross-boresight or roll) is
/// wrong.
pub const WRONG_SIGMAS: f64 = 10.0;

/// Frame period and exposure of the runs, s.
pub const EXPOSURE_S: f64 = 0.1;

const ARCSEC_PER_RAD: f64 = 206_264.806;

/// A rate to run: its name (`cross` about the camera's y axis, across the boresight, or
/// `roll` about the boresight) and its magnitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateCase {
    /// `cross` or `roll`.
    pub motion: &'static str,
    /// deg/s.
    pub rate_deg_s: f64,
}

impl RateCase {
    /// The camera-frame rate vector, deg/s.
    pub fn vector_deg_s(&self) -> [f64; 3] {
        if self.motion == "roll" {
            [0.0, 0.0, self.rate_deg_s]
        } else {
            [0.0, self.rate_deg_s, 0.0]
        }
    }
}

/// The rates of the table: at rest, 0.5, 1, 2 and 3 deg/s across the boresight, 1 deg/s in
/// roll.
pub const RATE_CASES: [RateCase; 6] = [
    RateCase {
        motion: "cross",
        rate_deg_s: 0.0,
    },
    RateCase {
        motion: "cross",
        rate_deg_s: 0.5,
    },
    RateCase {
        motion: "cross",
        rate_deg_s: 1.0,
    },
    RateCase {
        motion: "cross",
        rate_deg_s: 2.0,
    },
    RateCase {
        motion: "cross",
        rate_deg_s: 3.0,
    },
    RateCase {
        motion: "roll",
        rate_deg_s: 1.0,
    },
];

/// The SIL configuration of run `seed` of `case`: `frames` frames.
pub fn config(case: &RateCase, seed: u64, frames: u32) -> SilConfig {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5241_5445);
    let q0 = random_attitude(&mut rng);
    let profile = RateProfile::constant(case.vector_deg_s().map(f64::to_radians));
    // Valid by construction: finite rate, exposure equal to the period.
    let motion = ExposureMotion::new(profile, EXPOSURE_S, EXPOSURE_S)
        .unwrap_or_else(|e| unreachable!("{e}"));
    // The tracker is told the exposure it runs with (its mid-exposure tags follow it).
    let mut tracker = SilConfig::default().tracker;
    tracker.exposure_ms = (EXPOSURE_S * 1e3).round() as u32;
    SilConfig {
        frames,
        seed,
        tracker,
        sky: Some(SkyScene::ccd47_15deg_moving(q0, motion)),
        period_us: (EXPOSURE_S * 1e6).round() as u64,
        ..SilConfig::default()
    }
}

/// One rate's results.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RateRow {
    /// The rate.
    pub case: Option<RateCase>,
    /// Runs.
    pub runs: usize,
    /// Frames over all runs.
    pub frames: usize,
    /// Frames with an attitude.
    pub solved: usize,
    /// Solved frames that are wrong (see the module docs).
    pub wrong: usize,
    /// Largest total error of a solved frame, arcsec.
    pub worst_arcsec: f64,
    /// RMS cross-boresight error of the solved frames that are not wrong, arcsec.
    pub rms_cross_arcsec: f64,
    /// RMS of their reported 1-sigma cross-boresight bound, arcsec.
    pub bound_cross_arcsec: f64,
}

impl RateRow {
    /// Frames with an attitude, of all frames.
    pub fn availability(&self) -> f64 {
        if self.frames == 0 {
            0.0
        } else {
            self.solved as f64 / self.frames as f64
        }
    }

    /// RMS error over RMS bound across the boresight (0 without a frame).
    pub fn ratio(&self) -> f64 {
        if self.bound_cross_arcsec > 0.0 {
            self.rms_cross_arcsec / self.bound_cross_arcsec
        } else {
            0.0
        }
    }
}

/// Whether a solved frame with error `e_rad` (camera frame) and bounds `sigma_cross_rad`,
/// `sigma_roll_rad` is wrong.
pub fn is_wrong(e_rad: [f64; 3], sigma_cross_rad: f64, sigma_roll_rad: f64) -> bool {
    let cross = e_rad[0].hypot(e_rad[1]);
    let total = cross.hypot(e_rad[2]);
    total * ARCSEC_PER_RAD > WRONG_ARCSEC
        || cross > WRONG_SIGMAS * sigma_cross_rad
        || e_rad[2].abs() > WRONG_SIGMAS * sigma_roll_rad
}

/// Adds `report`'s frames to `row`.
pub fn add_run(row: &mut RateRow, report: &SilReport, sums: &mut (f64, f64, usize)) {
    row.runs += 1;
    for f in &report.frames {
        row.frames += 1;
        let Some(c) = &f.attitude else { continue };
        let (Ok(fix), Some(e)) = (c.fix.as_ref(), c.error_rad()) else {
            continue;
        };
        row.solved += 1;
        let a = &fix.attitude;
        let total = e[0].hypot(e[1]).hypot(e[2]) * ARCSEC_PER_RAD;
        row.worst_arcsec = row.worst_arcsec.max(total);
        if is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad()) {
            row.wrong += 1;
            continue;
        }
        sums.0 += e[0] * e[0] + e[1] * e[1];
        sums.1 += a.boresight_sigma_rad().powi(2);
        sums.2 += 1;
    }
}

/// Runs `case` over seeds `seed0 .. seed0 + runs`, `frames` frames each.
pub fn run_case(case: &RateCase, seed0: u64, runs: u64, frames: u32) -> Result<RateRow, String> {
    let mut row = RateRow {
        case: Some(*case),
        ..RateRow::default()
    };
    let mut sums = (0.0, 0.0, 0usize);
    for k in 0..runs {
        let report = sil::run(&config(case, seed0 + k, frames))?;
        add_run(&mut row, &report, &mut sums);
    }
    if sums.2 > 0 {
        let rms = |v: f64| (v / sums.2 as f64).sqrt() * ARCSEC_PER_RAD;
        row.rms_cross_arcsec = rms(sums.0);
        row.bound_cross_arcsec = rms(sums.1);
    }
    Ok(row)
}

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "motion,rate_deg_s,runs,frames,solved,availability,wrong,worst_arcsec,rms_cross_arcsec,bound_cross_arcsec,ratio";

/// The rows as CSV, after `comment` lines (each prefixed `# `).
pub fn csv(rows: &[RateRow], comment: &[&str]) -> String {
    let mut out = crate::figures::csv::csv_head(comment, CSV_HEADER);
    for r in rows {
        let (motion, rate) = r.case.map_or(("", 0.0), |c| (c.motion, c.rate_deg_s));
        out.push_str(&format!(
            "{motion},{rate},{},{},{},{:.4},{},{:.2},{:.3},{:.3},{:.3}\n",
            r.runs,
            r.frames,
            r.solved,
            r.availability(),
            r.wrong,
            r.worst_arcsec,
            r.rms_cross_arcsec,
            r.bound_cross_arcsec,
            r.ratio()
        ));
    }
    out
}
