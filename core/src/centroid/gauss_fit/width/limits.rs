//! When the width fit's numbers are not to be trusted: the goodness-of-fit limits that set
//! [`CentroidFlags::POOR_FIT`](crate::centroid::CentroidFlags::POOR_FIT) and the rule that
//! sets [`CentroidFlags::SIGMA_UNRELIABLE`](crate::centroid::CentroidFlags::SIGMA_UNRELIABLE).
//! Closed forms: a cube root's worth of arithmetic and one square root per star.

use super::params::SQRT_031;
use crate::centroid::math;

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
