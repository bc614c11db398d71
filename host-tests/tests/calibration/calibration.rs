//! Calibrated electrons against an f64 reference of the same formula, over the full input
//! range: random raw lines, maps and levels on both outputs, the covered-column dark scale,
//! hot and telegraph pixels, and the extremes (all 0, all 65535, maps at their limits).

use fixed::types::U8F8;
use proptest::prelude::*;
use startrack_core::calib::formula::QUANTISATION_E;
use startrack_core::calib::hot::{HOT_DARK_REL_TOL, hot_dark_e};
use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::geometry::{Output, ReadoutGeometry};
use startrack_core::table::{
    CalibTable, HotPixel, HotPolicy, MapHeader, MapSpec, TableSpec, write_table,
};
use startrack_core::units::{
    ColumnBiasAdu, DarkRel, ERatePerS, Electrons, FlatInv, GainEPerAdu, Kelvin,
};
use startrack_core::window::Rect;

/// A small sensor: 4 over-scan, 3 covered, 10 x 6 active, two outputs (5 active columns each).
const G: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 4,
    covered_px: 3,
    active_cols: 10,
    active_rows: 6,
    lines: 7,
    outputs: 2,
};

#[derive(Clone, Debug)]
struct Maps {
    gains: Vec<GainEPerAdu>,
    column_bias: Vec<ColumnBiasAdu>,
    tile_log2: u8,
    dark: Vec<DarkRel>,
    flat: Vec<FlatInv>,
    hot: Vec<HotPixel>,
    telegraph: Vec<(u16, u16)>,
}

fn tiles(tile_log2: u8) -> usize {
    MapHeader::for_area(G.active_cols, G.active_rows, tile_log2).tiles()
}

fn maps() -> impl Strategy<Value = Maps> {
    (0u8..3).prop_flat_map(|t| {
        let n = tiles(t);
        (
            prop::collection::vec(1u32.., 2),
            prop::collection::vec(any::<i16>(), G.line_len()),
            prop::collection::vec(any::<u8>(), n),
            prop::collection::vec(1u16.., n),
            prop::collection::btree_map(
                (0u16..6, 0u16..10),
                (any::<u32>(), 1u16.., any::<bool>()),
                0..4,
            ),
            prop::collection::btree_set((0u16..6, 0u16..10), 0..3),
        )
            .prop_map(move |(g, cb, d, f, hot, tel)| {
                // A pixel is either hot or telegraph, not both.
                let telegraph = tel
                    .into_iter()
                    .map(|(y, x)| (x, y))
                    .filter(|&(x, y)| !hot.contains_key(&(y, x)))
                    .collect();
                Maps {
                    gains: g.into_iter().map(GainEPerAdu::from_bits).collect(),
                    column_bias: cb.into_iter().map(ColumnBiasAdu::from_bits).collect(),
                    tile_log2: t,
                    dark: d.into_iter().map(DarkRel::from_bits).collect(),
                    flat: f.into_iter().map(FlatInv::from_bits).collect(),
                    hot: hot
                        .into_iter()
                        .map(|((y, x), (rate, dbl, excl))| HotPixel {
                            x,
                            y,
                            rate_e_per_s: ERatePerS::from_bits(rate),
                            doubling_k: U8F8::from_bits(dbl),
                            policy: if excl {
                                HotPolicy::Exclude
                            } else {
                                HotPolicy::Correct
                            },
                        })
                        .collect(),
                    telegraph,
                }
            })
    })
}

const T_REF: f64 = 293.0;

fn encode(m: &Maps, sat: u16) -> Vec<u8> {
    let spec = TableSpec {
        geometry: G,
        saturation_adu: sat,
        gains: &m.gains,
        column_bias: Some(&m.column_bias),
        dark_rel: Some(MapSpec {
            tile_log2: m.tile_log2,
            tiles: &m.dark,
        }),
        flat_inv: Some(MapSpec {
            tile_log2: m.tile_log2,
            tiles: &m.flat,
        }),
        hot_ref_k: Kelvin::from_num(T_REF),
        hot: &m.hot,
        telegraph: &m.telegraph,
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    };
    let mut buf = vec![0u8; spec.encoded_len()];
    let n = write_table(&spec, &mut buf).expect("valid spec");
    assert_eq!(n, buf.len());
    buf
}

/// f64 median of the over-scan samples an output reads.
fn ref_bias(line: &[u16], output: usize) -> f64 {
    let (s, e) = G.overscan_cols(Output(output as u8));
    let mut v: Vec<f64> = line[s..e].iter().map(|&r| f64::from(r)).collect();
    v.sort_by(f64::total_cmp);
    (v[(v.len() - 1) / 2] + v[v.len() / 2]) / 2.0
}

fn gain_f(m: &Maps, col: usize) -> f64 {
    m.gains[G.output_of_col(col).0 as usize].to_num::<f64>()
}

/// The covered pixel `col` of `line` in electrons, f64.
fn ref_covered_e(m: &Maps, line: &[u16], col: usize) -> f64 {
    let out = G.output_of_col(col).0 as usize;
    (f64::from(line[col]) - ref_bias(line, out) - m.column_bias[col].to_num::<f64>())
        * gain_f(m, col)
}

/// Mean of the covered pixels of `lines` within 5 robust sigmas of their line's median (the
/// estimator's definition, in f64; the values are first rounded to 1/64 e- as the core does).
fn ref_dark_scale(m: &Maps, lines: &[Vec<u16>]) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for line in lines {
        let v: Vec<f64> = G
            .covered_cols()
            .iter()
            .flat_map(|&(s, e)| s..e)
            .map(|c| ref_covered_e(m, line, c))
            .collect();
        // The band is applied in 1/64 e- units, as the core does, so that no sample sits on
        // a different side of it through rounding alone.
        let mut v: Vec<i64> = v.into_iter().map(|x| (x * 64.0).round() as i64).collect();
        v.sort();
        let k = v.len();
        let sigma = ((v[3 * k / 4] - v[k / 4]) * 1000 / 1349).max(64);
        for x in v.iter().filter(|x| (*x - v[k / 2]).abs() <= 5 * sigma) {
            sum += *x as f64 / 64.0;
            n += 1;
        }
    }
    sum / n as f64
}

fn tile_index(m: &Maps, x: usize, y: usize) -> usize {
    let h = MapHeader::for_area(G.active_cols, G.active_rows, m.tile_log2);
    (y >> m.tile_log2) * h.tiles_x as usize + (x >> m.tile_log2)
}

/// The calibration formula in f64 for active pixel (x, y), with `dark_e` the dark charge.
fn ref_pixel(m: &Maps, line: &[u16], x: usize, y: usize, dark_e: f64) -> f64 {
    let col = G.raw_col_of_x(x);
    let out = G.output_of_col(col).0 as usize;
    let d = f64::from(line[col]) - ref_bias(line, out) - m.column_bias[col].to_num::<f64>();
    let inv = m.flat[tile_index(m, x, y)].to_num::<f64>();
    (d * gain_f(m, col) - dark_e) * inv
}

fn ref_hot_dark(h: &HotPixel, temp_k: f64, exposure_ms: u32) -> f64 {
    let f = 2f64.powf(((temp_k - T_REF) / h.doubling_k.to_num::<f64>()).clamp(-64.0, 64.0));
    (h.rate_e_per_s.to_num::<f64>() * f64::from(exposure_ms) * 1e-3 * f).min(4.0 * 1048576.0)
}

/// Calibrates every active row and checks each pixel against the reference.
fn check_frame(
    m: &Maps,
    lines: &[Vec<u16>],
    sat: u16,
    exposure_ms: u32,
    temp_k: f64,
) -> Result<(), TestCaseError> {
    let bytes = encode(m, sat);
    let table = CalibTable::parse(&bytes).expect("written table parses");
    let mut est = DarkScaleEstimator::new();
    let levels: Vec<LineLevels> = lines
        .iter()
        .map(|l| LineLevels::measure(&G, l).unwrap())
        .collect();
    for (l, lv) in lines.iter().zip(&levels) {
        for o in 0..2 {
            prop_assert_eq!(lv.bias(Output(o as u8)).to_num::<f64>(), ref_bias(l, o));
        }
        est.add_line(&table, l, lv).unwrap();
    }
    let scale = est.estimate().unwrap();
    let want_scale = ref_dark_scale(m, lines).clamp(-1048576.0, 1048576.0);
    // Each covered value is rounded to 1/64 e- before averaging, then the mean is rounded.
    prop_assert!(
        (scale.to_num::<f64>() - want_scale).abs() <= 1.0 / 64.0,
        "dark scale {} vs {}",
        scale,
        want_scale
    );

    let cond = FrameConditions {
        dark_scale_e: scale,
        exposure_ms,
        temperature_k: Kelvin::from_num(temp_k),
    };
    let cal = FrameCalibration::new(table, cond);
    let scale_f = scale.to_num::<f64>();
    for (y, (line, lv)) in lines
        .iter()
        .zip(&levels)
        .enumerate()
        .take(G.active_rows as usize)
    {
        let mut e = vec![Electrons::ZERO; G.active_cols as usize];
        let mut f = vec![PixelFlags::empty(); e.len()];
        let all = cal
            .calibrate_span(y as u16, 0, line, lv, &mut e, &mut f)
            .unwrap();
        prop_assert_eq!(all, f.iter().fold(PixelFlags::empty(), |a, b| a | *b));
        for x in 0..G.active_cols as usize {
            let raw = line[G.raw_col_of_x(x)];
            prop_assert_eq!(f[x].contains(PixelFlags::SATURATED), raw >= sat);
            let hot = m
                .hot
                .iter()
                .find(|h| (h.x as usize, h.y as usize) == (x, y));
            let tel = m.telegraph.contains(&(x as u16, y as u16));
            let got = e[x].to_num::<f64>();
            match (hot, tel) {
                (Some(h), _) if h.policy == HotPolicy::Exclude => {
                    prop_assert!(f[x].contains(PixelFlags::HOT_EXCLUDED) && got == 0.0);
                }
                (_, true) => prop_assert!(f[x].contains(PixelFlags::TELEGRAPH) && got == 0.0),
                (Some(h), _) => {
                    prop_assert!(f[x].contains(PixelFlags::HOT_CORRECTED));
                    let dark = ref_hot_dark(h, temp_k, exposure_ms);
                    let want = ref_pixel(m, line, x, y, dark);
                    let inv = m.flat[tile_index(m, x, y)].to_num::<f64>();
                    let tol =
                        QUANTISATION_E + (f64::from(HOT_DARK_REL_TOL) * dark + 1.0 / 64.0) * inv;
                    prop_assert!((got - want).abs() <= tol, "hot ({x},{y}): {got} vs {want}");
                }
                (None, false) => {
                    prop_assert!(!f[x].intersects(
                        PixelFlags::HOT_CORRECTED
                            | PixelFlags::HOT_EXCLUDED
                            | PixelFlags::TELEGRAPH
                    ));
                    let dark = m.dark[tile_index(m, x, y)].to_num::<f64>() * scale_f;
                    let want = ref_pixel(m, line, x, y, dark);
                    prop_assert!(
                        (got - want).abs() <= QUANTISATION_E,
                        "({x},{y}): {got} vs {want}"
                    );
                }
            }
        }
    }
    Ok(())
}

fn raw_lines() -> impl Strategy<Value = Vec<Vec<u16>>> {
    prop::collection::vec(
        prop::collection::vec(any::<u16>(), G.line_len()),
        G.lines as usize,
    )
}

/// Lines with a realistic structure: bias near `bias`, covered pixels with dark, active
/// pixels anywhere, and a cosmic-ray hit in one over-scan element.
fn structured_lines() -> impl Strategy<Value = Vec<Vec<u16>>> {
    (0u16..60000, 0u16..2000, raw_lines()).prop_map(|(bias, dark, mut lines)| {
        for (i, l) in lines.iter_mut().enumerate() {
            for (c, v) in l.iter_mut().enumerate() {
                let noise = *v % 16;
                *v = match G.segment(c) {
                    Some(startrack_core::geometry::Segment::OverScan) => bias + noise,
                    Some(startrack_core::geometry::Segment::Covered) => {
                        bias + dark.min(65535 - bias - 16) + noise
                    }
                    _ => *v,
                };
            }
            l[i % 4] = 65535;
        }
        lines
    })
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(300)))]

    #[test]
    fn random_everything_matches_f64(m in maps(), lines in raw_lines(), sat in any::<u16>(),
                                     exp in 0u32..100_000, temp in 150.0f64..350.0) {
        check_frame(&m, &lines, sat, exp, temp)?;
    }

    #[test]
    fn structured_frames_match_f64(m in maps(), lines in structured_lines(), exp in 0u32..10_000) {
        check_frame(&m, &lines, 65535, exp, 253.0)?;
    }

    /// A window calibrates to exactly the same values as the spans of the same pixels.
    #[test]
    fn window_equals_spans(m in maps(), lines in raw_lines(), x0 in 0u16..10, y0 in 0u16..6, w in 0u16..=10, h in 0u16..=6) {
        let (w, h) = (w.min(10 - x0), h.min(6 - y0));
        let bytes = encode(&m, 60000);
        let table = CalibTable::parse(&bytes).unwrap();
        let cal = FrameCalibration::new(table, FrameConditions {
            dark_scale_e: Electrons::from_num(250), exposure_ms: 1000, temperature_k: Kelvin::from_num(260) });
        let rect = Rect { x0, y0, width: w, height: h };
        let levels: Vec<LineLevels> = lines.iter().map(|l| LineLevels::measure(&G, l).unwrap()).collect();
        let raw: Vec<u16> = (y0..y0 + h).flat_map(|y| {
            let l = &lines[y as usize];
            (x0..x0 + w).map(move |x| l[G.raw_col_of_x(x as usize)])
        }).collect();
        let mut e = vec![Electrons::ZERO; rect.len()];
        let mut f = vec![PixelFlags::empty(); rect.len()];
        cal.calibrate_window(rect, &raw, &levels[y0 as usize..(y0 + h) as usize], &mut e, &mut f).unwrap();
        for r in 0..h {
            let y = y0 + r;
            let mut se = vec![Electrons::ZERO; w as usize];
            let mut sf = vec![PixelFlags::empty(); w as usize];
            cal.calibrate_span(y, x0, &lines[y as usize], &levels[y as usize], &mut se, &mut sf).unwrap();
            let row = (r * w) as usize..((r + 1) * w) as usize;
            prop_assert_eq!(&e[row.clone()], &se[..]);
            prop_assert_eq!(&f[row], &sf[..]);
        }
    }
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(300)))]

    /// Any sub-span (any start, any length, across tile and output boundaries) calibrates to
    /// the same bits as those pixels of the whole line, which `check_frame` compares to f64:
    /// the per-run hoisting of the look-ups in `calibrate_span` starts runs anywhere.
    #[test]
    fn sub_spans_equal_whole_line(m in maps(), lines in raw_lines(), y in 0u16..6, x0 in 0u16..10, w in 1u16..=10) {
        let w = w.min(10 - x0);
        let bytes = encode(&m, 60000);
        let table = CalibTable::parse(&bytes).unwrap();
        let cal = FrameCalibration::new(table, FrameConditions {
            dark_scale_e: Electrons::from_num(-37.25), exposure_ms: 1000, temperature_k: Kelvin::from_num(260) });
        let line = &lines[y as usize];
        let lv = LineLevels::measure(&G, line).unwrap();
        let mut e = vec![Electrons::ZERO; 10];
        let mut f = vec![PixelFlags::empty(); 10];
        cal.calibrate_span(y, 0, line, &lv, &mut e, &mut f).unwrap();
        let mut se = vec![Electrons::ZERO; w as usize];
        let mut sf = vec![PixelFlags::empty(); w as usize];
        cal.calibrate_span(y, x0, line, &lv, &mut se, &mut sf).unwrap();
        prop_assert_eq!(&e[x0 as usize..(x0 + w) as usize], &se[..]);
        prop_assert_eq!(&f[x0 as usize..(x0 + w) as usize], &sf[..]);
    }
}

/// Maps at their limits in every combination with raw lines at 0 and 65535: no overflow, and
/// still within the quantisation of the f64 reference.
#[test]
fn extremes_match_f64() {
    let n = tiles(0);
    for gain in [1u32, u32::MAX] {
        for cb in [i16::MIN, 0, i16::MAX] {
            for rel in [0u8, 255] {
                for inv in [1u16, u16::MAX] {
                    for (os, cov, act) in [
                        (0u16, 0u16, 0u16),
                        (0, 65535, 65535),
                        (65535, 0, 0),
                        (65535, 65535, 65535),
                        (0, 65535, 0),
                    ] {
                        let m = Maps {
                            gains: vec![GainEPerAdu::from_bits(gain); 2],
                            column_bias: vec![ColumnBiasAdu::from_bits(cb); G.line_len()],
                            tile_log2: 0,
                            dark: vec![DarkRel::from_bits(rel); n],
                            flat: vec![FlatInv::from_bits(inv); n],
                            hot: vec![],
                            telegraph: vec![],
                        };
                        let line: Vec<u16> = (0..G.line_len())
                            .map(|c| match G.segment(c) {
                                Some(startrack_core::geometry::Segment::OverScan) => os,
                                Some(startrack_core::geometry::Segment::Covered) => cov,
                                _ => act,
                            })
                            .collect();
                        let lines = vec![line; G.lines as usize];
                        check_frame(&m, &lines, 65535, 1000, 293.0).unwrap_or_else(|e| {
                            panic!(
                                "gain {gain} cb {cb} rel {rel} inv {inv} ({os},{cov},{act}): {e}"
                            )
                        });
                    }
                }
            }
        }
    }
}

/// The largest and smallest possible calibrated values sit inside the documented bound
/// (±21.1 M e-) and do not clamp.
#[test]
fn calibrated_range_bound() {
    let bytes = encode(
        &Maps {
            gains: vec![GainEPerAdu::MAX; 2],
            column_bias: vec![ColumnBiasAdu::MIN; G.line_len()],
            tile_log2: 0,
            dark: vec![DarkRel::MAX; tiles(0)],
            flat: vec![FlatInv::MAX; tiles(0)],
            hot: vec![],
            telegraph: vec![],
        },
        65535,
    );
    let table = CalibTable::parse(&bytes).unwrap();
    for (raw, bias, scale) in [(65535u16, 0u16, -1048576i32), (0, 65535, 1048576)] {
        let mut line = vec![raw; G.line_len()];
        for o in 0..2 {
            let (s, e) = G.overscan_cols(Output(o));
            line[s..e].fill(bias);
        }
        let lv = LineLevels::measure(&G, &line).unwrap();
        let cal = FrameCalibration::new(
            table,
            FrameConditions {
                dark_scale_e: Electrons::from_num(scale),
                exposure_ms: 0,
                temperature_k: Kelvin::from_num(273),
            },
        );
        let mut e = [Electrons::ZERO; 10];
        let mut f = [PixelFlags::empty(); 10];
        cal.calibrate_span(0, 0, &line, &lv, &mut e, &mut f)
            .unwrap();
        for v in e {
            let v = v.to_num::<f64>();
            assert!(v.abs() > 2.0e7 && v.abs() < 21.1e6, "{v}");
        }
    }
}

/// micromath's powf keeps the hot-pixel law within its documented tolerance over the range
/// of temperatures and doubling intervals a flight unit meets.
#[test]
fn hot_dark_law_accuracy() {
    let mut worst = 0f64;
    for dbl in [3.0, 5.5, 6.3, 8.0, 12.0] {
        for t10 in 2000..3300 {
            let t = f64::from(t10) / 10.0;
            let h = HotPixel {
                x: 0,
                y: 0,
                rate_e_per_s: ERatePerS::from_num(1000),
                doubling_k: U8F8::from_num(dbl),
                policy: HotPolicy::Correct,
            };
            let want = ref_hot_dark(&h, t, 10_000);
            if !(1.0..=1.0e6).contains(&want) {
                continue;
            }
            let got = hot_dark_e(&h, Kelvin::from_num(T_REF), Kelvin::from_num(t), 10_000)
                .to_num::<f64>();
            // Beyond the relative tolerance, the output is rounded to 1/64 e-.
            worst = worst.max(((got - want).abs() - 1.0 / 128.0).max(0.0) / want);
        }
    }
    assert!(
        worst < f64::from(HOT_DARK_REL_TOL),
        "worst relative error {worst}"
    );
}

/// Lines of the wrong length and spans outside the active area are typed errors.
#[test]
fn bad_spans_are_errors() {
    use startrack_core::calib::{CalibError, LineError};
    let m = Maps {
        gains: vec![GainEPerAdu::ONE; 2],
        column_bias: vec![ColumnBiasAdu::ZERO; G.line_len()],
        tile_log2: 1,
        dark: vec![DarkRel::ONE; tiles(1)],
        flat: vec![FlatInv::ONE; tiles(1)],
        hot: vec![],
        telegraph: vec![],
    };
    let bytes = encode(&m, 65535);
    let table = CalibTable::parse(&bytes).unwrap();
    let cal = FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: Electrons::ZERO,
            exposure_ms: 0,
            temperature_k: Kelvin::from_num(273),
        },
    );
    let line = vec![100u16; G.line_len()];
    assert_eq!(
        LineLevels::measure(&G, &line[1..]),
        Err(LineError::Length {
            expected: G.line_len() as u16,
            got: G.line_len() as u32 - 1
        })
    );
    let lv = LineLevels::measure(&G, &line).unwrap();
    let mut e = [Electrons::ZERO; 3];
    let mut f = [PixelFlags::empty(); 3];
    assert_eq!(
        cal.calibrate_span(0, 8, &line, &lv, &mut e, &mut f),
        Err(CalibError::OutsideActiveArea)
    );
    assert_eq!(
        cal.calibrate_span(6, 0, &line, &lv, &mut e, &mut f),
        Err(CalibError::OutsideActiveArea)
    );
    assert_eq!(
        cal.calibrate_span(0, 0, &line, &lv, &mut e, &mut f[..2]),
        Err(CalibError::BufferLength)
    );
    let rect = Rect {
        x0: 0,
        y0: 0,
        width: 3,
        height: 1,
    };
    assert_eq!(
        cal.calibrate_window(rect, &line[..3], &[], &mut e, &mut f),
        Err(CalibError::BufferLength)
    );
    assert_eq!(
        cal.calibrate_span(0, 0, &line, &lv, &mut e, &mut f),
        Ok(PixelFlags::empty())
    );
}

/// A cosmic-ray hit in the over-scan leaves the bias where it was; one in the covered
/// columns leaves the frame's dark scale within a fraction of an electron.
#[test]
fn levels_are_robust_to_a_cosmic_ray() {
    let m = Maps {
        gains: vec![GainEPerAdu::ONE; 2],
        column_bias: vec![ColumnBiasAdu::ZERO; G.line_len()],
        tile_log2: 0,
        dark: vec![DarkRel::ONE; tiles(0)],
        flat: vec![FlatInv::ONE; tiles(0)],
        hot: vec![],
        telegraph: vec![],
    };
    let bytes = encode(&m, 65535);
    let table = CalibTable::parse(&bytes).unwrap();
    // Over-scan at 1000 +- 2 ADU, covered at 1250 +- 3 (250 e- of dark at 1 e-/ADU).
    let line = |y: usize| -> Vec<u16> {
        (0..G.line_len())
            .map(|c| {
                let wiggle = ((c * 7 + y * 3) % 5) as u16;
                match G.segment(c) {
                    Some(startrack_core::geometry::Segment::OverScan) => 998 + wiggle,
                    Some(startrack_core::geometry::Segment::Covered) => {
                        1247 + wiggle + (c % 2) as u16
                    }
                    _ => 1000,
                }
            })
            .collect()
    };
    let mut clean = DarkScaleEstimator::new();
    let mut hit = DarkScaleEstimator::new();
    for y in 0..G.lines as usize {
        let l = line(y);
        let lv = LineLevels::measure(&G, &l).unwrap();
        clean.add_line(&table, &l, &lv).unwrap();
        let mut h = l.clone();
        // One hit in an over-scan element of each output and one in a covered pixel.
        h[G.overscan_cols(Output(0)).0] = 65535;
        h[G.overscan_cols(Output(1)).0] = 65535;
        h[G.covered_cols()[y % 2].0] = 60000;
        let lvh = LineLevels::measure(&G, &h).unwrap();
        for o in 0..2 {
            let shift =
                (lvh.bias(Output(o)).to_num::<f64>() - lv.bias(Output(o)).to_num::<f64>()).abs();
            // The median moves by at most one rank: half the spread of the clean samples.
            assert!(shift <= 2.0, "output {o} bias moved {shift} ADU");
        }
        hit.add_line(&table, &h, &lv).unwrap();
    }
    let (c, h) = (
        clean.estimate().unwrap().to_num::<f64>(),
        hit.estimate().unwrap().to_num::<f64>(),
    );
    assert!((c - 250.0).abs() < 3.0, "{c}");
    assert!(
        (h - c).abs() < 0.5,
        "a cosmic ray moved the dark scale from {c} to {h}"
    );
}
