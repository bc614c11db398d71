//! The fixed-point formats of every calibrated quantity, with their units and ranges.
//!
//! `IaFb` / `UaFb` are the `fixed` crate's types: a integer bits (sign included for `I`),
//! b fraction bits, resolution 2^-b. Ranges below are the ones this crate guarantees, which
//! may be narrower than the type's; the bounds are what the overflow proofs in
//! [`crate::calib::formula`] rely on.
//!
//! | quantity | type | unit | range | resolution |
//! |---|---|---|---|---|
//! | raw sample | `u16` | ADU | 0..=65535 | 1 |
//! | line bias level | [`BiasAdu`] = U28F4 | ADU | 0..=65535 | 1/16 |
//! | column bias offset | [`ColumnBiasAdu`] = I12F4 | ADU | -2048..2048 | 1/16 |
//! | output gain | [`GainEPerAdu`] = U4F28 | e-/ADU | (0, 16) | 2^-28 |
//! | relative dark | [`DarkRel`] = U2F6 | 1 (covered mean = 1) | 0..4 | 1/64 |
//! | inverse flat | [`FlatInv`] = U2F14 | 1 (1/flat) | (0, 4) | 2^-14 |
//! | dark scale | [`Electrons`] = I26F6 | e- | ±[`DARK_SCALE_LIMIT_E`] | 1/64 |
//! | calibrated pixel | [`Electrons`] = I26F6 | e- | ±2^25 (actual bound ±21.1 M) | 1/64 |

use fixed::types::{I12F4, I26F6, U2F6, U2F14, U4F28, U28F4};

/// Electrons, signed (noise takes calibrated values below zero). I26F6: ±33.5 M e-,
/// resolution 1/64 e-. Calibrated pixels are bounded by ±21.1 M e- for any input.
pub type Electrons = I26F6;

/// A line's bias level in ADU, measured on the over-scan. U28F4 limited to 0..=65535.
pub type BiasAdu = U28F4;

/// A column's bias offset from the line's over-scan level, in ADU. I12F4: -2048..2048,
/// resolution 1/16 ADU.
pub type ColumnBiasAdu = I12F4;

/// An output's conversion gain in electrons per ADU. U4F28: 0..16 (0 is rejected), resolution
/// 2^-28 e-/ADU (a relative error below 1e-7 at the CCD47-20's ~1.5 e-/ADU).
pub type GainEPerAdu = U4F28;

/// A pixel's dark signal relative to the covered pixels' mean (1.0 = same as covered).
/// U2F6: 0..3.984, resolution 1/64. Brighter pixels belong in the hot-pixel list.
pub type DarkRel = U2F6;

/// The inverse of a pixel's flat-field response (1.0 = nominal). U2F14: 2^-14..4, resolution
/// 2^-14 (6e-5). Stored inverted so calibration multiplies instead of divides. 0 is rejected.
pub type FlatInv = U2F14;

/// The largest magnitude of a dark scale: 2^20 e- (the largest signal a 16-bit sample can
/// hold at the largest gain is 65535 x 16 = 1,048,560 e-).
pub const DARK_SCALE_LIMIT_E: Electrons = Electrons::from_bits(1 << 26);

/// A temperature in kelvin, U16F16 (0..65536 K, resolution 1.5e-5 K).
pub type Kelvin = fixed::types::U16F16;

/// A dark rate in electrons per second, U16F16 (0..65536 e-/s).
pub type ERatePerS = fixed::types::U16F16;
