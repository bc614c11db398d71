//! The dark-law section (kind 11): the covered pixels' mean dark rate at a reference
//! temperature, its doubling temperature and the band the tracker's dark ratio may move in,
//! so that a table built from lab frames (`startrack calib frames`) arms the tracker's dark
//! drift check in flight without any code in the home. Reading it costs five integer loads
//! and four range checks at parse time; the [`DarkLaw`] it yields is 16 bytes.
//!
//! # Layout (16 bytes, little-endian)
//!
//! | offset | type | field | format, range, resolution |
//! |---|---|---|---|
//! | 0 | u32 | covered dark rate at `T_ref` | U16F16 e-/px/s, > 0, 1.5e-5 e-/px/s |
//! | 4 | u32 | reference temperature `T_ref` | U16F16 K, 100..=400 K, 1.5e-5 K |
//! | 8 | u16 | doubling temperature | U8F8 K, 2..=20 K, 0.004 K |
//! | 10 | u16 | band low (ratio measured/predicted) | U8F8, < band high, 0.004 |
//! | 12 | u16 | band high | U8F8, > band low |
//! | 14 | u16 | reserved | 0 |
//!
//! A field out of its range is [`TableError::OutOfRange`] with `index` the field's number:
//! 0 rate (zero), 1 reference temperature, 2 doubling temperature, 3 band (low not below
//! high).

use super::bytes::{u16_at, u32_at};
use super::error::{SectionKind, TableError};
use crate::units::{ERatePerS, Kelvin};
use fixed::types::U8F8;

/// Bytes of the dark-law section.
pub const DARK_LAW_SECTION_LEN: usize = 16;
/// The doubling temperatures a stored law may have, K (silicon dark current doubles every
/// 5 to 9 K near room temperature; the range leaves room for other sensors).
pub const DOUBLING_RANGE_K: [u8; 2] = [2, 20];
/// The reference temperatures a stored law may have, K.
pub const REFERENCE_RANGE_K: [u16; 2] = [100, 400];

/// The covered pixels' dark law from the lab, and the band the tracker's dark ratio may
/// move in: `predicted_e = rate x exposure x 2^((T - T_ref) / doubling)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DarkLaw {
    /// Mean dark rate of the covered pixels at `reference_k`, e-/px/s (U16F16).
    pub rate_e_per_s: ERatePerS,
    /// Temperature of `rate_e_per_s`, K (U16F16).
    pub reference_k: Kelvin,
    /// The rate doubles every this many kelvin (U8F8, > 0).
    pub doubling_k: U8F8,
    /// Lowest ratio measured/predicted still in band (U8F8).
    pub band_low: U8F8,
    /// Highest ratio still in band (U8F8).
    pub band_high: U8F8,
}

impl DarkLaw {
    /// The band a law gets when its maker states none: 0.8 to 1.25 (a quarter up or a
    /// fifth down, ten times the ratio's scatter on a frame of the small lab set).
    /// (U8F8 bits: 205/256 = 0.801, 320/256 = 1.25.)
    pub const DEFAULT_BAND: [U8F8; 2] = [U8F8::from_bits(205), U8F8::from_bits(320)];

    /// The dark signal the law predicts after `exposure_ms` at `temperature_k`, e-; `None`
    /// for a zero doubling temperature.
    pub fn predicted_e(&self, temperature_k: Kelvin, exposure_ms: u32) -> Option<f32> {
        if self.doubling_k == U8F8::ZERO {
            return None;
        }
        let dt = temperature_k.to_num::<f32>() - self.reference_k.to_num::<f32>();
        let factor = libm::exp2f((dt / self.doubling_k.to_num::<f32>()).clamp(-64.0, 64.0));
        Some(self.rate_e_per_s.to_num::<f32>() * (exposure_ms as f32 * 1e-3) * factor)
    }

    /// The section's bytes (any law encodes; the parser checks the ranges, so the table
    /// writer rejects a law out of range).
    pub fn encode(&self) -> [u8; DARK_LAW_SECTION_LEN] {
        let mut out = [0u8; DARK_LAW_SECTION_LEN];
        let fields: [(usize, &[u8]); 5] = [
            (0, &self.rate_e_per_s.to_bits().to_le_bytes()),
            (4, &self.reference_k.to_bits().to_le_bytes()),
            (8, &self.doubling_k.to_bits().to_le_bytes()),
            (10, &self.band_low.to_bits().to_le_bytes()),
            (12, &self.band_high.to_bits().to_le_bytes()),
        ];
        for (off, b) in fields {
            if let Some(dst) = out.get_mut(off..off + b.len()) {
                dst.copy_from_slice(b);
            }
        }
        out
    }

    /// The index of the first field out of its documented range (see the module's
    /// layout), or `None` when the law is usable.
    pub fn out_of_range_field(&self) -> Option<u32> {
        let t_ref = self.reference_k;
        let [dlo, dhi] = DOUBLING_RANGE_K;
        let [tlo, thi] = REFERENCE_RANGE_K;
        if self.rate_e_per_s == ERatePerS::ZERO {
            Some(0)
        } else if t_ref < Kelvin::from_num(tlo) || t_ref > Kelvin::from_num(thi) {
            Some(1)
        } else if self.doubling_k < U8F8::from_num(dlo) || self.doubling_k > U8F8::from_num(dhi) {
            Some(2)
        } else if self.band_low >= self.band_high {
            Some(3)
        } else {
            None
        }
    }
}

/// Decodes and checks a section.
pub(crate) fn parse(b: &[u8]) -> Result<DarkLaw, TableError> {
    let k = SectionKind::DarkLaw;
    if b.len() != DARK_LAW_SECTION_LEN {
        return Err(TableError::SectionLength(k));
    }
    let w = |off: usize| u32_at(b, off).ok_or(TableError::SectionLength(k));
    let h = |off: usize| u16_at(b, off).ok_or(TableError::SectionLength(k));
    if h(14)? != 0 {
        return Err(TableError::Reserved);
    }
    let law = DarkLaw {
        rate_e_per_s: ERatePerS::from_bits(w(0)?),
        reference_k: Kelvin::from_bits(w(4)?),
        doubling_k: U8F8::from_bits(h(8)?),
        band_low: U8F8::from_bits(h(10)?),
        band_high: U8F8::from_bits(h(12)?),
    };
    match law.out_of_range_field() {
        Some(index) => Err(TableError::OutOfRange { section: k, index }),
        None => Ok(law),
    }
}
