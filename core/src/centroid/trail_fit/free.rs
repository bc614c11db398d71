//! The trailed-star fit with the trail unknown: length, angle and PSF width fitted with the
//! position at mid-exposure, flux and a residual background, and the test that says whether
//! a star is trailed at all, for a frame whose motion nothing predicted (acquisition while
//! the spacecraft turns).
//!
//! # Two nested models on the same pixels
//! - round: `m_k = B + N g(u, v)` with `L = 0` and the width `s` free, `(x, y, N, B, s)`;
//! - trailed: the same with the trail `L` and its angle `phi` free, `(x, y, N, B, s, L,
//!   phi)`, the angle a unit direction turned by each step (no trigonometric function),
//!
//! `g` the trailed Gaussian of [`super`] (`s^2` the PSF's variance plus the pixel's 1/12).
//! Both are fitted by Gauss-Newton with the weights `1 / (max(N g, 0) + var_bg + 1)` from
//! the model, refreshed each step; `chi2 = sum (F_k - m_k)^2 w_k` at each solution. The
//! trailed model holds the round one (`L = 0`), and near it a short trail only stretches the
//! PSF along `phi` by the variance `L^2 / 12`: the two extra parameters act like an
//! ellipse's two shape parameters, so for a round star the improvement `dchi2 = chi2_round -
//! chi2_trailed` follows `chi2(2)` with a known variance, and `2 F(2, d)` when the variance
//! is the window border's own (`d` = border pixels - 1). The star is **trailed** when
//! `dchi2` exceeds that distribution's upper [`TRAIL_FALSE_ALARM`] point
//! ([`trail_dchi2_limit`], closed form: `P(F(2, d) > f) = (1 + 2 f / d)^(-d/2)`), i.e. a
//! round star is called trailed once in 1,000 tests; the host test `centroid_trail_free`
//! holds it on round stars of widths 0.6-2 px and SNR 10-1000 whose width nobody told
//! the fit. A star of another width than the configured PSF's is a round star of its own
//! width, not a trail (the width is free in both models). A star the test would call
//! trailed whose fitted trail is shorter than 3 `s` (nearly round) gets a second round fit
//! started from the trailed solution, and the better round fit is the one compared (a round
//! fit from the CoG can stop on a worse minimum: a wide bright star whose wings reach the
//! border).
//!
//! # Start and steps
//! Round: the power-1 CoG of the window, `N` its sum, `s` from `start_sigma_px`. Trailed:
//! the round solution's position, flux and background, `s` from `start_sigma_px`, the trail
//! from `start_trail_px` (the blob's elongation). Steps are capped: the position at one
//! pixel, `s` at half its value (kept within `0.3 ..= side / 2`), `L` at half its value or
//! 1 px, `phi` at 0.5 rad. Stop when the position, `s` and `L` steps are all below
//! `tolerance_px`. A fit that leaves the window, loses its flux or its trail (`L` below
//! [`MIN_TRAIL_PX`], where `phi` is no longer defined), or meets normal equations that are
//! not positive definite, fails; running out of steps is `NOT_CONVERGED`.
//!
//! # Error estimate
//! `sigma_x_px`, `sigma_y_px` and their covariance `cov_xy_px2` from `(J^T W J)^-1` of the
//! trailed model with every parameter free: the position's error with the trail and the width unknown. For a trail symmetric
//! about its midpoint the position's information is orthogonal to the trail's length and
//! angle (the model is even in `(u, v) -> (-u, -v)`, its position derivatives odd), so the
//! price is small: the bound of a trail whose length is known.
//!
//! # Cost
//! Per step and pixel: the held fit's two `erfc`-and-density evaluations and exponential,
//! a few more multiplies for the width, length and angle derivatives, the weight's divide
//! and the 7x7 normal matrix's 28 upper-triangle sums and 7 right-hand sides; a 7x7
//! Cholesky per step. The round model costs the
//! same per step. Measured on the Cortex-M7 (`cargo m7-bench`, QEMU instructions): an
//! acquisition frame whose 30 stars (PSF sigma 1 px) are trailed 6 px along the rows, each
//! window up to 15 x 15, costs ~80 M against ~39 M for the same frame of still stars
//! (`tracker_acquisition_frame_trailed` against `tracker_acquisition_frame`), ~1.4 M a
//! trailed star for both fits, ~29 times the held trailed fit on 7x7; only the stars
//! acquisition screens (an elongated blob) pay it.

use super::{Along, FRAC_1_SQRT_2PI, Trail, bounded_covariance};
use crate::centroid::cog::cog_in_box;
use crate::centroid::gauss_fit::{position_covariance, solve_k, variance};
use crate::centroid::math::{self, pos};
use crate::centroid::pixel_box::PixelBox;
use crate::centroid::prepared::{Measured, Prepared};
use crate::centroid::{Background, Centroid, CentroidFlags, CentroidInput};
use crate::clamp::clamp;
use crate::table::pixcorr::CogPower;

/// Parameters of [`trail_fit_free`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FreeTrailParams {
    /// The PSF's Gaussian sigma at rest the fits start from, px.
    pub start_sigma_px: f32,
    /// The trail the trailed fit starts from (column and row displacement over the
    /// exposure, px; only the segment matters, not its sign).
    pub start_trail_px: (f32, f32),
    /// Largest number of Gauss-Newton steps of each model.
    pub max_iterations: u8,
    /// Convergence threshold on the position, width and length steps, px.
    pub tolerance_px: f32,
    /// Background source (the residual background is fitted over it).
    pub background: Background,
}

impl FreeTrailParams {
    /// Twenty steps to 1e-3 px over a perimeter-median background.
    pub const fn new(start_sigma_px: f32, start_trail_px: (f32, f32)) -> Self {
        Self {
            start_sigma_px,
            start_trail_px,
            max_iterations: 20,
            tolerance_px: 1e-3,
            background: Background::PerimeterMedian,
        }
    }
}

/// The false-alarm probability of the trailed test on a round star.
pub const TRAIL_FALSE_ALARM: f32 = 1e-3;

/// Shortest trail the trailed model keeps, px: below it the angle is undefined and the
/// fit fails (the star is round).
pub const MIN_TRAIL_PX: f32 = 0.3;

/// A trailed solution shorter than this many `s` (the PSF sigma with the pixel's variance)
/// that the test would call trailed is checked against a second round fit started from it.
const REFIT_TRAIL_SIGMAS: f32 = 3.0;

/// The result of [`trail_fit_free`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrailedFit {
    /// The trailed model's position at mid-exposure, flux, SNR and sigmas (every parameter
    /// free); `NOT_CONVERGED` (the window's CoG) when the trailed fit failed.
    pub centroid: Centroid,
    /// The covariance of the position's column and row errors, px^2 (0 when the fit failed):
    /// a trail at an angle to the rows correlates them ([`super::TrailFit`]).
    pub cov_xy_px2: f32,
    /// The fitted trail over the exposure, column and row, px (its sign is arbitrary).
    pub trail_px: (f32, f32),
    /// The trail length's 1-sigma error, px.
    pub sigma_length_px: f32,
    /// The fitted PSF sigma at rest, px (the pixel's 1/12 px^2 taken out).
    pub psf_sigma_px: f32,
    /// The trailed model's chi-square (NaN when it failed).
    pub chi2: f32,
    /// The round model's chi-square on the same pixels (NaN when it failed).
    pub chi2_round: f32,
    /// Usable pixels less the trailed model's 7 parameters.
    pub dof: u16,
    /// Usable pixels of the window's border (the background variance's sample).
    pub border: u16,
    /// The round fit converged (else `chi2_round` is its last step's, above its minimum).
    pub round_converged: bool,
}

impl TrailedFit {
    /// The trailed model's improvement on the round one (NaN when either failed).
    pub fn delta_chi2(&self) -> f32 {
        self.chi2_round - self.chi2
    }

    /// True when both fits succeeded and the trailed one is better than a round star gives
    /// with probability [`TRAIL_FALSE_ALARM`] (module docs).
    pub fn is_trailed(&self) -> bool {
        !self
            .centroid
            .flags
            .intersects(CentroidFlags::NOT_CONVERGED | CentroidFlags::DEGENERATE)
            && self.delta_chi2() > trail_dchi2_limit(self.border)
    }

    /// The trailed model's `chi2 / dof`.
    pub fn chi2_dof(&self) -> f32 {
        self.chi2 / f32::from(self.dof.max(1))
    }
}

/// The `dchi2` a round star exceeds with probability [`TRAIL_FALSE_ALARM`]: `2 f` with `f`
/// the upper 1e-3 point of `F(2, border - 1)` (the variance from `border` pixels),
/// `d (1e3^(2/d) - 1)` with `d = border - 1`; `2 ln 1e3` = 13.8 (chi-square, 2 dof) for
/// `border` 0; 15.6 with a 15 x 15 window's border, 18.9 with a 7 x 7's; `f32::MAX` for a
/// border of 1 to 3 pixels (nothing to test against).
pub fn trail_dchi2_limit(border: u16) -> f32 {
    /// `ln(1 / TRAIL_FALSE_ALARM)`.
    const LN_1E3: f32 = 6.907_755;
    match border {
        0 => 2.0 * LN_1E3,
        1..=3 => f32::MAX,
        _ => {
            let d = f32::from(border - 1);
            d * (math::exp(2.0 * LN_1E3 / d) - 1.0)
        }
    }
}

/// Parameters in the normal equations' order: position (`x`, `y`: 0 and 1, as
/// [`position_covariance`] takes them), flux, background, width, trail length and angle.
const K: usize = 7;
const N_IX: usize = 2;
const L_IX: usize = 5;

/// The fit's parameters (window-relative position, px; `s` with the pixel's variance).
#[derive(Clone, Copy, Debug)]
struct Theta {
    x: f32,
    y: f32,
    flux: f32,
    bg: f32,
    s: f32,
    l: f32,
    /// The trail's unit direction (its angle `phi` is the parameter: a step `dphi` rotates
    /// it, no trigonometric function evaluated).
    ex: f32,
    ey: f32,
}

impl Theta {
    /// The model's shape.
    fn shape(&self) -> Trail {
        Trail {
            inv_s: 1.0 / self.s,
            l_px: if self.l >= 0.05 * self.s { self.l } else { 0.0 },
            ex: self.ex,
            ey: self.ey,
        }
    }
}

/// The normal equations at `theta` with the parameters of `free` fitted (the others' rows
/// pinned to a unit diagonal), and the chi-square there.
fn normal_equations(
    p: &Prepared<'_>,
    whole: PixelBox,
    theta: &Theta,
    free: [bool; K],
) -> ([[f32; K]; K], [f32; K], f32) {
    let t = theta.shape();
    let k = t.inv_s;
    let var1 = p.bg.variance_e2 + 1.0;
    let mut a = [[0.0f32; K]; K];
    let mut b = [0.0f32; K];
    let mut chi2 = 0.0f32;
    let mask = free.map(|f| if f { 1.0f32 } else { 0.0 });
    for (col, row, f) in p.box_pixels(whole) {
        let (dc, dr) = (f32::from(col) - theta.x, f32::from(row) - theta.y);
        let (u, v) = t.rotate(dc, dr);
        let (vv, dvv) = t.across(v);
        let tv = v * k;
        let dvs = vv * (tv * tv - 1.0) * k;
        let Along { a: al, da, ends } = t.along(u);
        let (das, dal) = if t.l_px > 0.0 {
            let (zh, zl, gh, gl) = ends;
            let inv_l = 1.0 / t.l_px;
            // (u +- L/2) / s = z sqrt 2.
            let (th, tl) = (
                zh * core::f32::consts::SQRT_2,
                zl * core::f32::consts::SQRT_2,
            );
            (
                -(th * gh - tl * gl) * FRAC_1_SQRT_2PI * k * inv_l,
                (0.5 * (gh + gl) * FRAC_1_SQRT_2PI * k - al) * inv_l,
            )
        } else {
            let tu = u * k;
            (al * (tu * tu - 1.0) * k, 0.0)
        };
        let g = al * vv;
        let (gu, gv) = (da * vv, al * dvv);
        // du/dx = -ex, dv/dx = ey; du/dy = -ey, dv/dy = -ex; du/dphi = v, dv/dphi = -u.
        let gx = -t.ex * gu + t.ey * gv;
        let gy = -t.ey * gu - t.ex * gv;
        let gs = das * vv + al * dvs;
        let gphi = gu * v - gv * u;
        let flux = theta.flux;
        let star = flux * g;
        let wt = 1.0 / (pos(star) + var1);
        let j = [
            flux * gx,
            flux * gy,
            g,
            1.0,
            flux * gs,
            flux * dal * vv,
            flux * gphi,
        ];
        let mut j = j;
        for (ji, m) in j.iter_mut().zip(mask) {
            *ji *= m;
        }
        let res = f - (theta.bg + star);
        chi2 += res * res * wt;
        // The upper triangle; the lower is mirrored once at the end.
        for (i, ((row_a, bi), ji)) in a.iter_mut().zip(b.iter_mut()).zip(j.iter()).enumerate() {
            let jw = ji * wt;
            *bi += jw * res;
            for (aim, jm) in row_a.iter_mut().zip(j.iter()).skip(i) {
                *aim += jw * jm;
            }
        }
    }
    for i in 0..K {
        for m in 0..i {
            let upper = a.get(m).and_then(|r| r.get(i)).copied().unwrap_or(0.0);
            if let Some(v) = a.get_mut(i).and_then(|r| r.get_mut(m)) {
                *v = upper;
            }
        }
    }
    for (i, (row_a, f)) in a.iter_mut().zip(free.iter()).enumerate() {
        if !f && let Some(d) = row_a.get_mut(i) {
            *d = 1.0;
        }
    }
    (a, b, chi2)
}

impl Fit {
    /// `chi2_round` less this fit's chi-square (NaN when either is).
    fn chi2_round_gap(&self, chi2_round: f32) -> f32 {
        chi2_round - self.chi2
    }
}

/// `theta` with its direction turned by `dphi` (|dphi| <= 0.5 rad): `cos` and `sin` by
/// their series to the fourth and fifth order (within 3e-5 there), the direction then
/// renormalised to unit length.
fn rotated(theta: Theta, dphi: f32) -> Theta {
    let d2 = dphi * dphi;
    let c = 1.0 - 0.5 * d2 * (1.0 - d2 / 12.0);
    let s = dphi * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0));
    let (ex, ey) = (c * theta.ex - s * theta.ey, s * theta.ex + c * theta.ey);
    let n = math::sqrt(ex * ex + ey * ey);
    Theta {
        ex: ex / n,
        ey: ey / n,
        ..theta
    }
}

/// A converged (or last) fit: parameters, chi-square, and the covariance's factor there.
struct Fit {
    theta: Theta,
    chi2: f32,
    factor: ([f32; K], [[f32; K]; K]),
    converged: bool,
}

/// Gauss-Newton from `theta` on the parameters of `free`; `None` on a failure (module docs).
fn fit(
    p: &Prepared<'_>,
    whole: PixelBox,
    mut theta: Theta,
    free: [bool; K],
    params: &FreeTrailParams,
) -> Option<Fit> {
    let (wmax, hmax) = (f32::from(p.width) - 0.5, f32::from(p.height) - 0.5);
    let s_max = 0.5 * f32::from(p.width.max(p.height));
    let l_max = math::sqrt(wmax * wmax + hmax * hmax);
    let tol = params.tolerance_px;
    let trailed = free.get(L_IX).copied().unwrap_or(false);
    for _ in 0..params.max_iterations {
        let (a, b, chi2) = normal_equations(p, whole, &theta, free);
        let (step, d, l) = solve_k(&a, &b)?;
        let [sx, sy, sn, sb, ss, sl, sphi] = step;
        let dx = sx.clamp(-1.0, 1.0);
        let dy = sy.clamp(-1.0, 1.0);
        let ds = clamp(ss, -0.5 * theta.s, 0.5 * theta.s);
        let lim_l = (0.5 * theta.l).max(1.0);
        let dl = clamp(sl, -lim_l, lim_l);
        if dx.abs() < tol && dy.abs() < tol && ds.abs() < tol && dl.abs() < tol {
            return Some(Fit {
                theta,
                chi2,
                factor: (d, l),
                converged: true,
            });
        }
        theta = Theta {
            x: theta.x + dx,
            y: theta.y + dy,
            flux: theta.flux + sn,
            bg: theta.bg + sb,
            s: clamp(theta.s + ds, 0.3, s_max),
            l: (theta.l + dl).min(l_max),
            ..rotated(theta, sphi.clamp(-0.5, 0.5))
        };
        let inside = (-0.5..=wmax).contains(&theta.x) && (-0.5..=hmax).contains(&theta.y);
        if !inside
            || theta.flux.is_nan()
            || theta.flux <= 0.0
            || (trailed && theta.l < MIN_TRAIL_PX)
        {
            return None;
        }
    }
    let (a, b, chi2) = normal_equations(p, whole, &theta, free);
    let (_, d, l) = solve_k(&a, &b)?;
    Some(Fit {
        theta,
        chi2,
        factor: (d, l),
        converged: false,
    })
}

/// The trailed and the round fit of `input`, and the test between them (module docs).
pub fn trail_fit_free(input: &CentroidInput<'_>, params: &FreeTrailParams) -> TrailedFit {
    let failed = |c: Centroid, border: u16| TrailedFit {
        centroid: c,
        cov_xy_px2: 0.0,
        trail_px: (0.0, 0.0),
        sigma_length_px: f32::NAN,
        psf_sigma_px: f32::NAN,
        chi2: f32::NAN,
        chi2_round: f32::NAN,
        dof: 0,
        border,
        round_converged: false,
    };
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return failed(c, 0),
    };
    let whole = PixelBox {
        col0: 0,
        row0: 0,
        col1: p.width - 1,
        row1: p.height - 1,
    };
    let border = p.perimeter_usable();
    let Some(start) = cog_in_box(&p, whole, p.centre(), CogPower::One) else {
        return failed(p.degenerate(CentroidFlags::empty()), border);
    };
    let give_up = |chi2_round: f32, round_converged: bool| TrailedFit {
        chi2_round,
        round_converged,
        ..failed(p.finish(start, CentroidFlags::NOT_CONVERGED), border)
    };
    let n_px = p.box_pixels(whole).count();
    let total: f32 = p.box_pixels(whole).map(|(_, _, f)| f).sum();
    let s0 = {
        let s = crate::centroid::cog::usable_sigma_px(params.start_sigma_px);
        math::sqrt(s * s + 1.0 / 12.0)
    };
    let round_free = [true, true, true, true, true, false, false];
    let theta0 = Theta {
        x: start.col,
        y: start.row,
        flux: total.max(start.flux_e),
        bg: 0.0,
        s: s0,
        l: 0.0,
        ex: 1.0,
        ey: 0.0,
    };
    let round = fit(&p, whole, theta0, round_free, params);
    let chi2_round = round.as_ref().map_or(f32::NAN, |r| r.chi2);
    let round_converged = round.as_ref().is_some_and(|r| r.converged);
    let (tx, ty) = params.start_trail_px;
    let l0 = math::sqrt(tx * tx + ty * ty);
    if !(l0.is_finite() && l0 >= MIN_TRAIL_PX) {
        return give_up(chi2_round, round_converged);
    }
    let theta = Theta {
        s: s0,
        l: l0,
        ex: tx / l0,
        ey: ty / l0,
        ..round.as_ref().map_or(theta0, |r| r.theta)
    };
    let Some(tr) = fit(&p, whole, theta, [true; K], params) else {
        return give_up(chi2_round, round_converged);
    };
    // A trailed solution shorter than 3 s is nearly round: a large improvement on the round
    // fit then says the round fit stopped on a worse minimum than the round model's (a wide
    // bright star whose border holds its wings), so the round model is fitted again from
    // there and the better round fit compared. A longer trail's improvement is its own
    // (and the refit, far from the round minimum, would cost a whole fit).
    let (mut chi2_round, mut round_converged) = (chi2_round, round_converged);
    let near_round = tr.theta.l < REFIT_TRAIL_SIGMAS * tr.theta.s;
    let gap = tr.chi2_round_gap(chi2_round);
    if near_round && (gap.is_nan() || gap > trail_dchi2_limit(border)) {
        let again = Theta {
            l: 0.0,
            ex: 1.0,
            ey: 0.0,
            ..tr.theta
        };
        if let Some(r) = fit(&p, whole, again, round_free, params)
            && (chi2_round.is_nan() || r.chi2 < chi2_round)
        {
            chi2_round = r.chi2;
            round_converged = r.converged;
        }
    }
    let (d, l) = tr.factor;
    let th = tr.theta;
    let (var_x, var_y, cov_xy) = position_covariance(&l, &d);
    let m = Measured {
        col: th.x,
        row: th.y,
        flux_e: th.flux,
        snr: th.flux / math::sqrt(variance(&l, &d, N_IX)).max(f32::MIN_POSITIVE),
        sigma_col: math::sqrt(var_x),
        sigma_row: math::sqrt(var_y),
    };
    let extra = if tr.converged {
        CentroidFlags::empty()
    } else {
        CentroidFlags::NOT_CONVERGED
    };
    let (c, s) = (th.ex, th.ey);
    let centroid = p.finish(m, extra);
    TrailedFit {
        centroid,
        cov_xy_px2: bounded_covariance(&centroid, cov_xy),
        trail_px: (th.l * c, th.l * s),
        sigma_length_px: math::sqrt(variance(&l, &d, L_IX)),
        psf_sigma_px: math::sqrt(pos(th.s * th.s - 1.0 / 12.0)),
        chi2: tr.chi2,
        chi2_round,
        dof: u16::try_from(n_px.saturating_sub(K)).unwrap_or(u16::MAX),
        border,
        round_converged,
    }
}
