//! The tracker on a turning sky ([`startrack_sim::sky::motion`]): stars trailed during the
//! exposure, measured by the trailed-star fit once the tracker knows their motion (from the
//! last two frames, or from the attitude's prediction of the catalog's windows), against the
//! truth at mid-exposure; the rate table and a slew held on the catalog's windows.

use rand::SeedableRng;
use startrack_analysis::sil_rates;
use startrack_core::tracker::{Mode, Provenance};
use startrack_homes::sil::{self, SilConfig, SilFrame};
use startrack_sim::sky::field::random_attitude;
use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
use startrack_sim::sky::scene::SkyScene;

/// A sky turning at `rate_deg_s` (camera frame) during 100 ms exposures every 100 ms, from
/// a seeded attitude, the tracker told that exposure.
pub fn turning_sky(seed: u64, rate_deg_s: [f64; 3], frames: u32) -> SilConfig {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let q0 = random_attitude(&mut rng);
    let profile = RateProfile::constant(rate_deg_s.map(f64::to_radians));
    let motion = ExposureMotion::new(profile, 0.1, 0.1).unwrap();
    let mut tracker = SilConfig::default().tracker;
    tracker.exposure_ms = 100;
    SilConfig {
        frames,
        seed,
        tracker,
        sky: Some(SkyScene::ccd47_15deg_moving(q0, motion)),
        ..SilConfig::default()
    }
}

/// chi^2 over both axes of a frame's matched usable centroids (blends aside, [`sil_rates::blended`])
/// against their own sigmas, the number of terms, and how many of those stars were measured
/// as trailed.
fn frame_chi2(f: &SilFrame) -> (f64, usize, usize) {
    let (mut sum, mut n, mut trailed) = (0.0, 0, 0);
    for m in &f.stars {
        let Some(t) = m.truth.filter(|_| m.star.is_centroid()) else {
            continue;
        };
        if sil_rates::blended(f, &t) {
            continue;
        }
        let s = &m.star;
        sum += ((f64::from(s.x_px) - t.x_px) / f64::from(s.sigma_x_px)).powi(2)
            + ((f64::from(s.y_px) - t.y_px) / f64::from(s.sigma_y_px)).powi(2);
        n += 2;
        trailed += usize::from(s.provenance.contains(Provenance::TRAILED));
    }
    (sum, n, trailed)
}

/// At 1 deg/s across the boresight (6.8 px trails): from the third tracking frame on (the
/// motion measured between two tracking frames) every matched star is measured as trailed,
/// the positions at mid-exposure (blends aside) have a chi^2/dof of 0.7-1.4 against the reported sigmas,
/// and each attitude is within 5 of its sigmas on every axis. The first tracking frames
/// (the motion unknown, then measured from truncated trails) are not asserted: the CLI's
/// figures in docs/tracker.md state them.
#[test]
fn trailed_stars_are_fitted_at_mid_exposure_once_the_motion_is_known() {
    let config = turning_sky(5, [0.0, 1.0, 0.0], 7);
    let report = sil::run(&config).unwrap();
    let first_tracking = report
        .frames
        .iter()
        .position(|f| f.summary.mode == Mode::Tracking)
        .unwrap();
    let steady = &report.frames[first_tracking + 3..];
    assert!(steady.len() >= 2, "{} frames", report.frames.len());
    let (mut sum, mut n) = (0.0, 0);
    for f in steady {
        assert_eq!(f.summary.mode, Mode::Tracking, "frame {}", f.summary.frame);
        let (s, k, trailed) = frame_chi2(f);
        assert!(k >= 40, "frame {}: {k} terms", f.summary.frame);
        assert_eq!(trailed * 2, k, "frame {}: not all trailed", f.summary.frame);
        sum += s;
        n += k;
        let c = f.attitude.as_ref().unwrap();
        // Tagged at the truth's mid-exposure: the SIL's frames integrate the motion's
        // exposure from their start (its line source's integration).
        let tagged_us = c.report.unwrap().mid_exposure_us;
        assert_eq!(
            tagged_us,
            (c.t_mid_s * 1e6).round() as u64,
            "frame {}",
            f.summary.frame
        );
        let fix = c.fix.as_ref().unwrap();
        let e = c.error_rad().unwrap();
        for (i, v) in e.iter().enumerate() {
            let sigma = fix.attitude.cov_rad2[i][i].sqrt();
            assert!(
                v.abs() < 5.0 * sigma,
                "frame {}: axis {i} error {v:e} rad, sigma {sigma:e}",
                f.summary.frame
            );
        }
    }
    let chi2 = sum / n as f64;
    assert!((0.7..1.4).contains(&chi2), "chi2/dof {chi2}");
}

/// Frames `from..` of `report` each solved, none wrong, and each attitude within 5 of its
/// sigmas on every axis.
fn solved_within_5_sigmas(report: &sil::SilReport, from: usize) {
    for f in &report.frames {
        let n = f.summary.frame;
        let c = f.attitude.as_ref().unwrap();
        let Ok(fix) = c.fix.as_ref() else {
            assert!((n as usize) < from, "frame {n}: no attitude");
            continue;
        };
        let e = c.error_rad().unwrap();
        let a = &fix.attitude;
        assert!(
            !sil_rates::is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad()),
            "frame {n}: wrong, {e:?}"
        );
        if n as usize >= from {
            for (i, v) in e.iter().enumerate() {
                let sigma = a.cov_rad2[i][i].sqrt();
                assert!(
                    v.abs() < 5.0 * sigma,
                    "frame {n}: axis {i} {v:e} rad, sigma {sigma:e}"
                );
            }
        }
    }
}

/// A trailed star's trail is its motion over the frame's own integration, as the line
/// source reports it, not over the configured exposure: at 1 deg/s across the boresight
/// with the scene integrating 100 ms every 100 ms (6.8 px trails) and the tracker told
/// 39 ms, every frame from the fourth (the catalog's windows from the fifth) is solved
/// within 5 of its sigmas, none wrong (a trail told 39 ms gave an attitude 10 sigmas off);
/// and at the flight timing (39 ms every 49.4 ms), where a tracked star's last motion is
/// 1.27 times its trail, the same.
#[test]
fn trails_are_taken_over_the_frames_own_integration() {
    let mut told_short = turning_sky(5, [0.0, 1.0, 0.0], 10);
    told_short.tracker.exposure_ms = 39;
    solved_within_5_sigmas(&sil::run(&told_short).unwrap(), 3);
    let case = sil_rates::RateCase {
        motion: "cross",
        rate_deg_s: 1.0,
    };
    solved_within_5_sigmas(&sil::run(&sil_rates::config(&case, 5, 10)).unwrap(), 3);
}

/// At 0.5 deg/s across the boresight in the flight's 39 ms a star trails 1.3 px, less than
/// the moments' screen for a trail: the bright stars of the rate table's seed-102 field fit
/// a round Gaussian badly (POOR_FIT) and, ranked below every clean star, left lost in space
/// the field's faintest 32 (no identification). Fitted as trails when the round fit cannot
/// describe them, the five brightest true stars of the field are in the acquisition
/// frame's list, measured trailed and clean, and the frame solves, not wrong.
#[test]
fn a_bright_star_smeared_below_the_screen_is_fitted_as_a_trail() {
    let case = sil_rates::RateCase {
        motion: "cross",
        rate_deg_s: 0.5,
    };
    let report = sil::run(&sil_rates::config(&case, 102, 1)).unwrap();
    let f = &report.frames[0];
    assert_eq!(f.summary.mode, Mode::Acquisition);
    let mut bright: Vec<_> = f
        .truth
        .iter()
        .filter(|t| sil::in_field(t, &Default::default()))
        .collect();
    bright.sort_by(|a, b| b.signal_e.total_cmp(&a.signal_e));
    for t in bright.iter().take(5) {
        let m = f
            .stars
            .iter()
            .find(|m| m.truth.is_some_and(|u| u == **t))
            .unwrap_or_else(|| panic!("{t:?} not in the list"));
        assert!(
            m.star.provenance.contains(Provenance::TRAILED),
            "{:?}",
            m.star
        );
        assert!(m.star.fit_is_clean(), "{:?}", m.star);
    }
    let c = f.attitude.as_ref().unwrap();
    let fix = c.fix.as_ref().unwrap();
    let e = c.error_rad().unwrap();
    let a = &fix.attitude;
    assert!(
        !sil_rates::is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad()),
        "{e:?}"
    );
}

/// The mean normalised errors squared along and across the trail
/// ([`sil_rates::principal_nees`]) of a run's stars measured as trailed (clean, matched,
/// blends aside), from the fourth frame on, and how many.
pub fn trailed_nees(report: &sil::SilReport) -> ([f64; 2], usize) {
    let mut sum = [0.0; 2];
    let mut n = 0;
    for f in report.frames.iter().skip(3) {
        for m in &f.stars {
            let s = &m.star;
            let Some(t) = m.truth.filter(|_| s.is_centroid() && s.fit_is_clean()) else {
                continue;
            };
            if sil_rates::blended(f, &t) || !s.provenance.contains(Provenance::TRAILED) {
                continue;
            }
            if let Some(v) = sil_rates::principal_nees(s, [t.x_px, t.y_px]) {
                sum = [sum[0] + v[0], sum[1] + v[1]];
                n += 1;
            }
        }
    }
    (sum.map(|v| v / n.max(1) as f64), n)
}

/// A trailed star's reported 2x2 covariance says what its errors are, along its trail and
/// across it: at 1 and 3 deg/s across the boresight at the flight timing (seed 100, 40
/// frames), the mean normalised error squared of the trailed stars is within 0.85-1.25 on
/// each axis (about 1,170 stars a rate: the mean's standard deviation about 0.04). The
/// attitude takes that covariance whole ([`startrack_core::attitude::refine`]); with the
/// larger sigma a star it was 1.27 times too wide about the axis the trails do not cross.
#[test]
fn trailed_stars_covariance_says_what_their_errors_are() {
    for rate in [1.0, 3.0] {
        let case = sil_rates::RateCase {
            motion: "cross",
            rate_deg_s: rate,
        };
        let report = sil::run(&sil_rates::config(&case, 100, 40)).unwrap();
        let (nees, n) = trailed_nees(&report);
        eprintln!(
            "{rate} deg/s: {n} trailed stars, NEES along {:.3}, across {:.3}",
            nees[0], nees[1]
        );
        assert!(n >= 500, "{rate} deg/s: {n} stars");
        for v in nees {
            assert!((0.85..=1.25).contains(&v), "{rate} deg/s: {nees:?}");
        }
    }
}

/// The committed rate table (docs/tracker.md, "At body rate").
pub const RATES_CSV: &str = "host-tests/figures/sil-rates.csv";

/// The rate table in short (one seeded attitude, 12 frames, at rest, 1 and 2 deg/s across
/// the boresight, the flight timing): every frame has an attitude from power-on (two
/// acquisition frames, the second giving the rate, then the catalog's windows), none is
/// wrong, and from the third frame on the catalog predicts every frame's windows. The long
/// table (docs/tracker.md, "At body rate") states the rest.
#[test]
fn rate_table_in_short_has_no_wrong_attitude() {
    let frames = 12;
    for i in [0, 2, 3] {
        let case = sil_rates::RATE_CASES[i];
        let report = sil::run(&sil_rates::config(&case, 100, frames)).unwrap();
        let mut row = sil_rates::RateRow::default();
        sil_rates::add_run(&mut row, &report, &mut sil_rates::Sums::default());
        assert_eq!(row.frames, frames as usize);
        assert_eq!(row.wrong, 0, "{case:?}: {row:?}");
        assert_eq!(row.solved, row.frames, "{case:?}: {row:?}");
        for f in &report.frames[2..] {
            assert_eq!(f.summary.mode, Mode::Tracking, "{case:?}");
            assert!(
                f.predicted_windows >= 20,
                "{case:?}: frame {}",
                f.summary.frame
            );
        }
    }
}

/// Runs and frames a run of the full rate table: 10 seeded attitudes (seeds 100-109) of 300
/// frames (14.8 s) a rate, 3000 frames: with none missed, the availability is above 99.9 %
/// at 95 % confidence (no miss in `n` frames puts the miss rate below `3 / n`).
pub const RATE_TABLE_RUNS: (u64, u32) = (10, 300);

/// The full rate table: every rate of [`sil_rates::RATE_CASES`] over [`RATE_TABLE_RUNS`] at
/// the flight configuration, written to [`RATES_CSV`]. Minutes in the test profile:
/// `cargo test -p startrack-host --test tracker sil_motion::rate_table -- --ignored --nocapture`.
#[test]
#[ignore = "Monte Carlo over six rates, minutes; its CSV is committed"]
fn rate_table_writes_its_csv() {
    let (runs, frames) = RATE_TABLE_RUNS;
    let rows: Vec<_> = sil_rates::RATE_CASES
        .iter()
        .map(|c| {
            let r = sil_rates::run_case(c, 100, runs, frames).unwrap();
            eprintln!("{c:?}: {r:?}");
            r
        })
        .collect();
    let text = sil_rates::csv(
        &rows,
        &[
            "The SIL over the sky turning during 39 ms exposures every 49.4 ms (the flight configuration), 10 seeded attitudes (seeds 100-109) of 300 frames a rate, from power-on.",
            "cargo test -p startrack-host --test tracker sil_motion::rate_table -- --ignored --nocapture",
        ],
    );
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(RATES_CSV);
    std::fs::write(&path, &text).unwrap();
    eprint!("{text}");
}

/// The exposure chart's CSV, beside the rate table's.
pub const EXPOSURE_CSV: &str = "host-tests/figures/exposure-chart.csv";

/// The exposure chart: every exposure of [`exposure_chart::EXPOSURES_MS`] at every rate of
/// [`exposure_chart::RATES_DEG_S`], one seeded attitude (seed 200) of
/// [`exposure_chart::FRAMES`] frames a point, written to [`EXPOSURE_CSV`] and its PNG beside
/// it. Minutes in the test profile:
/// `cargo test -p startrack-host --test tracker sil_motion::exposure_chart -- --ignored --nocapture`.
#[test]
#[ignore = "Monte Carlo over 36 points, minutes; its CSV and PNG are committed"]
fn exposure_chart_writes_its_csv_and_png() {
    use startrack_analysis::exposure_chart;
    let mut points = Vec::new();
    for &rate in &exposure_chart::RATES_DEG_S {
        for &ms in &exposure_chart::EXPOSURES_MS {
            let p = exposure_chart::run_point(rate, ms, 200, exposure_chart::FRAMES).unwrap();
            eprintln!("{p:?}");
            points.push(p);
        }
    }
    let text = exposure_chart::csv(
        &points,
        &[
            "The SIL over the sky turning across the boresight during exposures back to back, one seeded attitude (seed 200) of 6 frames a point; a point trailing more than 30 px an exposure is not run (0 frames).",
            "cargo test -p startrack-host --test tracker sil_motion::exposure_chart -- --ignored --nocapture",
        ],
    );
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    std::fs::write(root.join(EXPOSURE_CSV), &text).unwrap();
    let written = exposure_chart::plot(
        &points,
        &root.join("host-tests/figures"),
        "exposure-chart.png",
    )
    .unwrap();
    eprintln!("{written:?}");
    eprint!("{text}");
}

/// The star signal follows the exposure: the same still sky over a 50 ms exposure gives each
/// star half the electrons of the 100 ms reference's.
#[test]
fn star_signal_scales_with_the_exposure() {
    let bytes = startrack_sim::sky::scene::committed_catalog().unwrap();
    let cat = startrack_core::catalog::Catalog::parse(&bytes).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let q0 = random_attitude(&mut rng);
    let scene = |exposure_s: f64| {
        let profile = RateProfile::constant([0.0; 3]);
        let motion = ExposureMotion::new(profile, exposure_s, exposure_s).unwrap();
        SkyScene::ccd47_15deg_moving(q0, motion)
    };
    let (long, short) = (scene(0.1), scene(0.05));
    let (a, b) = (long.stars(&cat, 0, 1.2), short.stars(&cat, 0, 1.2));
    assert!(a.len() > 10 && a.len() == b.len());
    for (s, t) in a.iter().zip(&b) {
        assert!((t.signal_e - 0.5 * s.signal_e).abs() < 1e-9 * s.signal_e);
    }
}

/// The rate table's run of seed 100 ([`sil_rates::config`]) slewing from rest across the
/// boresight at `accel_deg_s2` to `rate_deg_s`, exposures of `exposure_ms` every
/// `period_us` (the tracker told them), `frames` frames.
fn slew(
    rate_deg_s: f64,
    accel_deg_s2: f64,
    exposure_ms: u32,
    period_us: u64,
    frames: u32,
) -> SilConfig {
    let case = sil_rates::RateCase {
        motion: "cross",
        rate_deg_s,
    };
    let mut config = sil_rates::config(&case, 100, frames);
    if let Some(m) = config.sky.as_mut().and_then(|s| s.motion.as_mut()) {
        m.profile.accel_rad_s2 = accel_deg_s2.to_radians();
        m.exposure_s = f64::from(exposure_ms) * 1e-3;
        m.period_s = period_us as f64 * 1e-6;
    }
    config.tracker.exposure_ms = exposure_ms;
    config.period_us = period_us;
    // The platform's bound is the slew's own acceleration (at least the cycle's default).
    config.max_accel_rad_s2 = accel_deg_s2.to_radians().max(config.max_accel_rad_s2);
    config
}

/// A slew from rest to 3 deg/s across the boresight (2 deg/s^2, the rate reached at 1.5 s,
/// frame 30) at the flight timing, 39 ms exposures every 49.4 ms (7.9 px trails at 3 deg/s):
/// after the first two frames' lost-in-space attitudes (the second for the rate) the
/// tracker never acquires again; every frame has an attitude, none is wrong
/// ([`sil_rates::is_wrong`]), and every frame's attitude is within 5 of its sigmas on each
/// axis: while the rate changes a star's centroid is past its mid-exposure position
/// (`k alpha T^2`, 0.46 to 1 arcsec here), which the attitude stage takes out with the
/// acceleration the rate filter measures, its uncertainty in the covariance (and before
/// the filter has the 4 attitudes that measure it, the platform's bound). The rate is
/// within 5 of its sigmas across the boresight too, but around the ramp's end (frames 28 to
/// 35: the jerk, which no model here holds, restarts the filter). From frame 2 every frame
/// but one (the restart's) tracks the catalog's predicted windows, its attitude from their
/// identities. Seconds in the test profile.
#[test]
fn catalog_windows_hold_a_slew_to_3_deg_s() {
    let config = slew(3.0, 2.0, 39, 49_400, 45);
    let report = sil::run(&config).unwrap();
    let mut unpredicted = 0;
    for f in &report.frames {
        let n = f.summary.frame;
        let expected = if n < 2 {
            Mode::Acquisition
        } else {
            Mode::Tracking
        };
        assert_eq!(f.summary.mode, expected, "frame {n}");
        let c = f.attitude.as_ref().unwrap();
        let fix = c.fix.as_ref().unwrap_or_else(|e| panic!("frame {n}: {e}"));
        let e = c.error_rad().unwrap();
        let a = &fix.attitude;
        let wrong = sil_rates::is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad());
        assert!(!wrong, "frame {n}: {e:?}");
        for (i, v) in e.iter().enumerate() {
            let sigma = a.cov_rad2[i][i].sqrt();
            assert!(
                v.abs() < 5.0 * sigma,
                "frame {n}: axis {i} {v:e} rad, sigma {sigma:e}"
            );
        }
        if let Some(r) = c.report.and_then(|r| r.rate)
            && !(28..=35).contains(&n)
        {
            for i in 0..2 {
                // The report's rate is the negative of the scene's body rate.
                let d = r.w_rad_s[i] + c.true_rate_rad_s[i];
                let sigma = r.cov_rad2_s2[i][i].sqrt();
                assert!(
                    d.abs() < 5.0 * sigma,
                    "frame {n}: rate axis {i} {d:e} rad/s, sigma {sigma:e}"
                );
            }
        }
        if n >= 2 && f.predicted_windows < 20 {
            unpredicted += 1;
        } else if n >= 2 {
            assert!(c.identified >= 20, "frame {n}: {} identified", c.identified);
        }
    }
    assert!(
        unpredicted <= 1,
        "{unpredicted} tracking frames without the catalog's windows"
    );
}

/// Slews from rest across the boresight (seed 100), each frame's mode, predicted windows,
/// stars identified by them, and attitude error against its bound per axis, printed with a
/// line per slew (frames, wrong, the largest error over its sigma on an axis across the
/// boresight): at the flight timing at 1 deg/s^2 to 2 deg/s, 2 deg/s^2 and 5 deg/s^2 to
/// 3 deg/s, and with 100 ms exposures every 100 ms at 1 deg/s^2 to 2 deg/s
/// (docs/tracker.md, "At body rate", quotes them). Seconds:
/// `cargo test -p startrack-host --test tracker sil_motion::slew_frames -- --ignored --nocapture`.
#[test]
#[ignore = "prints slews' frames for docs/tracker.md; asserts nothing"]
fn slew_frames() {
    const ARCSEC: f64 = 206_264.806;
    for (rate, accel, exposure_ms, period_us, frames) in [
        (2.0, 1.0, 39, 49_400, 60),
        (3.0, 2.0, 39, 49_400, 45),
        (3.0, 5.0, 39, 49_400, 45),
        (2.0, 1.0, 100, 100_000, 30),
    ] {
        let report = sil::run(&slew(rate, accel, exposure_ms, period_us, frames)).unwrap();
        let (mut wrong, mut worst, mut worst_rate) = (0, 0.0f64, 0.0f64);
        let (mut nees, mut n, mut rate_nees, mut n_rate) = (0.0, 0, 0.0, 0);
        for f in &report.frames {
            let c = f.attitude.as_ref().unwrap();
            let line =
                match (&c.fix, c.error_rad()) {
                    (Ok(fix), Some(e)) => {
                        let a = &fix.attitude;
                        let s: Vec<f64> = (0..3).map(|i| a.cov_rad2[i][i].sqrt()).collect();
                        let is_wrong =
                            sil_rates::is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad());
                        wrong += usize::from(is_wrong);
                        worst = worst.max((e[0] / s[0]).abs()).max((e[1] / s[1]).abs());
                        nees += a.nees(e).unwrap_or(f64::INFINITY);
                        n += 1;
                        let rate = c.report.and_then(|r| r.rate).map(|r| {
                        // The report's rate is the negative of the scene's body rate.
                        let d: [f64; 3] =
                            std::array::from_fn(|i| r.w_rad_s[i] + c.true_rate_rad_s[i]);
                        let sr: [f64; 3] = std::array::from_fn(|i| r.cov_rad2_s2[i][i].sqrt());
                        worst_rate = worst_rate.max((d[0] / sr[0]).abs()).max((d[1] / sr[1]).abs());
                        rate_nees += r.nees(d).unwrap_or(f64::INFINITY);
                        n_rate += 1;
                        format!(
                            "; rate error {:+.1} {:+.1} {:+.1} arcsec/s, sigma {:.1} {:.1} {:.1}",
                            d[0] * ARCSEC,
                            d[1] * ARCSEC,
                            d[2] * ARCSEC,
                            sr[0] * ARCSEC,
                            sr[1] * ARCSEC,
                            sr[2] * ARCSEC
                        )
                    });
                        format!(
                            "error {:+.2} {:+.2} {:+.2} arcsec, sigma {:.2} {:.2} {:.2}{}{}",
                            e[0] * ARCSEC,
                            e[1] * ARCSEC,
                            e[2] * ARCSEC,
                            s[0] * ARCSEC,
                            s[1] * ARCSEC,
                            s[2] * ARCSEC,
                            rate.unwrap_or_default(),
                            if is_wrong { ", wrong" } else { "" }
                        )
                    }
                    (Err(e), _) => e.to_string(),
                    _ => String::new(),
                };
            eprintln!(
                "frame {:2} {:11} predicted {:2} identified {:2}: {line}",
                f.summary.frame,
                f.summary.mode.name(),
                f.predicted_windows,
                c.identified
            );
        }
        eprintln!(
            "slew to {rate} deg/s at {accel} deg/s^2, {exposure_ms} ms every {period_us} us: {} frames, {wrong} wrong, largest cross-boresight error {worst:.1} of its sigmas, mean NEES {:.2}; rate: largest cross-boresight error {worst_rate:.1} of its sigmas, mean NEES {:.2}",
            report.frames.len(),
            nees / f64::from(n.max(1)),
            rate_nees / f64::from(n_rate.max(1))
        );
    }
}
