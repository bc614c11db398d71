//! Accuracy of the core's f32 functions (`centroid::math`) against f64, over their useful
//! ranges, and a self-check of the f64 erf used by the PSF reference.
//!
//! `-- --nocapture` prints the measured worst errors (quoted in the module docs).

#[path = "common/psf.rs"]
mod psf;

use startrack_core::centroid::math;

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
fn ln_absolute_error() {
    let mut worst: f64 = 0.0;
    for e in samples(-140.0, 127.0, 400_000) {
        let x = 2f64.powf(e) as f32;
        if x == 0.0 {
            continue;
        }
        let got = f64::from(math::ln(x));
        let want = f64::from(x).ln();
        // Absolute near 1, relative (f32 rounding of the result) far from it.
        worst = worst.max((got - want).abs() / (1.0 + want.abs()));
    }
    eprintln!("ln: worst error {worst:.2e} x (1 + |ln x|)");
    assert!(worst < 2e-7, "{worst}");
    for bad in [0.0, -1.0, f32::NAN] {
        assert!(math::ln(bad).is_finite());
    }
    assert!(math::ln(f32::INFINITY).is_finite());
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
fn edge_grid_against_f64() {
    // The Gauss fit's edges: `erfc_abs_and_gauss` at (u0 + k) h with the exponentials from a
    // recurrence. A value is at most j <= 5 steps from a direct `exp` (error d = 1e-7, the
    // measured bound of the test above), step i's factor carrying d + i (d + e) (q's error
    // accumulates; e = 6e-8, one rounding), each step one more rounding, the first step
    // downwards a divide: relative error <= d + (j + 1) d + j (j - 1) / 2 (d + e) + (j + 1) e
    // = 2.6e-6 for j = 5 (measured: ~1e-6, the errors partly cancel). erfc = poly(t) g <= 1,
    // so its error is within `erfc_abs_and_gauss`'s allowance (1.35e-6) plus that: 4e-6.
    let (mut worst_erfc, mut worst_gauss): (f64, f64) = (0.0, 0.0);
    let mut out = [[0.0f32; 3]; 32];
    for h in [0.02f32, 0.1, 0.4, 0.707, 1.3, 3.5, 7.1] {
        for u0 in samples(-31.5, 0.5, 2000) {
            for n in [1usize, 2, 6, 8, 17, 32] {
                let out = &mut out[..n];
                let u0 = u0 as f32;
                math::EdgeGrid::new(h).fill(u0, out);
                for (k, &[z, e, g]) in out.iter().enumerate() {
                    assert_eq!(z, (u0 + k as f32) * h, "z at k {k}");
                    let x = ((f64::from(u0) + k as f64) * f64::from(h)).abs();
                    worst_erfc = worst_erfc.max((f64::from(e) - psf::erfc(x)).abs());
                    worst_gauss = worst_gauss.max((f64::from(g) - (-x * x).exp()).abs());
                }
            }
        }
    }
    eprintln!(
        "EdgeGrid::fill: worst absolute error {worst_erfc:.2e} (erfc), {worst_gauss:.2e} (exp)"
    );
    assert!(worst_erfc < 4e-6, "{worst_erfc}");
    assert!(worst_gauss < 2.6e-6, "{worst_gauss}");
    // Not finite or not positive spacing: per-edge values, still finite.
    for (u0, h) in [
        (f32::NAN, 0.5),
        (0.0, f32::NAN),
        (0.0, -1.0),
        (f32::INFINITY, 1.0),
    ] {
        let mut out = [[0.0f32; 3]; 4];
        math::EdgeGrid::new(h).fill(u0, &mut out);
        assert!(
            out.iter().all(|o| o[1].is_finite() && o[2].is_finite()),
            "{out:?}"
        );
    }
}
