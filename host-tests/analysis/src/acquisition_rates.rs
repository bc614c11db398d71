//! Lost in space while the spacecraft turns: acquisition frames only, on the SIL's sky
//! turning during each exposure ([`startrack_sim::sky::motion`]), each run one frame (the
//! tracker's first frame is an acquisition frame, so every frame here is identified from
//! nothing), per rate and exposure over seeded attitudes: the frames solved and wrong
//! ([`sil_rates::is_wrong`]: over 60 arcsec, or 10 of its own sigmas), the stars found,
//! measured as trailed and usable for identification, and the trailed positions' chi^2/dof
//! against their own sigmas (the truth at mid-exposure, blends aside: [`sil_rates::blended`]).
//!
//! The rate is about the camera's x axis (`--rate-deg-s W,0,0`: the field moves along the
//! rows), the exposure equal to the frame period, the tracker told it, the flight
//! configuration otherwise. Cost: one acquisition frame per run (~1 s in the test profile).

use crate::sil_rates;
use rand::SeedableRng;
use startrack_core::tracker::{Provenance, StarFlags};
use startrack_homes::sil::{self, SilConfig, SilReport};
use startrack_sim::sky::field::random_attitude;
use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
use startrack_sim::sky::scene::SkyScene;

const ARCSEC_PER_RAD: f64 = 206_264.806;

/// One point: the rate about the camera's x axis and the exposure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AcqCase {
    /// deg/s about the camera's x axis.
    pub rate_deg_s: f64,
    /// Exposure and frame period, ms.
    pub exposure_ms: u32,
}

impl AcqCase {
    /// A star's trail over the exposure, px (the SIL's 15-degree field on 1024 px).
    pub fn trail_px(&self) -> f64 {
        self.rate_deg_s * f64::from(self.exposure_ms) * 1e-3 * 1024.0 / 15.0
    }
}

/// The points of the table: at rest, 0.5, 1, 1.5, 2 deg/s at 100 ms, and 2 and 3 deg/s at
/// 50 ms.
pub const ACQ_CASES: [AcqCase; 7] = [
    AcqCase {
        rate_deg_s: 0.0,
        exposure_ms: 100,
    },
    AcqCase {
        rate_deg_s: 0.5,
        exposure_ms: 100,
    },
    AcqCase {
        rate_deg_s: 1.0,
        exposure_ms: 100,
    },
    AcqCase {
        rate_deg_s: 1.5,
        exposure_ms: 100,
    },
    AcqCase {
        rate_deg_s: 2.0,
        exposure_ms: 100,
    },
    AcqCase {
        rate_deg_s: 2.0,
        exposure_ms: 50,
    },
    AcqCase {
        rate_deg_s: 3.0,
        exposure_ms: 50,
    },
];

/// The SIL configuration of run `seed` of `case`: one frame.
pub fn config(case: &AcqCase, seed: u64) -> SilConfig {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x4143_5155);
    let q0 = random_attitude(&mut rng);
    let profile = RateProfile::constant([case.rate_deg_s.to_radians(), 0.0, 0.0]);
    let exposure_s = f64::from(case.exposure_ms) * 1e-3;
    // Valid by construction: a finite rate, the exposure equal to the period.
    let motion = ExposureMotion::new(profile, exposure_s, exposure_s)
        .unwrap_or_else(|e| unreachable!("{e}"));
    let mut tracker = SilConfig::default().tracker;
    tracker.exposure_ms = case.exposure_ms;
    SilConfig {
        frames: 1,
        seed,
        tracker,
        sky: Some(SkyScene::ccd47_15deg_moving(q0, motion)),
        period_us: u64::from(case.exposure_ms) * 1000,
        ..SilConfig::default()
    }
}

/// One point's results.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AcqRow {
    /// The point.
    pub case: Option<AcqCase>,
    /// Acquisition frames run.
    pub frames: usize,
    /// Frames with an attitude.
    pub solved: usize,
    /// Solved frames that are wrong.
    pub wrong: usize,
    /// Stars reported, per frame.
    pub stars: f64,
    /// Stars measured as trailed, per frame.
    pub trailed: f64,
    /// Stars identification may use (a centroid, its trail not unknown, not saturated), per
    /// frame.
    pub usable: f64,
    /// chi^2/dof of the matched trailed positions against their own sigmas (both axes,
    /// blends aside; NaN without one).
    pub trailed_chi2_dof: f64,
    /// RMS cross-boresight error of the solved frames that are not wrong, arcsec.
    pub rms_cross_arcsec: f64,
}

/// Adds one run's frames to `row`; `sums`: (trailed chi^2, its terms, cross error^2,
/// solved-and-right frames).
pub fn add_run(row: &mut AcqRow, report: &SilReport, sums: &mut (f64, usize, f64, usize)) {
    for f in &report.frames {
        row.frames += 1;
        row.stars += f.stars.len() as f64;
        for m in &f.stars {
            let s = &m.star;
            let trailed = s.provenance.contains(Provenance::TRAILED);
            row.trailed += f64::from(u8::from(trailed));
            let usable = s.is_centroid()
                && !s.flags.intersects(
                    StarFlags::TRAIL_UNKNOWN | StarFlags::SATURATED | StarFlags::DETECT_SATURATED,
                );
            row.usable += f64::from(u8::from(usable));
            let Some(t) = m.truth.filter(|_| trailed && usable) else {
                continue;
            };
            if sil_rates::blended(f, &t) {
                continue;
            }
            sums.0 += ((f64::from(s.x_px) - t.x_px) / f64::from(s.sigma_x_px)).powi(2)
                + ((f64::from(s.y_px) - t.y_px) / f64::from(s.sigma_y_px)).powi(2);
            sums.1 += 2;
        }
        let Some(c) = &f.attitude else { continue };
        let (Ok(fix), Some(e)) = (c.fix.as_ref(), c.error_rad()) else {
            continue;
        };
        row.solved += 1;
        let a = &fix.attitude;
        if sil_rates::is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad()) {
            row.wrong += 1;
            continue;
        }
        sums.2 += e[0] * e[0] + e[1] * e[1];
        sums.3 += 1;
    }
}

/// Runs `case` over seeds `seed0 .. seed0 + runs`.
pub fn run_case(case: &AcqCase, seed0: u64, runs: u64) -> Result<AcqRow, String> {
    let mut row = AcqRow {
        case: Some(*case),
        ..AcqRow::default()
    };
    let mut sums = (0.0, 0usize, 0.0, 0usize);
    for k in 0..runs {
        let report = sil::run(&config(case, seed0 + k))?;
        add_run(&mut row, &report, &mut sums);
    }
    let n = row.frames.max(1) as f64;
    row.stars /= n;
    row.trailed /= n;
    row.usable /= n;
    row.trailed_chi2_dof = if sums.1 > 0 {
        sums.0 / sums.1 as f64
    } else {
        f64::NAN
    };
    if sums.3 > 0 {
        row.rms_cross_arcsec = (sums.2 / sums.3 as f64).sqrt() * ARCSEC_PER_RAD;
    }
    Ok(row)
}

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "rate_deg_s,exposure_ms,trail_px,frames,solved,wrong,stars,trailed,usable,trailed_chi2_dof,rms_cross_arcsec";

/// The rows as CSV, after `comment` lines (each prefixed `# `).
pub fn csv(rows: &[AcqRow], comment: &[&str]) -> String {
    let mut out = crate::figures::csv::csv_head(comment, CSV_HEADER);
    for r in rows {
        let Some(c) = r.case else { continue };
        out.push_str(&format!(
            "{},{},{:.1},{},{},{},{:.1},{:.1},{:.1},{:.3},{:.3}\n",
            c.rate_deg_s,
            c.exposure_ms,
            c.trail_px(),
            r.frames,
            r.solved,
            r.wrong,
            r.stars,
            r.trailed,
            r.usable,
            r.trailed_chi2_dof,
            r.rms_cross_arcsec
        ));
    }
    out
}
