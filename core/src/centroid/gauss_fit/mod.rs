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
//! configuration, the near-CRLB one) the same estimator runs on three
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
//! bench's bright star, 2 steps; the exact counts are in docs/speed.md, checked against the
//! bench's CSV):
//!
//! | configuration | 5x5 | 7x7 |
//! |---|---|---|
//! | background held and given (`centroid_gauss_fit_given_bg_*`: `startrack accuracy`'s) | ~4,800 | ~7,000 |
//! | perimeter median, `B` fitted (`centroid_gauss_fit_*`: [`GaussFitParams::new`]) | ~16,800 | ~22,000 |
//!
//! Of the held 7x7's ~7,000 (QEMU `-d exec` trace, docs/speed.md): ~1,430 a step for the
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

mod general;
mod held;
mod width;

// The 4x4 Jacobi-scaled Cholesky solve, shared with the trailed-star fit.
pub(super) use general::{Normal, position_covariance, solve, solve_k, variance};

pub use width::{
    CHI2_FLAG_Z, MAX_WIDTH_FIT_SIDE, MIN_PRIOR_SCATTER_PX, MIN_SIGMA_PX, PSF_MISMATCH_Z, PsfFit,
    WidthFitParams, WidthPrior, chi2_dof_limit, chi2_dof_limit_border, gauss_fit_width,
    gauss_fit_width_prior, sigma_unreliable,
};

use super::math;
use super::prepared::Prepared;
use super::{Background, Centroid, CentroidFlags, CentroidInput};

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
    general::fit(&p, params)
}

// The pieces both paths share: the PSF's pixel profile along one axis and the step check.

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

/// True when a Gauss-Newton step left the position inside the window's pixel edges
/// (`-1/2 ..= wmax`, `-1/2 ..= hmax`, window-relative) and the flux positive: else the fit
/// gives up (module docs, failure policy).
#[inline(always)]
fn step_usable(x: f32, y: f32, flux: f32, wmax: f32, hmax: f32) -> bool {
    (-0.5..=wmax).contains(&x) && (-0.5..=hmax).contains(&y) && flux > 0.0
}

/// The brightest pixel of a window without excluded pixels (ties to the one nearest the
/// window's centre pixel, as [`Prepared::peak`]), by one walk of the pixel bits.
#[inline(always)]
fn peak_clean(p: &Prepared<'_>) -> Option<(u16, u16)> {
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
    best_i.map(at)
}
