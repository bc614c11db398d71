//! The SIL with bright objects, stray light and radiation ([`startrack_analysis::bright`]):
//! the targets on short scenes (no wrong attitude, an attitude in every frame with at least
//! three unaffected stars, recovery within two frames of the Moon leaving, the cause
//! flagged), the availability table behind `#[ignore]`, and the particle-hit test's
//! rejections of hits and of real stars.

use startrack_analysis::bright::{self, BrightRow};
use startrack_core::centroid::gauss_fit::{WidthFitParams, gauss_fit_width};
use startrack_core::centroid::{Background, CentroidInput};
use startrack_core::detect::{HitLimits, is_particle_hit};
use startrack_core::tracker::{HIT_MONITOR_FRACTION, HIT_WIDTH_FRACTION, TrackerConfig};
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_homes::demo::render_frame;
use startrack_homes::home::process_frame;
use startrack_sim::sim::protons::{ProtonEnv, ProtonHits};
use startrack_sim::sim::{SensorParams, Simulator};
use startrack_test_support::field::field;

/// The availability table's CSV.
pub const BRIGHT_CSV: &str = "host-tests/figures/bright-availability.csv";

fn check_targets(r: &BrightRow) {
    assert_eq!(r.wrong, 0, "{r:?}");
    // Every frame's flags are true of it: none stale, none without its cause.
    assert_eq!(r.wrong_flags, 0, "{r:?}");
    assert_eq!(
        r.eligible_solved, r.eligible,
        "attitude where 3 stars are clear: {r:?}"
    );
    match r.scene.as_str() {
        "moon leaving" => {
            assert!(r.flagged_moon > 0 && r.masked > 0, "{r:?}");
            assert!(r.recovery_frames.is_some_and(|k| k <= 2), "{r:?}");
        }
        "earth limb" => assert!(r.flagged_earth > 0 && r.flagged_moon == 0, "{r:?}"),
        "sun 32 deg" => assert_eq!(r.flagged_sun, r.frames, "{r:?}"),
        "venus" => assert!(
            r.masked > 0 && r.flagged_moon + r.flagged_earth == 0,
            "{r:?}"
        ),
        "saa" | "flare" => assert!(r.flagged_radiation > 0 && r.hits > 0, "{r:?}"),
        _ => {}
    }
}

/// Every short scene: no wrong attitude, an attitude wherever three stars are clear, the
/// Moon's recovery within 2 frames, the cause flagged, no frame's flags wrong. About 20 s
/// in the test profile.
#[test]
fn short_bright_scenes_meet_the_targets() {
    for case in bright::short_cases(10) {
        let r = bright::run_case(&case, 7).unwrap();
        eprintln!("{r:?}");
        check_targets(&r);
    }
}

/// The availability table: the short scenes over 100 frames and the Moon crossing the whole
/// field (1,230 frames), written to [`BRIGHT_CSV`] and asserted as the short test does.
/// About four minutes in the test profile:
/// `cargo test -p startrack-host --test tracker sil_bright::availability_table -- --ignored --nocapture`.
#[test]
#[ignore = "the bright scenes over 100 to 1,230 frames, minutes; its CSV is committed"]
fn availability_table_writes_its_csv() {
    let mut cases = bright::short_cases(100);
    cases.push(bright::moon_crossing());
    let rows: Vec<BrightRow> = cases
        .iter()
        .map(|c| {
            let r = bright::run_case(c, 7).unwrap();
            eprintln!("{r:?}");
            r
        })
        .collect();
    let text = bright::csv(
        &rows,
        &[
            "The SIL's still sky (seed 7) with bright objects, stray light and protons; the flight tracker, 100 ms frames.",
            "cargo test -p startrack-host --test tracker sil_bright::availability_table -- --ignored --nocapture",
        ],
    );
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(BRIGHT_CSV);
    std::fs::write(&path, &text).unwrap();
    eprint!("{text}");
    for r in &rows {
        check_targets(r);
    }
}

/// The hit test on the tracker tests' field with PSF variation (80 % radii 0.8 to 2 px about
/// a configured 1.4): no real star is rejected over 6 seeded frames of 60 stars, which is
/// what an earlier width-based hit flag did.
#[test]
fn no_real_star_is_taken_for_a_hit_with_psf_variation() {
    let config = TrackerConfig {
        max_stars: 1024,
        psf_a_px: 1.4,
        ..TrackerConfig::FLIGHT
    };
    let (mut stars, mut hits) = (0usize, 0usize);
    for seed in 11..17 {
        let (sim, table_bytes) = field(seed, 60);
        let table = startrack_core::table::CalibTable::parse(&table_bytes).unwrap();
        let raw = render_frame(&sim);
        let p = process_frame(table, &raw, config, None).unwrap();
        stars += p.stars.len();
        hits += usize::from(p.summary.hits);
    }
    eprintln!("{hits} hits among {stars} stars reported");
    assert!(stars >= 300, "{stars}");
    assert_eq!(hits, 0);
}

/// Which test catches which hit: SAA hits alone on a dark frame, each window around a hit's
/// brightest pixel measured as the tracker does (the width-free fit, the sharpness test of
/// [`is_particle_hit`]); printed with `--nocapture`. The tracker rejects a hit the
/// sharpness test calls one; the rest are reported, `POOR_FIT` (ranked below the clean
/// stars) when the fit's chi-square is high (here: above 3).
#[test]
fn which_test_catches_which_hit() {
    let params = SensorParams {
        seed: 5,
        ..SensorParams::default()
    };
    let psf_a_px = TrackerConfig::FLIGHT.psf_a_px;
    let limits = HitLimits::of_min_a(HIT_WIDTH_FRACTION * psf_a_px);
    let monitor = HitLimits::of_min_a(HIT_MONITOR_FRACTION * psf_a_px);
    let hits = ProtonHits::draw(ProtonEnv::Saa, 5, 0, 1024, 1024, 0.1);
    // Each track alone, its window 7 x 7 about its brightest pixel, on the sensor's dark
    // and read noise (no calibration: the dark's mean taken off).
    let sim = Simulator::new(params.clone(), Vec::new());
    let (mut sharp, mut counted, mut poor, mut passed, mut n) = (0, 0, 0, 0, 0);
    for t in hits.tracks.iter().take(120) {
        let c = [
            (t.from_px[0] + t.to_px[0]) / 2.0,
            (t.from_px[1] + t.to_px[1]) / 2.0,
        ];
        if !(10.0..1010.0).contains(&c[0]) || !(10.0..1010.0).contains(&c[1]) {
            continue;
        }
        let (cx, cy) = (c[0].round() as i64, c[1].round() as i64);
        let mut best = (0.0, cx, cy);
        for y in cy - 8..=cy + 8 {
            for x in cx - 8..=cx + 8 {
                let v = hits.at(x as usize, y as usize);
                if v > best.0 {
                    best = (v, x, y);
                }
            }
        }
        let rect = Rect {
            x0: (best.1 - 3) as u16,
            y0: (best.2 - 3) as u16,
            width: 7,
            height: 7,
        };
        let e: Vec<Electrons> = (0..49)
            .map(|k| {
                let (x, y) = (usize::from(rect.x0) + k % 7, usize::from(rect.y0) + k / 7);
                let noise = sim.params.read_noise_e
                    * (((x * 7919 + y * 104_729) % 1000) as f64 / 500.0 - 1.0);
                Electrons::from_num(hits.at(x, y) + noise)
            })
            .collect();
        let input = CentroidInput::new(Window::new(rect, &e).unwrap());
        let fit = gauss_fit_width(
            &input,
            &WidthFitParams {
                start_box: 5,
                background: Background::PerimeterMedian,
                ..WidthFitParams::new()
            },
        );
        if fit.centroid.snr < 3.0 {
            continue;
        }
        n += 1;
        counted += usize::from(is_particle_hit(&input, &monitor));
        if is_particle_hit(&input, &limits) {
            sharp += 1;
        } else if fit.chi2_dof > 3.0 {
            poor += 1;
        } else {
            passed += 1;
        }
    }
    eprintln!(
        "of {n} SAA hits: counted by the monitor {counted}; rejected by the sharpness test {sharp}, else chi-square (POOR_FIT, ranked below) {poor}, passed as stars {passed}"
    );
    assert!(n >= 50, "{n}");
    assert!(sharp + poor >= n * 7 / 10, "{sharp} {poor} of {n}");
    assert!(counted >= n / 10, "{counted} of {n}");
}

/// The sharpness test on noise-free images: no Gaussian star wider than the limit (0.6 px)
/// is a hit at any sub-pixel phase (the limit is the centred star's ratio), and a
/// diffusion-wide point charge (sigma 0.3 px) is one.
#[test]
fn sharpness_limit_holds_at_every_phase() {
    use startrack_core::centroid::test_only_math::pixel_fraction;
    let limits = HitLimits::of_min_a(0.6);
    let image = |sigma: f32, cx: f32, cy: f32, flux: f32| -> Vec<Electrons> {
        (0..49)
            .map(|k| {
                let (x, y) = ((k % 7) as f32, (k / 7) as f32);
                Electrons::from_num(
                    100.0 + flux * pixel_fraction(x, cx, sigma) * pixel_fraction(y, cy, sigma),
                )
            })
            .collect()
    };
    let rect = Rect {
        x0: 100,
        y0: 100,
        width: 7,
        height: 7,
    };
    let hit = |e: &[Electrons]| {
        is_particle_hit(&CentroidInput::new(Window::new(rect, e).unwrap()), &limits)
    };
    for a in [0.65f32, 0.8, 1.2, 2.0] {
        let sigma = 0.31f32.sqrt() * a;
        for i in 0..5 {
            for j in 0..5 {
                let (cx, cy) = (3.0 + 0.2 * i as f32 - 0.4, 3.0 + 0.2 * j as f32 - 0.4);
                assert!(!hit(&image(sigma, cx, cy, 1e5)), "a {a} at ({cx}, {cy})");
            }
        }
    }
    assert!(hit(&image(0.3, 3.0, 3.0, 1e4)));
}

/// Radiation while turning: the SIL's sky turning at 1 deg/s across the boresight (2.65 px
/// trails in the flight's 39 ms exposures, a frame every 50 ms) from power-on, at the SAA's
/// and a solar flare's proton rates, three seeded attitudes of 20 frames each: no wrong
/// attitude in any frame, every frame's flags true of it, radiation flagged, and at both
/// rates lost in space from power-on in the first frame and an attitude in every frame (60
/// of 60): the acquisition's lists keep the stars that agree with the frame's common trail
/// before the round hits and the tracks ([`startrack_core::detect::CommonMotion`]), and
/// the kept records off it and brighter than the stars on it are left out of the attitude
/// (docs/tracker.md, "Radiation while turning").
#[test]
fn turning_with_protons_is_never_wrong() {
    for env in [ProtonEnv::Saa, ProtonEnv::Flare] {
        let mut solved = 0;
        for seed in 1..=3 {
            let (r, first) = bright::run_turning(env, 1.0, 20, seed).unwrap();
            eprintln!(
                "{} seed {seed}: first attitude {first:?}, {r:?}",
                env.name()
            );
            assert_eq!(r.wrong, 0, "{r:?}");
            assert_eq!(r.wrong_flags, 0, "{r:?}");
            assert!(r.flagged_radiation > 0, "{r:?}");
            solved += r.solved;
            assert_eq!(first, Some(0), "lost in space from power-on: {r:?}");
            assert_eq!(r.solved, r.frames, "{r:?}");
        }
        eprintln!("{}: {solved} of 60 frames with an attitude", env.name());
    }
}
