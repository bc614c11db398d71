//! The calibration formula on fixed-point bits, shared by the per-pixel calibration
//! (`pixel.rs`), the dark-scale estimate (`levels.rs`), the raw pre-filter of the
//! scan and the fused raw centre of gravity, so that all of them compute the same bits.
//!
//! ```text
//! electrons = ((raw - bias_level - column_bias) * gain_output - dark_rel * dark_scale) * flat_inv
//! ```
//! Dark charge does not pass through the photo-response, so it comes off before the flat.
//! `dark_rel * dark_scale` is the paper's dark pre-calculation: the stored map is relative to
//! the covered pixels and `dark_scale` is this frame's covered-pixel signal in electrons, so
//! no temperature is needed for normal pixels.
//!
//! # Fixed-point arithmetic and why it cannot overflow
//! With the formats of [`crate::units`], for any raw sample and any table or levels value:
//! - `d = 16 raw - 16 bias - 16 column_bias` (1/16 ADU): |d| < 2^20 + 2^15 < 2^21, i32.
//! - `s = d * gain_bits` (2^-32 e-): |s| < 2^21 * 2^32 = 2^53, i64; then >> 16 (2^-16 e-),
//!   truncation error < 2^-16 e-.
//! - `k = dark_rel_bits * dark_scale_bits << 4` (2^-16 e-): |k| < 2^8 * 2^26 * 2^4 = 2^38.
//! - `(s - k) * flat_inv_bits` (2^-30 e-): < (2^37 + 2^38) * 2^16 < 2^55, i64.
//! - rounded >> 24 to I26F6: |result| <= (65535+2048) * 16 + 4 * 2^20) * 4 e- = 21.1 M e-
//!   = 1.35e9 LSB < 2^31, i32.
//!
//! The result differs from the exact value of the same formula (with the table's quantised
//! values) by at most [`QUANTISATION_E`]. Host property tests check this over the full range.
//!
//! # Cost
//! Per pixel one 32x32->64 multiply, one 64x16 multiply and shifts (no clamp: the bound
//! above); every function here is inlined into its caller's loop.

use crate::units::{BiasAdu, ColumnBiasAdu, DarkRel, FlatInv, GainEPerAdu};

/// Largest difference between a calibrated pixel and the exact (f64) value of the formula
/// with the same table values: 1/64 e- of output rounding (1/128) plus the truncation of the
/// signal term (2^-16 e-) times the inverse flat (< 4).
pub const QUANTISATION_E: f64 = 1.0 / 128.0 + 4.0 / 65536.0;

/// `16 * (bias + column_bias)` as i32 (1/16 ADU).
#[inline(always)]
pub(crate) fn offset_16ths(bias: BiasAdu, column_bias: ColumnBiasAdu) -> i32 {
    // bias <= 65535 * 16 < 2^20 (from a u16 median): the cast keeps the value.
    (bias.to_bits().min(65535 * 16) as i32) + i32::from(column_bias.to_bits())
}

/// `(raw - offset) * gain` in I26F6 bits, rounded (used for the covered pixels, which have no
/// flat or dark correction of their own).
#[inline(always)]
pub(crate) fn signal_bits(raw: u16, offset_16ths: i32, gain: GainEPerAdu) -> i32 {
    let d = (i32::from(raw) << 4) - offset_16ths;
    let s = i64::from(d) * i64::from(gain.to_bits());
    ((s + (1 << 25)) >> 26) as i32
}

/// The calibration formula on bits; see the module docs for the bounds.
#[inline(always)]
pub(crate) fn pixel_bits(
    raw: u16,
    offset_16ths: i32,
    gain: GainEPerAdu,
    dark_16: i64,
    flat: FlatInv,
) -> i32 {
    pixel_bits_d((i32::from(raw) << 4) - offset_16ths, gain, dark_16, flat)
}

/// The calibration formula from `d = 16 raw - offset` (1/16 ADU, |d| < 2^21): monotone
/// non-decreasing in `d` (positive gain and inverse flat, floor shifts, clamp), which the
/// raw pre-filter of `detect::prefilter` relies on.
#[inline(always)]
pub(crate) fn pixel_bits_d(d: i32, gain: GainEPerAdu, dark_16: i64, flat: FlatInv) -> i32 {
    let s = (i64::from(d) * i64::from(gain.to_bits())) >> 16;
    let e = (s - dark_16) * i64::from(flat.to_bits());
    // No clamp: the module docs prove |result| <= 1.35e9 < 2^31 for every input (the regular
    // dark term is below 2^38 in 2^-16 e-, the hot-pixel one below HOT_DARK_LIMIT_E), so the
    // cast keeps the value; the calibration property tests check the extremes.
    ((e + (1 << 23)) >> 24) as i32
}

/// The regular dark term in 2^-16 e-.
#[inline(always)]
pub(crate) fn dark_16ths(rel: DarkRel, dark_scale_bits: i32) -> i64 {
    (i64::from(rel.to_bits()) * i64::from(dark_scale_bits)) << 4
}
