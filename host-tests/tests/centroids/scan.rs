//! The raw pre-filtered scan (`detect::ScanDetector`) against the calibrated path
//! (`LineDetector` fed every calibrated line, same background stride): the candidates must be
//! identical, bit for bit, on simulated CCD47-20 frames, including maps with a large spread
//! of dark, flat and column bias; and the scan must calibrate only a small part of a quiet
//! frame (otherwise it is no faster). The closed-blob reports of acquisition
//! (`push_raw_line_closed` against `LineDetector::push_line_closed`) must agree line by line.

use startrack_core::calib::{FrameCalibration, FrameConditions, LineLevels, PixelFlags};
use startrack_core::detect::{DetectConfig, LineDetector, ScanDetector};
use startrack_core::table::CalibTable;
use startrack_core::units::{Electrons, Kelvin};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};

struct Frame {
    table: Vec<u8>,
    lines: Vec<(Vec<u16>, LineLevels)>,
    dark_scale_e: Electrons,
    params: SensorParams,
}

fn frame(params: SensorParams, n_stars: usize, tile_log2: u8) -> Frame {
    let stars = startrack_homes::demo::star_field(params.seed, n_stars, &params);
    let sim = Simulator::new(params.clone(), stars);
    let g = params.geometry;
    let table = sim
        .truth_table_tiled(TruthSections::ALL, tile_log2)
        .unwrap();
    let parsed = CalibTable::parse(&table).unwrap();
    let raw = startrack_homes::demo::render_frame(&sim);
    let levels = startrack_homes::home::frame_levels(&parsed, &raw).unwrap();
    let lines = raw
        .chunks_exact(g.line_len())
        .map(<[u16]>::to_vec)
        .zip(levels.lines)
        .collect();
    Frame {
        table,
        lines,
        dark_scale_e: levels.dark_scale_e.unwrap(),
        params,
    }
}

/// Runs both paths, the reference through `LineDetector::push_line_closed` and the scan
/// through `ScanDetector::push_raw_line_closed` (as the firmware's acquisition), checking
/// line by line that both report the same closed candidates and dropped counts, and that the
/// scan's whole calibrated line (background rows only) is the reference's. With
/// `dark_steps`, the dark scale changes every 3 lines (as the firmware's first frame, which
/// calibrates each line with the running estimate): the reference calibrates each line with
/// it, the scan gets it through `set_conditions`. Returns (reference, scan, calibrated
/// fraction). `warmup`: rows that all update the background (`with_background_warmup`).
fn both(
    f: &Frame,
    stride: u16,
    warmup: u16,
    dark_steps: bool,
) -> (LineDetector<256>, ScanDetector<'_, 256>, f64) {
    let g = f.params.geometry;
    let table = CalibTable::parse(&f.table).unwrap();
    let conditions = |y: usize| FrameConditions {
        dark_scale_e: if dark_steps {
            // Steps of -80 %, 0 and +80 % around the frame's estimate, every 3 lines (inside
            // tile rows of 8): far more than the running estimate moves, so that bounds
            // kept from another dark scale would show.
            f.dark_scale_e * Electrons::from_num(0.2 + 0.8 * ((y / 3) % 3) as f64)
        } else {
            f.dark_scale_e
        },
        exposure_ms: 1000,
        temperature_k: Kelvin::from_num(293),
    };
    let mut reference =
        LineDetector::<256>::new(DetectConfig::default(), g.active_cols, g.active_rows)
            .with_background_stride(stride)
            .with_background_warmup(warmup);
    let mut scan = ScanDetector::<256>::new(
        FrameCalibration::new(table, conditions(0)),
        DetectConfig::default(),
        stride,
    )
    .with_background_warmup(warmup);
    let mut e = vec![Electrons::ZERO; usize::from(g.active_cols)];
    let mut fl = vec![PixelFlags::empty(); e.len()];
    let (mut closed_ref, mut closed_scan) = (Default::default(), Default::default());
    let mut closed_total = 0usize;
    for (y, (raw, lv)) in f.lines.iter().enumerate().take(usize::from(g.active_rows)) {
        let cal = FrameCalibration::new(table, conditions(y));
        cal.calibrate_span(y as u16, 0, raw, lv, &mut e, &mut fl)
            .unwrap();
        let whole = reference.background_due(y as u16);
        reference
            .push_line_closed(y as u16, &e, &fl, &mut closed_ref)
            .unwrap();
        scan.set_conditions(conditions(y));
        scan.push_raw_line_closed(y as u16, raw, lv, &mut closed_scan)
            .unwrap();
        assert_eq!(sorted(&closed_ref), sorted(&closed_scan), "line {y}");
        assert_eq!(reference.dropped(), scan.detector().dropped(), "line {y}");
        closed_total += closed_ref.len();
        match scan.whole_line() {
            Some((se, sf)) => {
                assert!(whole, "line {y}: a whole line off the background rows");
                assert_eq!((se, sf), (&e[..], &fl[..]), "line {y}");
            }
            None => assert!(!whole, "line {y}: background row not reported whole"),
        }
    }
    reference.finish_closed(&mut closed_ref);
    scan.finish_closed(&mut closed_scan);
    assert_eq!(sorted(&closed_ref), sorted(&closed_scan), "finish");
    closed_total += closed_ref.len();
    // Every candidate was reported once, when it closed (the list never overflows here).
    if reference.dropped() == 0 {
        assert_eq!(closed_total, reference.candidates().len());
    }
    let total = f64::from(g.active_cols) * f64::from(g.active_rows);
    let frac = f64::from(scan.calibrated_px()) / total;
    (reference, scan, frac)
}

fn sorted(c: &[startrack_core::detect::Detection]) -> Vec<startrack_core::detect::Detection> {
    let mut v = c.to_vec();
    v.sort_by_key(|a| (a.peak_y, a.peak_x));
    v
}

#[test]
fn scan_equals_calibrated_path_on_simulated_frames() {
    for (seed, stride) in [(3u64, 1u16), (5, 8), (7, 64)] {
        let f = frame(
            SensorParams {
                seed,
                ..SensorParams::default()
            },
            60,
            3,
        );
        let (reference, scan, frac) = both(&f, stride, if seed == 7 { 16 } else { 0 }, seed == 5);
        assert!(
            reference.candidates().len() >= 40,
            "seed {seed}: only {} candidates",
            reference.candidates().len()
        );
        assert_eq!(
            sorted(reference.candidates()),
            sorted(scan.candidates()),
            "seed {seed} stride {stride}"
        );
        assert_eq!(reference.dropped(), scan.detector().dropped());
        assert_eq!(reference.dropped_pixels(), scan.detector().dropped_pixels());
        println!(
            "seed {seed} stride {stride}: {} candidates, {:.2} % of the pixels calibrated",
            scan.candidates().len(),
            100.0 * frac
        );
        // The background rows alone are 1/stride of the frame (1.6 % at 64); the pre-filter
        // passes the star pixels and the ~1 % of noise samples above 2.5 sigma, with the
        // spans between them.
        if stride == 64 {
            assert!(frac < 0.10, "calibrated {frac}");
        }
    }
}

/// The longest background stride the tracker's acquisition has used (64; its flight
/// configuration, `TrackerConfig::FLIGHT`, uses 16), and its warm-up rows: the most
/// demanding case for the noise estimate.
const FW_STRIDE: u16 = 64;
const FW_WARMUP: u16 = 16;

#[test]
fn scan_noise_candidates_no_more_than_with_every_row_background() {
    // Noise candidates (farther than 3 px from every true star) of the scan at stride 64
    // with 16 warm-up rows against a LineDetector updating its background on every
    // row, on 8 simulated frames of 25 stars. Both counts are Poisson with (under the
    // hypothesis of equal rates) the same mean: their difference has a standard deviation
    // of sqrt(a + b); the scan may exceed the reference by 3 of those, plus 1 for tiny
    // counts. Without the warm-up (stride 64 alone) the first row's noise estimate sets the
    // thresholds for hundreds of rows and the count jumps (32 against 0 on these frames,
    // measured): that must fail here. Every star found by the reference
    // must be found by the scan.
    let (mut noise_ref, mut noise_scan) = (0usize, 0usize);
    for seed in 30..38u64 {
        let f = frame(
            SensorParams {
                seed,
                ..SensorParams::default()
            },
            25,
            3,
        );
        let stars = startrack_homes::demo::star_field(seed, 25, &f.params);
        let g = f.params.geometry;
        let table = CalibTable::parse(&f.table).unwrap();
        let cal = FrameCalibration::new(
            table,
            FrameConditions {
                dark_scale_e: f.dark_scale_e,
                exposure_ms: 1000,
                temperature_k: Kelvin::from_num(293),
            },
        );
        let mut reference =
            LineDetector::<64>::new(DetectConfig::default(), g.active_cols, g.active_rows);
        let mut scan = ScanDetector::<64>::new(cal, DetectConfig::default(), FW_STRIDE)
            .with_background_warmup(FW_WARMUP);
        let mut e = vec![Electrons::ZERO; usize::from(g.active_cols)];
        let mut fl = vec![PixelFlags::empty(); e.len()];
        for (y, (raw, lv)) in f.lines.iter().enumerate().take(usize::from(g.active_rows)) {
            cal.calibrate_span(y as u16, 0, raw, lv, &mut e, &mut fl)
                .unwrap();
            reference.push_line(y as u16, &e, &fl).unwrap();
            scan.push_raw_line(y as u16, raw, lv).unwrap();
        }
        reference.finish();
        scan.finish();
        let dist = |d: &startrack_core::detect::Detection, s: &startrack_sim::sim::Star| {
            (f64::from(d.x_px) - s.x_px).hypot(f64::from(d.y_px) - s.y_px)
        };
        let noise = |c: &[startrack_core::detect::Detection]| {
            c.iter()
                .filter(|d| stars.iter().all(|s| dist(d, s) > 3.0))
                .count()
        };
        noise_ref += noise(reference.candidates());
        noise_scan += noise(scan.candidates());
        for s in &stars {
            let found =
                |c: &[startrack_core::detect::Detection]| c.iter().any(|d| dist(d, s) < 1.5);
            if found(reference.candidates()) {
                assert!(found(scan.candidates()), "seed {seed}: scan missed {s:?}");
            }
        }
    }
    let allowed = noise_ref as f64 + 3.0 * ((noise_ref + noise_scan) as f64).sqrt() + 1.0;
    println!("noise candidates in 8 frames: every-row background {noise_ref}, scan {noise_scan}");
    assert!(
        noise_scan as f64 <= allowed,
        "scan: {noise_scan} noise candidates, every-row background {noise_ref}"
    );
}

#[test]
fn scan_equals_calibrated_path_with_large_map_spread() {
    // Per-pixel maps with strong dark non-uniformity, flat variation and column bias: the
    // chunk bounds are loose, most chunks go to the exact path, and the result must not
    // change.
    let f = frame(
        SensorParams {
            seed: 9,
            dsnu: 0.5,
            prnu: 0.05,
            column_bias_sigma_adu: 40.0,
            dark_mean_e: 400.0,
            ..SensorParams::default()
        },
        40,
        0,
    );
    let (reference, scan, frac) = both(&f, 16, 4, true);
    assert_eq!(sorted(reference.candidates()), sorted(scan.candidates()));
    println!(
        "large spread: {:.2} % of the pixels calibrated",
        100.0 * frac
    );
}

#[test]
fn scan_equals_calibrated_path_when_the_bias_jumps() {
    // The quiet test's window is fixed when a tile row's bounds are computed, from that
    // line's bias: lines whose bias then drops far below it (the window's base goes
    // negative: the exact mask decides) or jumps far above it must still give the same
    // candidates. Every raw sample of a line (over-scan included, so the measured bias
    // follows) is offset by up to 20000 ADU, changing from line to line inside tile rows.
    let mut f = frame(
        SensorParams {
            seed: 11,
            ..SensorParams::default()
        },
        40,
        3,
    );
    let g = f.params.geometry;
    for (y, (raw, lv)) in f.lines.iter_mut().enumerate() {
        let offset: u16 = match (y % 8, y % 3) {
            (0, _) => 20_000,
            (_, 0) => 6_000,
            _ => 0,
        };
        for v in raw.iter_mut() {
            *v = v.saturating_add(offset);
        }
        *lv = LineLevels::measure(&g, raw).unwrap();
    }
    for stride in [8u16, 64] {
        let (reference, scan, frac) = both(&f, stride, 0, false);
        assert!(
            reference.candidates().len() >= 20,
            "only {} candidates",
            reference.candidates().len()
        );
        assert_eq!(
            sorted(reference.candidates()),
            sorted(scan.candidates()),
            "stride {stride}"
        );
        println!(
            "bias jumps, stride {stride}: {:.2} % of the pixels calibrated",
            100.0 * frac
        );
    }
}

mod random_tables {
    //! Random tables (any gain, flat, dark, column bias, tile size, hot and telegraph pixels,
    //! saturation, either sign of the dark scale) on random frames with bright spots: the
    //! pre-filter's bound must hold for all of them, so the candidates stay identical.

    use super::*;
    use fixed::types::{U8F8, U16F16};
    use proptest::prelude::*;
    use startrack_core::geometry::ReadoutGeometry;
    use startrack_core::table::{HotPixel, HotPolicy, MapHeader, MapSpec, TableSpec, write_table};
    use startrack_core::units::{ColumnBiasAdu, DarkRel, FlatInv, GainEPerAdu};

    /// 40 x 24 active, two outputs split at column 20 (inside a 16-pixel chunk).
    const G: ReadoutGeometry = ReadoutGeometry {
        overscan_px: 4,
        covered_px: 3,
        active_cols: 40,
        active_rows: 24,
        lines: 24,
        outputs: 2,
    };

    #[allow(clippy::too_many_arguments)]
    fn check(
        tile_log2: u8,
        gains: [u32; 2],
        column_bias: Vec<i16>,
        dark: Vec<u8>,
        flat: Vec<u16>,
        hot: Vec<(u16, u16, bool)>,
        spots: Vec<(u16, u16, u16)>,
        noise: Vec<u16>,
        sat: u16,
        dark_scale_bits: i32,
        stride: u16,
        uniform: bool,
    ) -> Result<(), TestCaseError> {
        // Uniform maps make the pre-filter's bound tight (a unit or two of 1/16 ADU from the
        // limit), so a bound that is too high shows; random maps test it under any spread.
        let (column_bias, dark, flat) = if uniform {
            (
                vec![column_bias[0]; column_bias.len()],
                vec![dark[0]],
                vec![flat[0]],
            )
        } else {
            (column_bias, dark, flat)
        };
        let n_tiles = MapHeader::for_area(G.active_cols, G.active_rows, tile_log2).tiles();
        let gains: Vec<GainEPerAdu> = gains.iter().map(|&g| GainEPerAdu::from_bits(g)).collect();
        let cb: Vec<ColumnBiasAdu> = column_bias
            .iter()
            .map(|&b| ColumnBiasAdu::from_bits(b))
            .collect();
        let dark: Vec<DarkRel> = dark
            .iter()
            .cycle()
            .take(n_tiles)
            .map(|&d| DarkRel::from_bits(d))
            .collect();
        let flat: Vec<FlatInv> = flat
            .iter()
            .cycle()
            .take(n_tiles)
            .map(|&f| FlatInv::from_bits(f))
            .collect();
        let mut hot: Vec<HotPixel> = hot
            .iter()
            .map(|&(x, y, ex)| HotPixel {
                x,
                y,
                rate_e_per_s: U16F16::from_num(50),
                doubling_k: U8F8::from_num(6),
                policy: if ex {
                    HotPolicy::Exclude
                } else {
                    HotPolicy::Correct
                },
            })
            .collect();
        hot.sort_by_key(|h| (h.y, h.x));
        hot.dedup_by_key(|h| (h.y, h.x));
        let telegraph = [(7u16, 5u16), (33, 17)];
        let spec = TableSpec {
            geometry: G,
            saturation_adu: sat,
            gains: &gains,
            column_bias: Some(&cb),
            dark_rel: Some(MapSpec {
                tile_log2,
                tiles: &dark,
            }),
            flat_inv: Some(MapSpec {
                tile_log2,
                tiles: &flat,
            }),
            hot_ref_k: Kelvin::from_num(263),
            hot: &hot,
            telegraph: &telegraph,
            cti: None,
            psf_model: None,
            camera_model: None,
            dark_law: None,
        };
        let mut buf = vec![0u8; spec.encoded_len()];
        write_table(&spec, &mut buf).unwrap();
        let table = CalibTable::parse(&buf).unwrap();
        let cal = FrameCalibration::new(
            table,
            FrameConditions {
                dark_scale_e: Electrons::from_bits(dark_scale_bits),
                exposure_ms: 500,
                temperature_k: Kelvin::from_num(270),
            },
        );
        // Every above-threshold pixel becomes a candidate (no peak, size or SNR cut), so a
        // single pixel the pre-filter wrongly drops changes the list.
        let config = DetectConfig {
            peak_sigmas: 0.0,
            min_pixels: 1,
            min_snr: -1.0,
            ..DetectConfig::default()
        };
        let mut reference = LineDetector::<256>::new(config, G.active_cols, G.active_rows)
            .with_background_stride(stride);
        let mut scan = ScanDetector::<256>::new(cal, config, stride);
        let mut e = vec![Electrons::ZERO; usize::from(G.active_cols)];
        let mut fl = vec![PixelFlags::empty(); e.len()];
        let (mut closed_ref, mut closed_scan) = (Default::default(), Default::default());
        let mut k = 0usize;
        for y in 0..G.active_rows {
            let line: Vec<u16> = (0..G.line_len())
                .map(|c| {
                    // Near-Gaussian noise (sum of four uniform draws): a tail past the 2.5 and
                    // 5 sigma thresholds, so samples sit at every distance from them.
                    let mut v = 1000u32;
                    for _ in 0..4 {
                        k += 1;
                        v += u32::from(noise[k % noise.len()] % 32);
                    }
                    if let Some(x) = c.checked_sub(G.first_active_col()) {
                        for &(sx, sy, a) in &spots {
                            if (x as u16).abs_diff(sx) <= 1 && y.abs_diff(sy) <= 1 {
                                v += u32::from(a);
                            }
                        }
                    }
                    v.min(65535) as u16
                })
                .collect();
            let lv = LineLevels::measure(&G, &line).unwrap();
            cal.calibrate_span(y, 0, &line, &lv, &mut e, &mut fl)
                .unwrap();
            reference
                .push_line_closed(y, &e, &fl, &mut closed_ref)
                .unwrap();
            scan.push_raw_line_closed(y, &line, &lv, &mut closed_scan)
                .unwrap();
            prop_assert_eq!(sorted(&closed_ref), sorted(&closed_scan), "line {}", y);
            prop_assert_eq!(reference.dropped(), scan.detector().dropped());
        }
        reference.finish_closed(&mut closed_ref);
        scan.finish_closed(&mut closed_scan);
        prop_assert_eq!(sorted(&closed_ref), sorted(&closed_scan));
        prop_assert_eq!(sorted(reference.candidates()), sorted(scan.candidates()));
        Ok(())
    }

    proptest! {
        #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(200)))]

        #[test]
        fn scan_equals_calibrated_path_on_random_tables(
            tile_log2 in 0u8..4,
            gains in [1u32..=u32::MAX, 1u32..=u32::MAX],
            column_bias in prop::collection::vec(any::<i16>(), G.line_len()),
            dark in prop::collection::vec(any::<u8>(), 1..40),
            flat in prop::collection::vec(1u16.., 1..40),
            hot in prop::collection::vec((0u16..40, 0u16..24, any::<bool>()), 0..4),
            spots in prop::collection::vec((0u16..40, 0u16..24, prop_oneof![0u16..200, 0u16..30000]), 0..8),
            noise in prop::collection::vec(any::<u16>(), 997..1500),
            sat in 1000u16..=65535,
            dark_scale_bits in -(1i32 << 20)..(1i32 << 20),
            stride in 1u16..6,
            uniform in any::<bool>(),
        ) {
            check(tile_log2, gains, column_bias, dark, flat, hot, spots, noise, sat, dark_scale_bits, stride, uniform)?;
        }
    }
}
