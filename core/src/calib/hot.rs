//! The dark signal of a hot pixel. Hot pixels do not follow the covered pixels (the paper:
//! "these elements generally have a different temperature dependence"), so each carries its
//! own law: `dark_e = rate_ref x exposure x 2^((T - T_ref) / doubling)`.
//!
//! Computed in f32 on the M7's FPU when a hot pixel falls inside a read window (rare), with
//! `libm::exp2f` (correct to about one ulp; micromath's `powf` is 0.8 % off,
//! hundreds of electrons on a bright hot pixel); relative error below [`HOT_DARK_REL_TOL`].

use crate::table::HotPixel;
use crate::units::{DARK_SCALE_LIMIT_E, Electrons, Kelvin};

/// Relative accuracy of [`hot_dark_e`] against the exact law (tested against f64 in
/// host-tests), on top of the 1/64 e- output resolution.
pub const HOT_DARK_REL_TOL: f32 = 1e-5;

/// Largest hot-pixel dark signal: 4 x 2^20 e-, the same bound as the regular dark term
/// (relative dark < 4 times a dark scale of at most 2^20 e-), which the overflow proof of
/// [`crate::calib::formula`] relies on.
pub(crate) const HOT_DARK_LIMIT_E: Electrons =
    Electrons::from_bits(DARK_SCALE_LIMIT_E.to_bits() * 4 - 1);

/// The dark charge of `hot` after `exposure_ms` at `temperature_k`, given the table's reference
/// temperature; clamped to `0..=HOT_DARK_LIMIT_E`.
pub fn hot_dark_e(
    hot: &HotPixel,
    t_ref_k: Kelvin,
    temperature_k: Kelvin,
    exposure_ms: u32,
) -> Electrons {
    let dt = temperature_k.to_num::<f32>() - t_ref_k.to_num::<f32>();
    let doublings = dt / hot.doubling_k.to_num::<f32>();
    // libm on the host too, so the host computes exactly what the M7 does.
    let factor = libm::exp2f(doublings.clamp(-64.0, 64.0));
    let e = hot.rate_e_per_s.to_num::<f32>() * (exposure_ms as f32 * 1e-3) * factor;
    let lim = HOT_DARK_LIMIT_E.to_num::<f32>();
    // NaN cannot arise (all inputs are finite and the doubling is > 0), but a NaN would clamp
    // to 0 here rather than panic in the conversion.
    let e = if e.is_nan() { 0.0 } else { e.clamp(0.0, lim) };
    Electrons::checked_from_num(e).unwrap_or(Electrons::ZERO)
}
