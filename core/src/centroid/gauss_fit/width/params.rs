//! The width fit's parameters, limits and result: what a caller sets
//! ([`WidthFitParams`], [`WidthPrior`]) and gets back ([`PsfFit`]). Plain values, no cost.

use crate::centroid::{Background, Centroid};

/// Largest window side fitted (the profile buffers' length).
pub const MAX_WIDTH_FIT_SIDE: u16 = 16;
pub(super) const M: usize = MAX_WIDTH_FIT_SIDE as usize;

/// The smallest PSF sigma the fit reports, px (a = 0.45 px): a star narrower than that
/// (or one whose noise says so) is fitted with `s` held at this floor, the position and flux
/// free: below it the pixel's own width hides the star's, the width derivative vanishes and
/// the position's with it when the star sits inside one pixel.
pub const MIN_SIGMA_PX: f32 = 0.25;

/// The width's step threshold over the position's: `s` is worth less to the position than
/// its own step suggests (its error is several times the position's), so it stops at 10x the
/// position tolerance.
pub(super) const S_TOLERANCE_FACTOR: f32 = 10.0;

/// The smallest starting sigma, px (a = 0.72 px): a noisy box's moments can put a star
/// inside one pixel, where the model's position derivatives are steep and the first steps
/// wild; from 0.4 px the fit finds narrower stars in a step or two.
pub(super) const MIN_START_SIGMA_PX: f32 = 0.4;

/// `sqrt(0.31)`: the 80 %-energy radius `a` of a 2-D Gaussian is `s / sqrt(0.31)`.
pub(super) const SQRT_031: f32 = 0.556_776_4;

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

/// Parameters of [`gauss_fit_width`](super::gauss_fit_width).
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
    ///
    /// [`chi2_dof_limit`]: super::chi2_dof_limit
    /// [`CentroidFlags::POOR_FIT`]: crate::centroid::CentroidFlags::POOR_FIT
    pub chi2_flag_z: f32,
    /// With a field PSF model ([`gauss_fit_width_prior`]): the largest `|z|` of the star's
    /// own width against the model's before the star is flagged
    /// [`CentroidFlags::PSF_MISMATCH`] and fitted width-free; [`PSF_MISMATCH_Z`] by default.
    ///
    /// [`gauss_fit_width_prior`]: super::gauss_fit_width_prior
    /// [`CentroidFlags::PSF_MISMATCH`]: crate::centroid::CentroidFlags::PSF_MISMATCH
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
    pub(super) fn unfitted(centroid: Centroid) -> Self {
        Self {
            centroid,
            psf_a_px: 0.0,
            sigma_psf_a_px: 0.0,
            chi2_dof: 0.0,
        }
    }
}

/// A Gaussian prior on `s`: the model's `s` and the information `1 / sigma_s^2`.
#[derive(Clone, Copy)]
pub(super) struct Prior {
    pub(super) s_model: f32,
    pub(super) info: f32,
}
