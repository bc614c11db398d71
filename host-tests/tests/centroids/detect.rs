//! Streaming detection: on a simulated CCD47-20 frame end to end, and the cases it must
//! handle: hot and telegraph pixels never detect, the candidate list keeps the brightest when
//! full, random frames never panic.

use proptest::prelude::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use startrack_core::calib::{FrameCalibration, FrameConditions, PixelFlags};
use startrack_core::detect::{DetectConfig, DetectError, DetectionFlags, LineDetector};
use startrack_core::table::CalibTable;
use startrack_core::units::{Electrons, Kelvin};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator, Star};

const W: u16 = 256;
const H: u16 = 128;

/// A synthetic calibrated frame: background 100 e-, noise sigma 10 e-, Gaussian stars.
fn synthetic(stars: &[(f64, f64, f64)], seed: u64) -> Vec<Vec<Electrons>> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, 10.0).unwrap();
    (0..H)
        .map(|y| {
            (0..W)
                .map(|x| {
                    let star: f64 = stars
                        .iter()
                        .map(|&(sx, sy, f)| {
                            let d2 = (f64::from(x) - sx).powi(2) + (f64::from(y) - sy).powi(2);
                            f / (2.0 * std::f64::consts::PI) * (-d2 / 2.0).exp()
                        })
                        .sum();
                    Electrons::from_num(100.0 + star + n.sample(&mut r))
                })
                .collect()
        })
        .collect()
}

fn run<const N: usize>(
    lines: &[Vec<Electrons>],
    flags: &dyn Fn(u16, u16) -> PixelFlags,
) -> LineDetector<N> {
    let mut d = LineDetector::<N>::new(DetectConfig::default(), W, H);
    for (y, l) in lines.iter().enumerate() {
        let f: Vec<PixelFlags> = (0..W).map(|x| flags(x, y as u16)).collect();
        d.push_line(y as u16, l, &f).unwrap();
    }
    d.finish();
    d
}

#[test]
fn finds_isolated_stars_and_nothing_else() {
    let stars = [
        (40.3, 30.7, 5000.0),
        (200.0, 90.2, 20000.0),
        (120.6, 64.4, 1500.0),
    ];
    let d = run::<16>(&synthetic(&stars, 1), &|_, _| PixelFlags::empty());
    assert_eq!(d.candidates().len(), 3, "{:?}", d.candidates());
    for &(sx, sy, f) in &stars {
        let c = d
            .candidates()
            .iter()
            .find(|c| (f64::from(c.x_px) - sx).abs() < 0.5 && (f64::from(c.y_px) - sy).abs() < 0.5)
            .unwrap_or_else(|| panic!("star at ({sx},{sy}) not found: {:?}", d.candidates()));
        // Above-threshold pixels hold most, not all, of the flux.
        assert!(
            f64::from(c.flux_e) > 0.5 * f && f64::from(c.flux_e) < 1.05 * f,
            "{c:?}"
        );
        assert!(c.snr > 3.0);
        assert!(c.flags.is_empty(), "{c:?}");
    }
}

#[test]
fn hot_and_telegraph_pixels_never_detect() {
    // Two 2x2 clusters of bright pixels, far above any threshold: they look like stars
    // unless calibration flags them.
    let mut lines = synthetic(&[], 2);
    let hot = |x: u16, y: u16| (50..52).contains(&x) && (20..22).contains(&y);
    let rts = |x: u16, y: u16| (150..152).contains(&x) && (80..82).contains(&y);
    for y in 0..H {
        for x in 0..W {
            if hot(x, y) || rts(x, y) {
                lines[usize::from(y)][usize::from(x)] = Electrons::from_num(50_000);
            }
        }
    }
    let unflagged = run::<16>(&lines, &|_, _| PixelFlags::empty());
    assert_eq!(
        unflagged.candidates().len(),
        2,
        "the same pixels unflagged are detected"
    );
    for (h, t) in [
        (PixelFlags::HOT_CORRECTED, PixelFlags::TELEGRAPH),
        (PixelFlags::HOT_EXCLUDED, PixelFlags::TELEGRAPH),
    ] {
        let flagged = run::<16>(&lines, &|x, y| {
            if hot(x, y) {
                h
            } else if rts(x, y) {
                t
            } else {
                PixelFlags::empty()
            }
        });
        assert!(
            flagged.candidates().is_empty(),
            "{:?}",
            flagged.candidates()
        );
    }
    // A lone bright pixel (a cosmic ray, an unlisted hot pixel) is not a star either.
    let mut single = synthetic(&[], 2);
    single[40][100] = Electrons::from_num(50_000);
    assert!(
        run::<16>(&single, &|_, _| PixelFlags::empty())
            .candidates()
            .is_empty()
    );
}

/// Ten separated stars (x px, y px, flux e-) on a diagonal, fluxes 2000..20000 e-: more
/// than a 4-entry list holds, each brighter than the last.
fn ten_stars() -> Vec<(f64, f64, f64)> {
    (0..10)
        .map(|i| {
            (
                20.0 + 22.0 * f64::from(i),
                20.0 + 9.0 * f64::from(i),
                2000.0 * f64::from(i + 1),
            )
        })
        .collect()
}

#[test]
fn full_list_keeps_the_brightest_and_counts_the_rest() {
    let stars = ten_stars();
    let d = run::<4>(&synthetic(&stars, 3), &|_, _| PixelFlags::empty());
    assert_eq!(d.dropped(), 6);
    let mut fluxes: Vec<f32> = d.candidates().iter().map(|c| c.flux_e).collect();
    fluxes.sort_by(f32::total_cmp);
    let mut all = run::<16>(&synthetic(&stars, 3), &|_, _| PixelFlags::empty())
        .candidates()
        .iter()
        .map(|c| c.flux_e)
        .collect::<Vec<_>>();
    assert_eq!(all.len(), 10);
    all.sort_by(f32::total_cmp);
    assert_eq!(fluxes, all[6..].to_vec());
}

#[test]
fn flags_edges_pairs_and_saturation() {
    let lines = synthetic(
        &[
            (0.4, 60.0, 20000.0),
            (100.0, 60.0, 30000.0),
            (104.0, 60.0, 30000.0),
            (180.0, 40.0, 20000.0),
        ],
        4,
    );
    let d = run::<16>(&lines, &|x, y| {
        if (x, y) == (180, 40) {
            PixelFlags::SATURATED
        } else {
            PixelFlags::empty()
        }
    });
    let at = |x: f32| {
        d.candidates()
            .iter()
            .find(|c| (c.x_px - x).abs() < 3.0)
            .unwrap_or_else(|| panic!("{x}: {:?}", d.candidates()))
    };
    assert!(at(0.5).flags.contains(DetectionFlags::EDGE));
    assert!(
        at(102.0).flags.contains(DetectionFlags::BLENDED),
        "{:?}",
        at(102.0)
    );
    assert!(at(180.0).flags.contains(DetectionFlags::SATURATED));
    assert!(
        !at(180.0).flags.contains(DetectionFlags::BLENDED),
        "{:?}",
        at(180.0)
    );
}

/// Close pairs that merge into one blob are flagged blended, at any orientation and flux
/// ratio down to 1:3; isolated stars across widths and SNR are not.
#[test]
fn close_pairs_are_flagged_blended_and_single_stars_are_not() {
    for (i, (dx, dy)) in [(4.0, 0.0), (0.0, 4.5), (3.5, 3.0), (5.0, 2.5)]
        .into_iter()
        .enumerate()
    {
        let lines = synthetic(
            &[(100.0, 60.0, 30_000.0), (100.0 + dx, 60.0 + dy, 10_000.0)],
            10 + i as u64,
        );
        let d = run::<16>(&lines, &|_, _| PixelFlags::empty());
        assert_eq!(d.candidates().len(), 1, "({dx},{dy}): {:?}", d.candidates());
        assert!(
            d.candidates()[0].flags.contains(DetectionFlags::BLENDED),
            "({dx},{dy}): {:?}",
            d.candidates()
        );
    }
    let singles: Vec<(f64, f64, f64)> = (0..12)
        .map(|i| {
            (
                15.0 + 19.3 * f64::from(i),
                30.0 + 6.1 * f64::from(i),
                300.0 * 2f64.powi(i % 6),
            )
        })
        .collect();
    for seed in 0..5 {
        let d = run::<16>(&synthetic(&singles, 20 + seed), &|_, _| PixelFlags::empty());
        for c in d.candidates() {
            assert!(
                !c.flags.contains(DetectionFlags::BLENDED),
                "seed {seed}: {c:?}"
            );
        }
    }
}

#[test]
fn bad_lines_are_typed_errors() {
    let mut d = LineDetector::<4>::new(DetectConfig::default(), W, H);
    let l = vec![Electrons::ZERO; usize::from(W)];
    let f = vec![PixelFlags::empty(); usize::from(W)];
    assert_eq!(
        d.push_line(0, &l[1..], &f[1..]),
        Err(DetectError::LineLength)
    );
    assert_eq!(d.push_line(0, &l, &f[1..]), Err(DetectError::LineLength));
    d.push_line(5, &l, &f).unwrap();
    assert_eq!(d.push_line(5, &l, &f), Err(DetectError::RowOrder));
}

/// End to end on the simulated sensor: calibrate each line with the core, detect, and match
/// against the simulator's stars.
#[test]
fn simulated_frame_end_to_end() {
    let params = SensorParams {
        seed: 11,
        ..SensorParams::default()
    };
    let stars = startrack_homes::demo::star_field(11, 25, &params);
    let sim = Simulator::new(params.clone(), stars.clone());
    let g = params.geometry;
    let table = sim.truth_table(TruthSections::ALL).unwrap();
    let table = CalibTable::parse(&table).unwrap();
    let raw = startrack_homes::demo::render_frame(&sim);
    let levels = startrack_homes::home::frame_levels(&table, &raw).unwrap();
    let lines: Vec<_> = raw.chunks_exact(g.line_len()).zip(&levels.lines).collect();
    let cal = FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: levels.dark_scale_e.unwrap(),
            exposure_ms: 1000,
            temperature_k: Kelvin::from_num(293),
        },
    );
    let mut d = LineDetector::<64>::new(DetectConfig::default(), g.active_cols, g.active_rows);
    let mut e = vec![Electrons::ZERO; usize::from(g.active_cols)];
    let mut f = vec![PixelFlags::empty(); e.len()];
    for (y, (raw, lv)) in lines.iter().enumerate().take(usize::from(g.active_rows)) {
        cal.calibrate_span(y as u16, 0, raw, lv, &mut e, &mut f)
            .unwrap();
        d.push_line(y as u16, &e, &f).unwrap();
    }
    d.finish();
    let matched = |s: &Star| {
        d.candidates().iter().any(|c| {
            (f64::from(c.x_px) - s.x_px).abs() < 1.0 && (f64::from(c.y_px) - s.y_px).abs() < 1.0
        })
    };
    for s in &stars {
        assert!(matched(s), "missed {s:?}");
    }
    let false_alarms = d
        .candidates()
        .iter()
        .filter(|c| {
            !stars.iter().any(|s| {
                (f64::from(c.x_px) - s.x_px).abs() < 3.0 && (f64::from(c.y_px) - s.y_px).abs() < 3.0
            })
        })
        .count();
    assert_eq!(false_alarms, 0, "{:?}", d.candidates());
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(64)))]
    /// Any values and flags: no panic, every candidate finite and inside the area.
    #[test]
    fn random_frames_never_panic(bits in prop::collection::vec((any::<i32>(), 0u8..16), 48 * 24), bright in any::<bool>()) {
        let (w, h) = (48u16, 24u16);
        let mut d = LineDetector::<8>::new(DetectConfig::default(), w, h);
        for y in 0..h {
            let row = &bits[usize::from(y * w)..usize::from((y + 1) * w)];
            let e: Vec<Electrons> = row.iter().map(|(b, _)| Electrons::from_bits(if bright { *b } else { *b >> 16 })).collect();
            let f: Vec<PixelFlags> = row.iter().map(|(_, f)| PixelFlags::from_bits_truncate(*f)).collect();
            d.push_line(y, &e, &f).unwrap();
        }
        d.finish();
        // Overflow policy: a loss is only counted when the list is full.
        prop_assert!(d.candidates().len() <= 8);
        prop_assert!(d.dropped() == 0 || d.candidates().len() == 8);
        for c in d.candidates() {
            prop_assert!(c.x_px.is_finite() && c.y_px.is_finite() && c.snr.is_finite() && c.flux_e.is_finite());
            prop_assert!(c.x_px >= 0.0 && c.x_px <= f32::from(w - 1) && c.y_px >= 0.0 && c.y_px <= f32::from(h - 1));
        }
    }
}

/// `push_line_closed` reports each kept candidate once, on the line that completed it (a
/// line after the blob's rows), and `finish_closed` the rest: together, the final list.
#[test]
fn closed_candidates_are_reported_once_when_their_blob_ends() {
    let stars = ten_stars();
    let lines = synthetic(&stars, 3);
    let flags = vec![PixelFlags::empty(); usize::from(W)];
    for capacity_limited in [false, true] {
        let mut d16 = LineDetector::<16>::new(DetectConfig::default(), W, H);
        let mut d4 = LineDetector::<4>::new(DetectConfig::default(), W, H);
        let mut reported = Vec::new();
        for (y, l) in lines.iter().enumerate() {
            let y = y as u16;
            if capacity_limited {
                let mut closed = Default::default();
                d4.push_line_closed(y, l, &flags, &mut closed).unwrap();
                reported.extend(closed.iter().map(|c| (y, *c)));
            } else {
                let mut closed = Default::default();
                d16.push_line_closed(y, l, &flags, &mut closed).unwrap();
                reported.extend(closed.iter().map(|c| (y, *c)));
            }
        }
        let finals: Vec<_> = if capacity_limited {
            let mut closed = Default::default();
            d4.finish_closed(&mut closed);
            reported.extend(closed.iter().map(|c| (H, *c)));
            d4.candidates().to_vec()
        } else {
            let mut closed = Default::default();
            d16.finish_closed(&mut closed);
            reported.extend(closed.iter().map(|c| (H, *c)));
            d16.candidates().to_vec()
        };
        for (y, c) in &reported {
            assert!(
                c.peak_y < *y,
                "reported at {y} before its peak row {}",
                c.peak_y
            );
        }
        // Every final candidate was reported exactly once.
        for f in &finals {
            assert_eq!(reported.iter().filter(|(_, c)| c == f).count(), 1, "{f:?}");
        }
        if capacity_limited {
            // Brighter candidates that replaced fainter ones were reported too, and those
            // replaced later are not in the final list: more reports than final entries.
            assert!(reported.len() >= finals.len());
            assert_eq!(finals.len(), 4);
        } else {
            assert_eq!(reported.len(), 10);
            assert_eq!(finals.len(), 10);
        }
    }
}
