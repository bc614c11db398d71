//! Weighted least-squares fit of the pixel-integrated Gaussian (paper eq. 3 and 5) by a few
//! Gauss-Newton steps: position, flux and a residual background, the PSF sigma known.
//!
//! # Model and fit
//! ```text
//! m_k = B + N P(c_k; x) P(r_k; y),   P(i; x) = Phi((i + 1/2 - x)/s) - Phi((i - 1/2 - x)/s)
//! minimise sum((F_k - m_k)^2 / v_k),  v_k = max(N P P, 0) + var_bg + 1 e-^2
//! ```
//! on the usable pixels of the window, `F_k` background-subtracted (perimeter or given), so
//! `B` is what is left of the background (started at 0; held at 0 when `fit_background` is
//! off). The weights come from the model, not the data (a data-weighted fit biases the flux
//! low), and are refreshed each step, which makes the fit the Gaussian approximation of the
//! Poisson maximum likelihood; the extra 1 e-^2 keeps the weights finite on a noise-free
//! window. Each step solves the 4x4 normal equations `(J^T W J) d = J^T W r`, Jacobi-scaled
//! and Cholesky-factored in f32; `P` and `dP/dx` are separable, so a step needs `width + 1`
//! and `height + 1` evaluations of `erfc` and of the normal density, not one per pixel.
//!
//! Start: the power-1 CoG of a `start_box` around the brightest pixel, `N` = the window's
//! sum. Stop when both position steps are below `tolerance_px`. Failure policy: a step that
//! leaves the window, a flux that is not positive, or normal equations that are not positive
//! definite return the starting CoG with `NOT_CONVERGED`; running out of iterations returns
//! the last estimate with `NOT_CONVERGED`. Steps are capped at one pixel.
//!
//! # Error estimate
//! The covariance `(J^T W J)^-1` at the solution (after convergence, the one of the last
//! step's start, less than `tolerance_px` away, so no extra evaluation): `sigma_x`, `sigma_y` and the flux error are
//! the square roots of its diagonal. `flux_e` is the fitted total flux `N` (the whole PSF, not
//! the window's share) and `snr` is `N / sigma_N` (which, unlike eq. 8, charges the fit for
//! the background it also fits).
//!
//! # Cost
//! Per step: `w + h + 2` `erfc` and normal-density evaluations (one per pixel edge, shared
//! by neighbouring pixels), then ~20 multiply-adds per pixel for the upper triangle of the
//! normal equations; 3-5 steps. A 9x9 window is ~15 k flops per star, about the IWC's.
//!
//! # Where it fails
//! - A wrong PSF sigma: position stays nearly unbiased for a symmetric star, flux does not;
//!   undersampled stars (s < 0.4 px) become sensitive to it.
//! - Non-Gaussian PSFs (coma, defocus): a model error; use the CoG with a correction table.
//! - Blends and cosmic rays in the window pull the fit (no outlier rejection).
//! - `erfc` by Abramowitz & Stegun 7.1.26 (error below 1.5e-7 per edge, so a few 1e-7 of
//!   the flux per pixel) limits the noise-free accuracy to ~1e-5 px.

use super::cog::{cog_start, usable_sigma_px};
use super::{
    Background, Centroid, CentroidFlags, CentroidInput, MAX_SIDE, Measured, Prepared, math,
};

/// Parameters of [`gauss_fit`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GaussFitParams {
    /// The PSF's Gaussian sigma, px (`sqrt(0.31) a`); values below 0.1 px are taken as 0.1.
    pub psf_sigma_px: f32,
    /// Largest number of Gauss-Newton steps (0 returns the starting CoG).
    pub max_iterations: u8,
    /// Convergence threshold on the position step, px.
    pub tolerance_px: f32,
    /// Side of the starting CoG's box, px.
    pub start_box: u8,
    /// Fit a residual background `B` (else hold it at 0, trusting the background source).
    pub fit_background: bool,
    /// Background source.
    pub background: Background,
}

impl GaussFitParams {
    /// Eight steps to 1e-4 px from a 5x5 CoG, fitting the residual background over a
    /// perimeter-median estimate.
    pub const fn new(psf_sigma_px: f32) -> Self {
        Self {
            psf_sigma_px,
            max_iterations: 8,
            tolerance_px: 1e-4,
            start_box: 5,
            fit_background: true,
            background: Background::PerimeterMedian,
        }
    }
}

type Mat4 = [[f32; 4]; 4];

fn at(m: &Mat4, i: usize, j: usize) -> f32 {
    m.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0)
}

fn set(m: &mut Mat4, i: usize, j: usize, v: f32) {
    if let Some(x) = m.get_mut(i).and_then(|r| r.get_mut(j)) {
        *x = v;
    }
}

fn vget(v: &[f32; 4], i: usize) -> f32 {
    v.get(i).copied().unwrap_or(0.0)
}

/// Cholesky factor (lower) of a symmetric positive-definite matrix, or `None`.
fn cholesky(a: &Mat4) -> Option<Mat4> {
    let mut l = [[0.0f32; 4]; 4];
    for j in 0..4 {
        let d = at(a, j, j) - (0..j).map(|k| at(&l, j, k) * at(&l, j, k)).sum::<f32>();
        if d.is_nan() || d <= 1e-12 {
            return None;
        }
        let ljj = math::sqrt(d);
        set(&mut l, j, j, ljj);
        for i in j + 1..4 {
            let s = at(a, i, j) - (0..j).map(|k| at(&l, i, k) * at(&l, j, k)).sum::<f32>();
            set(&mut l, i, j, s / ljj);
        }
    }
    Some(l)
}

/// Solves `L L^T x = b`.
fn chol_solve(l: &Mat4, b: &[f32; 4]) -> [f32; 4] {
    let mut y = [0.0f32; 4];
    for i in 0..4 {
        let s = vget(b, i) - (0..i).map(|k| at(l, i, k) * vget(&y, k)).sum::<f32>();
        if let Some(v) = y.get_mut(i) {
            *v = s / at(l, i, i);
        }
    }
    let mut x = [0.0f32; 4];
    for i in (0..4).rev() {
        let s = vget(&y, i) - (i + 1..4).map(|k| at(l, k, i) * vget(&x, k)).sum::<f32>();
        if let Some(v) = x.get_mut(i) {
            *v = s / at(l, i, i);
        }
    }
    x
}

/// Per-column (or per-row) pixel fractions and their derivatives for centre `c`, from one
/// `erfc` and one density per pixel *edge* (`n + 1` of each, shared by the two pixels an edge
/// separates), both from one exponential ([`math::erfc_abs_and_gauss`], A&S 7.1.26). With
/// `E(z) = erfc(|z|)` at the edges the fraction takes the same tail-side cases as
/// [`math::pixel_fraction`], so no two numbers near 1 are subtracted.
fn profile(
    n: u16,
    c: f32,
    s: f32,
    frac: &mut [f32; MAX_SIDE as usize],
    dfrac: &mut [f32; MAX_SIDE as usize],
) {
    const FRAC_1_SQRT_2: f32 = core::f32::consts::FRAC_1_SQRT_2;
    // Edge k is at i - 1/2 for pixel i = k; z scaled for erfc, t for the density.
    // phi(u/s) = exp(-z^2) / sqrt(2 pi) with z = u / (s sqrt 2).
    const FRAC_1_SQRT_2PI: f32 = 0.398_942_3;
    let edge = |k: u16| {
        let z = (f32::from(k) - 0.5 - c) / s * FRAC_1_SQRT_2;
        let (e, g) = math::erfc_abs_and_gauss(z);
        (z, e, FRAC_1_SQRT_2PI * g)
    };
    let mut lo = edge(0);
    for ((i, f), d) in (0..n).zip(frac.iter_mut()).zip(dfrac.iter_mut()) {
        let hi = edge(i + 1);
        let ((zl, el, pl), (zh, eh, ph)) = (lo, hi);
        let v = if zl >= 0.0 {
            0.5 * (el - eh)
        } else if zh <= 0.0 {
            0.5 * (eh - el)
        } else {
            1.0 - 0.5 * (el + eh)
        };
        *f = v.max(0.0);
        // dP/dc = (phi(lo) - phi(hi)) / s
        *d = (pl - ph) / s;
        lo = hi;
    }
}

/// Parameter order in the normal equations.
const X: usize = 0;
const Y: usize = 1;
const N: usize = 2;
const B: usize = 3;

/// The fit state: parameters, normal matrix and right-hand side at those parameters.
struct Normal {
    a: Mat4,
    b: [f32; 4],
}

/// Fills the normal equations at (x, y, flux, bg).
fn normal_equations(p: &Prepared<'_>, theta: [f32; 4], s: f32, fit_bg: bool) -> Normal {
    const M: usize = MAX_SIDE as usize;
    let (mut px, mut dpx, mut py, mut dpy) = ([0.0f32; M], [0.0f32; M], [0.0f32; M], [0.0f32; M]);
    profile(p.width, vget(&theta, X), s, &mut px, &mut dpx);
    profile(p.height, vget(&theta, Y), s, &mut py, &mut dpy);
    let (flux, bg) = (vget(&theta, N), vget(&theta, B));
    if !p.flags.contains(CentroidFlags::EXCLUDED_PIXEL) {
        return normal_equations_clean(p, (&px, &dpx, &py, &dpy), flux, bg, fit_bg);
    }
    normal_equations_general(p, (&px, &dpx, &py, &dpy), flux, bg, fit_bg)
}

/// The normal equations' sums over the usable pixels (excluded ones skipped).
fn normal_equations_general(
    p: &Prepared<'_>,
    (px, dpx, py, dpy): Profiles<'_>,
    flux: f32,
    bg: f32,
    fit_bg: bool,
) -> Normal {
    let mut a = [[0.0f32; 4]; 4];
    let mut b = [0.0f32; 4];
    let whole = super::PixelBox {
        col0: 0,
        row0: 0,
        col1: p.width - 1,
        row1: p.height - 1,
    };
    for (col, row, f) in p.box_pixels(whole) {
        let (c, r) = (usize::from(col), usize::from(row));
        let (fx, fy) = (
            px.get(c).copied().unwrap_or(0.0),
            py.get(r).copied().unwrap_or(0.0),
        );
        let (dx, dy) = (
            dpx.get(c).copied().unwrap_or(0.0),
            dpy.get(r).copied().unwrap_or(0.0),
        );
        let star = flux * fx * fy;
        let model = bg + star;
        let wt = 1.0 / (star.max(0.0) + p.bg.variance_e2 + 1.0);
        let j = [
            flux * dx * fy,
            flux * fx * dy,
            fx * fy,
            if fit_bg { 1.0 } else { 0.0 },
        ];
        let res = f - model;
        for (i, (row_a, bi)) in a.iter_mut().zip(b.iter_mut()).enumerate() {
            let ji = vget(&j, i) * wt;
            *bi += ji * res;
            // The upper triangle only (the matrix is symmetric): 10 products, not 16.
            for (k, aik) in row_a.iter_mut().enumerate().skip(i) {
                *aik += ji * vget(&j, k);
            }
        }
    }
    for i in 1..4 {
        for k in 0..i {
            let v = at(&a, k, i);
            set(&mut a, i, k, v);
        }
    }
    if !fit_bg {
        // Pin B: a unit diagonal with no coupling (its step is then 0).
        set(&mut a, B, B, 1.0);
    }
    Normal { a, b }
}

/// [`normal_equations`] on a window without excluded pixels: a walk of the pixel rows with
/// the row's factors hoisted, the ten upper-triangle sums and the four right-hand sides in
/// scalars (registers), the same terms as the general loop.
fn normal_equations_clean(
    p: &Prepared<'_>,
    (px, dpx, py, dpy): Profiles<'_>,
    flux: f32,
    bg: f32,
    fit_bg: bool,
) -> Normal {
    let w = usize::from(p.width).max(1);
    let j3 = if fit_bg { 1.0f32 } else { 0.0 };
    let var1 = p.bg.variance_e2 + 1.0;
    // The level and every difference in i32 (one vcvt per pixel, not a library i64
    // conversion); a window where that fails takes the general loop.
    let Ok(level) = i32::try_from(p.bg.level_bits) else {
        return normal_equations_general(p, (px, dpx, py, dpy), flux, bg, fit_bg);
    };
    let mut overflow = false;
    let (mut a00, mut a01, mut a02, mut a03, mut a11) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    let (mut a12, mut a13, mut a22, mut a23, mut a33) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    let (mut b0, mut b1, mut b2, mut b3) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
    let rows = p.pixels.chunks_exact(w).zip(py.iter().zip(dpy.iter()));
    for (line, (&fy, &dy)) in rows {
        let (nfy, ndy) = (flux * fy, flux * dy);
        for (e, (&fx, &dx)) in line.iter().zip(px.iter().zip(dpx.iter())) {
            let (d, o) = e.to_bits().overflowing_sub(level);
            overflow |= o;
            let f = d as f32 / 64.0;
            let star = nfy * fx;
            let wt = 1.0 / (super::pos(star) + var1);
            let (j0, j1, j2) = (nfy * dx, ndy * fx, fx * fy);
            let res = f - (bg + star);
            let (w0, w1, w2, w3) = (j0 * wt, j1 * wt, j2 * wt, j3 * wt);
            a00 += w0 * j0;
            a01 += w0 * j1;
            a02 += w0 * j2;
            a03 += w0 * j3;
            a11 += w1 * j1;
            a12 += w1 * j2;
            a13 += w1 * j3;
            a22 += w2 * j2;
            a23 += w2 * j3;
            a33 += w3 * j3;
            b0 += w0 * res;
            b1 += w1 * res;
            b2 += w2 * res;
            b3 += w3 * res;
        }
    }
    if overflow {
        return normal_equations_general(p, (px, dpx, py, dpy), flux, bg, fit_bg);
    }
    let a = [
        [a00, a01, a02, a03],
        [a01, a11, a12, a13],
        [a02, a12, a22, a23],
        [a03, a13, a23, if fit_bg { a33 } else { 1.0 }],
    ];
    Normal {
        a,
        b: [b0, b1, b2, b3],
    }
}

/// The four profiles of [`normal_equations`]: column fractions and derivatives, then rows'.
type Profiles<'r> = (
    &'r [f32; MAX_SIDE as usize],
    &'r [f32; MAX_SIDE as usize],
    &'r [f32; MAX_SIDE as usize],
    &'r [f32; MAX_SIDE as usize],
);

/// Jacobi-scales, factors and solves; returns the step and the scaled factor.
fn solve(n: &Normal) -> Option<([f32; 4], [f32; 4], Mat4)> {
    let mut d = [0.0f32; 4];
    for (i, di) in d.iter_mut().enumerate() {
        let aii = at(&n.a, i, i);
        if aii.is_nan() || aii <= 0.0 {
            return None;
        }
        *di = 1.0 / math::sqrt(aii);
    }
    let mut sa = [[0.0f32; 4]; 4];
    for i in 0..4 {
        for k in 0..4 {
            set(&mut sa, i, k, at(&n.a, i, k) * vget(&d, i) * vget(&d, k));
        }
    }
    let l = cholesky(&sa)?;
    let sb = [0, 1, 2, 3].map(|i| vget(&n.b, i) * vget(&d, i));
    let z = chol_solve(&l, &sb);
    let step = [0, 1, 2, 3].map(|i| vget(&z, i) * vget(&d, i));
    step.iter().all(|v| v.is_finite()).then_some((step, d, l))
}

/// The variance of parameter `i` from the scaled factor: `d_i^2 [(D A D)^-1]_ii`.
fn variance(l: &Mat4, d: &[f32; 4], i: usize) -> f32 {
    let e = [0, 1, 2, 3].map(|k| if k == i { 1.0 } else { 0.0 });
    let z = chol_solve(l, &e);
    vget(&z, i) * vget(d, i) * vget(d, i)
}

/// The Gaussian fit of `input` (see the module docs).
pub fn gauss_fit(input: &CentroidInput<'_>, params: &GaussFitParams) -> Centroid {
    let (p, start, mut extra) = match cog_start(input, params.background, params.start_box) {
        Ok(s) => s,
        Err(c) => return c,
    };
    let s = usable_sigma_px(params.psf_sigma_px);
    let whole = super::PixelBox {
        col0: 0,
        row0: 0,
        col1: p.width - 1,
        row1: p.height - 1,
    };
    let total: f32 = p.box_pixels(whole).map(|(_, _, f)| f).sum();
    let mut theta = [start.col, start.row, total.max(start.flux_e), 0.0];
    let (wmax, hmax) = (f32::from(p.width) - 0.5, f32::from(p.height) - 0.5);
    let give_up = |extra: CentroidFlags| p.finish(start, extra | CentroidFlags::NOT_CONVERGED);
    let mut converged = params.max_iterations == 0;
    // The factor of the converged step's normal equations: the covariance there, a step of
    // under `tolerance_px` from the solution, instead of one more evaluation.
    let mut last_factor = None;
    for _ in 0..params.max_iterations {
        let Some((step, d, l)) = solve(&normal_equations(&p, theta, s, params.fit_background))
        else {
            return give_up(extra);
        };
        let sx = vget(&step, X).clamp(-1.0, 1.0);
        let sy = vget(&step, Y).clamp(-1.0, 1.0);
        theta = [
            vget(&theta, X) + sx,
            vget(&theta, Y) + sy,
            vget(&theta, N) + vget(&step, N),
            vget(&theta, B) + vget(&step, B),
        ];
        let (x, y, flux) = (vget(&theta, X), vget(&theta, Y), vget(&theta, N));
        if !(-0.5..=wmax).contains(&x)
            || !(-0.5..=hmax).contains(&y)
            || flux.is_nan()
            || flux <= 0.0
        {
            return give_up(extra);
        }
        if sx.abs() < params.tolerance_px && sy.abs() < params.tolerance_px {
            converged = true;
            last_factor = Some((d, l));
            break;
        }
    }
    if !converged {
        extra |= CentroidFlags::NOT_CONVERGED;
    }
    // Covariance at the solution (or at the converged step's start, within tolerance_px).
    let factor = match last_factor {
        Some(f) => Some(f),
        None => {
            solve(&normal_equations(&p, theta, s, params.fit_background)).map(|(_, d, l)| (d, l))
        }
    };
    let Some((d, l)) = factor else {
        return give_up(extra);
    };
    let flux = vget(&theta, N);
    let m = Measured {
        col: vget(&theta, X),
        row: vget(&theta, Y),
        flux_e: flux,
        snr: flux / math::sqrt(variance(&l, &d, N)).max(f32::MIN_POSITIVE),
        sigma_col: math::sqrt(variance(&l, &d, X)),
        sigma_row: math::sqrt(variance(&l, &d, Y)),
    };
    p.finish(m, extra)
}
