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
//! # Held background
//! With `fit_background` off, no excluded pixel and sides up to 16 px (`startrack accuracy`'s
//! configuration, and the near-CRLB method of issue 5) the same estimator runs on three
//! parameters `(x, y, N)` (the 4x4 system's `B` row is then a decoupled unit pivot with a
//! zero step, so nothing changes but the work):
//! - `J = (N fy dx, N fx dy, fx fy)` separates: per pixel only the weight (one divide), the
//!   residual and five row sums `w dx^2, w dx fx, w fx^2, w dx r, w fx r`; per row nine
//!   multiply-adds with the row's `fy, dy`; the powers of `N` once at the end.
//! - The 3x3 system by `LDL^T` (no square root; a pivot below `1e-12` of its diagonal is
//!   "not positive definite", the 4x4 path's test on the Jacobi-scaled matrix); the
//!   covariance diagonal from the factor, `sum_k (L^-1)_ki^2 / d_k`.
//! - The edge `erfc`s and densities by [`math::EdgeGrid::pixels`]: `exp(-z^2)` by a
//!   two-multiply recurrence along the edges.
//! - Start: the peak by one walk of the pixel bits, the power-1 CoG of the box in f32 sums,
//!   `N` = the box's flux (the first step solves the linear `N` anyway); on failure the exact
//!   starting CoG (`cog_in_box`, with its error estimate) is computed then.
//!
//! The host test `centroid_gauss_fit` checks this path against an f64 implementation of the
//! same estimator (2e-6 px at `tolerance_px` 1e-6, 4e-6 px at the default 1e-4; error
//! estimate within 1e-4 relative).
//!
//! # Error estimate
//! The covariance `(J^T W J)^-1` at the solution (after convergence, the one of the last
//! step's start, less than `tolerance_px` away, so no extra evaluation): `sigma_x`,
//! `sigma_y` and the flux error are the square roots of its diagonal. `flux_e` is the fitted
//! total flux `N` (the whole PSF, not the window's share) and `snr` is `N / sigma_N` (which,
//! unlike eq. 8, charges the fit for the background when it also fits it).
//!
//! # Cost
//! Per step: `w + h + 2` `erfc` and normal-density evaluations (one per pixel edge, shared
//! by neighbouring pixels), then the normal equations' sums per pixel; from the CoG start
//! a bright star converges in 2 steps (the covariance comes from the last one), a faint one
//! in 3-4. Measured on the Cortex-M7 (`cargo m7-bench`, QEMU instructions per star, the
//! bench's bright star, 2 steps):
//!
//! | configuration | 5x5 | 7x7 |
//! |---|---|---|
//! | background held and given (`centroid_gauss_fit_given_bg_*`: `startrack accuracy`'s) | 4,765 | 7,057 |
//! | perimeter median, `B` fitted (`centroid_gauss_fit_*`: [`GaussFitParams::new`]) | 16,799 | 22,039 |
//!
//! Of the held 7x7's ~7,060 (QEMU `-d exec` trace, see the README): ~1,430 a step for the
//! normal equations (~18 instructions a pixel: load, convert, weight divide, residual, five
//! multiply-adds; ~65 a row, with the 4-way unrolled loop's remainder), ~500 a step per axis
//! for the edge profile (~40 an edge: the A&S divide and polynomial, the recurrence, the
//! tail-side difference; ~200 for the two `exp` and the divide that start it), ~450 for the
//! peak walk, ~400 for the start's box CoG, ~150 a step for the solve and bookkeeping, ~390
//! for validating the window (`Prepared::new`), ~240 for the output (three square roots,
//! `finish`). The perimeter-median path adds the median and the 4x4 Jacobi-Cholesky solve.
//!
//! # Where it fails
//! - A wrong PSF sigma: position stays nearly unbiased for a symmetric star, flux does not;
//!   undersampled stars (s < 0.4 px) become sensitive to it.
//! - Non-Gaussian PSFs (coma, defocus): a model error; use the CoG with a correction table.
//! - Blends and cosmic rays in the window pull the fit (no outlier rejection).
//! - `erfc` by Abramowitz & Stegun 7.1.26 (error below 1.5e-7 per edge; with the f32
//!   rounding and the `exp` recurrence the pixel fractions are within 4e-6 of the unit flux,
//!   measured 5e-7, host test `centroid_math`) limits the noise-free accuracy to ~1e-5 px
//!   (measured 3e-6 to 6e-6 px for a = 0.5..2, host test `centroid_gauss_fit`).

use super::cog::{CogPower, cog_in_box, usable_sigma_px};
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
/// separates), the densities by [`math::EdgeGrid::pixels`]' recurrence and `erfc` by A&S
/// 7.1.26. With `E(z) = erfc(|z|)` at the edges the fraction takes the same tail-side cases
/// as [`math::pixel_fraction`], so no two numbers near 1 are subtracted.
fn profile(n: u16, c: f32, grid: &Grid, frac: &mut [f32], dfrac: &mut [f32]) {
    let n = usize::from(n);
    let (Some(frac), Some(dfrac)) = (frac.get_mut(..n), dfrac.get_mut(..n)) else {
        return;
    };
    // Edge k is at k - 1/2: z = (k - 1/2 - c) h; dP/dc = (phi(lo) - phi(hi)) / s.
    grid.edges.pixels(-0.5 - c, grid.dscale, frac, dfrac);
}

/// The PSF's edge grid: spacing `h = 1 / (s sqrt 2)` in erfc's units and the density's
/// scale `1 / (s sqrt(2 pi))` (`phi(u / s) / s = exp(-z^2) dscale`, `z = u h`).
struct Grid {
    edges: math::EdgeGrid,
    dscale: f32,
}

impl Grid {
    fn new(s: f32) -> Self {
        const FRAC_1_SQRT_2: f32 = core::f32::consts::FRAC_1_SQRT_2;
        const FRAC_1_SQRT_2PI: f32 = 0.398_942_3;
        Self {
            edges: math::EdgeGrid::new(FRAC_1_SQRT_2 / s),
            dscale: FRAC_1_SQRT_2PI / s,
        }
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
    let grid = Grid::new(s);
    profile(p.width, vget(&theta, X), &grid, &mut px, &mut dpx);
    profile(p.height, vget(&theta, Y), &grid, &mut py, &mut dpy);
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
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return c,
    };
    if !params.fit_background
        && !p.flags.contains(CentroidFlags::EXCLUDED_PIXEL)
        && p.width <= held::MAX_SIDE
        && p.height <= held::MAX_SIDE
    {
        return held::fit(&p, params);
    }
    fit_general(&p, params)
}

/// True when a Gauss-Newton step left the position inside the window's pixel edges
/// (`-1/2 ..= wmax`, `-1/2 ..= hmax`, window-relative) and the flux positive: else the fit
/// gives up (module docs, failure policy).
#[inline(always)]
fn step_usable(x: f32, y: f32, flux: f32, wmax: f32, hmax: f32) -> bool {
    (-0.5..=wmax).contains(&x) && (-0.5..=hmax).contains(&y) && flux > 0.0
}

/// The starting CoG on an already prepared window: the power-1 CoG of a
/// `start_box` around the peak, and `EDGE_CLIPPED` when the box was clipped.
fn start_cog(p: &Prepared<'_>, start_box: u8) -> Result<(Measured, CentroidFlags), Centroid> {
    let Some((pc, pr)) = p.peak() else {
        return Err(p.degenerate(CentroidFlags::empty()));
    };
    let (bx, clipped) = p.box_around(pc, pr, start_box);
    let extra = if clipped {
        CentroidFlags::EDGE_CLIPPED
    } else {
        CentroidFlags::empty()
    };
    match cog_in_box(p, bx, (pc, pr), CogPower::One) {
        Some(start) => Ok((start, extra)),
        None => Err(p.degenerate(extra)),
    }
}

/// The four-parameter fit (background fitted, or excluded pixels): the module docs' method
/// with the 4x4 Jacobi-scaled Cholesky solve.
fn fit_general(p: &Prepared<'_>, params: &GaussFitParams) -> Centroid {
    let (start, mut extra) = match start_cog(p, params.start_box) {
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
        let Some((step, d, l)) = solve(&normal_equations(p, theta, s, params.fit_background))
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
        if !step_usable(x, y, flux, wmax, hmax) {
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
            solve(&normal_equations(p, theta, s, params.fit_background)).map(|(_, d, l)| (d, l))
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

/// The three-parameter fit (x, y, N) with the background held, on a window without excluded
/// pixels: the same model, weights, start, steps and stopping rule as [`fit_general`] with
/// `fit_background` off (whose `B` row is a decoupled unit pivot with a zero step), computed
/// with less work. See the module docs' "Held background" section.
mod held {
    use super::{Centroid, GaussFitParams};
    use super::{
        CentroidFlags, CogPower, Grid, Measured, Prepared, cog_in_box, math, profile,
        usable_sigma_px,
    };

    /// Largest window side of this path (its profile buffers are zeroed per fit, so they
    /// are sized for star windows, not for [`super::MAX_SIDE`]); larger windows take the
    /// general path with `B` pinned.
    pub(super) const MAX_SIDE: u16 = 16;
    const M: usize = MAX_SIDE as usize;

    /// The LDL^T factor of the 3x3 normal matrix: unit lower `l10, l20, l21` and the
    /// reciprocal pivots `1/d0, 1/d1, 1/d2`.
    struct Ldl {
        l10: f32,
        l20: f32,
        l21: f32,
        id: [f32; 3],
    }

    impl Ldl {
        /// Factors `a` (upper triangle `a00 a01 a02 a11 a12 a22`); `None` unless every pivot
        /// is above `1e-12` of its diagonal element (the 4x4 path's test on the Jacobi-scaled
        /// matrix) and finite.
        fn new(a: [f32; 6]) -> Option<Self> {
            let [a00, a01, a02, a11, a12, a22] = a;
            let ok = |d: f32, aii: f32| d > 1e-12 * aii && d.is_finite() && aii.is_finite();
            if !(a00 > 0.0 && a00.is_finite()) {
                return None;
            }
            let id0 = 1.0 / a00;
            let (l10, l20) = (a01 * id0, a02 * id0);
            let d1 = a11 - l10 * a01;
            if !ok(d1, a11) {
                return None;
            }
            let id1 = 1.0 / d1;
            let l21 = (a12 - l20 * a01) * id1;
            let d2 = a22 - l20 * a02 - l21 * l21 * d1;
            if !ok(d2, a22) {
                return None;
            }
            Some(Self {
                l10,
                l20,
                l21,
                id: [id0, id1, 1.0 / d2],
            })
        }

        /// Solves `A x = b`.
        fn solve(&self, b: [f32; 3]) -> [f32; 3] {
            let [id0, id1, id2] = self.id;
            let [b0, b1, b2] = b;
            let y1 = b1 - self.l10 * b0;
            let y2 = b2 - self.l20 * b0 - self.l21 * y1;
            let x2 = y2 * id2;
            let x1 = y1 * id1 - self.l21 * x2;
            let x0 = b0 * id0 - self.l10 * x1 - self.l20 * x2;
            [x0, x1, x2]
        }

        /// The diagonal of `A^-1`: `sum_k (L^-1)_ki^2 / d_k`.
        fn inverse_diagonal(&self) -> [f32; 3] {
            let [id0, id1, id2] = self.id;
            let m20 = self.l10 * self.l21 - self.l20;
            [
                id0 + self.l10 * self.l10 * id1 + m20 * m20 * id2,
                id1 + self.l21 * self.l21 * id2,
                id2,
            ]
        }
    }

    /// The normal equations at `(x, y, n)`: upper triangle and right-hand side.
    ///
    /// With `j = (N fy dx, N fx dy, fx fy)` every product separates into a row factor and a
    /// column sum: per pixel only the weight, the residual and five row sums
    /// (`w dx^2, w dx fx, w fx^2, w dx r, w fx r`), per row nine multiply-adds, and the
    /// powers of `N` once at the end.
    #[allow(clippy::too_many_arguments)]
    fn normal(
        p: &Prepared<'_>,
        level_e: f32,
        var1: f32,
        grid: &Grid,
        (x, y, n): (f32, f32, f32),
        prof: &mut [[f32; M]; 4],
    ) -> ([f32; 6], [f32; 3]) {
        let [px, dpx, py, dpy] = prof;
        profile(p.width, x, grid, px, dpx);
        profile(p.height, y, grid, py, dpy);
        let w = usize::from(p.width).max(1);
        let (mut a00, mut a01, mut a02, mut a11, mut a12, mut a22) =
            (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let (mut b0, mut b1, mut b2) = (0.0f32, 0.0f32, 0.0f32);
        let rows = p.pixels.chunks_exact(w).zip(py.iter().zip(dpy.iter()));
        for (line, (&fy, &dy)) in rows {
            let nfy = n * fy;
            let (mut r1, mut r2, mut r3, mut r4, mut r5) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
            for (e, (&fx, &dx)) in line.iter().zip(px.iter().zip(dpx.iter())) {
                let f = e.to_bits() as f32 * (1.0 / 64.0) - level_e;
                let star = nfy * fx;
                let wt = 1.0 / (star + var1);
                let res = f - star;
                let (wdx, wfx) = (wt * dx, wt * fx);
                r1 += wdx * dx;
                r2 += wdx * fx;
                r3 += wfx * fx;
                r4 += wdx * res;
                r5 += wfx * res;
            }
            let (fy2, fdy) = (fy * fy, fy * dy);
            a00 += fy2 * r1;
            a01 += fdy * r2;
            a02 += fy2 * r2;
            a11 += dy * dy * r3;
            a12 += fdy * r3;
            a22 += fy2 * r3;
            b0 += fy * r4;
            b1 += dy * r5;
            b2 += fy * r5;
        }
        let n2 = n * n;
        (
            [a00 * n2, a01 * n2, a02 * n, a11 * n2, a12 * n, a22],
            [b0 * n, b1 * n, b2],
        )
    }

    /// The start: the peak (the brightest pixel, ties to the one nearest the window's centre
    /// pixel, as [`Prepared::peak`]) in one walk of the pixel bits, then the power-1 CoG of
    /// the `start_box` around it in f32 sums; its flux also starts `N`. `None`: no positive
    /// flux in the box.
    fn start(p: &Prepared<'_>, level_e: f32, start_box: u8) -> Option<Start> {
        let w = usize::from(p.width).max(1);
        let (cc, cr) = p.centre();
        let at = |i: usize| ((i % w) as u16, (i / w) as u16);
        let dist2 = |i: usize| {
            let (c, r) = at(i);
            let (dc, dr) = (u32::from(c.abs_diff(cc)), u32::from(r.abs_diff(cr)));
            dc * dc + dr * dr
        };
        let (mut best_v, mut best_i) = (i32::MIN, None);
        for (i, e) in p.pixels.iter().enumerate() {
            let b = e.to_bits();
            if b > best_v {
                (best_v, best_i) = (b, Some(i));
            } else if b == best_v && best_i.is_none_or(|j| dist2(i) < dist2(j)) {
                best_i = Some(i);
            }
        }
        let peak = at(best_i?);
        let (bx, clipped) = p.box_around(peak.0, peak.1, start_box);
        let (mut s0, mut sc, mut sr) = (0.0f32, 0.0f32, 0.0f32);
        let mut rf = f32::from(bx.row0);
        for row in bx.row0..=bx.row1 {
            let first = usize::from(row) * w;
            let line = p
                .pixels
                .get(first + usize::from(bx.col0)..=first + usize::from(bx.col1))?;
            let (mut rs, mut rc, mut cf) = (0.0f32, 0.0f32, f32::from(bx.col0));
            for e in line {
                let f = e.to_bits() as f32 * (1.0 / 64.0) - level_e;
                rs += f;
                rc += f * cf;
                cf += 1.0;
            }
            s0 += rs;
            sc += rc;
            sr += rs * rf;
            rf += 1.0;
        }
        (s0 > 0.0).then(|| Start {
            peak,
            theta: (sc / s0, sr / s0, s0),
            clipped,
        })
    }

    /// [`start`]'s result: the peak pixel, `(x, y, N)` and whether the box was clipped.
    struct Start {
        peak: (u16, u16),
        theta: (f32, f32, f32),
        clipped: bool,
    }

    /// The held-background fit (see [`held`]).
    pub(super) fn fit(p: &Prepared<'_>, params: &GaussFitParams) -> Centroid {
        let level_e = p.bg.level_e();
        let Some(Start {
            peak,
            theta: (x0, y0, flux0),
            clipped,
        }) = start(p, level_e, params.start_box)
        else {
            return super::fit_general(p, params);
        };
        let mut extra = if clipped {
            CentroidFlags::EDGE_CLIPPED
        } else {
            CentroidFlags::empty()
        };
        // Failure returns the exact starting CoG, with its own error estimate.
        let give_up = |extra: CentroidFlags| {
            let (bx, _) = p.box_around(peak.0, peak.1, params.start_box);
            match cog_in_box(p, bx, peak, CogPower::One) {
                Some(m) => p.finish(m, extra | CentroidFlags::NOT_CONVERGED),
                None => p.degenerate(extra),
            }
        };
        let grid = Grid::new(usable_sigma_px(params.psf_sigma_px));
        let var1 = p.bg.variance_e2 + 1.0;
        let (wmax, hmax) = (f32::from(p.width) - 0.5, f32::from(p.height) - 0.5);
        let mut theta = (x0, y0, flux0);
        let mut prof = [[0.0f32; M]; 4];
        let mut converged = params.max_iterations == 0;
        let mut last = None;
        for _ in 0..params.max_iterations {
            let (a, b) = normal(p, level_e, var1, &grid, theta, &mut prof);
            let Some(f) = Ldl::new(a) else {
                return give_up(extra);
            };
            let [dx, dy, dn] = f.solve(b);
            let (sx, sy) = (dx.clamp(-1.0, 1.0), dy.clamp(-1.0, 1.0));
            theta = (theta.0 + sx, theta.1 + sy, theta.2 + dn);
            let (x, y, flux) = theta;
            if !super::step_usable(x, y, flux, wmax, hmax) {
                return give_up(extra);
            }
            if sx.abs() < params.tolerance_px && sy.abs() < params.tolerance_px {
                converged = true;
                last = Some(f);
                break;
            }
        }
        if !converged {
            extra |= CentroidFlags::NOT_CONVERGED;
        }
        let factor = match last {
            Some(f) => Some(f),
            None => Ldl::new(normal(p, level_e, var1, &grid, theta, &mut prof).0),
        };
        let Some(f) = factor else {
            return give_up(extra);
        };
        let [vx, vy, vn] = f.inverse_diagonal();
        let (x, y, flux) = theta;
        let m = Measured {
            col: x,
            row: y,
            flux_e: flux,
            snr: flux / math::sqrt(vn).max(f32::MIN_POSITIVE),
            sigma_col: math::sqrt(vx),
            sigma_row: math::sqrt(vy),
        };
        p.finish(m, extra)
    }
}
