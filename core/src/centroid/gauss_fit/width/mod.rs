//! The pixel-integrated Gaussian fit with the PSF width free: `(x, y, N, s)`, for stars whose
//! width is not known (defocus, field curvature and coma change it across the field and from
//! star to star). Reports each star's width `psf_a_px` with its error and a goodness of fit
//! `chi2_dof`, and flags a window the model cannot describe. With a field PSF model (table
//! section 9) the same fit takes the model's width as a prior ([`gauss_fit_width_prior`]):
//! near the bound of a star whose width is known, for the price of one matrix element.
//! Cost: two or three Gauss-Newton steps for a bright star, each linear in the window's
//! pixels (# Cost).
//!
//! # Model and fit
//! ```text
//! m_k = N P(c_k; x, s) P(r_k; y, s),   P(i; x, s) = Phi((i + 1/2 - x)/s) - Phi((i - 1/2 - x)/s)
//! minimise chi2 = sum((F_k - m_k)^2 / v_k),  v_k = max(m_k, 0) + var_bg + 1 e-^2
//! ```
//! over the usable pixels of the window, `F_k` background-subtracted with the background
//! held (the perimeter's median or mean, or given; not fitted): the held path of
//! [`super::gauss_fit`] with `s` a fourth parameter. Weights from the model, refreshed each
//! Gauss-Newton step. The Jacobian separates, `J = (N fy dx, N fx dy, fx fy, N (wx fy + fx
//! wy))` with `f, d, w` the pixel fraction and its derivatives by the centre and by `s`
//! ([`crate::centroid::math::EdgeGrid::pixels_with_width`]), so per pixel only the weight
//! (one divide), the residual and ten row sums; per row the 4x4 normal matrix's ten terms
//! and four right-hand sides (`normal.rs`). The 4x4 system by `LDL^T` (no square root; a
//! pivot below `1e-12` of its diagonal is "not positive definite").
//!
//! Start (`start.rs`): the peak, then in the `start_box` around it the power-1 CoG
//! (position), the box's flux (`N`) and its second moments, `s^2 = (var_x + var_y) / 2 -
//! 1/12` (the pixel's own variance removed), clamped to `MIN_SIGMA_PX ..= side / 2`. Steps
//! (`fit.rs`): position capped at one pixel, `s` at half its value. Stop when the position
//! and `s` steps are all below `tolerance_px`, or all below `tolerance_sigmas` of their own
//! errors. Failure (a step leaving the window, `N <= 0`, `s` leaving `MIN_SIGMA_PX ..= side
//! / 2`, a matrix that is not positive definite) returns the starting CoG with
//! [`CentroidFlags::NOT_CONVERGED`]; running out of steps returns the last estimate with the
//! same flag. Windows over [`MAX_WIDTH_FIT_SIDE`] px a side are not fitted (the profile
//! buffers are sized for star windows): the starting CoG with `NOT_CONVERGED`.
//!
//! # Background
//! With the border's median (the flight's), the per-pixel variance is the border's sample
//! variance about the median, pixels beyond 4 MAD-sigmas left out (a hot pixel, a cosmic
//! ray): the MAD's own variance over 16-24 pixels is noisy, and at low SNR the position's
//! sigma scales with it (`border.rs`). When the fitted star's brightest border pixel exceeds
//! half the background's noise, the border holds the star's wings, which bias the median
//! high and add their spread to the variance: once, the background is estimated again from
//! the border's residuals to the fitted star and one more Gauss-Newton step is taken from
//! the solution (its covariance from the step's start, its chi2 the linearised model's
//! prediction at the step's end, `chi2 - b . d`). One step rather than a second
//! convergence: the new background moves the solution little.
//!
//! # With a field PSF model
//! [`gauss_fit_width_prior`] adds the model's width at the star as a Gaussian prior,
//! `s ~ N(s_model, (scatter sqrt 0.31)^2)`: a fifth measurement row `(0, 0, 0, 1)` with
//! weight `I_p = 1 / sigma_p^2`, i.e. `I_p` added to the normal matrix's `s s` element and
//! `I_p (s_model - s)` to its right-hand side (MAP; `chi2` stays the data's). The fit starts
//! at the model's width. A star whose own width disagrees with the model (the width-free
//! fit's `s` against `s_model`, with the fit's and the model's variance: `z^2 = (s_map -
//! s_model)^2 I I_p / (I + I_p)`, `I` the data's information on `s`) by more than
//! [`PSF_MISMATCH_Z`] is refitted width-free and flagged [`CentroidFlags::PSF_MISMATCH`]:
//! a blend, a cosmic ray, a PSF the model does not describe. A scatter below
//! [`MIN_PRIOR_SCATTER_PX`] is taken as that.
//!
//! # Error estimate and goodness of fit
//! `sigma_x`, `sigma_y`, `sigma_N`, `sigma_s` from the diagonal of `(J^T W J)^-1` at the
//! solution (the last step's start, less than `tolerance_px` away): the information with the
//! width a free parameter, so a star's position error includes what not knowing its width
//! costs (with a prior, what knowing it to the model's scatter costs). `v_k` counts the
//! star's shot noise and the perimeter's measured variance (sky and dark shot noise, read
//! noise, the dark and flat maps' residual non-uniformity together). The held level's own
//! error (common to every pixel) is left out: its term `level_var (A^-1 J^T W 1)^2` moves
//! the position's pulls by 0.01 at most in the width-unknown table (docs/accuracy.md) and
//! would cost a few instructions a pixel a step.
//! `psf_a_px = s / sqrt(0.31)` with `sigma_psf_a_px = sigma_s / sqrt(0.31)`.
//! `chi2_dof = chi2 / (n - 4)` over the `n` usable pixels; for a star the model describes it
//! follows `chi2(n - 4) / (n - 4)` with a given background variance, and above
//! [`chi2_dof_limit`] (the distribution's upper `z`-sigma point, `z` = [`CHI2_FLAG_Z`]: a
//! false-flag rate of 1e-3 per star) the centroid gets [`CentroidFlags::POOR_FIT`]: a
//! blend, a cosmic ray, coma or defocus the Gaussian cannot follow. With the variance from
//! the window's own border (the flight's) the statistic is `F`-distributed, not chi-square,
//! and the limit is [`chi2_dof_limit_border`]'s (`limits.rs`; the host test
//! `centroid_gauss_fit_width` holds its false-flag rate on clean stars). The position is
//! still reported, flagged, never as a clean number. Where the linearised sigmas are known
//! to miss the error by more than 10 % (without a model, a star that may be narrower than
//! a = 0.7 px below SNR 60: [`sigma_unreliable`]) the centroid gets
//! [`CentroidFlags::SIGMA_UNRELIABLE`].
//!
//! # Cost
//! Per step `w + h + 2` edge `erfc`s, densities and width terms, the ten row sums of the
//! normal equations a pixel, and a 4x4 `LDL^T`; from the moment start a bright star
//! converges in two steps on 5x5, three on 7x7. With a prior that agrees with the star the
//! fit starts at the model's width (a 7x7 star needs a step less); a mismatched star pays
//! the width-free fit again. The border's clipped variance (one pass over the border) and
//! the wings' refit (the border's median of the residuals and one more step, on stars whose
//! wings reach the border) come with the flight's background; the chi2's predicted fall
//! after each step (the refit's goodness of fit) is four multiply-adds a step. The Cortex-M7
//! counts, background given, are `centroid_gauss_fit_width_*` in docs/speed.md; the
//! flight's background is inside `tracker_tracking_frame` there.
//!
//! # Where it fails
//! - Faint stars (SNR below ~10 in 5x5): the width is poorly determined and the position
//!   error grows towards the fixed-width fit's at a wrong width; `NOT_CONVERGED` is more
//!   frequent.
//! - Non-Gaussian PSFs: the fitted `s` is the Gaussian closest to the PSF; the position is
//!   the model's centre, not the PSF's centroid; `chi2_dof` flags a strong mismatch.
//! - A perimeter that holds much of the star (a window too small for the star) biases the
//!   held background high and `s` low beyond what the one refit recovers.
//! - Below a = 0.7 px without a model: the width and the position couple (through the
//!   pixel's own width), the fit is non-linear there and the sigmas are ~30 % small below
//!   SNR 60 (flagged); a model removes it.

mod border;
mod fit;
mod limits;
mod normal;
mod params;
mod start;

pub use limits::{chi2_dof_limit, chi2_dof_limit_border, sigma_unreliable};
pub use params::{
    CHI2_FLAG_Z, MAX_WIDTH_FIT_SIDE, MIN_PRIOR_SCATTER_PX, MIN_SIGMA_PX, PSF_MISMATCH_Z, PsfFit,
    WidthFitParams, WidthPrior,
};

use crate::centroid::prepared::Prepared;
use crate::centroid::{CentroidFlags, CentroidInput};
use fit::{fit, fit_z};
use params::{Prior, SQRT_031};

/// The width-free Gaussian fit of `input` (see the module docs).
pub fn gauss_fit_width(input: &CentroidInput<'_>, params: &WidthFitParams) -> PsfFit {
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return PsfFit::unfitted(c),
    };
    if p.flags.contains(CentroidFlags::EXCLUDED_PIXEL) {
        fit::<false>(&p, params, None)
    } else {
        fit::<true>(&p, params, None)
    }
}

/// The width fit of `input` with a field PSF model's width as a Gaussian prior (see the
/// module docs, "With a field PSF model"): the MAP fit, or, when the star's own width
/// disagrees with the model, the width-free fit flagged [`CentroidFlags::PSF_MISMATCH`].
pub fn gauss_fit_width_prior(
    input: &CentroidInput<'_>,
    params: &WidthFitParams,
    prior: &WidthPrior,
) -> PsfFit {
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return PsfFit::unfitted(c),
    };
    let sp = prior.scatter_px.max(MIN_PRIOR_SCATTER_PX) * SQRT_031;
    let s_model = prior.a_px * SQRT_031;
    let info = 1.0 / (sp * sp);
    if !(s_model.is_finite() && s_model > 0.0 && info.is_finite()) {
        return gauss_fit_width(input, params);
    }
    let prior = Some(Prior { s_model, info });
    let clean = !p.flags.contains(CentroidFlags::EXCLUDED_PIXEL);
    let (map, z) = if clean {
        fit_z::<true>(&p, params, prior)
    } else {
        fit_z::<false>(&p, params, prior)
    };
    if z <= params.mismatch_z {
        return map;
    }
    let mut free = if clean {
        fit::<true>(&p, params, None)
    } else {
        fit::<false>(&p, params, None)
    };
    free.centroid.flags |= CentroidFlags::PSF_MISMATCH;
    free
}
