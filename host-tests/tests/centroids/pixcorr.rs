//! The pixel-phase correction of the centre of gravity, end to end: curves built by
//! `startrack_sim::pixcorr` (f64, `libm::erf`), applied by the core
//! (`startrack_core::centroid::pixcorr`, f32) to the core's CoG of stars rendered by this
//! test's own f64 pixel-integrated Gaussian (`common/psf.rs`, its own erf), against the true
//! positions.
//!
//! `cargo test -p startrack-host --test centroids pixcorr:: -- --nocapture` prints, for every PSF width,
//! box, power and background, the systematic error before and after the correction (RMS over
//! a grid of true phases in both axes) or why no curve exists.

use startrack_test_support::psf;

use psf::{Star, Win, render, sigma_of_a, to_electrons};
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::{PixCorr, PixCorrBackground, PixCorrError, PixCorrSet};
use startrack_core::window::Window;
use startrack_sim::pixcorr::{BuildError, CurveSpec, build_curve, measured_phase};

const WIDTHS_A: [f64; 8] = [0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 2.5, 3.0];
/// The required bound on the corrected CoG's systematic error, px RMS.
const LIMIT_PX: f64 = 0.003;

fn background(kind: PixCorrBackground) -> Background {
    match kind {
        PixCorrBackground::Given => Background::Given {
            level_e: 0.0,
            variance_e2: 0.0,
        },
        PixCorrBackground::PerimeterMean => Background::PerimeterMean,
        PixCorrBackground::PerimeterMedian => Background::PerimeterMedian,
    }
}

/// (RMS before, RMS after, worst after) of the x and y errors over a grid of true phases.
fn residuals(spec: &CurveSpec, curve: &PixCorr<'_>) -> (f64, f64, f64) {
    let side = u16::from(spec.box_side) + 2;
    let win = Win::centred(300, 400, side);
    let params = CogParams {
        power: spec.power,
        box_side: spec.box_side,
        anchor: Anchor::Peak,
        background: background(spec.background),
    };
    let (mut before, mut after, mut worst, mut n) = (0.0, 0.0, 0.0f64, 0.0);
    let phases: Vec<f64> = (0..25).map(|i| -0.48 + 0.04 * f64::from(i)).collect();
    for &px in &phases {
        for &py in phases.iter().step_by(4) {
            let star = Star {
                x: 300.0 + px,
                y: 400.0 + py,
                sigma: sigma_of_a(spec.a_px),
                flux: 1.0e6,
            };
            let e = to_electrons(&render(win, star, 0.0));
            let w = Window::new(win.rect(), &e).unwrap();
            let c = cog(&CentroidInput::new(w), &params);
            assert!(
                !c.flags
                    .intersects(CentroidFlags::DEGENERATE | CentroidFlags::CLAMPED),
                "{spec:?}: {c:?}"
            );
            let k = curve.apply(c);
            for (raw, cor, truth) in [(c.x_px, k.x_px, star.x), (c.y_px, k.y_px, star.y)] {
                let (r, a) = (f64::from(raw) - truth, f64::from(cor) - truth);
                before += r * r;
                after += a * a;
                worst = worst.max(a.abs());
                n += 1.0;
            }
        }
    }
    ((before / n).sqrt(), (after / n).sqrt(), worst)
}

#[test]
fn corrected_cog_systematic_error_below_3_millipixels() {
    let mut applied = 0;
    for background in [
        PixCorrBackground::Given,
        PixCorrBackground::PerimeterMean,
        PixCorrBackground::PerimeterMedian,
    ] {
        for power in [CogPower::One, CogPower::Two] {
            for box_side in [3u8, 5, 7] {
                for a_px in WIDTHS_A {
                    let spec = CurveSpec {
                        a_px,
                        box_side,
                        power,
                        background,
                        knots: 33,
                    };
                    match build_curve(&spec) {
                        Ok(built) => {
                            let (curve, _) = PixCorr::parse(&built.bytes).unwrap();
                            let (before, after, worst) = residuals(&spec, &curve);
                            eprintln!(
                                "{background:?} {power:?} box {box_side} a {a_px:4.2}: systematic {before:.4} px -> {after:.5} px RMS (worst {worst:.4}), m_max {:.3}",
                                built.header.phase_max_px
                            );
                            assert!(
                                after < LIMIT_PX,
                                "{spec:?}: corrected RMS {after} px (uncorrected {before})"
                            );
                            applied += 1;
                        }
                        Err(e) => eprintln!(
                            "{background:?} {power:?} box {box_side} a {a_px:4.2}: no curve ({e})"
                        ),
                    }
                }
            }
        }
    }
    // Power 1 with a given background must be invertible everywhere in 0.5..3 px.
    assert!(applied >= 24, "only {applied} curves built");
}

#[test]
fn power_one_given_background_builds_for_every_width() {
    for box_side in [3u8, 5, 7] {
        for a_px in WIDTHS_A {
            let spec = CurveSpec {
                a_px,
                box_side,
                power: CogPower::One,
                background: PixCorrBackground::Given,
                knots: 33,
            };
            assert!(build_curve(&spec).is_ok(), "{spec:?}");
        }
    }
}

#[test]
fn core_interpolation_matches_f64_inverse() {
    // Between the knots the core's cubic against the exact inverse of m(p) in f64, found here
    // by bisection on the builder's m: the interpolation error alone.
    let spec = CurveSpec {
        a_px: 1.0,
        box_side: 5,
        power: CogPower::One,
        background: PixCorrBackground::Given,
        knots: 33,
    };
    let built = build_curve(&spec).unwrap();
    let (curve, len) = PixCorr::parse(&built.bytes).unwrap();
    assert_eq!(len, built.bytes.len());
    let mut worst = 0.0f64;
    for i in 0..200 {
        let p = -0.495 + 0.99 * f64::from(i) / 199.0;
        let m = measured_phase(&spec, p, 0.0);
        let (c, slope) = curve.correction(m as f32);
        worst = worst.max((m + f64::from(c) - p).abs());
        // The slope dp/dm against a finite difference of the exact m(p).
        let h = 1e-4;
        let dm =
            (measured_phase(&spec, p + h, 0.0) - measured_phase(&spec, p - h, 0.0)) / (2.0 * h);
        assert!(
            ((1.0 + f64::from(slope)) * dm - 1.0).abs() < 0.02,
            "phase {p}: slope {slope}, dm/dp {dm}"
        );
    }
    eprintln!("largest |core interpolation - exact inverse|: {worst:.2e} px");
    assert!(worst < 2e-4, "{worst}");
}

#[test]
fn undersampled_power_two_is_refused() {
    // Power 2 on a PSF much smaller than a pixel: the centre pixel holds nearly all the weight
    // and m(p) is flat around p = 0.
    let spec = CurveSpec {
        a_px: 0.3,
        box_side: 5,
        power: CogPower::Two,
        background: PixCorrBackground::Given,
        knots: 33,
    };
    assert!(matches!(
        build_curve(&spec),
        Err(BuildError::NotMonotone { .. })
    ));
}

#[test]
fn bad_curves_are_typed_errors() {
    let spec = CurveSpec {
        a_px: 1.5,
        box_side: 5,
        power: CogPower::Two,
        background: PixCorrBackground::PerimeterMedian,
        knots: 17,
    };
    let good = build_curve(&spec).unwrap().bytes;
    let cases: [(usize, u8, PixCorrError); 7] = [
        (0, 3, PixCorrError::Power(3)),
        (1, 4, PixCorrError::BoxSide(4)),
        (1, 33, PixCorrError::BoxSide(33)),
        (2, 7, PixCorrError::Background(7)),
        (3, 4, PixCorrError::Knots(4)),
        (7, 0x81, PixCorrError::PhaseMax),
        (8, 1, PixCorrError::FirstKnot),
    ];
    for (at, value, want) in cases {
        let mut b = good.clone();
        b[at] = value;
        assert_eq!(
            PixCorr::parse(&b).map(|_| ()),
            Err(want),
            "byte {at} = {value}"
        );
    }
    for cut in 0..good.len() {
        assert_eq!(
            PixCorr::parse(&good[..cut]).map(|_| ()),
            Err(PixCorrError::TooShort)
        );
    }
    // A set: two curves back to back, lookup by nearest width, a trailing byte rejected.
    let other = build_curve(&CurveSpec { a_px: 2.5, ..spec }).unwrap().bytes;
    let both = [good.clone(), other].concat();
    let set = PixCorrSet::parse(2, &both).unwrap();
    let found = set
        .find(CogPower::Two, 5, PixCorrBackground::PerimeterMedian, 2.2)
        .unwrap();
    assert_eq!(found.header().a_px.to_num::<f64>(), 2.5);
    assert!(
        set.find(CogPower::One, 5, PixCorrBackground::PerimeterMedian, 2.2)
            .is_none()
    );
    let mut long = both.clone();
    long.push(0);
    assert_eq!(
        PixCorrSet::parse(2, &long).map(|_| ()),
        Err((2, PixCorrError::TooShort))
    );
}

#[test]
fn apply_never_produces_nan_and_keeps_degenerate() {
    let spec = CurveSpec {
        a_px: 0.75,
        box_side: 3,
        power: CogPower::One,
        background: PixCorrBackground::Given,
        knots: 65,
    };
    let built = build_curve(&spec).unwrap();
    let (curve, _) = PixCorr::parse(&built.bytes).unwrap();
    for x in [
        f32::NAN,
        f32::INFINITY,
        -f32::INFINITY,
        1e30,
        -1e30,
        0.5,
        -0.5,
        1023.49,
    ] {
        let (c, s) = curve.correction(x);
        assert!(c.is_finite() && s.is_finite(), "{x}: {c} {s}");
    }
    let e = vec![startrack_core::units::Electrons::ZERO; 25];
    let w = Window::new(Win::centred(10, 10, 5).rect(), &e).unwrap();
    let c = cog(&CentroidInput::new(w), &CogParams::new(CogPower::One, 3));
    assert!(c.flags.contains(CentroidFlags::DEGENERATE));
    assert_eq!(curve.apply(c), c);
}

#[test]
fn a_table_with_curves_from_the_host_builder() {
    use startrack_core::table::CalibTable;
    use startrack_sim::pixcorr::{build_curves, write_table_with_curves};
    let specs: Vec<CurveSpec> = [0.75, 1.5, 3.0]
        .iter()
        .map(|&a_px| CurveSpec {
            a_px,
            box_side: 5,
            power: CogPower::One,
            background: PixCorrBackground::Given,
            knots: 33,
        })
        .collect();
    let curves = build_curves(&specs).unwrap();
    let gains = [startrack_core::units::GainEPerAdu::ONE];
    let spec = startrack_core::table::TableSpec {
        geometry: startrack_core::geometry::ReadoutGeometry::CCD47_20_DUAL,
        saturation_adu: 65_000,
        gains: &[gains[0], gains[0]],
        column_bias: None,
        dark_rel: None,
        flat_inv: None,
        hot_ref_k: startrack_core::units::Kelvin::ZERO,
        hot: &[],
        telegraph: &[],
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    };
    let bytes = write_table_with_curves(&spec, &curves).unwrap();
    let t = CalibTable::parse(&bytes).unwrap();
    assert_eq!(t.pixcorr().len(), 3);
    // The nearest width is chosen; the stored curve is the built one.
    let c = t
        .pixcorr()
        .find(CogPower::One, 5, PixCorrBackground::Given, 1.4)
        .unwrap();
    assert_eq!(c.header(), curves[1].header);
    assert_eq!(c.knot_bytes(), &curves[1].bytes[8..]);
    // A refused spec names its index.
    let bad = [
        specs[0],
        CurveSpec {
            a_px: 0.5,
            power: CogPower::Two,
            ..specs[0]
        },
    ];
    assert!(matches!(
        build_curves(&bad),
        Err((1, BuildError::NotMonotone { .. }))
    ));
}
