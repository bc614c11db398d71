//! The few f32 functions the centroid methods need, for `no_std` (core has no `sqrt`, `exp`
//! or `ln` for floats; `micromath`'s `sqrt` is documented as a ~5 % approximation and its
//! `exp`/`ln` state no accuracy, too loose a basis for sub-millipixel work). They are
//! `libm` (rust-lang's port of musl's libm, about 1 ulp) behind total wrappers that give a
//! finite value for any input; the host test `centroid_math` checks the accuracy.
//!
//! | function | method |
//! |---|---|
//! | [`sqrt`] | `libm::sqrtf` |
//! | [`exp`] | `libm::expf` |
//! | [`ln`] | `libm::logf` |
//! | [`erfc`] | `libm::erfcf` |
//! | [`pixel_fraction`] | difference of two `erfc`, taken on the tail side |
//! | [`erfc_abs_and_gauss`] | Abramowitz & Stegun 7.1.26 and the `exp` it shares |
//!
//! Every function returns a finite value for any input (documented per function), so no NaN
//! reaches a centroid. Cost: a few multiplies and one divide each (sqrt: 4 divides).

/// Square root; 0 for negative, zero or NaN input, `f32::MAX` for +inf.
pub fn sqrt(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        return 0.0;
    }
    libm::sqrtf(x.min(f32::MAX))
}

/// e^x; 0 below -87.3, `f32::MAX` above 88.7 (and for +inf), 0 for NaN.
pub fn exp(x: f32) -> f32 {
    if x.is_nan() || x <= -87.3 {
        return 0.0;
    }
    if x > 88.7 {
        return f32::MAX;
    }
    libm::expf(x)
}

/// Natural logarithm; `-104` (below ln of the smallest positive f32) for zero, negative or
/// NaN input, `f32::MAX.ln()` for +inf.
pub fn ln(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        return -104.0;
    }
    libm::logf(x.min(f32::MAX))
}

/// The complementary error function, Abramowitz & Stegun 7.1.26:
/// `erfc(x) = t (a1 + t (a2 + ... + t a5)) exp(-x^2)`, `t = 1 / (1 + p x)` for `x >= 0`, and
/// `2 - erfc(-x)` below. Absolute error below 1.5e-7 in exact arithmetic; the relative error
/// grows in the far tail (about 1e-3 at x = 4, where erfc is 1.5e-8). Finite for any input
/// (NaN gives 1).
pub fn erfc(x: f32) -> f32 {
    if x.is_nan() {
        return 1.0;
    }
    libm::erfcf(x)
}

/// `(erfc(|z|), exp(-z^2))` from one exponential: Abramowitz & Stegun 7.1.26,
/// `erfc(x) = t (a1 + t (a2 + t (a3 + t (a4 + t a5)))) exp(-x^2)`, `t = 1 / (1 + p x)`,
/// absolute error below 1.5e-7 in exact arithmetic (the host test `centroid_math` bounds the
/// f32 result against an f64 reference). The second value is what a normal density at
/// `sqrt(2) z` needs, so a caller that wants both (the Gauss fit's pixel edges) pays one
/// `exp` and one divide instead of `erfcf` and `expf`. NaN gives `(1, 0)`.
pub fn erfc_abs_and_gauss(z: f32) -> (f32, f32) {
    if z.is_nan() {
        return (1.0, 0.0);
    }
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [
        0.254_829_6,
        -0.284_496_74,
        1.421_413_7,
        -1.453_152_1,
        1.061_405_4,
    ];
    let x = z.abs();
    let g = exp(-x * x);
    let t = 1.0 / (1.0 + P * x);
    let [a1, a2, a3, a4, a5] = A;
    let poly = t * (a1 + t * (a2 + t * (a3 + t * (a4 + t * a5))));
    (poly * g, g)
}

/// The standard normal density `exp(-z^2/2) / sqrt(2 pi)`.
pub fn norm_pdf(z: f32) -> f32 {
    0.398_942_3 * exp(-0.5 * z * z)
}

/// The fraction of a unit 1-D Gaussian (sigma `s`, centre `c`) falling in the pixel centred at
/// `i`: `Phi((i + 1/2 - c) / s) - Phi((i - 1/2 - c) / s)` (paper eq. 3 for eq. 5), computed
/// from the tail on the same side so that no two numbers near 1 are subtracted.
pub fn pixel_fraction(i: f32, c: f32, s: f32) -> f32 {
    const FRAC_1_SQRT_2: f32 = core::f32::consts::FRAC_1_SQRT_2;
    let lo = (i - 0.5 - c) / s * FRAC_1_SQRT_2;
    let hi = (i + 0.5 - c) / s * FRAC_1_SQRT_2;
    let p = if lo >= 0.0 {
        0.5 * (erfc(lo) - erfc(hi))
    } else if hi <= 0.0 {
        0.5 * (erfc(-hi) - erfc(-lo))
    } else {
        1.0 - 0.5 * (erfc(-lo) + erfc(hi))
    };
    p.max(0.0)
}
