//! The fused raw-window corrected CoG (`centroid::raw_cog`) against an f64 evaluation of the
//! calibration formula and against the general path (`calibrate_window` + `cog` with the given
//! background, box anchored on the same pixel), over random tables, levels and raw samples of
//! the full 16-bit range; its fall-backs and flags; its error estimate against the scatter of
//! a seeded Monte Carlo; and no panic on arbitrary input. The per-box plan
//! (`RawCogPlan`): plan + apply equals the one-shot `raw_cog` bit for bit, a stale plan is
//! refused.

use startrack_test_support::psf;

use fixed::types::U8F8;
use proptest::prelude::*;
use psf::{Rng, Star, Win, add_noise, render, sigma_of_a};
use startrack_analysis::accuracy::flux_for_snr;
use startrack_core::calib::formula::QUANTISATION_E;
use startrack_core::calib::{FrameCalibration, FrameConditions, LineLevels, PixelFlags};
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::raw_cog::{
    MAX_BOX_SIDE, PlanError, RawCog, RawCogParams, RawCogPlan, RawWindow, raw_cog,
};
use startrack_core::centroid::{Background, Centroid, CentroidFlags, CentroidInput};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::{
    CalibTable, HotPixel, HotPolicy, MapHeader, MapSpec, TableSpec, write_table,
};
use startrack_core::units::{
    ColumnBiasAdu, DARK_SCALE_LIMIT_E, DarkRel, ERatePerS, Electrons, FlatInv, GainEPerAdu,
};
use startrack_core::window::{Rect, Window};

/// 40 x 24 active pixels on two outputs (the split at active column 20).
const G: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 4,
    covered_px: 3,
    active_cols: 40,
    active_rows: 24,
    lines: 25,
    outputs: 2,
};

/// 2^-24: one f32 rounding, relative.
const EPS: f64 = 1.0 / 16_777_216.0;

/// A calibration table's contents.
#[derive(Clone, Debug)]
struct Maps {
    gains: [u32; 2],
    column_bias: Vec<i16>,
    tile_log2: u8,
    dark: Vec<u8>,
    flat: Vec<u16>,
    dark_scale_bits: i32,
    saturation_adu: u16,
    hot: Vec<HotPixel>,
    telegraph: Vec<(u16, u16)>,
    /// False: the table has no column-bias, dark or flat section (neutral values).
    with_maps: bool,
}

fn tiles(tile_log2: u8) -> usize {
    MapHeader::for_area(G.active_cols, G.active_rows, tile_log2).tiles()
}

impl Maps {
    /// A plain table: gain `gain` e-/ADU on both outputs, no column bias, dark or flat map.
    fn plain(gain: f64) -> Self {
        let n = tiles(3);
        Self {
            gains: [GainEPerAdu::from_num(gain).to_bits(); 2],
            column_bias: vec![0; G.line_len()],
            tile_log2: 3,
            dark: vec![DarkRel::ONE.to_bits(); n],
            flat: vec![FlatInv::ONE.to_bits(); n],
            dark_scale_bits: 0,
            saturation_adu: 65_535,
            hot: vec![],
            telegraph: vec![],
            with_maps: true,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        let gains = self.gains.map(GainEPerAdu::from_bits);
        let cb: Vec<ColumnBiasAdu> = self
            .column_bias
            .iter()
            .map(|b| ColumnBiasAdu::from_bits(*b))
            .collect();
        let dark: Vec<DarkRel> = self.dark.iter().map(|b| DarkRel::from_bits(*b)).collect();
        let flat: Vec<FlatInv> = self.flat.iter().map(|b| FlatInv::from_bits(*b)).collect();
        let spec = TableSpec {
            geometry: G,
            saturation_adu: self.saturation_adu,
            gains: &gains,
            column_bias: self.with_maps.then_some(&cb[..]),
            dark_rel: self.with_maps.then_some(MapSpec {
                tile_log2: self.tile_log2,
                tiles: &dark,
            }),
            flat_inv: self.with_maps.then_some(MapSpec {
                tile_log2: self.tile_log2,
                tiles: &flat,
            }),
            hot_ref_k: fixed::types::U16F16::from_num(263),
            hot: &self.hot,
            telegraph: &self.telegraph,
            cti: None,
            psf_model: None,
            camera_model: None,
            dark_law: None,
        };
        let mut buf = vec![0u8; spec.encoded_len()];
        let n = write_table(&spec, &mut buf).expect("table writes");
        buf.truncate(n);
        buf
    }

    fn conditions(&self) -> FrameConditions {
        FrameConditions {
            dark_scale_e: Electrons::from_bits(self.dark_scale_bits),
            exposure_ms: 200,
            temperature_k: fixed::types::U16F16::from_num(258),
        }
    }

    /// The exact value of the calibration formula (f64) for active pixel (x, y), and its two
    /// terms' magnitudes `|A d| + |K|`.
    fn exact_e(&self, x: u16, y: u16, raw: u16, bias_16: i64) -> (f64, f64) {
        let col = G.raw_col_of_x(usize::from(x));
        let out = usize::from(G.output_of_col(col).0);
        let ti = {
            let h = MapHeader::for_area(G.active_cols, G.active_rows, self.tile_log2);
            let tx = usize::from(x >> self.tile_log2);
            let ty = usize::from(y >> self.tile_log2);
            ty * usize::from(h.tiles_x) + tx
        };
        let (cb, dark, flat) = if self.with_maps {
            (self.column_bias[col], self.dark[ti], self.flat[ti])
        } else {
            (0, DarkRel::ONE.to_bits(), FlatInv::ONE.to_bits())
        };
        let d = 16 * i64::from(raw) - bias_16.min(65_535 * 16) - i64::from(cb);
        let lim = DARK_SCALE_LIMIT_E.to_bits();
        let ds = self.dark_scale_bits.clamp(-lim, lim);
        let dark_16 = i64::from(dark) * i64::from(ds) * 16;
        let flat = f64::from(flat) / 16_384.0;
        let ad = d as f64 * f64::from(self.gains[out]) / 4_294_967_296.0 * flat;
        let k = dark_16 as f64 / 65_536.0 * flat;
        (ad - k, ad.abs() + k.abs())
    }

    /// Number of cells of equal constants a box covers (column runs x tile rows).
    fn cells(&self, b: Rect) -> usize {
        let l = if self.with_maps { self.tile_log2 } else { 16 };
        let runs = |keys: Vec<(usize, u32)>| 1 + keys.windows(2).filter(|w| w[0] != w[1]).count();
        let cols = runs(
            (b.x0..b.x0 + b.width)
                .map(|x| {
                    let o = usize::from(G.output_of_col(G.raw_col_of_x(usize::from(x))).0);
                    (o, u32::from(x) >> l)
                })
                .collect(),
        );
        let rows = runs(
            (b.y0..b.y0 + b.height)
                .map(|y| (0, u32::from(y) >> l))
                .collect(),
        );
        cols * rows
    }
}

/// A raw line whose over-scan strips read `bias` (per output): the levels measure exactly it.
fn levels_for(bias: [u16; 2]) -> LineLevels {
    let mut line = vec![0u16; G.line_len()];
    let os = usize::from(G.overscan_px);
    let n = line.len();
    line[..os].fill(bias[0]);
    line[n - os..].fill(bias[1]);
    LineLevels::measure(&G, &line).expect("line length")
}

/// The general path on the box `b` (whole window = box): `calibrate_window` + `cog` with
/// the given background over the box.
fn general(
    cal: &FrameCalibration<'_>,
    b: Rect,
    raw: &[u16],
    levels: &[LineLevels],
    level_e: f32,
    var: f32,
) -> Centroid {
    let mut e = vec![Electrons::ZERO; b.len()];
    let mut f = vec![PixelFlags::empty(); b.len()];
    cal.calibrate_window(b, raw, levels, &mut e, &mut f)
        .expect("window calibrates");
    let win = Window::new(b, &e).expect("window");
    cog(
        &CentroidInput::new(win).with_pixel_flags(&f),
        &CogParams {
            power: CogPower::One,
            box_side: b.width.max(b.height) as u8,
            anchor: Anchor::WindowCentre,
            background: Background::Given {
                level_e,
                variance_e2: var,
            },
        },
    )
}

/// Reference sums of the exact formula for the box `b` anchored at (ax, ay): for the weights
/// 1, dx, dy: `S_w = sum w (e - L)`, and the f32-error scale `M_w = sum |w| (|A d| + |K| + |L|)`
/// and `N_w = sum |w|`.
struct RefSums {
    s: [f64; 3],
    m: [f64; 3],
    n: [f64; 3],
}

fn ref_sums(
    maps: &Maps,
    b: Rect,
    (ax, ay): (u16, u16),
    raw: &[u16],
    bias: &[[u16; 2]],
    level: f64,
) -> RefSums {
    let mut r = RefSums {
        s: [0.0; 3],
        m: [0.0; 3],
        n: [0.0; 3],
    };
    for row in 0..b.height {
        for col in 0..b.width {
            let (x, y) = (b.x0 + col, b.y0 + row);
            let o = usize::from(G.output_of_col(G.raw_col_of_x(usize::from(x))).0);
            let v = raw[usize::from(row) * usize::from(b.width) + usize::from(col)];
            let (e, mag) = maps.exact_e(x, y, v, 16 * i64::from(bias[usize::from(row)][o]));
            let dx = f64::from(x) - f64::from(ax);
            let dy = f64::from(y) - f64::from(ay);
            for (k, w) in [1.0, dx, dy].into_iter().enumerate() {
                r.s[k] += w * (e - level);
                r.m[k] += w.abs() * (mag + level.abs());
                r.n[k] += w.abs();
            }
        }
    }
    r
}

/// The level as the general path quantises it (1/64 e-, rounded, saturating at i32 bits).
fn quantised_level(level_e: f32) -> f64 {
    let b = f64::from(level_e) * 64.0;
    let r = if b >= 0.0 { b + 0.5 } else { b - 0.5 };
    f64::from(r.clamp(i32::MIN as f64, i32::MAX as f64) as i32) / 64.0
}

fn maps() -> impl Strategy<Value = Maps> {
    (0u8..4).prop_flat_map(|t| {
        let n = tiles(t);
        (
            (1u32.., 1u32..),
            prop::collection::vec(any::<i16>(), G.line_len()),
            prop::collection::vec(any::<u8>(), n),
            prop::collection::vec(1u16.., n),
            -(1i32 << 26)..=(1 << 26),
            prop::bool::weighted(0.85),
        )
            .prop_map(move |((g0, g1), cb, d, f, ds, with_maps)| Maps {
                gains: [g0, g1],
                column_bias: cb,
                tile_log2: t,
                dark: d,
                flat: f,
                dark_scale_bits: ds,
                saturation_adu: 65_535,
                hot: vec![],
                telegraph: vec![],
                with_maps,
            })
    })
}

/// A box (= window) of side 3..=9 anywhere on the area (across the output split and tile
/// edges too), its raw samples (full range, or a star-like few thousand ADU over a bias) and
/// per-row biases.
#[allow(clippy::type_complexity)]
fn scene() -> impl Strategy<Value = (Rect, Vec<u16>, Vec<[u16; 2]>, f32, f32)> {
    (1u16..=4).prop_flat_map(|h| {
        let s = 2 * h + 1;
        let n = usize::from(s) * usize::from(s);
        (
            0..=G.active_cols - s,
            0..=G.active_rows - s,
            prop_oneof![
                prop::collection::vec(any::<u16>(), n),
                (0u16..60_000, prop::collection::vec(0u16..5_000, n))
                    .prop_map(|(base, v)| v.into_iter().map(|x| base + x).collect()),
            ],
            prop::collection::vec(any::<[u16; 2]>(), usize::from(s)),
            -1.0e5f32..1.0e5,
            0.0f32..1.0e4,
        )
            .prop_map(move |(x0, y0, raw, bias, level, var)| {
                (
                    Rect {
                        x0,
                        y0,
                        width: s,
                        height: s,
                    },
                    raw,
                    bias,
                    level,
                    var,
                )
            })
    })
}

/// `|a - b| <= tol` with a message.
fn close(what: &str, a: f64, b: f64, tol: f64) -> Result<(), TestCaseError> {
    prop_assert!(
        (a - b).abs() <= tol,
        "{what}: {a} vs {b}: |diff| {} > tol {tol}",
        (a - b).abs()
    );
    Ok(())
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(2000)))]

    /// Flux and position of the fused path against the f64 formula (within the module's f32
    /// bound) and against the general path (plus its per-pixel rounding), over the full range.
    #[test]
    fn fused_equals_formula_and_general_path(maps in maps(), sc in scene()) {
        let (b, raw, bias, level_e, var) = sc;
        let bytes = maps.bytes();
        let table = CalibTable::parse(&bytes).expect("table parses");
        let cal = FrameCalibration::new(table, maps.conditions());
        let levels: Vec<LineLevels> = bias.iter().map(|b| levels_for(*b)).collect();
        let anchor = (b.x0 + b.width / 2, b.y0 + b.height / 2);
        let params = RawCogParams {
            box_side: b.width as u8,
            level_e,
            variance_e2: var,
            curve: None,
        };
        let win = RawWindow { rect: b, raw: &raw, levels: &levels };
        let got = raw_cog(&cal, &win, anchor, &params);
        let plan = RawCogPlan::new(&cal, b, anchor, params.box_side).expect("plan builds");
        prop_assert!(same(&plan.apply(&cal, &win, &params).expect("fresh plan"), &got));
        let c = got.centroid;
        prop_assert!(!got.general_path);
        prop_assert!(c.x_px.is_finite() && c.y_px.is_finite() && c.sigma_x_px.is_finite());
        prop_assert!(c.snr.is_finite() && c.flux_e.is_finite() && c.sigma_y_px.is_finite());
        let l = quantised_level(level_e);
        let r = ref_sums(&maps, b, anchor, &raw, &bias, l);
        // The module's bound: (10 + cells) roundings of 2^-24 of M_w; ulp-level slack for the
        // solve's own roundings below.
        let cells = maps.cells(b) as f64;
        let tol: Vec<f64> = r.m.iter().map(|m| (10.0 + cells) * EPS * m).collect();
        // The general path's sums: per-pixel rounding, then its f32 conversions.
        let tol_g: Vec<f64> = r.n.iter().zip(r.m.iter())
            .map(|(n, m)| n * QUANTISATION_E + 4.0 * EPS * m).collect();
        let s = r.s[0];
        if s <= 4.0 * (tol[0] + tol_g[0]) {
            // No clear star: the flux may round either way; only "no panic, no NaN".
            return Ok(());
        }
        prop_assert!(!c.flags.contains(CentroidFlags::DEGENERATE), "{c:?} S {s}");
        close("flux vs f64", f64::from(c.flux_e), s, tol[0] + 2.0 * EPS * s)?;
        let g = general(&cal, b, &raw, &levels, level_e, var);
        prop_assert!(!g.flags.contains(CentroidFlags::DEGENERATE));
        close("flux vs general", f64::from(c.flux_e), f64::from(g.flux_e),
            tol[0] + tol_g[0] + 4.0 * EPS * s)?;
        // Positions: x = S_dx / S; the clamp to the box applies to both paths.
        let lo = (f64::from(b.x0) - 0.5, f64::from(b.y0) - 0.5);
        let pos_tol = |t: &[f64], k: usize, o: f64| {
            (t[k] + o.abs() * t[0]) / (s - t[0]) + 4.0 * EPS * (f64::from(b.x0.max(b.y0)) + 10.0)
        };
        for (k, (got, gen_, a, lo)) in [
            (c.x_px, g.x_px, anchor.0, lo.0),
            (c.y_px, g.y_px, anchor.1, lo.1),
        ].into_iter().enumerate() {
            let o = r.s[k + 1] / s;
            let want = (f64::from(a) + o).clamp(lo, lo + f64::from(b.width));
            let t = pos_tol(&tol, k + 1, o);
            close("position vs f64", f64::from(got), want, t)?;
            let tg: Vec<f64> = tol.iter().zip(tol_g.iter()).map(|(a, b)| a + b).collect();
            close("position vs general", f64::from(got), f64::from(gen_), pos_tol(&tg, k + 1, o))?;
        }
        // The general path sees the same flags but EDGE_CLIPPED / NOT_CONVERGED (a window
        // equal to the box cannot move) and its own clamp.
        let mask = CentroidFlags::SATURATED | CentroidFlags::EXCLUDED_PIXEL;
        prop_assert_eq!(c.flags & mask, g.flags & mask);
    }

    /// Arbitrary raw samples, levels, tables, anchors, sides and backgrounds, with defects:
    /// a centroid (maybe flagged), never a panic or a non-finite value.
    #[test]
    fn no_panic_on_arbitrary_input(
        maps in maps(),
        raw in prop::collection::vec(any::<u16>(), 0..150),
        bias in prop::collection::vec(any::<[u16; 2]>(), 0..13),
        rect in (0u16..45, 0u16..30, 0u16..13, 0u16..13),
        anchor in (0u16..50, 0u16..30),
        side in any::<u8>(),
        level_e in any::<f32>(),
        var in any::<f32>(),
        hot in prop::collection::btree_set((0u16..24, 0u16..40), 0..6),
    ) {
        let mut maps = maps;
        maps.hot = hot.iter().enumerate().map(|(i, (y, x))| HotPixel {
            x: *x, y: *y,
            rate_e_per_s: ERatePerS::from_num(40),
            doubling_k: U8F8::from_num(6.5),
            policy: if i % 2 == 0 { HotPolicy::Correct } else { HotPolicy::Exclude },
        }).collect();
        let bytes = maps.bytes();
        let table = CalibTable::parse(&bytes).expect("table parses");
        let cal = FrameCalibration::new(table, maps.conditions());
        let levels: Vec<LineLevels> = bias.iter().map(|b| levels_for(*b)).collect();
        let rect = Rect { x0: rect.0, y0: rect.1, width: rect.2, height: rect.3 };
        let win = RawWindow { rect, raw: &raw, levels: &levels };
        let params = RawCogParams { box_side: side, level_e, variance_e2: var, curve: None };
        let got = raw_cog(&cal, &win, anchor, &params);
        let c = got.centroid;
        for v in [c.x_px, c.y_px, c.flux_e, c.snr, c.sigma_x_px, c.sigma_y_px] {
            prop_assert!(v.is_finite());
        }
        // The plan of the same inputs: refused (and the one-shot degenerate) or the same
        // result bit for bit; never a panic.
        match RawCogPlan::new(&cal, rect, anchor, side) {
            Ok(plan) => {
                prop_assert!(plan.is_for(&cal, rect, anchor, side));
                let r = plan.apply(&cal, &win, &params);
                prop_assert!(r.is_ok_and(|r| same(&r, &got)), "{r:?} vs {got:?}");
            }
            Err(e) => {
                prop_assert_eq!(e, PlanError::BadInput);
                prop_assert!(c.flags.contains(CentroidFlags::DEGENERATE));
            }
        }
    }
}

/// The frame calibration of `maps` (its table bytes leaked: a test lives briefly).
fn cal_of(maps: &Maps) -> FrameCalibration<'static> {
    let bytes: &'static [u8] = Box::leak(maps.bytes().into_boxed_slice());
    FrameCalibration::new(
        CalibTable::parse(bytes).expect("table parses"),
        maps.conditions(),
    )
}

/// Raw samples of a noise-free star of `flux_e` at (sx, sy), width `a`, on `bg_e` e-/px over
/// bias 1000 ADU, gain `gain`, in window `w`.
fn star_raw(w: Win, (sx, sy): (f64, f64), a: f64, flux_e: f64, bg_e: f64, gain: f64) -> Vec<u16> {
    let star = Star {
        x: sx,
        y: sy,
        sigma: sigma_of_a(a),
        flux: flux_e,
    };
    render(w, star, bg_e)
        .iter()
        .map(|e| (1000.0 + e / gain).round().clamp(0.0, 65_535.0) as u16)
        .collect()
}

fn run(cal: &FrameCalibration<'_>, w: Win, raw: &[u16], anchor: (u16, u16), side: u8) -> RawCog {
    let levels = vec![levels_for([1000, 1000]); usize::from(w.h)];
    let win = RawWindow {
        rect: w.rect(),
        raw,
        levels: &levels,
    };
    raw_cog(
        cal,
        &win,
        anchor,
        &RawCogParams {
            box_side: side,
            level_e: 20.0,
            variance_e2: 45.0,
            curve: None,
        },
    )
}

#[test]
fn reanchors_once_onto_the_cog_pixel() {
    let maps = Maps::plain(1.5);
    let cal = cal_of(&maps);
    let w = Win::centred(20, 12, 11);
    // True centre 0.8 px right of the anchor's centre: the CoG lands past half a pixel.
    let raw = star_raw(w, (20.8, 12.0), 1.2, 50_000.0, 20.0, 1.5);
    let got = run(&cal, w, &raw, (20, 12), 7);
    assert!(got.reanchored, "{got:?}");
    assert!(!got.centroid.flags.contains(CentroidFlags::NOT_CONVERGED));
    // The general path anchored at the new pixel (21, 12).
    let b = Rect {
        x0: 18,
        y0: 9,
        width: 7,
        height: 7,
    };
    let mut braw = Vec::new();
    for r in 0..7 {
        let start = (2 + r) * 11 + 3;
        braw.extend_from_slice(&raw[start..start + 7]);
    }
    let levels = vec![levels_for([1000, 1000]); 7];
    let g = general(&cal, b, &braw, &levels, 20.0, 45.0);
    assert!((got.centroid.x_px - g.x_px).abs() < 1e-4, "{got:?} {g:?}");
    assert!((got.centroid.y_px - g.y_px).abs() < 1e-4);
    // In a window equal to the box it cannot move: flagged.
    let w7 = Win::centred(20, 12, 7);
    let raw7 = star_raw(w7, (20.8, 12.0), 1.2, 50_000.0, 20.0, 1.5);
    let got7 = run(&cal, w7, &raw7, (20, 12), 7);
    assert!(!got7.reanchored);
    assert!(got7.centroid.flags.contains(CentroidFlags::NOT_CONVERGED));
}

#[test]
fn flags_saturation_clipping_and_empty_boxes() {
    let mut maps = Maps::plain(1.5);
    maps.saturation_adu = 30_000;
    let cal = cal_of(&maps);
    let w = Win::centred(20, 12, 7);
    let bright = star_raw(w, (20.0, 12.0), 1.0, 200_000.0, 20.0, 1.5);
    assert!(bright.iter().any(|v| *v >= 30_000));
    let c = run(&cal, w, &bright, (20, 12), 7).centroid;
    assert!(c.flags.contains(CentroidFlags::SATURATED), "{c:?}");
    let faint = star_raw(w, (20.0, 12.0), 1.0, 2_000.0, 20.0, 1.5);
    let c = run(&cal, w, &faint, (20, 12), 7).centroid;
    assert!(c.flags.is_empty(), "{c:?}");
    // Anchor one pixel from the window's edge: a 7x7 box is clipped.
    let c = run(&cal, w, &faint, (18, 12), 7).centroid;
    assert!(c.flags.contains(CentroidFlags::EDGE_CLIPPED), "{c:?}");
    // Nothing above the level: degenerate, at the anchor.
    let flat = vec![1000u16; 49];
    let c = run(&cal, w, &flat, (20, 12), 7).centroid;
    assert!(c.flags.contains(CentroidFlags::DEGENERATE), "{c:?}");
    assert_eq!((c.x_px, c.y_px), (20.0, 12.0));
    // Bad input: a side above the maximum, an anchor outside, short buffers.
    assert!(
        run(&cal, w, &faint, (20, 12), MAX_BOX_SIDE + 2)
            .centroid
            .flags
            .contains(CentroidFlags::DEGENERATE)
    );
    assert!(
        run(&cal, w, &faint, (30, 12), 7)
            .centroid
            .flags
            .contains(CentroidFlags::DEGENERATE)
    );
    assert!(
        run(&cal, w, &faint[..40], (20, 12), 7)
            .centroid
            .flags
            .contains(CentroidFlags::DEGENERATE)
    );
}

#[test]
fn defects_go_through_the_general_path() {
    let w = Win::centred(20, 12, 7);
    let b = w.rect();
    let raw = star_raw(w, (20.2, 11.9), 1.2, 20_000.0, 20.0, 1.5);
    let levels = vec![levels_for([1000, 1000]); 7];
    for (hot, tel) in [
        (Some(HotPolicy::Correct), false),
        (Some(HotPolicy::Exclude), false),
        (None, true),
    ] {
        let mut maps = Maps::plain(1.5);
        if let Some(policy) = hot {
            maps.hot = vec![HotPixel {
                x: 21,
                y: 13,
                rate_e_per_s: ERatePerS::from_num(40),
                doubling_k: U8F8::from_num(6.5),
                policy,
            }];
        }
        if tel {
            maps.telegraph = vec![(19, 11)];
        }
        let cal = cal_of(&maps);
        let got = run(&cal, w, &raw, (20, 12), 7);
        assert!(got.general_path);
        let g = general(&cal, b, &raw, &levels, 20.0, 45.0);
        // The same calibration and CoG: identical position and flux.
        assert_eq!((got.centroid.x_px, got.centroid.y_px), (g.x_px, g.y_px));
        assert_eq!(got.centroid.flux_e, g.flux_e);
        let excluded = got.centroid.flags.contains(CentroidFlags::EXCLUDED_PIXEL);
        assert_eq!(excluded, hot != Some(HotPolicy::Correct), "{got:?}");
    }
    // A defect on the box's rows but outside its columns keeps the fused path.
    let mut maps = Maps::plain(1.5);
    maps.telegraph = vec![(30, 12)];
    let cal = cal_of(&maps);
    assert!(!run(&cal, w, &raw, (20, 12), 7).general_path);
}

/// The error estimate against the measured scatter: seeded Monte Carlo of stars at random
/// sub-pixel positions, SNR 10, 30, 100 (eq. 8 in the 7x7 box), a = 1, 1.5, 2 px, Gaussian
/// noise of variance `mu + var_bg`, quantised to ADU by gain 1.5 (adds 1.5^2/12 e-^2, counted
/// in var_bg).
#[test]
fn sigma_estimate_matches_the_scatter() {
    const TRIALS: usize = 600;
    let maps = Maps::plain(1.5);
    let cal = cal_of(&maps);
    let (bg, read) = (100.0, 5.0);
    let var_bg = bg + read * read + 1.5 * 1.5 / 12.0;
    // The scatter of N residuals has a relative standard error 1/sqrt(2 (N - 1)); the mean
    // estimate's is far smaller. 3 standard errors either side of the 0.8..1.2 band.
    let slack = 3.0 / (2.0 * (TRIALS as f64 - 1.0)).sqrt();
    let mut rng = Rng::new(0x5eed_f00d);
    for snr in [10.0, 30.0, 100.0] {
        for a in [1.0, 1.5, 2.0] {
            let flux = flux_for_snr(snr, 7.0, var_bg);
            let w = Win::centred(20, 12, 9);
            let (mut res, mut est, mut moved) = (Vec::new(), Vec::new(), 0usize);
            for _ in 0..TRIALS {
                let (px, py) = (rng.uniform() - 0.5, rng.uniform() - 0.5);
                let star = Star {
                    x: 20.0 + px * 0.6,
                    y: 12.0 + py * 0.6,
                    sigma: sigma_of_a(a),
                    flux,
                };
                let mean = render(w, star, bg);
                let noisy = add_noise(&mean, bg, bg + read * read, &mut rng);
                let raw: Vec<u16> = noisy
                    .iter()
                    .map(|e| (1000.0 + e / 1.5).round().clamp(0.0, 65_535.0) as u16)
                    .collect();
                let levels = vec![levels_for([1000, 1000]); 9];
                let win = RawWindow {
                    rect: w.rect(),
                    raw: &raw,
                    levels: &levels,
                };
                let got = raw_cog(
                    &cal,
                    &win,
                    (20, 12),
                    &RawCogParams {
                        box_side: 7,
                        level_e: bg as f32,
                        variance_e2: var_bg as f32,
                        curve: None,
                    },
                );
                if got.reanchored {
                    moved += 1;
                }
                let c = got.centroid;
                if c.flags.contains(CentroidFlags::DEGENERATE) {
                    continue;
                }
                // Residual against the noise-free CoG of the box the method measured (the
                // truncation and pixelisation bias is not noise).
                let (ax, ay) = got.anchor;
                let (c0, r0) = (usize::from(ax - 19), usize::from(ay - 11));
                let (mut s, mut sx) = (0.0, 0.0);
                for r in r0..r0 + 7 {
                    for col in c0..c0 + 7 {
                        let v = mean[r * 9 + col] - bg;
                        s += v;
                        sx += v * (col as f64 - 4.0);
                    }
                }
                res.push(f64::from(c.x_px) - (20.0 + sx / s));
                est.push(f64::from(c.sigma_x_px));
            }
            assert!(
                res.len() > TRIALS * 9 / 10,
                "snr {snr} a {a}: too many failures"
            );
            let (_, scatter) = psf::mean_std(&res);
            let (est_mean, _) = psf::mean_std(&est);
            let ratio = est_mean / scatter;
            println!(
                "snr {snr} a {a}: sigma_est {est_mean:.4} scatter {scatter:.4} ratio {ratio:.3} \
                 ({moved} re-anchored of {TRIALS})"
            );
            assert!(
                (0.8 - slack..=1.2 + slack).contains(&ratio),
                "snr {snr} a {a}: ratio {ratio} outside 0.8..1.2 +- {slack}"
            );
        }
    }
}

/// Bit-for-bit equality of two results (`-0.0` and `0.0` told apart).
fn same(a: &RawCog, b: &RawCog) -> bool {
    let bits = |c: &Centroid| {
        [c.x_px, c.y_px, c.flux_e, c.snr, c.sigma_x_px, c.sigma_y_px].map(f32::to_bits)
    };
    bits(&a.centroid) == bits(&b.centroid)
        && a.centroid.flags == b.centroid.flags
        && a.general_path == b.general_path
        && a.reanchored == b.reanchored
        && a.anchor == b.anchor
}

/// A plan is refused for a frame calibration (dark scale, table), window, or box side other
/// than its own, and works again once rebuilt; a failed rebuild leaves it refusing.
#[test]
fn stale_plans_are_refused() {
    let mut maps = Maps::plain(1.5);
    maps.dark_scale_bits = 1000;
    let cal = cal_of(&maps);
    let w = Win::centred(20, 12, 11);
    let raw = star_raw(w, (20.2, 11.9), 1.2, 50_000.0, 20.0, 1.5);
    let levels = vec![levels_for([1000, 1000]); 11];
    let win = RawWindow {
        rect: w.rect(),
        raw: &raw,
        levels: &levels,
    };
    let params = RawCogParams {
        box_side: 7,
        level_e: 20.0,
        variance_e2: 45.0,
        curve: None,
    };
    let mut plan = RawCogPlan::new(&cal, w.rect(), (20, 12), 7).expect("plan");
    let fresh = plan.apply(&cal, &win, &params).expect("fresh");
    assert!(same(&fresh, &raw_cog(&cal, &win, (20, 12), &params)));
    assert!(!fresh.centroid.flags.contains(CentroidFlags::DEGENERATE));
    // Another dark scale (next frame's exposure or temperature).
    let mut other = maps.clone();
    other.dark_scale_bits = 5000;
    let cal_ds = cal_of(&other);
    assert_eq!(plan.apply(&cal_ds, &win, &params), Err(PlanError::Stale));
    assert!(!plan.is_for(&cal_ds, w.rect(), (20, 12), 7));
    // Another table (other gains).
    let cal_gain = cal_of(&Maps::plain(1.25));
    assert_eq!(plan.apply(&cal_gain, &win, &params), Err(PlanError::Stale));
    // The window moved (the star's anchor moved with it).
    let w2 = Win::centred(21, 12, 11);
    let raw2 = star_raw(w2, (20.2, 11.9), 1.2, 50_000.0, 20.0, 1.5);
    let win2 = RawWindow {
        rect: w2.rect(),
        raw: &raw2,
        levels: &levels,
    };
    assert_eq!(plan.apply(&cal, &win2, &params), Err(PlanError::Stale));
    // Another box side.
    let p5 = RawCogParams {
        box_side: 5,
        ..params
    };
    assert_eq!(plan.apply(&cal, &win, &p5), Err(PlanError::Stale));
    // Rebuilt for the moved window: accepted, and equal to the one-shot there.
    plan.rebuild(&cal, w2.rect(), (21, 12), 7).expect("rebuild");
    assert!(plan.is_for(&cal, w2.rect(), (21, 12), 7));
    let moved = plan.apply(&cal, &win2, &params).expect("rebuilt");
    assert!(same(&moved, &raw_cog(&cal, &win2, (21, 12), &params)));
    assert_eq!(plan.apply(&cal, &win, &params), Err(PlanError::Stale));
    // A failed rebuild (anchor outside the window) leaves the plan refusing everything.
    assert_eq!(
        plan.rebuild(&cal, w2.rect(), (0, 0), 7),
        Err(PlanError::BadInput)
    );
    assert_eq!(plan.apply(&cal, &win2, &params), Err(PlanError::Stale));
    assert_eq!(
        RawCogPlan::EMPTY.apply(&cal, &win, &params),
        Err(PlanError::Stale)
    );
}

/// The plan's size as documented (the firmware keeps one per tracked star).
#[test]
fn plan_is_small() {
    let n = std::mem::size_of::<RawCogPlan>();
    assert!(n <= 480, "RawCogPlan is {n} bytes");
}
