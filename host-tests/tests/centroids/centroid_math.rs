//! Accuracy of the core's f32 functions (`centroid::math`) against f64, over their useful
//! ranges, and a self-check of the f64 erf used by the PSF reference.
//!
//! `-- --nocapture` prints the measured worst errors (quoted in the module docs).

use startrack_test_support::psf;

use startrack_core::centroid::test_only_math as math;

/// Log-spaced and linear samples of [lo, hi].
fn samples(lo: f64, hi: f64, n: usize) -> impl Iterator<Item = f64> {
    (0..=n).map(move |i| lo + (hi - lo) * i as f64 / n as f64)
}

#[test]
fn sqrt_relative_error() {
    let mut worst: f64 = 0.0;
    for e in samples(-120.0, 120.0, 200_000) {
        let x = 2f64.powf(e) as f32;
        let got = f64::from(math::sqrt(x));
        let want = f64::from(x).sqrt();
        worst = worst.max((got / want - 1.0).abs());
    }
    eprintln!("sqrt: worst relative error {worst:.2e}");
    assert!(worst < 2.5e-7);
    assert_eq!(math::sqrt(-1.0), 0.0);
    assert_eq!(math::sqrt(f32::NAN), 0.0);
    assert_eq!(math::sqrt(0.0), 0.0);
    assert!(math::sqrt(f32::INFINITY).is_finite());
}

#[test]
fn exp_relative_error() {
    let mut worst: f64 = 0.0;
    for x in samples(-87.0, 88.0, 400_000) {
        let x = x as f32;
        let got = f64::from(math::exp(x));
        let want = f64::from(x).exp();
        worst = worst.max((got / want - 1.0).abs());
    }
    eprintln!("exp: worst relative error {worst:.2e}");
    assert!(worst < 5e-7);
    assert_eq!(math::exp(-1000.0), 0.0);
    assert_eq!(math::exp(f32::NAN), 0.0);
    assert!(math::exp(1000.0).is_finite() && math::exp(f32::INFINITY).is_finite());
}

#[test]
fn erfc_and_pixel_fraction() {
    // The f64 reference itself: known values and continuity at the series/fraction switch.
    assert!((psf::erf(1.0) - 0.842_700_792_949_714_9).abs() < 1e-14);
    assert!((psf::erf(0.5) - 0.520_499_877_813_046_5).abs() < 1e-14);
    assert!((psf::erfc(3.0) / 2.209_049_699_858_544e-5 - 1.0).abs() < 1e-12);
    assert!((psf::erfc(2.5 - 1e-12) - psf::erfc(2.5)).abs() < 1e-13);

    let mut worst: f64 = 0.0;
    for x in samples(-6.0, 6.0, 120_000) {
        let got = f64::from(math::erfc(x as f32));
        let want = if x >= 0.0 {
            psf::erfc(f64::from(x as f32))
        } else {
            2.0 - psf::erfc(-f64::from(x as f32))
        };
        worst = worst.max((got - want).abs());
    }
    eprintln!("erfc: worst absolute error {worst:.2e}");
    assert!(worst < 6e-7);
    assert!(math::erfc(f32::NAN).is_finite());

    let mut worst: f64 = 0.0;
    for s in [0.2, 0.28, 0.5, 1.0, 1.7] {
        for c in samples(-0.5, 0.5, 100) {
            for i in -8..=8 {
                let got = f64::from(math::pixel_fraction(i as f32, c as f32, s as f32));
                let want = psf::pixel_frac(f64::from(i), f64::from(c as f32), f64::from(s as f32));
                worst = worst.max((got - want).abs());
            }
        }
    }
    eprintln!("pixel_fraction: worst absolute error {worst:.2e} (of the unit flux)");
    assert!(worst < 6e-7);
}

#[test]
fn erfc_abs_and_gauss_against_f64() {
    // The Gauss fit's per-edge pair: erfc(|z|) within A&S 7.1.26's 1.5e-7 plus the f32
    // rounding of its ~10 operations on values below 2 (half an ulp of 2, 1.2e-7, each):
    // 1.35e-6; exp(-z^2) <= 1 with `math::exp`'s 5e-7 relative error.
    let (mut worst_erfc, mut worst_gauss): (f64, f64) = (0.0, 0.0);
    for z in samples(-6.0, 6.0, 120_000) {
        let z32 = z as f32;
        let (e, g) = math::erfc_abs_and_gauss(z32);
        let x = f64::from(z32).abs();
        worst_erfc = worst_erfc.max((f64::from(e) - psf::erfc(x)).abs());
        worst_gauss = worst_gauss.max((f64::from(g) - (-x * x).exp()).abs());
    }
    eprintln!(
        "erfc_abs_and_gauss: worst absolute error {worst_erfc:.2e} (erfc), {worst_gauss:.2e} (exp)"
    );
    assert!(worst_erfc < 1.35e-6, "{worst_erfc}");
    assert!(worst_gauss < 5e-7, "{worst_gauss}");
    assert_eq!(math::erfc_abs_and_gauss(f32::NAN), (1.0, 0.0));
}

#[test]
fn edge_grid_pixels_against_f64() {
    // The Gauss fit's pixel profile: fractions and density differences from the edges
    // z_k = (u0 + k) h, the exponentials by a recurrence. An edge's exp is at most 5 steps
    // from a direct `exp` (error d = 1e-7, the measured bound of the test above), step i's
    // factor carrying d + i (d + e) (q's error accumulates; e = 6e-8, one rounding), each
    // step one more rounding, the first step downwards a divide: relative error
    // <= d + (j + 1) d + j (j - 1) / 2 (d + e) + (j + 1) e = 2.6e-6 for j = 5 (measured
    // ~1e-6: the errors partly cancel). A fraction is half a difference of two erfc, each
    // within `erfc_abs_and_gauss`'s allowance (1.35e-6) plus 2.6e-6 g (erfc = poly(t) g,
    // poly(t) <= 1): 4e-6; a density difference is two such g: 5.2e-6.
    let (mut worst_frac, mut worst_diff): (f64, f64) = (0.0, 0.0);
    let (mut frac, mut diff) = ([0.0f32; 31], [0.0f32; 31]);
    for h in [0.02f32, 0.1, 0.4, 0.707, 1.3, 3.5, 7.1] {
        let grid = math::EdgeGrid::new(h);
        for u0 in samples(-31.5, 0.5, 2000) {
            for n in [1usize, 2, 5, 7, 17, 31] {
                let u0 = u0 as f32;
                grid.pixels(u0, 1.0, &mut frac[..n], &mut diff[..n]);
                let z = |k: usize| (f64::from(u0) + k as f64) * f64::from(h);
                for i in 0..n {
                    let (lo, hi) = (z(i), z(i + 1));
                    let want = if lo >= 0.0 {
                        0.5 * (psf::erfc(lo) - psf::erfc(hi))
                    } else {
                        0.5 * (psf::erfc(-hi) - psf::erfc(-lo))
                    };
                    let want_d = (-lo * lo).exp() - (-hi * hi).exp();
                    worst_frac = worst_frac.max((f64::from(frac[i]) - want).abs());
                    worst_diff = worst_diff.max((f64::from(diff[i]) - want_d).abs());
                }
            }
        }
    }
    eprintln!(
        "EdgeGrid::pixels: worst absolute error {worst_frac:.2e} (fraction), {worst_diff:.2e} \
         (density difference)"
    );
    assert!(worst_frac < 4e-6, "{worst_frac}");
    assert!(worst_diff < 5.2e-6, "{worst_diff}");
    // The scale multiplies the differences only.
    let grid = math::EdgeGrid::new(0.7);
    let (mut f1, mut d1, mut f2, mut d2) = ([0.0f32; 7], [0.0f32; 7], [0.0f32; 7], [0.0f32; 7]);
    grid.pixels(-3.2, 1.0, &mut f1, &mut d1);
    grid.pixels(-3.2, 0.5, &mut f2, &mut d2);
    assert_eq!(f1, f2);
    assert!(d1.iter().zip(&d2).all(|(a, b)| *b == 0.5 * a));
    // Not finite or not positive spacing: direct per-edge values, still finite.
    for (u0, h) in [
        (f32::NAN, 0.5),
        (0.0, f32::NAN),
        (0.0, -1.0),
        (f32::INFINITY, 1.0),
    ] {
        let (mut f, mut d) = ([0.0f32; 4], [0.0f32; 4]);
        math::EdgeGrid::new(h).pixels(u0, 1.0, &mut f, &mut d);
        assert!(f.iter().chain(&d).all(|v| v.is_finite()), "{f:?} {d:?}");
    }
}
