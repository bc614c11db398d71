//! The camera model both ways: pixel -> direction -> pixel and direction -> pixel ->
//! direction round trips over random models, pixels and colours (proptest), the tangential
//! and colour terms against their formulas, and the folded models the inverse must refuse.

use proptest::prelude::*;
use startrack_core::attitude::{Camera, CameraError};

/// The CCD47-20 behind a 15 degree field.
const F_PX: f64 = 3889.0;

fn model() -> impl Strategy<Value = Camera> {
    (
        (3000.0..5000.0f64, 400.0..620.0f64, 400.0..620.0f64),
        (-0.5..0.5f64, -2.0..2.0f64, -2e-3..2e-3f64, -2e-3..2e-3f64),
        (-2e-3..2e-3f64, 0.0..1.0f64),
    )
        .prop_map(|((f, cx, cy), (k1, k2, p1, p2), (c, bv0))| Camera {
            k1,
            k2,
            p1,
            p2,
            colour_scale_per_mag: c,
            colour_ref_bv_mag: bv0,
            ..Camera::pinhole(f, [cx, cy])
        })
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(2000)))]

    #[test]
    fn pixel_to_direction_to_pixel(
        cam in model(),
        x in -0.5..1023.5f64,
        y in -0.5..1023.5f64,
        bv in -0.4..2.5f64,
    ) {
        let d = cam.direction_of(x, y, bv);
        prop_assert!(d.is_ok(), "{d:?}");
        let d = d.unwrap_or_default();
        prop_assert!((d.iter().map(|c| c * c).sum::<f64>() - 1.0).abs() < 1e-12);
        let p = cam.project_of(d, bv).unwrap_or_default();
        prop_assert!((p[0] - x).abs() < 1e-6 && (p[1] - y).abs() < 1e-6, "{p:?} vs {x} {y}");
    }

    #[test]
    fn direction_to_pixel_to_direction(
        cam in model(),
        u in -0.13..0.13f64,
        v in -0.13..0.13f64,
        bv in -0.4..2.5f64,
    ) {
        let n = (u * u + v * v + 1.0).sqrt();
        let d = [u / n, v / n, 1.0 / n];
        let p = cam.project_of(d, bv).unwrap_or_default();
        let back = cam.direction_of(p[0], p[1], bv).unwrap_or_default();
        let err: f64 = d.iter().zip(back).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
        // The inverse stops within UNDISTORT_TOLERANCE (1e-12) of the distorted point; the
        // undistorted error is that over the Jacobian's smallest singular value (above 0.5
        // for these models), plus rounding.
        prop_assert!(err < 1e-11, "{err:e}");
    }

    #[test]
    fn any_input_gives_a_value_or_an_error(
        f in prop::num::f64::ANY,
        k1 in prop::num::f64::ANY,
        x in prop::num::f64::ANY,
        y in prop::num::f64::ANY,
        bv in prop::num::f64::ANY,
    ) {
        let cam = Camera { k1, ..Camera::pinhole(f, [511.5, 511.5]) };
        if let Ok(d) = cam.direction_of(x, y, bv) {
            prop_assert!(d.iter().all(|c| c.is_finite()));
        }
        prop_assert!(cam.direction(x, y).iter().all(|c| c.is_finite()));
        let _ = cam.project_of([x, y, 1.0], bv);
        let _ = cam.check_over(1024, 1024, [bv, 0.0]);
    }
}

#[test]
fn every_model_of_the_strategy_is_invertible_over_the_frame() {
    // The strategy's extremes (the corners of its box) pass the parse-time check.
    for k1 in [-0.5, 0.5] {
        for k2 in [-2.0, 2.0] {
            for p in [-2e-3, 2e-3] {
                let cam = Camera {
                    k1,
                    k2,
                    p1: p,
                    p2: -p,
                    colour_scale_per_mag: 2e-3,
                    ..Camera::pinhole(3000.0, [400.0, 620.0])
                };
                assert_eq!(cam.check_over(1024, 1024, [-0.4, 2.5]), Ok(()), "{cam:?}");
            }
        }
    }
}

#[test]
fn tangential_and_colour_terms_follow_their_formulas() {
    let cam = Camera {
        p1: 1e-3,
        p2: -2e-3,
        ..Camera::pinhole(F_PX, [511.5, 511.5])
    };
    let (x, y) = (0.1, -0.05);
    let r2 = x * x + y * y;
    let d = cam.distort(x, y);
    assert!((d[0] - (x + 2.0 * 1e-3 * x * y - 2e-3 * (r2 + 2.0 * x * x))).abs() < 1e-15);
    assert!((d[1] - (y + 1e-3 * (r2 + 2.0 * y * y) - 2.0 * 2e-3 * x * y)).abs() < 1e-15);

    // Lateral colour moves a star along the radius by c (B-V - ref) times its radius.
    let cam = Camera {
        colour_scale_per_mag: 3e-4,
        colour_ref_bv_mag: 0.6,
        ..Camera::pinhole(F_PX, [511.5, 511.5])
    };
    let dir = cam.direction(1011.5, 511.5);
    let red = cam.project_of(dir, 1.6).unwrap_or_default();
    let blue = cam.project_of(dir, 0.1).unwrap_or_default();
    assert!(
        (red[0] - (1011.5 + 3e-4 * 1.0 * 500.0)).abs() < 1e-9,
        "{red:?}"
    );
    assert!(
        (blue[0] - (1011.5 - 3e-4 * 0.5 * 500.0)).abs() < 1e-9,
        "{blue:?}"
    );
    assert!((red[1] - 511.5).abs() < 1e-9);
}

#[test]
fn a_folded_model_has_no_inverse_and_says_so() {
    // 1 + 3 k1 r^2 < 0 before the corner (r^2 = 0.034): the image folds back.
    let cam = Camera {
        k1: -30.0,
        ..Camera::pinhole(F_PX, [511.5, 511.5])
    };
    assert_eq!(
        cam.check_over(1024, 1024, [0.6, 0.6]),
        Err(CameraError::NoInverse)
    );
    assert_eq!(
        cam.direction_of(1023.0, 1023.0, 0.6),
        Err(CameraError::NoInverse)
    );
    let bad_colour = Camera {
        colour_scale_per_mag: -1.0,
        ..Camera::pinhole(F_PX, [511.5, 511.5])
    };
    assert_eq!(
        bad_colour.direction_of(600.0, 600.0, 2.0),
        Err(CameraError::BadColour)
    );
    assert_eq!(
        Camera::pinhole(0.0, [0.0, 0.0]).direction_of(1.0, 1.0, 0.6),
        Err(CameraError::BadParameter)
    );
}
