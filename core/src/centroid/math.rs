//! The few f32 functions the centroid methods need, for `no_std` (core has no `sqrt`, `exp`
//! or `erfc` for floats, and the core forbids `unsafe`, so no `vsqrt` intrinsic; `micromath`'s
//! `sqrt` is documented as a ~5 % approximation and its `exp` states no accuracy, too
//! loose a basis for sub-millipixel work). `erfc` is `libm` (rust-lang's port of
//! musl's libm, about 1 ulp); `sqrt` and `exp` are written here for the Cortex-M7, where
//! libm's versions cost ~50 instructions a call (its `sqrtf` is a bit-by-bit software root).
//! All are total wrappers that give a finite value for any input; the host test
//! `centroid_math` checks the accuracy against f64.
//!
//! | function | method | bound (host test `centroid_math`) |
//! |---|---|---|
//! | [`sqrt`] | bit-pattern first guess, 2 Newton steps on `1/sqrt`, one Heron step (one divide) | 2.5e-7 relative |
//! | [`exp`] | `2^k e^r`, `|r| <= ln 2 / 2` (Cody-Waite), degree-7 Taylor polynomial | 5e-7 relative |
//! | [`erfc`] | `libm::erfcf` | 6e-7 absolute |
//! | [`pixel_fraction`] | difference of two `erfc`, taken on the tail side | 6e-7 absolute |
//! | [`erfc_abs_and_gauss`] | Abramowitz & Stegun 7.1.26 and the `exp` it shares | 1.35e-6 / 5e-7 absolute |
//! | [`EdgeGrid::pixels`] | pixel fractions from edge `erfc`s, `exp` by a recurrence | see [`EdgeGrid::pixels`] |
//!
//! Every function returns a finite value for any input (documented per function), so no NaN
//! reaches a centroid. Cost on the Cortex-M7 (QEMU instructions): `sqrt` ~25 with one
//! `vdiv` (~14 cycles on the M7), `exp` ~35 with none.

/// `max(v, 0)` (0 for NaN, as `f32::max`) by a compare: without `-C target-cpu=cortex-m7`
/// (the Cortex-M4 FPU, no `vmaxnm`) `f32::max` is a call to `fmaxf`.
#[inline(always)]
pub(crate) fn pos(v: f32) -> f32 {
    if v > 0.0 { v } else { 0.0 }
}

/// Square root; 0 for negative, zero or NaN input, `f32::MAX.sqrt()` for +inf.
///
/// `r0` from the bit pattern (`0x5f37_59df - bits / 2`, within 3.5 % of `1/sqrt(x)`), two
/// Newton steps `r <- r (3/2 - x r^2 / 2)` (relative error 3.5e-2 -> 1.8e-3 -> 5e-6), then
/// `s = x r` and one Heron step `(s + x / s) / 2`, which squares the error (to ~1e-11) and
/// leaves the f32 rounding of the last operations: about 1 ulp. Subnormal inputs are scaled
/// by `2^24` first (exact), the root by `2^-12`.
pub fn sqrt(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        return 0.0;
    }
    let x = x.min(f32::MAX);
    let (x, scale) = if x < f32::MIN_POSITIVE {
        (x * 16_777_216.0, 1.0 / 4096.0)
    } else {
        (x, 1.0)
    };
    let mut r = f32::from_bits(0x5f37_59df - (x.to_bits() >> 1));
    let hx = 0.5 * x;
    r *= 1.5 - hx * r * r;
    r *= 1.5 - hx * r * r;
    let s = x * r;
    0.5 * (s + x / s) * scale
}

/// e^x; 0 below -87.3, `f32::MAX` above 88.7 (and for +inf), 0 for NaN.
///
/// `k = round(x / ln 2)` (by adding `1.5 2^23`), `r = x - k ln 2` in two parts (Cody-Waite:
/// `k ln2_hi` is exact for `|k| <= 128`), `e^r` by its degree-7 Taylor polynomial on
/// `|r| <= 0.347` (truncation below 6e-9 relative), times `2^k` as two exponent-field
/// factors (`k` reaches 128, beyond one factor's range). The error is the f32 rounding of
/// ~10 operations: the host test bounds it at 5e-7 relative over `[-87, 88]`.
pub fn exp(x: f32) -> f32 {
    if x.is_nan() || x <= -87.3 {
        return 0.0;
    }
    if x > 88.7 {
        return f32::MAX;
    }
    const LOG2_E: f32 = core::f32::consts::LOG2_E;
    const LN2_HI: f32 = f32::from_bits(0x3f31_7200); // 0.693_145_75: 15 significant bits
    const LN2_LO: f32 = 1.428_606_8e-6;
    const ROUND: f32 = 12_582_912.0; // 1.5 2^23: adding it rounds to an integer
    let t = x * LOG2_E + ROUND;
    let kf = t - ROUND;
    // t's mantissa holds k (|k| <= 128) above ROUND's bits.
    let k = t.to_bits().wrapping_sub(ROUND.to_bits()) as i32;
    let r = (x - kf * LN2_HI) - kf * LN2_LO;
    const C: [f32; 8] = [
        1.0,
        1.0,
        0.5,
        1.0 / 6.0,
        1.0 / 24.0,
        1.0 / 120.0,
        1.0 / 720.0,
        1.0 / 5040.0,
    ];
    let [c0, c1, c2, c3, c4, c5, c6, c7] = C;
    let p = c0 + r * (c1 + r * (c2 + r * (c3 + r * (c4 + r * (c5 + r * (c6 + r * c7))))));
    // 2^k = 2^(k >> 1) 2^(k - (k >> 1)), each exponent in -63..=64.
    let k_hi = k >> 1;
    let k_lo = k - k_hi;
    let pow2 = |e: i32| f32::from_bits(((e + 127) as u32) << 23);
    p * pow2(k_hi) * pow2(k_lo)
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

/// `erfc(|z|)` from `exp(-z^2)`: A&S 7.1.26's polynomial in `t = 1 / (1 + p |z|)` times `g`.
#[inline(always)]
fn erfc_from_gauss(z: f32, g: f32) -> f32 {
    const P: f32 = 0.327_591_1;
    const A: [f32; 5] = [
        0.254_829_6,
        -0.284_496_74,
        1.421_413_7,
        -1.453_152_1,
        1.061_405_4,
    ];
    let t = 1.0 / (1.0 + P * z.abs());
    let [a1, a2, a3, a4, a5] = A;
    t * (a1 + t * (a2 + t * (a3 + t * (a4 + t * a5)))) * g
}

/// Edges between direct evaluations of [`EdgeGrid::pixels`]' recurrence.
const EDGE_RESTART: usize = 5;

/// Equally spaced points `z_k = (u0 + k) h` (the Gauss fit's pixel edges along one axis, in
/// units of `s sqrt 2`) and the constants of [`EdgeGrid::pixels`]' recurrence, computed once
/// per spacing.
#[derive(Clone, Copy, Debug)]
pub struct EdgeGrid {
    h: f32,
    hh: f32,
    /// `exp(-2 h^2)`, the ratio of successive step factors.
    q: f32,
}

impl EdgeGrid {
    /// The grid of spacing `h`; a spacing that is not finite or not positive makes
    /// [`Self::pixels`] evaluate every edge directly.
    pub fn new(h: f32) -> Self {
        let hh = h * h;
        Self {
            h,
            hh,
            q: exp(-2.0 * hh),
        }
    }

    /// Pixel fractions and density differences along one axis of a unit Gaussian, from the
    /// pixel edges `z_k = (u0 + k) h`, `k = 0..=n` for the `n = min(frac.len(), diff.len())`
    /// pixels (edge `k` is pixel `k`'s lower edge): with `E_k = erfc(|z_k|)` and
    /// `g_k = exp(-z_k^2)` ([`erfc_abs_and_gauss`] at each edge),
    /// ```text
    /// frac_i = max(P_i, 0),  P_i = (E_i - E_i+1) / 2  (z_i >= 0),  (E_i+1 - E_i) / 2  (z_i+1 <= 0),
    ///                              1 - (E_i + E_i+1) / 2  (otherwise: the tail side, as pixel_fraction)
    /// diff_i = scale (g_i - g_i+1)
    /// ```
    /// The exponentials come from a recurrence instead of one `exp` per edge: from
    /// `exp(-(z + h)^2) = exp(-z^2) rho(z)` with `rho(z) = exp(-(2 z h + h^2))` and
    /// `rho(z + h) = rho(z) q`, `q = exp(-2 h^2)`, two multiplies take `g` one edge further
    /// from `z = 0`, and `sigma(z) = exp(2 z h - h^2) = q / rho(z)` likewise towards negative
    /// `z`. It starts at the edge nearest `z = 0` (`|z| <= h / 2` there: two `exp` and a
    /// divide, or three `exp` for `h > 5.9`) and restarts from a direct `exp` pair every 5
    /// edges, so a value is at most 5 steps from a direct `exp`. The factors have exponents
    /// <= 0 (no overflow; an underflow is a true value below 1e-38). `q` is computed
    /// directly, not as `rho sigma`: its error enters every step (the product's doubled
    /// error gave 1.6e-6 after 5 steps, the direct `q` 7e-7; 6 steps between restarts gave
    /// 1.2e-6, 5 steps 9.5e-7; host test `centroid_math`). Cost per pixel: 2 multiplies,
    /// `erfc`'s divide and polynomial and the tail-side difference; per call 2 `exp` and a
    /// divide, and 2 `exp` more every 5 edges beyond the first 5 on either side (none for a
    /// 7x7 window's 8 edges around a centred star). `u0 + k` is exact for `|u0|, k < 2^18`,
    /// so `z_k` has one rounding and the recurrence follows the same `z_k` to that rounding.
    /// A `u0` or spacing that is not finite, or a spacing `<= 0`, falls back to
    /// [`erfc_abs_and_gauss`] per edge.
    pub fn pixels(&self, u0: f32, scale: f32, frac: &mut [f32], diff: &mut [f32]) {
        self.walk::<false>(u0, scale, 0.0, frac, diff, &mut []);
    }

    /// [`Self::pixels`] and, in `dwidth`, each pixel's derivative with respect to the
    /// Gaussian's sigma `s`: with `u = sqrt(2) z` the edge in sigmas,
    /// `dP_i/ds = (phi(u_i) u_i - phi(u_i+1) u_i+1) / s = wscale (g_i z_i - g_i+1 z_i+1)`,
    /// `wscale = 1 / (s sqrt(pi))` for a unit flux; the same edges and exponentials, two
    /// multiplies and a subtraction more per pixel. Pixels beyond `dwidth`'s length get none.
    pub fn pixels_with_width(
        &self,
        u0: f32,
        scale: f32,
        wscale: f32,
        frac: &mut [f32],
        diff: &mut [f32],
        dwidth: &mut [f32],
    ) {
        self.walk::<true>(u0, scale, wscale, frac, diff, dwidth);
    }

    /// The body of [`Self::pixels`] (`W` false: `dwidth` untouched, the same code as
    /// before it existed) and [`Self::pixels_with_width`].
    #[inline(always)]
    fn walk<const W: bool>(
        &self,
        u0: f32,
        scale: f32,
        wscale: f32,
        frac: &mut [f32],
        diff: &mut [f32],
        dwidth: &mut [f32],
    ) {
        let Self { h, hh, q } = *self;
        let n = frac.len().min(diff.len());
        let put = |f: &mut f32, d: &mut f32, (zl, el, gl): Edge, (zh, eh, gh): Edge| {
            let v = if zl >= 0.0 {
                0.5 * (el - eh)
            } else if zh <= 0.0 {
                0.5 * (eh - el)
            } else {
                1.0 - 0.5 * (el + eh)
            };
            *f = if v > 0.0 { v } else { 0.0 };
            *d = scale * (gl - gh);
        };
        let mut put_w = |i: usize, (zl, _, gl): Edge, (zh, _, gh): Edge| {
            if W && let Some(w) = dwidth.get_mut(i) {
                *w = wscale * (gl * zl - gh * zh);
            }
        };
        if !(u0.is_finite() && h.is_finite() && h > 0.0) {
            let edge = |k: f32| {
                let z = (u0 + k) * h;
                let (e, g) = erfc_abs_and_gauss(z);
                (z, e, g)
            };
            let mut k = 0.0f32;
            let mut lo = edge(k);
            for (i, (f, d)) in frac.iter_mut().zip(diff.iter_mut()).enumerate() {
                k += 1.0;
                let hi = edge(k);
                put(f, d, lo, hi);
                put_w(i, lo, hi);
                lo = hi;
            }
            return;
        }
        // The edge nearest z = 0 (saturating conversion; clamped to 0..=n).
        let m = ((0.5 - u0) as usize).min(n);
        let zm = (u0 + m as f32) * h;
        let (gm, rho_m) = (exp(-zm * zm), exp(-(2.0 * zm * h + hh)));
        // sigma_m = q / rho_m, with rho_m >= exp(-2 h^2) = q (|zm| <= h / 2, or zm further
        // negative when clamped); directly when q is near the f32 underflow (h > 5.9).
        let sigma_m = if q > 1e-30 {
            q / rho_m
        } else {
            exp(2.0 * zm * h - hh)
        };
        let edge_m = (zm, erfc_from_gauss(zm, gm), gm);
        let (Some((frac_dn, frac_up)), Some((diff_dn, diff_up))) = (
            frac.get_mut(..n).and_then(|f| f.split_at_mut_checked(m)),
            diff.get_mut(..n).and_then(|d| d.split_at_mut_checked(m)),
        ) else {
            return;
        };
        // Upwards: pixel i from edges i (lo) and i + 1, for i = m..n.
        let (mut lo, mut rho, mut left) = (edge_m, rho_m, EDGE_RESTART);
        let mut k = m as f32;
        for (j, (f, d)) in frac_up.iter_mut().zip(diff_up.iter_mut()).enumerate() {
            k += 1.0;
            let z = (u0 + k) * h;
            left -= 1;
            let g = if left == 0 {
                left = EDGE_RESTART;
                rho = exp(-(2.0 * z * h + hh));
                exp(-z * z)
            } else {
                let g = lo.2 * rho;
                rho *= q;
                g
            };
            let hi = (z, erfc_from_gauss(z, g), g);
            put(f, d, lo, hi);
            put_w(m + j, lo, hi);
            lo = hi;
        }
        // Downwards: pixel i from edges i and i + 1 (hi), for i = m - 1 down to 0.
        let (mut hi, mut sigma, mut left) = (edge_m, sigma_m, EDGE_RESTART);
        let mut k = m as f32;
        let mut i = m;
        for (f, d) in frac_dn.iter_mut().zip(diff_dn.iter_mut()).rev() {
            i -= 1;
            k -= 1.0;
            let z = (u0 + k) * h;
            left -= 1;
            let g = if left == 0 {
                left = EDGE_RESTART;
                sigma = exp(2.0 * z * h - hh);
                exp(-z * z)
            } else {
                let g = hi.2 * sigma;
                sigma *= q;
                g
            };
            let lo = (z, erfc_from_gauss(z, g), g);
            put(f, d, lo, hi);
            put_w(i, lo, hi);
            hi = lo;
        }
    }
}

/// An edge's `(z, erfc(|z|), exp(-z^2))`.
type Edge = (f32, f32, f32);

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
