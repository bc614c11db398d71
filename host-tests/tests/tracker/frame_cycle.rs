//! The core's frame cycle as the SIL runs it: every frame's summary goes into housekeeping
//! (the cycle's `Health` and the link's report agree with the frames' own counters), and over
//! the sky every frame carries the attitude stage's result.

use rand::SeedableRng;
use startrack_core::safe::ThermoSource;
use startrack_core::tracker::{Mode, TrackerConfig};
use startrack_homes::sil::{self, SilConfig};
use startrack_sim::sky::field::{FieldSpec, random_attitude};
use startrack_sim::sky::scene::SkyScene;

/// A sky run of `frames` frames whose star list keeps at most `max_stars`.
fn run(frames: u32, max_stars: u16) -> sil::SilReport {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let q0 = random_attitude(&mut rng);
    let f = FieldSpec::ccd47_15deg(0.0).camera.focal_length_px;
    let config = SilConfig {
        frames,
        sky: Some(SkyScene::ccd47_15deg(q0, [0.2 / f, 0.3 / f, 1e-5])),
        tracker: TrackerConfig {
            max_stars,
            ..SilConfig::default().tracker
        },
        ..SilConfig::default()
    };
    sil::run(&config).unwrap()
}

#[test]
fn housekeeping_follows_every_frame_of_the_cycle() {
    let frames = 20;
    // A star list cut to 6 a frame, so that the loss counters are not all zero.
    let r = run(frames, 6);
    let h = r.health;
    let last = r.frames.last().unwrap().summary;
    let sum = |f: &dyn Fn(&startrack_core::tracker::FrameSummary) -> u32| -> u32 {
        r.frames.iter().map(|fr| f(&fr.summary)).sum()
    };
    assert_eq!(h.frames, frames);
    assert_eq!(h.mode, last.mode);
    assert_eq!(h.frames_uncalibrated, sum(&|s| u32::from(!s.calibrated)));
    assert_eq!(h.lines_refused, sum(&|s| u32::from(s.lines_refused)));
    assert_eq!(h.track_lost, sum(&|s| u32::from(s.track_lost)));
    let lost = sum(&|s| {
        s.candidates_dropped
            + u32::from(s.windows_dropped)
            + u32::from(s.ring_lost)
            + u32::from(s.calib_failed)
            + u32::from(s.stars_dropped)
    });
    assert!(lost > 0, "the capped star list drops stars");
    assert_eq!(h.stars_lost, lost);
    // No thermometer in the SIL: housekeeping says so.
    assert_eq!(
        (h.temperature_k, h.temperature_source),
        (None, ThermoSource::None)
    );
    // The SIL's clock after the last frame's lines: its instant plus its exposure and the
    // board's readout of what it read, between a frame transfer (10.4 ms) and a full frame
    // (605.4 ms).
    let sil = SilConfig::default();
    let instant_ms = u64::from(last.frame) * sil.period_us / 1000;
    let read_from_ms = instant_ms + u64::from(sil.tracker.exposure_ms);
    assert!(
        (read_from_ms + 10..=read_from_ms + 606).contains(&h.uptime_ms),
        "{} ms, frame at {instant_ms} ms",
        h.uptime_ms
    );
    // The link's report counts the same frames.
    let hk = r.housekeeping;
    assert_eq!(hk.totals.frames, frames);
    assert_eq!(
        hk.totals.stars_dropped,
        sum(&|s| u32::from(s.stars_dropped))
    );
    assert_eq!(
        (hk.frame, hk.mode, hk.stars),
        (last.frame, last.mode, last.stars)
    );
    assert!(r.frames.iter().any(|fr| fr.summary.mode == Mode::Tracking));
}

#[test]
fn every_sky_frame_of_the_cycle_has_the_attitude_stage_result() {
    let r = run(6, SilConfig::default().tracker.max_stars);
    for fr in &r.frames {
        let check = fr
            .attitude
            .as_ref()
            .expect("a sky frame runs the attitude stage");
        let fix = check.fix.as_ref().expect("the field is identified");
        assert!(fix.matched >= 10, "frame {}: {fix:?}", fr.summary.frame);
        let e = check.error_rad().unwrap();
        assert!(
            e.iter().all(|v| v.abs() < sil::WRONG_ATTITUDE_RAD),
            "frame {}: {e:?}",
            fr.summary.frame
        );
    }
}
