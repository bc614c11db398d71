//! The three-parameter fit (x, y, N) with the background held, on a window without excluded
//! pixels, up to 16 px a side: the same model, weights, start, steps and stopping rule as the
//! general path ([`super::general`]) with `fit_background` off (whose `B` row is a decoupled
//! unit pivot with a zero step), computed with less work: see the "Held background" section
//! of [`super`].
//!
//! # Cost
//! ~4,800 (5x5) and ~7,000 (7x7) instructions per star on the M7
//! (`centroid_gauss_fit_given_bg_*` of `cargo m7-bench`, 2 steps): per step ~18 instructions
//! a pixel for the normal equations and ~40 an edge for the profiles (see [`super`] for the
//! whole breakdown).

use super::{GaussFitParams, Grid, general, profile, step_usable};
use crate::centroid::cog::{cog_in_box, usable_sigma_px};
use crate::centroid::math;
use crate::centroid::prepared::{Measured, Prepared};
use crate::centroid::{Centroid, CentroidFlags};
use crate::table::pixcorr::CogPower;

/// Largest window side of this path (its profile buffers are zeroed per fit, so they
/// are sized for star windows, not for [`crate::centroid::MAX_SIDE`]); larger windows take the
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
    let peak = super::peak_clean(p)?;
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

/// The held-background fit (see the module docs).
pub(super) fn fit(p: &Prepared<'_>, params: &GaussFitParams) -> Centroid {
    let level_e = p.bg.level_e();
    let Some(Start {
        peak,
        theta: (x0, y0, flux0),
        clipped,
    }) = start(p, level_e, params.start_box)
    else {
        return general::fit(p, params);
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
        if !step_usable(x, y, flux, wmax, hmax) {
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
