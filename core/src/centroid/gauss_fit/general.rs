//! The four-parameter Gauss fit `(x, y, N, B)`: the general path of [`super`], taken when
//! the residual background is fitted, when the window holds an excluded pixel, or when it is
//! wider than the held path's 16 px. Each Gauss-Newton step fills the 4x4 normal equations
//! (a register-only loop for a window without excluded pixels, the per-pixel iterator
//! otherwise), Jacobi-scales them and solves them by Cholesky; the covariance's diagonal
//! gives the error estimate.
//!
//! # Cost
//! Per step `w + h + 2` edge `erfc`s and densities, then the ten upper-triangle sums and four
//! right-hand sides per pixel, a 4x4 Cholesky (four square roots) and two triangular solves;
//! with the perimeter-median background, ~16,800 (5x5) and ~22,000 (7x7) instructions per star
//! on the M7 (`centroid_gauss_fit_*` of `cargo m7-bench`, 2 steps).

use super::{GaussFitParams, Grid, profile, step_usable};
use crate::centroid::cog::{cog_in_box, usable_sigma_px};
use crate::centroid::math::{self, pos};
use crate::centroid::pixel_box::PixelBox;
use crate::centroid::prepared::{Measured, Prepared};
use crate::centroid::{Centroid, CentroidFlags, MAX_SIDE};
use crate::table::pixcorr::CogPower;

pub(in crate::centroid) type Mat4 = [[f32; 4]; 4];

/// A solved `K x K` system: the step, the Jacobi scales and the scaled Cholesky factor.
pub(in crate::centroid) type Solved<const K: usize> = ([f32; K], [f32; K], [[f32; K]; K]);

fn at<const K: usize>(m: &[[f32; K]; K], i: usize, j: usize) -> f32 {
    m.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0)
}

fn set<const K: usize>(m: &mut [[f32; K]; K], i: usize, j: usize, v: f32) {
    if let Some(x) = m.get_mut(i).and_then(|r| r.get_mut(j)) {
        *x = v;
    }
}

fn vget<const K: usize>(v: &[f32; K], i: usize) -> f32 {
    v.get(i).copied().unwrap_or(0.0)
}

/// Cholesky factor (lower) of a symmetric positive-definite matrix, or `None`.
fn cholesky<const K: usize>(a: &[[f32; K]; K]) -> Option<[[f32; K]; K]> {
    let mut l = [[0.0f32; K]; K];
    for j in 0..K {
        let d = at(a, j, j) - (0..j).map(|k| at(&l, j, k) * at(&l, j, k)).sum::<f32>();
        if d.is_nan() || d <= 1e-12 {
            return None;
        }
        let ljj = math::sqrt(d);
        set(&mut l, j, j, ljj);
        for i in j + 1..K {
            let s = at(a, i, j) - (0..j).map(|k| at(&l, i, k) * at(&l, j, k)).sum::<f32>();
            set(&mut l, i, j, s / ljj);
        }
    }
    Some(l)
}

/// Solves `L L^T x = b`.
fn chol_solve<const K: usize>(l: &[[f32; K]; K], b: &[f32; K]) -> [f32; K] {
    let mut y = [0.0f32; K];
    for i in 0..K {
        let s = vget(b, i) - (0..i).map(|k| at(l, i, k) * vget(&y, k)).sum::<f32>();
        if let Some(v) = y.get_mut(i) {
            *v = s / at(l, i, i);
        }
    }
    let mut x = [0.0f32; K];
    for i in (0..K).rev() {
        let s = vget(&y, i) - (i + 1..K).map(|k| at(l, k, i) * vget(&x, k)).sum::<f32>();
        if let Some(v) = x.get_mut(i) {
            *v = s / at(l, i, i);
        }
    }
    x
}

/// Parameter order in the normal equations.
const X: usize = 0;
const Y: usize = 1;
const N: usize = 2;
const B: usize = 3;

/// The fit state: parameters, normal matrix and right-hand side at those parameters.
pub(in crate::centroid) struct Normal {
    pub(in crate::centroid) a: Mat4,
    pub(in crate::centroid) b: [f32; 4],
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
    let whole = PixelBox {
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
            let wt = 1.0 / (pos(star) + var1);
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
pub(in crate::centroid) fn solve(n: &Normal) -> Option<([f32; 4], [f32; 4], Mat4)> {
    solve_k(&n.a, &n.b)
}

/// [`solve`] for a `K x K` system `a d = b`: the step, the Jacobi scales and the scaled
/// Cholesky factor; `None` when `a` is not positive definite or the step not finite.
pub(in crate::centroid) fn solve_k<const K: usize>(
    a: &[[f32; K]; K],
    b: &[f32; K],
) -> Option<Solved<K>> {
    let mut d = [0.0f32; K];
    for (i, di) in d.iter_mut().enumerate() {
        let aii = at(a, i, i);
        if aii.is_nan() || aii <= 0.0 {
            return None;
        }
        *di = 1.0 / math::sqrt(aii);
    }
    let mut sa = [[0.0f32; K]; K];
    for i in 0..K {
        for k in 0..K {
            set(&mut sa, i, k, at(a, i, k) * vget(&d, i) * vget(&d, k));
        }
    }
    let l = cholesky(&sa)?;
    let mut sb = [0.0f32; K];
    for (i, v) in sb.iter_mut().enumerate() {
        *v = vget(b, i) * vget(&d, i);
    }
    let z = chol_solve(&l, &sb);
    let mut step = [0.0f32; K];
    for (i, v) in step.iter_mut().enumerate() {
        *v = vget(&z, i) * vget(&d, i);
    }
    step.iter().all(|v| v.is_finite()).then_some((step, d, l))
}

/// The variance of parameter `i` from the scaled factor: `d_i^2 [(D A D)^-1]_ii`.
pub(in crate::centroid) fn variance<const K: usize>(
    l: &[[f32; K]; K],
    d: &[f32; K],
    i: usize,
) -> f32 {
    let mut e = [0.0f32; K];
    if let Some(v) = e.get_mut(i) {
        *v = 1.0;
    }
    let z = chol_solve(l, &e);
    vget(&z, i) * vget(d, i) * vget(d, i)
}

/// The position's covariance from the scaled factor, parameters 0 (`x`) and 1 (`y`):
/// `(var_x, var_y, cov_xy)`, each `d_i d_j [(D A D)^-1]_ij` (two triangular solves, as two
/// [`variance`] calls).
pub(in crate::centroid) fn position_covariance<const K: usize>(
    l: &[[f32; K]; K],
    d: &[f32; K],
) -> (f32, f32, f32) {
    let column = |i: usize| {
        let mut e = [0.0f32; K];
        if let Some(v) = e.get_mut(i) {
            *v = 1.0;
        }
        chol_solve(l, &e)
    };
    let (z0, z1) = (column(0), column(1));
    let (d0, d1) = (vget(d, 0), vget(d, 1));
    (
        vget(&z0, 0) * d0 * d0,
        vget(&z1, 1) * d1 * d1,
        vget(&z0, 1) * d0 * d1,
    )
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

/// The four-parameter fit (background fitted, or excluded pixels): the method of [`super`]
/// with the 4x4 Jacobi-scaled Cholesky solve.
pub(super) fn fit(p: &Prepared<'_>, params: &GaussFitParams) -> Centroid {
    let (start, mut extra) = match start_cog(p, params.start_box) {
        Ok(s) => s,
        Err(c) => return c,
    };
    let s = usable_sigma_px(params.psf_sigma_px);
    let whole = PixelBox {
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
