//! The tracker's attitude at body rate: the SIL over the sky turning during each exposure
//! ([`startrack_sim::sky::motion`]) at a set of rates, each over seeded attitudes, with per
//! rate the frames that got an attitude (from power-on and from the first attitude on), the
//! wrong ones, the cross-boresight error against its reported bound, and the angular rate's
//! error against its covariance.
//!
//! A solved frame is **wrong** when its total error exceeds [`WRONG_ARCSEC`] or either part
//! exceeds [`WRONG_SIGMAS`] times its own 1-sigma bound (cross-boresight: the error's x, y
//! against `boresight_sigma_rad`; roll: z against `roll_sigma_rad`). The RMS error, the RMS
//! bound and the mean normalised error squared (NEES, 3 when the covariance is consistent)
//! are over the solved frames that are not wrong; the rate's over the frames whose report
//! carries a rate, against the true rate at mid-exposure.
//!
//! The scene is the flight configuration's: [`EXPOSURE_S`] exposures every [`PERIOD_S`] (the
//! 20 Hz readout's cycle of 30 windows), the tracker told that exposure, the SIL's sensor;
//! run `k` of a rate uses seed `seed0 + k` for the attitude and the sensor. The SIL's
//! acquisition frame integrates the same exposure in the same period (the board's full
//! frame takes 0.6 s: docs/tracker.md, "Time to the first attitude", states the time).
//! Cost: a run is what its frames cost in the SIL ([`startrack_homes::sil`]: ~1 s an
//! acquisition frame, ~0.02 s a tracking frame), so a rate that keeps losing its stars costs
//! most.

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

/// A star's normalised errors squared along the major and the minor axis of its reported
/// 2x2 position covariance (`sigma_x_px`, `sigma_y_px`, `cov_xy_px2`), against the true
/// position `truth_px`: for a trailed star the axes are along and across its trail. Each has
/// mean 1 over many stars when the covariance says what the errors are. `None` for a
/// covariance that is not positive definite.
pub fn principal_nees(
    s: &startrack_core::tracker::StarRecord,
    truth_px: [f64; 2],
) -> Option<[f64; 2]> {
    let (vx, vy) = (
        f64::from(s.sigma_x_px).powi(2),
        f64::from(s.sigma_y_px).powi(2),
    );
    let c = f64::from(s.cov_xy_px2);
    let (mean, half) = (0.5 * (vx + vy), (0.25 * (vx - vy).powi(2) + c * c).sqrt());
    let (major, minor) = (mean + half, mean - half);
    if !(minor > 0.0 && major.is_finite()) {
        return None;
    }
    // The major axis's direction: (c, major - vx), or the x axis when uncorrelated and
    // vx is the larger.
    let (ux, uy) = if c.abs() > 1e-30 || vy > vx {
        (c, major - vx)
    } else {
        (1.0, 0.0)
    };
    let n = ux.hypot(uy);
    let (ux, uy) = (ux / n, uy / n);
    let (ex, ey) = (
        f64::from(s.x_px) - truth_px[0],
        f64::from(s.y_px) - truth_px[1],
    );
    let (ea, ec) = (ex * ux + ey * uy, -ex * uy + ey * ux);
    Some([ea * ea / major, ec * ec / minor])
}

/// Tracking frames after an acquisition frame before a moving star's motion is measured
/// (`TRAIL_SETTLE_FRAMES`): a star that moved is flagged `TRAIL_UNKNOWN` in them.
pub const SETTLING_FRAMES: usize = startrack_core::tracker::TRAIL_SETTLE_FRAMES as usize;

/// A solved frame off by more than this in total is wrong, arcsec.
pub const WRONG_ARCSEC: f64 = 60.0;

/// A solved frame off by more than this many of its own sigmas (cross-boresight or roll) is
/// wrong.
pub const WRONG_SIGMAS: f64 = 10.0;

/// Exposure of the runs, s: the flight configuration's (`TrackerConfig::FLIGHT.exposure_ms`).
pub const EXPOSURE_S: f64 = 0.039;

/// Frame period of the runs, s: the 39 ms exposure and the 10.4 ms frame transfer, the
/// 20 Hz cycle of a tracking frame of up to 30 windows at 1 MHz (docs/tracker.md,
/// "Exposure").
pub const PERIOD_S: f64 = 0.0494;

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
    // Valid by construction: finite rate, exposure within the period.
    let motion =
        ExposureMotion::new(profile, PERIOD_S, EXPOSURE_S).unwrap_or_else(|e| unreachable!("{e}"));
    // The tracker is told the exposure it runs with (its mid-exposure tags follow it).
    let mut tracker = SilConfig::default().tracker;
    tracker.exposure_ms = (EXPOSURE_S * 1e3).round() as u32;
    SilConfig {
        frames,
        seed,
        tracker,
        sky: Some(SkyScene::ccd47_15deg_moving(q0, motion)),
        period_us: (PERIOD_S * 1e6).round() as u64,
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
    /// Frames from each run's first attitude on (that frame included).
    pub frames_after_first: usize,
    /// ... of them with an attitude.
    pub solved_after_first: usize,
    /// Full frames (acquisition) after each run's first attitude: the tracking lost.
    pub acquisitions_after_first: usize,
    /// Frames after each run's first attitude without one that are not among the
    /// [`SETTLING_FRAMES`] tracking frames after an acquisition frame.
    pub missed_after_settling: usize,
    /// Frames before each run's first attitude, summed over the runs (a run without one
    /// counts all its frames).
    pub frames_to_first: usize,
    /// Solved frames that are wrong (see the module docs).
    pub wrong: usize,
    /// Largest total error of a solved frame, arcsec.
    pub worst_arcsec: f64,
    /// RMS cross-boresight error of the solved frames that are not wrong, arcsec.
    pub rms_cross_arcsec: f64,
    /// RMS of their reported 1-sigma cross-boresight bound, arcsec.
    pub bound_cross_arcsec: f64,
    /// RMS roll error, arcsec.
    pub rms_roll_arcsec: f64,
    /// Mean normalised error squared of their attitudes (3 when consistent).
    pub attitude_nees: f64,
    /// Solved frames whose report carries a rate.
    pub with_rate: usize,
    /// RMS rate error per axis across the boresight, arcsec/s, over the frames whose rate
    /// comes from [`STEADY_RATE_ATTITUDES`] attitudes or more (the filter's acceleration
    /// measured; before it, the rate's bound holds the platform's assumed acceleration).
    pub rate_cross_arcsec_s: f64,
    /// RMS roll-rate error, arcsec/s, over the same frames.
    pub rate_roll_arcsec_s: f64,
    /// RMS of the rate's reported 1-sigma per axis across the boresight, arcsec/s, over the
    /// same frames.
    pub rate_bound_cross_arcsec_s: f64,
    /// Mean normalised error squared of the rates (3 when consistent).
    pub rate_nees: f64,
}

/// Running sums of a row's errors, for [`add_run`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sums {
    cross_rad2: f64,
    bound_rad2: f64,
    roll_rad2: f64,
    nees: f64,
    n: usize,
    rate_cross: f64,
    rate_roll: f64,
    rate_bound: f64,
    rate_nees: f64,
    n_rate: usize,
    n_rate_steady: usize,
}

impl RateRow {
    /// Frames with an attitude, of all frames.
    pub fn availability(&self) -> f64 {
        ratio(self.solved, self.frames)
    }

    /// Frames with an attitude, of the frames from each run's first attitude on.
    pub fn availability_after_first(&self) -> f64 {
        ratio(self.solved_after_first, self.frames_after_first)
    }

    /// Mean frames before the first attitude.
    pub fn mean_frames_to_first(&self) -> f64 {
        if self.runs == 0 {
            0.0
        } else {
            self.frames_to_first as f64 / self.runs as f64
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

    /// Takes the RMS figures from `sums`.
    pub fn finish(&mut self, sums: &Sums) {
        let rms = |v: f64, n: usize| {
            if n == 0 {
                0.0
            } else {
                (v / n as f64).sqrt() * ARCSEC_PER_RAD
            }
        };
        let mean = |v: f64, n: usize| if n == 0 { 0.0 } else { v / n as f64 };
        self.rms_cross_arcsec = rms(sums.cross_rad2, sums.n);
        self.bound_cross_arcsec = rms(sums.bound_rad2, sums.n);
        self.rms_roll_arcsec = rms(sums.roll_rad2, sums.n);
        self.attitude_nees = mean(sums.nees, sums.n);
        self.rate_cross_arcsec_s = rms(sums.rate_cross, 2 * sums.n_rate_steady);
        self.rate_roll_arcsec_s = rms(sums.rate_roll, sums.n_rate_steady);
        self.rate_bound_cross_arcsec_s = rms(sums.rate_bound, 2 * sums.n_rate_steady);
        self.rate_nees = mean(sums.rate_nees, sums.n_rate);
    }
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
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

/// Adds `report`'s frames to `row` and its error sums to `sums` ([`RateRow::finish`] then
/// takes the RMS figures).
pub fn add_run(row: &mut RateRow, report: &SilReport, sums: &mut Sums) {
    row.runs += 1;
    let solved = |f: &SilFrame| f.attitude.as_ref().is_some_and(|c| c.fix.is_ok());
    let first = report.frames.iter().position(solved);
    row.frames_to_first += first.unwrap_or(report.frames.len());
    // Rates reported so far in this run (the first comes with the second attitude).
    let mut rated = 0usize;
    for (k, f) in report.frames.iter().enumerate() {
        row.frames += 1;
        let after_first = first.is_some_and(|i| k >= i);
        if after_first {
            row.frames_after_first += 1;
        }
        if first.is_some_and(|i| k > i) {
            row.acquisitions_after_first +=
                usize::from(f.summary.mode == startrack_core::tracker::Mode::Acquisition);
        }
        let settling = report.frames[k.saturating_sub(SETTLING_FRAMES)..k]
            .iter()
            .any(|g| g.summary.mode == startrack_core::tracker::Mode::Acquisition);
        let Some((fix, e)) = f
            .attitude
            .as_ref()
            .and_then(|c| Some((c.fix.as_ref().ok()?, c.error_rad()?)))
        else {
            row.missed_after_settling += usize::from(after_first && !settling);
            continue;
        };
        let Some(c) = &f.attitude else { continue };
        row.solved += 1;
        row.solved_after_first += usize::from(after_first);
        let a = &fix.attitude;
        let total = e[0].hypot(e[1]).hypot(e[2]) * ARCSEC_PER_RAD;
        row.worst_arcsec = row.worst_arcsec.max(total);
        if is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad()) {
            row.wrong += 1;
            continue;
        }
        sums.cross_rad2 += e[0] * e[0] + e[1] * e[1];
        sums.bound_rad2 += a.boresight_sigma_rad().powi(2);
        sums.roll_rad2 += e[2] * e[2];
        sums.nees += a.nees(e).unwrap_or(f64::INFINITY);
        sums.n += 1;
        if let Some(r) = c.report.and_then(|r| r.rate) {
            row.with_rate += 1;
            // The report's rate is the attitude's, `q(t + dt) = exp(w dt) q(t)`: the negative
            // of the body rate a gyro on the camera reads, the scene's.
            let w = c.true_rate_rad_s.map(|v| -v);
            let d = [
                r.w_rad_s[0] - w[0],
                r.w_rad_s[1] - w[1],
                r.w_rad_s[2] - w[2],
            ];
            rated += 1;
            if rated + 1 >= STEADY_RATE_ATTITUDES {
                sums.rate_cross += d[0] * d[0] + d[1] * d[1];
                sums.rate_roll += d[2] * d[2];
                sums.rate_bound += r.cov_rad2_s2[0][0] + r.cov_rad2_s2[1][1];
                sums.n_rate_steady += 1;
            }
            sums.rate_nees += r.nees(d).unwrap_or(f64::INFINITY);
            sums.n_rate += 1;
        }
    }
}

/// Runs `case` over seeds `seed0 .. seed0 + runs`, `frames` frames each.
pub fn run_case(case: &RateCase, seed0: u64, runs: u64, frames: u32) -> Result<RateRow, String> {
    let mut row = RateRow {
        case: Some(*case),
        ..RateRow::default()
    };
    let mut sums = Sums::default();
    for k in 0..runs {
        let report = sil::run(&config(case, seed0 + k, frames))?;
        add_run(&mut row, &report, &mut sums);
    }
    row.finish(&sums);
    Ok(row)
}

/// Attitudes a run's rate comes from before its error and bound enter the rate's RMS
/// columns: from 4 the rate filter measures the acceleration
/// ([`startrack_core::attitude::RateFilter::acceleration`]); before, its bound holds the
/// platform's largest acceleration (tens of arcsec/s, a few frames a run). The NEES counts
/// every rate.
pub const STEADY_RATE_ATTITUDES: usize = 4;

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "motion,rate_deg_s,runs,frames,solved,availability,frames_to_first,frames_after_first,solved_after_first,availability_after_first,missed_after_settling,acquisitions_after_first,wrong,worst_arcsec,rms_cross_arcsec,bound_cross_arcsec,ratio,rms_roll_arcsec,attitude_nees,with_rate,rate_cross_arcsec_s,rate_bound_cross_arcsec_s,rate_roll_arcsec_s,rate_nees";

/// The rows as CSV, after `comment` lines (each prefixed `# `).
pub fn csv(rows: &[RateRow], comment: &[&str]) -> String {
    let mut out = crate::figures::csv::csv_head(comment, CSV_HEADER);
    for r in rows {
        let (motion, rate) = r.case.map_or(("", 0.0), |c| (c.motion, c.rate_deg_s));
        out.push_str(&format!(
            "{motion},{rate},{},{},{},{:.4},{},{},{},{:.4},{},{},{},{:.2},{:.3},{:.3},{:.3},{:.3},{:.2},{},{:.2},{:.2},{:.2},{:.2}\n",
            r.runs,
            r.frames,
            r.solved,
            r.availability(),
            r.frames_to_first,
            r.frames_after_first,
            r.solved_after_first,
            r.availability_after_first(),
            r.missed_after_settling,
            r.acquisitions_after_first,
            r.wrong,
            r.worst_arcsec,
            r.rms_cross_arcsec,
            r.bound_cross_arcsec,
            r.ratio(),
            r.rms_roll_arcsec,
            r.attitude_nees,
            r.with_rate,
            r.rate_cross_arcsec_s,
            r.rate_bound_cross_arcsec_s,
            r.rate_roll_arcsec_s,
            r.rate_nees,
        ));
    }
    out
}
