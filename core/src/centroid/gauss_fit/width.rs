//! The pixel-integrated Gaussian fit with the PSF width free: `(x, y, N, s)`, for stars whose
//! width is not known (defocus, field curvature and coma change it across the field and from
//! star to star). Reports each star's width `psf_a_px` with its error and a goodness of fit
//! `chi2_dof`, and flags a window the model cannot describe. With a field PSF model (table
//! section 9) the same fit takes the model's width as a prior ([`gauss_fit_width_prior`]):
//! near the bound of a star whose width is known, for the price of one matrix element.
//!
//! # Model and fit
//! ```text
//! m_k = N P(c_k; x, s) P(r_k; y, s),   P(i; x, s) = Phi((i + 1/2 - x)/s) - Phi((i - 1/2 - x)/s)
//! minimise chi2 = sum((F_k - m_k)^2 / v_k),  v_k = max(m_k, 0) + var_bg + 1 e-^2
//! ```
//! over the usable pixels of the window, `F_k` background-subtracted with the background
//! held (the perimeter's median or mean, or given; not fitted): the held path of [`super`]
//! with `s` a fourth parameter. Weights from the model, refreshed each Gauss-Newton step.
//! The Jacobian separates, `J = (N fy dx, N fx dy, fx fy, N (wx fy + fx wy))` with
//! `f, d, w` the pixel fraction and its derivatives by the centre and by `s`
//! ([`crate::centroid::math::EdgeGrid::pixels_with_width`]), so per pixel only the weight
//! (one divide), the residual and ten row sums; per row the 4x4 normal matrix's ten terms
//! and four right-hand sides. The 4x4 system by `LDL^T` (no square root; a pivot below
//! `1e-12` of its diagonal is "not positive definite").
//!
//! Start: the peak, then in the `start_box` around it the power-1 CoG (position), the box's
//! flux (`N`) and its second moments, `s^2 = (var_x + var_y) / 2 - 1/12` (the pixel's own
//! variance removed), clamped to `MIN_SIGMA_PX ..= side / 2`. Steps: position capped at one
//! pixel, `s` at half its value. Stop when the position and `s` steps are all below
//! `tolerance_px`. Failure (a step leaving the window, `N <= 0`, `s` leaving
//! `MIN_SIGMA_PX ..= side / 2`, a matrix that is not positive definite) returns the starting
//! CoG with [`CentroidFlags::NOT_CONVERGED`]; running out of steps returns the last estimate
//! with the same flag. Windows over 16 px a side are not fitted (the profile buffers are sized
//! for star windows): the starting CoG with `NOT_CONVERGED`.
//!
//! Background: with the border's median (the flight's), the per-pixel variance is the
//! border's sample variance about the median, pixels beyond 4 MAD-sigmas left out (a hot
//! pixel, a cosmic ray): the MAD's own variance of 16-24 pixels is noisy, and at low SNR the
//! sigmas scale with it (the pulls were 1.05-1.12 at SNR 10 with it). When the fitted star's
//! brightest border pixel exceeds half the background's noise (a = 2 px at SNR 100 in 7x7)
//! the border held its wings, biasing the median high and the variance with the wings'
//! spread (pull 0.77): once, the background is estimated again from the border's residuals
//! to the fitted star and one more Gauss-Newton step is taken from the solution (its
//! covariance from the step's start, its chi2 the linearised model's prediction at the
//! step's end, `chi2 - b . d`: the chi2 at the start, the new background against the old
//! star, flagged 4 % of the clean a = 2 px stars at SNR 100 in 7x7 and 65 % at SNR 200;
//! iterating to convergence instead costs a step, ~3,700 instructions a 7x7 star).
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
//! error (common to every pixel) is left out: added as `level_var (A^-1 J^T W 1)^2` it
//! moved the position's pulls by 0.01 at most in the width-unknown table, for ~3
//! instructions a pixel a step.
//! `psf_a_px = s / sqrt(0.31)` with `sigma_psf_a_px = sigma_s / sqrt(0.31)`.
//! `chi2_dof = chi2 / (n - 4)` over the `n` usable pixels; for a star the model describes it
//! follows `chi2(n - 4) / (n - 4)` with a given background variance, and above
//! [`chi2_dof_limit`] (the distribution's upper `z`-sigma point, `z` = [`CHI2_FLAG_Z`]: a
//! false-flag rate of 1e-3 per star) the centroid gets [`CentroidFlags::POOR_FIT`]: a
//! blend, a cosmic ray, coma or defocus the Gaussian cannot follow. With the variance from
//! the window's own border (the flight's) the statistic is `F`-distributed, not chi-square,
//! and the limit is [`chi2_dof_limit_border`]'s (the chi-square limit flagged 1.1-1.5 % of
//! clean stars in 7x7; host test `centroid_gauss_fit_width`: 0.05-0.5 % now, the rest the
//! held level's own error, left out of the limit). The position is still reported, flagged, never as a clean number.
//! Where the linearised sigmas are known to miss the error by more than 10 % (without a
//! model, a star that may be narrower than a = 0.7 px below SNR 60: [`sigma_unreliable`])
//! the centroid gets [`CentroidFlags::SIGMA_UNRELIABLE`].
//!
//! # Cost
//! Per step `w + h + 2` edge `erfc`s, densities and width terms, ~35 instructions a pixel
//! for the normal equations (the ten row sums), a 4x4 `LDL^T`; from the moment start the
//! bench's bright star converges in 2 steps on 5x5, 3 on 7x7. Measured on the Cortex-M7
//! (`cargo m7-bench`, background given; the exact counts in docs/speed.md): ~7,450
//! instructions for a 5x5 window (`centroid_gauss_fit_width_5x5`, ~2,700 a step, ~2,000 for
//! validation, start and output) and ~13,700 for 7x7 (`centroid_gauss_fit_width_7x7`,
//! ~3,700 a step): 1.5x and 1.9x the fit with the width given. With a prior that agrees
//! with the star, ~7,600 and ~10,100 (`centroid_gauss_fit_width_model_*`: it starts at the
//! model's width and the 7x7 fit needs a step less); a mismatched star pays the width-free
//! fit again. The border's clipped variance (~10 instructions a border pixel) and the wings'
//! refit (the border's median of the residuals and one more step, on stars whose wings
//! reach the border) are the flight's, not in these stages (background given): the 30-star
//! tracking frame, whose bench stars are bright and reach the border, grew by ~12,800
//! instructions a star with them (`tracker_tracking_frame`). The chi2's predicted fall
//! after each step (the refit's goodness of fit) adds ~40 instructions a step (75 and 115
//! on the bench's 5x5 and 7x7 stars).
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

use super::Grid;
use super::step_usable;
use crate::centroid::cog::{CogPower, cog_in_box};
use crate::centroid::math;
use crate::centroid::prepared::{Measured, Prepared};
use crate::centroid::{Background, BackgroundEstimate, Centroid, CentroidFlags, CentroidInput};

/// Largest window side fitted (the profile buffers' length).
pub const MAX_WIDTH_FIT_SIDE: u16 = 16;
const M: usize = MAX_WIDTH_FIT_SIDE as usize;

/// The smallest PSF sigma the fit reports, px (a = 0.45 px): a star narrower than that
/// (or one whose noise says so) is fitted with `s` held at this floor, the position and flux
/// free: below it the pixel's own width hides the star's, the width derivative vanishes and
/// the position's with it when the star sits inside one pixel.
pub const MIN_SIGMA_PX: f32 = 0.25;

/// The width's step threshold over the position's: `s` is worth less to the position than
/// its own step suggests (its error is several times the position's), so it stops at 10x the
/// position tolerance.
const S_TOLERANCE_FACTOR: f32 = 10.0;

/// The smallest starting sigma, px (a = 0.72 px): a noisy box's moments can put a star
/// inside one pixel, where the model's position derivatives are steep and the first steps
/// wild; from 0.4 px the fit finds narrower stars in a step or two.
const MIN_START_SIGMA_PX: f32 = 0.4;

/// `sqrt(0.31)`: the 80 %-energy radius `a` of a 2-D Gaussian is `s / sqrt(0.31)`.
const SQRT_031: f32 = 0.556_776_4;

/// The upper-tail point of the standard normal for the `POOR_FIT` flag: 3.09 sigma, a
/// one-sided false-flag rate of 1e-3 per star whose PSF the model describes.
pub const CHI2_FLAG_Z: f32 = 3.09;

/// The two-sided normal point for the `PSF_MISMATCH` flag: 3.29 sigma, a false-flag rate
/// of 1e-3 per star whose width the model describes within its scatter.
pub const PSF_MISMATCH_Z: f32 = 3.29;

/// The smallest model scatter the prior takes, px of `a` (one step of the table's U8F8
/// scatter): a model that claims to be exact still leaves the width a little freedom.
pub const MIN_PRIOR_SCATTER_PX: f32 = 1.0 / 256.0;

/// The field PSF model's width at a star (table section 9: [`crate::table::PsfModel::a_px`]
/// and its `scatter_px`), as a Gaussian prior on the fit's width.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WidthPrior {
    /// The model's 80 %-energy radius at the star, px.
    pub a_px: f32,
    /// The model's RMS scatter about it, px (at least [`MIN_PRIOR_SCATTER_PX`]).
    pub scatter_px: f32,
}

/// Parameters of [`gauss_fit_width`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WidthFitParams {
    /// Largest number of Gauss-Newton steps (0 returns the starting CoG, `NOT_CONVERGED`).
    pub max_iterations: u8,
    /// Convergence threshold on the position steps, px (the width's is 10 times this).
    pub tolerance_px: f32,
    /// The fit also stops when the position and width steps are all below this fraction of
    /// their own 1-sigma errors (0.02; 0 turns the rule off): a faint star's fit converges
    /// only linearly, and a step of 2 % of the error changes nothing a user can see.
    pub tolerance_sigmas: f32,
    /// Side of the starting CoG's and moments' box, px.
    pub start_box: u8,
    /// Background source (held, not fitted).
    pub background: Background,
    /// The normal upper-tail point of [`chi2_dof_limit`] (the false-flag rate of
    /// [`CentroidFlags::POOR_FIT`]); [`CHI2_FLAG_Z`] by default.
    pub chi2_flag_z: f32,
    /// With a field PSF model ([`gauss_fit_width_prior`]): the largest `|z|` of the star's
    /// own width against the model's before the star is flagged
    /// [`CentroidFlags::PSF_MISMATCH`] and fitted width-free; [`PSF_MISMATCH_Z`] by default.
    pub mismatch_z: f32,
}

impl WidthFitParams {
    /// Ten steps to 1e-4 px from a 5x5 box's CoG and moments, background the perimeter's
    /// median, the flag at [`CHI2_FLAG_Z`].
    pub const fn new() -> Self {
        Self {
            max_iterations: 10,
            tolerance_px: 1e-4,
            tolerance_sigmas: 0.02,
            start_box: 5,
            background: Background::PerimeterMedian,
            chi2_flag_z: CHI2_FLAG_Z,
            mismatch_z: PSF_MISMATCH_Z,
        }
    }
}

impl Default for WidthFitParams {
    fn default() -> Self {
        Self::new()
    }
}

/// A star's position with its own PSF width and goodness of fit.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PsfFit {
    /// Position, flux (the whole PSF's `N`), SNR (`N / sigma_N`), errors and flags.
    pub centroid: Centroid,
    /// The fitted PSF's 80 %-energy radius `a = s / sqrt(0.31)`, px; 0 when not fitted
    /// (degenerate or `NOT_CONVERGED` on a failure: the starting CoG).
    pub psf_a_px: f32,
    /// 1-sigma error of `psf_a_px`, px; 0 when not fitted.
    pub sigma_psf_a_px: f32,
    /// `chi2 / (n - 4)` at the solution; 0 when not fitted.
    pub chi2_dof: f32,
}

impl PsfFit {
    /// A centroid without a fitted width (a failure or a degenerate window).
    fn unfitted(centroid: Centroid) -> Self {
        Self {
            centroid,
            psf_a_px: 0.0,
            sigma_psf_a_px: 0.0,
            chi2_dof: 0.0,
        }
    }
}

/// True where the fit's `sigma_x`, `sigma_y` are known to miss its error by more than 10 %
/// (the pull table of docs/accuracy.md, `startrack accuracy --width-unknown`): without a
/// field PSF model, a star that may be narrower than a = 0.7 px (`s` less twice its error
/// below that) under SNR 60: the width and the position couple through the pixel's own
/// width and the fit is non-linear there (pulls 1.3 at a = 0.6 px, SNR 10-30). With the
/// model's width as a prior (`with_model`) no cell of the table misses: never. `s`,
/// `sigma_s` px.
pub fn sigma_unreliable(s: f32, sigma_s: f32, snr: f32, with_model: bool) -> bool {
    !with_model && s - 2.0 * sigma_s < 0.7 * SQRT_031 && snr < 60.0
}

/// The largest `chi2 / dof` a window of `dof` degrees of freedom passes: the chi-square
/// distribution's point `z` sigmas into its upper tail by the Wilson-Hilferty cube
/// (`(1 - c + z sqrt(c))^3`, `c = 2 / (9 dof)`; 0.6 % above the exact quantile at 10
/// dof, within 0.3 % from 20 on, at `z = 3.09`, host test `centroid_gauss_fit_width`). `f32::MAX` for 0 dof
/// (nothing to test).
pub fn chi2_dof_limit(dof: u16, z: f32) -> f32 {
    if dof == 0 {
        return f32::MAX;
    }
    let c = 2.0 / (9.0 * f32::from(dof));
    let t = 1.0 - c + z * math::sqrt(c);
    t * t * t
}

/// The largest `chi2 / dof` a window of `dof` degrees of freedom passes when the pixels'
/// background variance was estimated from `border` of its own pixels (their sample variance
/// about the held level; 0: a given variance, [`chi2_dof_limit`]). The border's residuals
/// then sum to `border - 1` variances whatever the noise, and the rest of the window's
/// `d = dof - border + 1` degrees of freedom are scaled by the estimate's error: `chi2 =
/// (border - 1) + d F(d, border - 1)`, `F` Fisher's distribution (measured in the host test
/// `centroid_gauss_fit_width`: the mean and variance of `chi2_dof` of clean stars match it
/// within a few per cent, where the chi-square law's variance is 30 % small in 7x7). The
/// `F` point `z` sigmas into its upper tail by Paulson's cube-root normal approximation
/// (the Wilson-Hilferty cube of both chi-squares; within 2 % of the exact 1e-3 quantile
/// for the 5x5 and 7x7 borders, same test). `f32::MAX` when nothing is left to test
/// (`d` or `border - 1` below 3, e.g. a 3x3 window).
pub fn chi2_dof_limit_border(dof: u16, border: u16, z: f32) -> f32 {
    if border == 0 {
        return chi2_dof_limit(dof, z);
    }
    let d2 = border.saturating_sub(1);
    let d1 = dof.saturating_sub(d2);
    if d1 < 3 || d2 < 3 {
        return f32::MAX;
    }
    let c1 = 2.0 / (9.0 * f32::from(d1));
    let c2 = 2.0 / (9.0 * f32::from(d2));
    let z2 = z * z;
    // ((1 - c2) u - (1 - c1))^2 = z^2 (c2 u^2 + c1), u = F^(1/3): the larger root.
    let a = (1.0 - c2) * (1.0 - c2) - z2 * c2;
    if a <= 0.0 {
        return f32::MAX;
    }
    let q = (1.0 - c2) * (1.0 - c1);
    let disc = q * q - a * ((1.0 - c1) * (1.0 - c1) - z2 * c1);
    let u = (q + math::sqrt(disc.max(0.0))) / a;
    (f32::from(d2) + f32::from(d1) * u * u * u) / f32::from(dof)
}

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

/// The normal equations' sums at one parameter point.
struct Normal {
    /// Upper triangle `a00 a01 a02 a03 a11 a12 a13 a22 a23 a33` (order `x, y, N, s`).
    a: [f32; 10],
    b: [f32; 4],
    /// `sum w r^2`.
    chi2: f32,
    /// Usable pixels.
    n: u16,
}

impl Normal {
    /// Adds the width's prior.
    fn add_prior(&mut self, pr: Prior, s: f32) {
        // The prior as a fifth measurement row `(0, 0, 0, 1)`, residual `s_model - s`, weight
        // `I_p`: not counted in `chi2` (the data's goodness of fit).
        self.a[9] += pr.info;
        self.b[3] += pr.info * (pr.s_model - s);
    }

    /// Holds `s`: its row and column decoupled, a unit pivot and a zero right-hand side
    /// (its step is then 0 and the other parameters' covariance that of the 3-parameter
    /// fit).
    fn pin_width(&mut self) {
        let [a00, a01, a02, _, a11, a12, _, a22, _, _] = self.a;
        self.a = [a00, a01, a02, 0.0, a11, a12, 0.0, a22, 0.0, 1.0];
        self.b[3] = 0.0;
    }
}

/// The six profiles along the two axes: fraction, centre and width derivatives.
type Profiles = [[f32; M]; 6];

/// The normal equations at `(x, y, n, s)` (`CLEAN`: no excluded pixel; else excluded pixels
/// get weight 0).
fn normal<const CLEAN: bool>(
    p: &Prepared<'_>,
    level_e: f32,
    var1: f32,
    (x, y, n, s): (f32, f32, f32, f32),
    prof: &mut Profiles,
) -> Normal {
    let grid = Grid::new(s);
    let wscale = core::f32::consts::SQRT_2 * grid.dscale;
    let [px, dpx, wpx, py, dpy, wpy] = prof;
    let (w, h) = (usize::from(p.width), usize::from(p.height));
    if let (Some(f), Some(d), Some(ws)) = (px.get_mut(..w), dpx.get_mut(..w), wpx.get_mut(..w)) {
        grid.edges
            .pixels_with_width(-0.5 - x, grid.dscale, wscale, f, d, ws);
    }
    if let (Some(f), Some(d), Some(ws)) = (py.get_mut(..h), dpy.get_mut(..h), wpy.get_mut(..h)) {
        grid.edges
            .pixels_with_width(-0.5 - y, grid.dscale, wscale, f, d, ws);
    }
    let mut a = [0.0f32; 10];
    let (mut b0, mut b1, mut b2, mut b3, mut chi2) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    let mut used = 0u16;
    let rows = p
        .pixels
        .chunks_exact(w.max(1))
        .zip(py.iter().zip(dpy.iter().zip(wpy.iter())));
    let mut first = 0usize;
    for (line, (&fy, (&dy, &wy))) in rows {
        let nfy = n * fy;
        let (mut sdd, mut sdf, mut sff, mut sdw, mut sfw) =
            (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let (mut sww, mut sdr, mut sfr, mut swr, mut srr) =
            (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let cols = px.iter().zip(dpx.iter().zip(wpx.iter()));
        for (i, (e, (&fx, (&dx, &wx)))) in line.iter().zip(cols).enumerate() {
            let f = e.to_bits() as f32 * (1.0 / 64.0) - level_e;
            let star = nfy * fx;
            let wt = if CLEAN {
                1.0 / (math::pos(star) + var1)
            } else if p.usable(first + i) {
                used += 1;
                1.0 / (math::pos(star) + var1)
            } else {
                0.0
            };
            let res = f - star;
            let (wd, wf, ww) = (wt * dx, wt * fx, wt * wx);
            sdd += wd * dx;
            sdf += wd * fx;
            sff += wf * fx;
            sdw += wd * wx;
            sfw += wf * wx;
            sww += ww * wx;
            sdr += wd * res;
            sfr += wf * res;
            swr += ww * res;
            srr += wt * res * res;
        }
        first += w;
        let (fy2, fdy, fwy) = (fy * fy, fy * dy, fy * wy);
        let [a00, a01, a02, a03, a11, a12, a13, a22, a23, a33] = &mut a;
        *a00 += fy2 * sdd;
        *a01 += fdy * sdf;
        *a02 += fy2 * sdf;
        *a03 += fy2 * sdw + fwy * sdf;
        *a11 += dy * dy * sff;
        *a12 += fdy * sff;
        *a13 += fdy * sfw + dy * wy * sff;
        *a22 += fy2 * sff;
        *a23 += fy2 * sfw + fwy * sff;
        *a33 += fy2 * sww + 2.0 * fwy * sfw + wy * wy * sff;
        b0 += fy * sdr;
        b1 += dy * sfr;
        b2 += fy * sfr;
        b3 += fy * swr + wy * sfr;
        chi2 += srr;
    }
    if CLEAN {
        used = p.width.saturating_mul(p.height);
    }
    let n2 = n * n;
    let [a00, a01, a02, a03, a11, a12, a13, a22, a23, a33] = a;
    Normal {
        a: [
            a00 * n2,
            a01 * n2,
            a02 * n,
            a03 * n2,
            a11 * n2,
            a12 * n,
            a13 * n2,
            a22,
            a23 * n,
            a33 * n2,
        ],
        b: [b0 * n, b1 * n, b2, b3 * n],
        chi2,
        n: used,
    }
}

/// The `LDL^T` factor of the 4x4 normal matrix: the unit lower triangle and the reciprocal
/// pivots.
struct Ldl4 {
    l: [f32; 6],
    id: [f32; 4],
}

impl Ldl4 {
    /// Factors `a` (upper triangle, [`Normal::a`]'s order); `None` unless every pivot is
    /// above `1e-12` of its diagonal element and finite.
    fn new(a: [f32; 10]) -> Option<Self> {
        let [a00, a01, a02, a03, a11, a12, a13, a22, a23, a33] = a;
        let ok = |d: f32, aii: f32| d > 1e-12 * aii && d.is_finite() && aii.is_finite();
        if !ok(a00, a00) || a00 <= 0.0 {
            return None;
        }
        let d0 = a00;
        let id0 = 1.0 / d0;
        let (l10, l20, l30) = (a01 * id0, a02 * id0, a03 * id0);
        let d1 = a11 - l10 * a01;
        if !ok(d1, a11) {
            return None;
        }
        let id1 = 1.0 / d1;
        let l21 = (a12 - l20 * a01) * id1;
        let l31 = (a13 - l30 * a01) * id1;
        let d2 = a22 - l20 * a02 - l21 * l21 * d1;
        if !ok(d2, a22) {
            return None;
        }
        let id2 = 1.0 / d2;
        let l32 = (a23 - l30 * a02 - l31 * l21 * d1) * id2;
        let d3 = a33 - l30 * a03 - l31 * l31 * d1 - l32 * l32 * d2;
        if !ok(d3, a33) {
            return None;
        }
        Some(Self {
            l: [l10, l20, l21, l30, l31, l32],
            id: [id0, id1, id2, 1.0 / d3],
        })
    }

    /// Solves `A x = b`.
    fn solve(&self, b: [f32; 4]) -> [f32; 4] {
        let [l10, l20, l21, l30, l31, l32] = self.l;
        let [id0, id1, id2, id3] = self.id;
        let [b0, b1, b2, b3] = b;
        let y1 = b1 - l10 * b0;
        let y2 = b2 - l20 * b0 - l21 * y1;
        let y3 = b3 - l30 * b0 - l31 * y1 - l32 * y2;
        let x3 = y3 * id3;
        let x2 = y2 * id2 - l32 * x3;
        let x1 = y1 * id1 - l21 * x2 - l31 * x3;
        let x0 = b0 * id0 - l10 * x1 - l20 * x2 - l30 * x3;
        [x0, x1, x2, x3]
    }

    /// The diagonal of `A^-1`: `sum_k (L^-1)_ki^2 / d_k`.
    fn inverse_diagonal(&self) -> [f32; 4] {
        let [l10, l20, l21, l30, l31, l32] = self.l;
        let [id0, id1, id2, id3] = self.id;
        // L^-1 (unit lower): m_ij = -sum_{k=j}^{i-1} l_ik m_kj.
        let m10 = -l10;
        let m20 = -(l20 + l21 * m10);
        let m21 = -l21;
        let m30 = -(l30 + l31 * m10 + l32 * m20);
        let m31 = -(l31 + l32 * m21);
        let m32 = -l32;
        [
            id0 + m10 * m10 * id1 + m20 * m20 * id2 + m30 * m30 * id3,
            id1 + m21 * m21 * id2 + m31 * m31 * id3,
            id2 + m32 * m32 * id3,
            id3,
        ]
    }
}

/// The start: the peak, the power-1 CoG, flux and second moments of the `start_box` around
/// it. `None`: no usable peak or no positive flux in the box. `CLEAN` (no excluded pixel):
/// the peak by one walk of the pixel bits and the box by row slices, as the held path's
/// start; else [`Prepared::peak`] and the box's usable pixels.
fn start<const CLEAN: bool>(p: &Prepared<'_>, level_e: f32, start_box: u8) -> Option<Start> {
    let peak = if CLEAN {
        super::peak_clean(p)?
    } else {
        p.peak()?
    };
    let (bx, clipped) = p.box_around(peak.0, peak.1, start_box);
    // Moments about the peak pixel, so the sums keep their precision.
    let (pc, pr) = (f32::from(peak.0), f32::from(peak.1));
    let (mut s0, mut sc, mut sr, mut scc, mut srr) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    if CLEAN {
        let w = usize::from(p.width).max(1);
        let mut dr = f32::from(bx.row0) - pr;
        for row in bx.row0..=bx.row1 {
            let first = usize::from(row) * w;
            let line = p
                .pixels
                .get(first + usize::from(bx.col0)..=first + usize::from(bx.col1))?;
            let (mut rs, mut rc, mut rcc, mut dc) =
                (0.0f32, 0.0f32, 0.0f32, f32::from(bx.col0) - pc);
            for e in line {
                let f = e.to_bits() as f32 * (1.0 / 64.0) - level_e;
                let fc = f * dc;
                rs += f;
                rc += fc;
                rcc += fc * dc;
                dc += 1.0;
            }
            s0 += rs;
            sc += rc;
            scc += rcc;
            let fr = rs * dr;
            sr += fr;
            srr += fr * dr;
            dr += 1.0;
        }
    } else {
        for (c, r, f) in p.box_pixels(bx) {
            let (dc, dr) = (f32::from(c) - pc, f32::from(r) - pr);
            let (fc, fr) = (f * dc, f * dr);
            s0 += f;
            sc += fc;
            sr += fr;
            scc += fc * dc;
            srr += fr * dr;
        }
    }
    if s0.is_nan() || s0 <= 0.0 {
        return None;
    }
    let inv = 1.0 / s0;
    let (mx, my) = (sc * inv, sr * inv);
    let var = 0.5 * (scc * inv - mx * mx + srr * inv - my * my) - 1.0 / 12.0;
    Some(Start {
        peak,
        theta: (pc + mx, pr + my, s0, math::sqrt(var)),
        clipped,
    })
}

/// [`start`]'s result: the peak pixel, `(x, y, N, s)` (`s` 0 when the moments gave no
/// positive variance) and whether the box was clipped.
struct Start {
    peak: (u16, u16),
    theta: (f32, f32, f32, f32),
    clipped: bool,
}

/// A Gaussian prior on `s`: the model's `s` and the information `1 / sigma_s^2`.
#[derive(Clone, Copy)]
struct Prior {
    s_model: f32,
    info: f32,
}

/// The width fit of a prepared window (see the module docs), free or with a prior.
fn fit<const CLEAN: bool>(
    p: &Prepared<'_>,
    params: &WidthFitParams,
    prior: Option<Prior>,
) -> PsfFit {
    fit_z::<CLEAN>(p, params, prior).0
}

/// [`fit`] and, with a prior, the mismatch statistic `|z|` of the star's own width against
/// the model's (0 without a prior or a converged fit).
fn fit_z<const CLEAN: bool>(
    p: &Prepared<'_>,
    params: &WidthFitParams,
    prior: Option<Prior>,
) -> (PsfFit, f32) {
    let give_up = |peak: Option<(u16, u16)>, extra: CentroidFlags| {
        let c = peak.and_then(|(pc, pr)| {
            let (bx, _) = p.box_around(pc, pr, params.start_box);
            cog_in_box(p, bx, (pc, pr), CogPower::One)
        });
        let f = PsfFit::unfitted(match c {
            Some(m) => p.finish(m, extra | CentroidFlags::NOT_CONVERGED),
            None => p.degenerate(extra),
        });
        (f, 0.0)
    };
    let Some(Start {
        peak,
        theta: (x0, y0, flux0, s0),
        clipped,
    }) = start::<CLEAN>(p, p.bg.level_e(), params.start_box)
    else {
        return give_up(p.peak(), CentroidFlags::empty());
    };
    let mut extra = if clipped {
        CentroidFlags::EDGE_CLIPPED
    } else {
        CentroidFlags::empty()
    };
    if p.width > MAX_WIDTH_FIT_SIDE || p.height > MAX_WIDTH_FIT_SIDE {
        return give_up(Some(peak), extra);
    }
    let max_s = 0.5 * f32::from(p.width.max(p.height));
    let mut prof = [[0.0f32; M]; 6];
    // The border's median is robust; its MAD's variance is noisy: the variance from the
    // border's clipped sample variance instead.
    // `border`: the pixels the variance came from (0: given), for the chi2's limit.
    let (bg, mut border) = match params.background {
        Background::PerimeterMedian => clipped_variance::<CLEAN>(p, &prof, 0.0, p.bg),
        Background::PerimeterMean => {
            let mut k = 0u16;
            border_walk::<CLEAN>(p, &prof, 0.0, |_| k += 1);
            (p.bg, k)
        }
        Background::Given { .. } => (p.bg, 0),
    };
    let (mut level_e, mut var1) = (bg.level_e(), bg.variance_e2 + 1.0);
    // With a prior the model's width starts the fit (and the moments' only the free one).
    let s_start = match prior {
        Some(pr) => pr.s_model.clamp(MIN_SIGMA_PX, max_s),
        None => s0.clamp(MIN_START_SIGMA_PX, max_s),
    };
    let it = Iteration {
        params,
        prior,
        max_s,
    };
    let Some(mut sol) = it.run::<CLEAN>(p, (level_e, var1), (x0, y0, flux0, s_start), &mut prof)
    else {
        return give_up(Some(peak), extra);
    };
    // The border (the background's source when not given) holds the star's wings: its
    // median was biased high and its spread taken for noise. Once, the background from the
    // border's residuals to the fitted star, and the fit again from where it stopped.
    if sol.converged
        && !matches!(params.background, Background::Given { .. })
        && wings_on_border(p, &prof, sol.theta.2) > WINGS_REFIT * math::sqrt(var1)
        && let Some((bg, k)) = border_residuals::<CLEAN>(p, &prof, sol.theta.2)
    {
        (level_e, var1, border) = (bg.level_e(), bg.variance_e2 + 1.0, k);
        let one = Iteration {
            params: &WidthFitParams {
                max_iterations: 1,
                ..*params
            },
            ..it
        };
        let Some(again) = one.run::<CLEAN>(p, (level_e, var1), sol.theta, &mut prof) else {
            return give_up(Some(peak), extra);
        };
        // One Gauss-Newton step from the solution (the new background moves it little):
        // the covariance from the step's start.
        let Solved {
            theta,
            last,
            prev,
            pinned,
            ..
        } = again;
        sol = Solved {
            theta,
            converged: true,
            last: last.or(prev),
            prev: None,
            pinned,
        };
    }
    let Solved {
        theta,
        converged,
        mut last,
        mut pinned,
        ..
    } = sol;
    if !converged {
        extra |= CentroidFlags::NOT_CONVERGED;
    }
    if last.is_none() {
        let mut nrm = normal::<CLEAN>(p, level_e, var1, theta, &mut prof);
        if let Some(pr) = prior {
            nrm.add_prior(pr, theta.3);
        }
        pinned = theta.3 <= MIN_SIGMA_PX && nrm.b[3] <= 0.0;
        if pinned {
            nrm.pin_width();
        }
        last = Ldl4::new(nrm.a).map(|f| (f, nrm.chi2, nrm.n));
    }
    let Some((f, chi2, n)) = last else {
        return give_up(Some(peak), extra);
    };
    let [vx, vy, vn, vs] = f.inverse_diagonal();
    let dof = n.saturating_sub(4);
    let chi2_dof = if dof > 0 { chi2 / f32::from(dof) } else { 0.0 };
    if chi2_dof > chi2_dof_limit_border(dof, border, params.chi2_flag_z) || !chi2_dof.is_finite() {
        extra |= CentroidFlags::POOR_FIT;
    }
    let (x, y, flux, s) = theta;
    let snr = flux / math::sqrt(vn).max(f32::MIN_POSITIVE);
    if sigma_unreliable(s, math::sqrt(vs), snr, prior.is_some()) {
        extra |= CentroidFlags::SIGMA_UNRELIABLE;
    }
    let m = Measured {
        col: x,
        row: y,
        flux_e: flux,
        snr,
        sigma_col: math::sqrt(vx),
        sigma_row: math::sqrt(vy),
    };
    let finite = |v: f32| if v.is_finite() { v } else { 0.0 };
    let z = match prior {
        Some(pr) if converged => mismatch_z(pr, s, vs, pinned),
        _ => 0.0,
    };
    let f = PsfFit {
        centroid: p.finish(m, extra),
        psf_a_px: finite(s / SQRT_031),
        sigma_psf_a_px: finite(math::sqrt(vs) / SQRT_031),
        chi2_dof: finite(chi2_dof),
    };
    (f, finite(z))
}

/// The border's brightest pixel's share of the fitted star over the background's noise
/// above which the background is estimated again from the border's residuals (0.5: a wing
/// of half the noise moves the border's median and widens its MAD by a few per cent).
const WINGS_REFIT: f32 = 0.5;

/// The Gauss-Newton iteration's fixed inputs.
struct Iteration<'a> {
    params: &'a WidthFitParams,
    prior: Option<Prior>,
    max_s: f32,
}

/// Where [`Iteration::run`] stopped: the parameters, whether it converged, the last
/// factor with its `chi2` and usable pixels (when converged) and whether `s` was pinned.
struct Solved {
    theta: (f32, f32, f32, f32),
    converged: bool,
    last: Option<(Ldl4, f32, u16)>,
    /// The last step's factor, converged or not.
    prev: Option<(Ldl4, f32, u16)>,
    pinned: bool,
}

impl Iteration<'_> {
    /// Gauss-Newton steps from `theta` with the background `(level_e, var1)` held; `None`
    /// when a step leaves the window or the matrix is not positive definite (give up). The
    /// profiles are left at the last step's start.
    fn run<const CLEAN: bool>(
        &self,
        p: &Prepared<'_>,
        (level_e, var1): (f32, f32),
        mut theta: (f32, f32, f32, f32),
        prof: &mut Profiles,
    ) -> Option<Solved> {
        let (wmax, hmax) = (f32::from(p.width) - 0.5, f32::from(p.height) - 0.5);
        let tol = self.params.tolerance_px;
        let mut pinned = false;
        let mut prev = None;
        for _ in 0..self.params.max_iterations {
            let mut nrm = normal::<CLEAN>(p, level_e, var1, theta, prof);
            if let Some(pr) = self.prior {
                nrm.add_prior(pr, theta.3);
            }
            // A star narrower than the floor: `s` held there while chi2 wants it lower.
            pinned = theta.3 <= MIN_SIGMA_PX && nrm.b[3] <= 0.0;
            if pinned {
                nrm.pin_width();
            }
            let f = Ldl4::new(nrm.a)?;
            let [dx, dy, dn, ds] = f.solve(nrm.b);
            let (sx, sy) = (dx.clamp(-1.0, 1.0), dy.clamp(-1.0, 1.0));
            let half = 0.5 * theta.3;
            let s_new = (theta.3 + ds.clamp(-half, half)).clamp(MIN_SIGMA_PX, self.max_s);
            let ss = s_new - theta.3;
            theta = (theta.0 + sx, theta.1 + sy, theta.2 + dn, s_new);
            let (x, y, flux, s) = theta;
            if !step_usable(x, y, flux, wmax, hmax) || !s.is_finite() {
                return None;
            }
            let done = if sx.abs() < tol && sy.abs() < tol && ss.abs() < S_TOLERANCE_FACTOR * tol {
                true
            } else if self.params.tolerance_sigmas > 0.0 {
                // Faint stars: Gauss-Newton converges only linearly (the noise's curvature
                // term it leaves out), so stop once every step is a small fraction of its own
                // error.
                let [vx, vy, _, vs] = f.inverse_diagonal();
                let t2 = self.params.tolerance_sigmas * self.params.tolerance_sigmas;
                sx * sx < t2 * vx && sy * sy < t2 * vy && ss * ss < t2 * vs
            } else {
                false
            };
            if done {
                return Some(Solved {
                    theta,
                    converged: true,
                    last: Some((f, nrm.chi2, nrm.n)),
                    prev: None,
                    pinned,
                });
            }
            // The chi2 the linearised model predicts after the full step (`chi2 - b . d`):
            // the one-step refit's goodness of fit at its end, not at its start.
            let [b0, b1, b2, b3] = nrm.b;
            let fall = b0 * dx + b1 * dy + b2 * dn + b3 * ds;
            prev = Some((f, (nrm.chi2 - fall).max(0.0), nrm.n));
        }
        Some(Solved {
            theta,
            converged: false,
            last: None,
            prev,
            pinned,
        })
    }
}

/// The fitted star's largest share of a border pixel, e- (flux `n`, the profiles of
/// [`normal`]): the brightest edge column's or row's fraction times the other axis' peak.
fn wings_on_border(p: &Prepared<'_>, prof: &Profiles, n: f32) -> f32 {
    let [px, _, _, py, _, _] = prof;
    let (w, h) = (usize::from(p.width), usize::from(p.height));
    let ends = |v: &[f32], len: usize| {
        let a = v.first().copied().unwrap_or(0.0);
        let b = v.get(len.saturating_sub(1)).copied().unwrap_or(0.0);
        a.max(b)
    };
    let peak = |v: &[f32], len: usize| v.iter().take(len).fold(0.0f32, |m, &x| m.max(x));
    n * (ends(px, w) * peak(py, h)).max(ends(py, h) * peak(px, w))
}

/// Calls `each` with `pixel - star` (bits, 1/64 e-) of every usable border pixel, the star of
/// flux `n` on the profiles of [`normal`] (`n` 0: the pixels themselves).
fn border_walk<const CLEAN: bool>(
    p: &Prepared<'_>,
    prof: &Profiles,
    n: f32,
    mut each: impl FnMut(i32),
) {
    let [px, _, _, py, _, _] = prof;
    let (w, h) = (p.width, p.height);
    for r in 0..h {
        let fy = py.get(usize::from(r)).copied().unwrap_or(0.0);
        let edge_row = r == 0 || r + 1 == h;
        let step = if edge_row {
            1
        } else {
            w.saturating_sub(1).max(1)
        };
        let mut c = 0u16;
        while c < w {
            let i = usize::from(r) * usize::from(w) + usize::from(c);
            if CLEAN || p.usable(i) {
                let star_bits = if n > 0.0 {
                    let fx = px.get(usize::from(c)).copied().unwrap_or(0.0);
                    (n * fx * fy * 64.0) as i32
                } else {
                    0
                };
                let e = p.pixels.get(i).map_or(0, |e| e.to_bits());
                each(e.saturating_sub(star_bits));
            }
            c += step;
        }
    }
}

/// Border pixels further than this many sigmas (the MAD's) from the level are left out of
/// [`clipped_variance`] (a hot pixel, a cosmic ray): at 4 sigmas a Gaussian loses 0.006 %
/// of its samples and 0.1 % of its variance.
const CLIP_SIGMAS: f32 = 4.0;

/// The background estimate with its variance from the border's sample variance about the
/// held level (`pixel - star` as [`border_walk`]), clipped at [`CLIP_SIGMAS`] of the MAD's
/// sigma (`bg.variance_e2`): the MAD's variance of 16-24 pixels is itself noisy (relative
/// error ~24 % on sigma for 24 pixels, against ~15 % for the sample variance), and at low SNR
/// the position's sigma scales with it, so the pulls were ~7 % high. Unchanged when fewer
/// than 2 pixels pass. With the number of pixels the variance came from.
fn clipped_variance<const CLEAN: bool>(
    p: &Prepared<'_>,
    prof: &Profiles,
    n: f32,
    bg: BackgroundEstimate,
) -> (BackgroundEstimate, u16) {
    let clip = CLIP_SIGMAS * math::sqrt(bg.variance_e2) * 64.0;
    let (mut ss, mut k, mut all) = (0.0f32, 0u16, 0u16);
    let level = bg.level_bits;
    border_walk::<CLEAN>(p, prof, n, |b| {
        let d = (i64::from(b) - level) as f32;
        all += 1;
        if d.abs() <= clip {
            ss += d * d;
            k += 1;
        }
    });
    if k < 2 {
        return (bg, all);
    }
    let var = ss / (f32::from(k - 1) * 4096.0);
    let est = BackgroundEstimate {
        variance_e2: var,
        level_variance_e2: var * core::f32::consts::FRAC_PI_2 / f32::from(all.max(1)),
        ..bg
    };
    (est, k)
}

/// The background from the border's residuals to the fitted star (flux `n`, the profiles
/// of [`normal`]): the median of `pixel - star` over the border's usable pixels, the
/// variance as [`clipped_variance`], with its pixel count. `None` for an empty border.
fn border_residuals<const CLEAN: bool>(
    p: &Prepared<'_>,
    prof: &Profiles,
    n: f32,
) -> Option<(BackgroundEstimate, u16)> {
    let mut ring = [0i32; 4 * M];
    let mut k = 0usize;
    border_walk::<CLEAN>(p, prof, n, |b| {
        if let Some(slot) = ring.get_mut(k) {
            *slot = b;
            k += 1;
        }
    });
    let bg = crate::centroid::background::median_estimate(ring.get_mut(..k)?)?;
    Some(clipped_variance::<CLEAN>(p, prof, n, bg))
}

/// `|z|` of the star's own width against the model's, from the MAP fit: with `I` the
/// data's information on `s` (the last pivot of the normal matrix less the prior's) and
/// `I_p` the prior's, the width-free fit's `s` would differ from the model's by
/// `(s_map - s_model) (I + I_p) / I`, whose variance (fit and model) is `1 / I + 1 / I_p`:
/// `z^2 = (s_map - s_model)^2 I I_p / (I + I_p)`. A width held at the floor (`pinned`: the
/// data wants it narrower still) counts as fully determined (`I` infinite).
fn mismatch_z(pr: Prior, s: f32, vs: f32, pinned: bool) -> f32 {
    let d = s - pr.s_model;
    let data = if pinned {
        f32::INFINITY
    } else {
        1.0 / vs - pr.info
    };
    let z2 = if data.is_nan() || data <= 0.0 {
        0.0
    } else if data.is_infinite() {
        d * d * pr.info
    } else {
        d * d * data * pr.info / (data + pr.info)
    };
    math::sqrt(z2)
}
