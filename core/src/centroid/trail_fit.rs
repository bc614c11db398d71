//! Weighted least-squares fit of a trailed star: a Gaussian PSF smeared along the straight
//! segment the star moved over during the exposure, the trail held (from the predicted
//! rate), position at mid-exposure, flux and a residual background fitted.
//!
//! # Model
//! With the trail vector `(tx, ty)` (image displacement from exposure start to end, px),
//! `L = |t|`, unit direction `e = t / L`, and a pixel centre at `(c, r)`, offsets
//! `u = (c - x) ex + (r - y) ey` along the trail and `v = -(c - x) ey + (r - y) ex` across:
//! ```text
//! m_k = B + N g(u, v),   g(u, v) = A(u) V(v)
//! A(u) = (Phi((u + L/2)/s) - Phi((u - L/2)/s)) / L,   V(v) = phi(v/s) / s
//! s^2 = psf_sigma^2 + 1/12
//! ```
//! the Gaussian of sigma `psf_sigma` convolved with a uniform motion over the segment
//! (closed form with `erfc`, Abramowitz & Stegun 7.1.26, absolute error 1.35e-6, shared with
//! the density's exponential by [`super::math::erfc_abs_and_gauss`]), sampled at the pixel
//! centre. The pixel's area is taken into the width as the unit box's variance 1/12 px^2
//! (the pixel integral of the trailed PSF is not separable for a trail at an angle): exact
//! in the second moments, a model error in the fourth that the host test
//! `centroid_trail_fit` bounds (noise-free, against a simulator that integrates each pixel
//! and the path). Below `L = 0.05 s` the trail is a point: `A(u) = phi(u/s)/s` (relative
//! model error below 1e-4). `(x, y)` is the star at mid-exposure, the segment's midpoint.
//!
//! # Fit
//! Gauss-Newton on `(x, y, N, B)` (or `(x, y, N)`, `B` held at 0, with `fit_background` off),
//! the weights `1 / (max(N g, 0) + var_bg + 1)` from the model refreshed each step, the 4x4
//! normal equations Jacobi-scaled and Cholesky-factored as the Gaussian fit's
//! ([`super::gauss_fit`]). Start: the power-1 CoG of the whole window (a trail's brightest
//! pixel is anywhere along it, its centre of light is the midpoint), `N` = the window's sum.
//! Stop when both position steps are below `tolerance_px`; steps are capped at one pixel. A
//! step that leaves the window, a flux that is not positive or normal equations that are not
//! positive definite return the starting CoG with `NOT_CONVERGED`; running out of iterations
//! returns the last estimate with `NOT_CONVERGED`. A non-finite trail gives `DEGENERATE`.
//!
//! # Error estimate
//! `sigma_x_px`, `sigma_y_px` from `(J^T W J)^-1` at the solution, as the Gaussian fit's, and
//! the covariance of the two, [`TrailFit::cov_xy_px2`]: a trail spreads the light along
//! itself, so the position is known worse along the trail than across it (along, the
//! segment's ends carry the information; across, the PSF's width), and a trail at an angle
//! to the rows correlates the column and row errors. The marginal sigmas alone would put the
//! along-trail error on both axes (a diagonal trail) or lose which axis is which; the
//! attitude takes the whole 2x2 ([`crate::attitude::refine`]). `flux_e` is the fitted total
//! flux `N` and `snr` is `N / sigma_N`.
//!
//! # Cost
//! Per step and pixel: two `erfc`-and-density evaluations (one exponential and one divide
//! each), one exponential for the cross-trail density, the weight's divide and the ten
//! normal-equation sums (no separable shortcut: the trail is at any angle). Measured on the
//! Cortex-M7 (`cargo m7-bench`, QEMU instructions per star, background given and held, the
//! bench's untrailed star with a (1.0, 0.5) px trail held): ~24,000 on 5x5
//! (`centroid_trail_fit_5x5`), ~47,000 on 7x7 (`centroid_trail_fit_7x7`), about 6.6x the
//! held Gaussian fit on the same window; the exact counts are in docs/speed.md. The cost
//! grows with the window's pixels (a 20 px trail needs a ~29 x 9 window, ~5x the 7x7's).
//!
//! # Where it fails
//! - A wrong trail (rate error): the position along the trail stays nearly unbiased for a
//!   symmetric smear, the flux and `chi2` do not; a curved trail (fast roll) is a model
//!   error.
//! - A trail longer than the window: the fit sees a truncated segment, the position along
//!   the trail is set by the window's edges (choose the window from the predicted trail).

use super::cog::{cog_in_box, usable_sigma_px};
use super::gauss_fit::{Normal, position_covariance, solve, variance};
use super::math::{self, pos};
use super::pixel_box::PixelBox;
use super::prepared::{Measured, Prepared};
use super::{Background, Centroid, CentroidFlags, CentroidInput};
use crate::table::pixcorr::CogPower;

mod accel;
mod free;

pub use accel::{ACCEL_OFFSET_SIGMA, accel_offset_fraction};
pub use free::{FreeTrailParams, TRAIL_FALSE_ALARM, TrailedFit, trail_dchi2_limit, trail_fit_free};

/// The result of [`trail_fit`]: the centroid at mid-exposure and the covariance of its column
/// and row errors.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrailFit {
    /// Position at mid-exposure, flux, SNR, the marginal sigmas and the flags.
    pub centroid: Centroid,
    /// Covariance of the column and row errors, px^2 (`|cov| <= sigma_x sigma_y`; 0 when the
    /// fit failed and the centroid is the window's CoG).
    pub cov_xy_px2: f32,
}

/// `cov_xy` bounded by the centroid's marginal sigmas (a correlation within +-1 after their
/// clamping), 0 when not finite.
pub(crate) fn bounded_covariance(c: &Centroid, cov_xy: f32) -> f32 {
    let m = c.sigma_x_px * c.sigma_y_px;
    if cov_xy.is_finite() && m.is_finite() {
        crate::clamp::clamp(cov_xy, -m, m)
    } else {
        0.0
    }
}

/// Parameters of [`trail_fit`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrailFitParams {
    /// The PSF's Gaussian sigma at rest, px; values below 0.1 px are taken as 0.1.
    pub psf_sigma_px: f32,
    /// Column displacement of the star from exposure start to end, px (from the predicted
    /// rate). Only the segment matters, not its sign.
    pub trail_dx_px: f32,
    /// Row displacement from exposure start to end, px.
    pub trail_dy_px: f32,
    /// Largest number of Gauss-Newton steps (0 returns the starting CoG).
    pub max_iterations: u8,
    /// Convergence threshold on the position step, px.
    pub tolerance_px: f32,
    /// Fit a residual background `B` (else hold it at 0, trusting the background source).
    pub fit_background: bool,
    /// Background source.
    pub background: Background,
}

impl TrailFitParams {
    /// Ten steps to 1e-4 px, fitting the residual background over a perimeter-median
    /// estimate, for the trail `(trail_dx_px, trail_dy_px)`.
    pub const fn new(psf_sigma_px: f32, trail_dx_px: f32, trail_dy_px: f32) -> Self {
        Self {
            psf_sigma_px,
            trail_dx_px,
            trail_dy_px,
            max_iterations: 10,
            tolerance_px: 1e-4,
            fit_background: true,
            background: Background::PerimeterMedian,
        }
    }
}

/// The trailed PSF's shape: width, trail length and direction.
#[derive(Clone, Copy, Debug)]
struct Trail {
    /// `1 / s`, px^-1.
    inv_s: f32,
    /// Trail length, px (0 for a point).
    l_px: f32,
    /// Unit direction.
    ex: f32,
    ey: f32,
}

const FRAC_1_SQRT_2: f32 = core::f32::consts::FRAC_1_SQRT_2;
const FRAC_1_SQRT_2PI: f32 = 0.398_942_3;

impl Trail {
    fn new(psf_sigma_px: f32, tx: f32, ty: f32) -> Option<Self> {
        if !(tx.is_finite() && ty.is_finite()) {
            return None;
        }
        let s0 = usable_sigma_px(psf_sigma_px);
        let s = math::sqrt(s0 * s0 + 1.0 / 12.0);
        let l = math::sqrt(tx * tx + ty * ty);
        if !l.is_finite() {
            return None;
        }
        let (l_px, ex, ey) = if l < 0.05 * s {
            (0.0, 1.0, 0.0)
        } else {
            (l, tx / l, ty / l)
        };
        Some(Self {
            inv_s: 1.0 / s,
            l_px,
            ex,
            ey,
        })
    }

    /// The profile along the trail at offset `u`: `A(u)`, `dA/du`, and the densities
    /// `exp(-z^2)` at the segment's two ends (`z = (u +- L/2) / (s sqrt 2)`, 0 for a point).
    #[inline(always)]
    fn along(&self, u: f32) -> Along {
        let k = self.inv_s;
        if self.l_px > 0.0 {
            let h = 0.5 * self.l_px;
            let (zh, zl) = ((u + h) * k * FRAC_1_SQRT_2, (u - h) * k * FRAC_1_SQRT_2);
            let (eh, gh) = math::erfc_abs_and_gauss(zh);
            let (el, gl) = math::erfc_abs_and_gauss(zl);
            // Phi(hi) - Phi(lo) on the tail side: no two numbers near 1 subtracted.
            let diff = if zl >= 0.0 {
                0.5 * (el - eh)
            } else if zh <= 0.0 {
                0.5 * (eh - el)
            } else {
                1.0 - 0.5 * (eh + el)
            };
            let inv_l = 1.0 / self.l_px;
            Along {
                a: pos(diff) * inv_l,
                da: (gh - gl) * FRAC_1_SQRT_2PI * k * inv_l,
                ends: (zh, zl, gh, gl),
            }
        } else {
            let tu = u * k;
            let a = math::exp(-0.5 * tu * tu) * FRAC_1_SQRT_2PI * k;
            Along {
                a,
                da: -tu * k * a,
                ends: (0.0, 0.0, 0.0, 0.0),
            }
        }
    }

    /// The offsets `(u, v)` along and across the trail of the pixel offset `(dc, dr)`.
    #[inline(always)]
    fn rotate(&self, dc: f32, dr: f32) -> (f32, f32) {
        (dc * self.ex + dr * self.ey, -dc * self.ey + dr * self.ex)
    }

    /// `(V(v), dV/dv)`, the density across the trail.
    #[inline(always)]
    fn across(&self, v: f32) -> (f32, f32) {
        let k = self.inv_s;
        let tv = v * k;
        let vv = math::exp(-0.5 * tv * tv) * FRAC_1_SQRT_2PI * k;
        (vv, -tv * k * vv)
    }

    /// `(g, dg/dx, dg/dy)` at the pixel offset `(dc, dr)` = pixel centre minus star.
    #[inline(always)]
    fn eval(&self, dc: f32, dr: f32) -> (f32, f32, f32) {
        let (u, v) = self.rotate(dc, dr);
        let (vv, dvv) = self.across(v);
        let Along { a, da, .. } = self.along(u);
        let g = a * vv;
        let (gu, gv) = (da * vv, a * dvv);
        // du/dx = -ex, dv/dx = ey; du/dy = -ey, dv/dy = -ex.
        (
            g,
            -self.ex * gu + self.ey * gv,
            -self.ey * gu - self.ex * gv,
        )
    }
}

/// [`Trail::along`]'s result.
#[derive(Clone, Copy, Debug)]
struct Along {
    /// `A(u)`, px^-1.
    a: f32,
    /// `dA/du`, px^-2.
    da: f32,
    /// `(zh, zl, exp(-zh^2), exp(-zl^2))` at the segment's ends (zeros for a point).
    ends: (f32, f32, f32, f32),
}

/// The normal equations at `theta = (x, y, N, B)` (window-relative), excluded pixels skipped.
fn normal_equations(
    p: &Prepared<'_>,
    whole: PixelBox,
    trail: &Trail,
    theta: [f32; 4],
    fit_bg: bool,
) -> Normal {
    let [x, y, flux, bg] = theta;
    let var1 = p.bg.variance_e2 + 1.0;
    let jb = if fit_bg { 1.0f32 } else { 0.0 };
    let mut a = [[0.0f32; 4]; 4];
    let mut b = [0.0f32; 4];
    for (col, row, f) in p.box_pixels(whole) {
        let (g, gx, gy) = trail.eval(f32::from(col) - x, f32::from(row) - y);
        let star = flux * g;
        let wt = 1.0 / (pos(star) + var1);
        let j = [flux * gx, flux * gy, g, jb];
        let res = f - (bg + star);
        for (i, (row_a, bi)) in a.iter_mut().zip(b.iter_mut()).enumerate() {
            let ji = j.get(i).copied().unwrap_or(0.0) * wt;
            *bi += ji * res;
            for (aik, jk) in row_a.iter_mut().zip(j.iter()) {
                *aik += ji * jk;
            }
        }
    }
    if !fit_bg {
        // Pin B: a unit diagonal with no coupling (its step is then 0).
        if let Some(r) = a.get_mut(3) {
            *r = [0.0, 0.0, 0.0, 1.0];
        }
        for r in a.iter_mut().take(3) {
            if let Some(v) = r.get_mut(3) {
                *v = 0.0;
            }
        }
    }
    Normal { a, b }
}

/// The trailed-star fit of `input` (see the module docs).
pub fn trail_fit(input: &CentroidInput<'_>, params: &TrailFitParams) -> TrailFit {
    let uncorrelated = |centroid: Centroid| TrailFit {
        centroid,
        cov_xy_px2: 0.0,
    };
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return uncorrelated(c),
    };
    let Some(trail) = Trail::new(params.psf_sigma_px, params.trail_dx_px, params.trail_dy_px)
    else {
        return uncorrelated(p.degenerate(CentroidFlags::empty()));
    };
    let whole = PixelBox {
        col0: 0,
        row0: 0,
        col1: p.width - 1,
        row1: p.height - 1,
    };
    let Some(start) = cog_in_box(&p, whole, p.centre(), CogPower::One) else {
        return uncorrelated(p.degenerate(CentroidFlags::empty()));
    };
    let total: f32 = p.box_pixels(whole).map(|(_, _, f)| f).sum();
    let mut theta = [start.col, start.row, total.max(start.flux_e), 0.0];
    let (wmax, hmax) = (f32::from(p.width) - 0.5, f32::from(p.height) - 0.5);
    let give_up = || uncorrelated(p.finish(start, CentroidFlags::NOT_CONVERGED));
    let mut converged = params.max_iterations == 0;
    let mut last_factor = None;
    for _ in 0..params.max_iterations {
        let normal = normal_equations(&p, whole, &trail, theta, params.fit_background);
        let Some((step, d, l)) = solve(&normal) else {
            return give_up();
        };
        let [s0, s1, s2, s3] = step;
        let (sx, sy) = (s0.clamp(-1.0, 1.0), s1.clamp(-1.0, 1.0));
        let [x, y, flux, bg] = theta;
        theta = [x + sx, y + sy, flux + s2, bg + s3];
        let [x, y, flux, _] = theta;
        if !((-0.5..=wmax).contains(&x) && (-0.5..=hmax).contains(&y) && flux > 0.0) {
            return give_up();
        }
        if sx.abs() < params.tolerance_px && sy.abs() < params.tolerance_px {
            converged = true;
            last_factor = Some((d, l));
            break;
        }
    }
    let extra = if converged {
        CentroidFlags::empty()
    } else {
        CentroidFlags::NOT_CONVERGED
    };
    let factor = match last_factor {
        Some(f) => Some(f),
        None => solve(&normal_equations(
            &p,
            whole,
            &trail,
            theta,
            params.fit_background,
        ))
        .map(|(_, d, l)| (d, l)),
    };
    let Some((d, l)) = factor else {
        return give_up();
    };
    let [x, y, flux, _] = theta;
    let (var_x, var_y, cov_xy) = position_covariance(&l, &d);
    let m = Measured {
        col: x,
        row: y,
        flux_e: flux,
        snr: flux / math::sqrt(variance(&l, &d, 2)).max(f32::MIN_POSITIVE),
        sigma_col: math::sqrt(var_x),
        sigma_row: math::sqrt(var_y),
    };
    let centroid = p.finish(m, extra);
    TrailFit {
        centroid,
        cov_xy_px2: bounded_covariance(&centroid, cov_xy),
    }
}
