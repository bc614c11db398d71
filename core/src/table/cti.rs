//! The charge-transfer (CTI) coefficients of table section 8: the centroid shift that charge
//! traps cause, per transfer and per output, and its signal law. What the shift is and how a
//! centroid is corrected with it is told in [`crate::calib::cti`]; this module holds the byte
//! format and its checks.
//!
//! # Format (read once into [`CtiCoeffs`], 12 + 8 x outputs bytes)
//! ```text
//! 0  u32  reference flux F_ref, e- (integer, > 0)
//! 4  u32  flux offset F_0, e- (integer): the background's share of the trap filling
//! 8  u16  signal exponent alpha, U0F16 (0 <= alpha < 1): the shift scales as
//!         ((F + F_0) / F_ref)^-alpha
//! 10 u16  reserved, 0
//! 12 per output (left first): u32 parallel shift per transfer, u32 serial shift per transfer,
//!    both U0F32 px at F + F_0 = F_ref (0 <= s < 1 px; resolution 2.3e-10 px)
//! ```
//! Cost: read once per frame ([`super::CalibTable::cti`]), 12 + 8 x outputs bytes.

use super::bytes::{u16_at, u32_at};
use crate::geometry::MAX_OUTPUTS;
use fixed::types::{U0F16, U0F32};

/// Size of the CTI section's own header (reference flux, flux offset, exponent, reserved).
pub const CTI_HEADER_LEN: usize = 12;
/// Size of one output's coefficients (parallel, serial).
pub const CTI_OUTPUT_LEN: usize = 8;

/// The shift per transfer of one output's charge, at the reference flux.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CtiOutput {
    /// Centroid shift per parallel (line) transfer, px, along +y (the deferred charge
    /// trails into lines read later).
    pub parallel_px: U0F32,
    /// Centroid shift per serial (register) transfer, px, away from this output's amplifier.
    pub serial_px: U0F32,
}

/// The CTI coefficients of a table (section 8).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CtiCoeffs {
    /// Flux at which the per-transfer shifts hold, e- (> 0).
    pub reference_flux_e: u32,
    /// Flux offset `F_0`, e-: the background fills traps too, so a faint star's shift levels
    /// off instead of growing as `F^-alpha`.
    pub flux_offset_e: u32,
    /// Signal exponent: the shift scales as `((F + F_0) / F_ref)^-alpha` (U0F16,
    /// `0 <= alpha < 1`).
    pub alpha: U0F16,
    /// Coefficients per output (left first); entries past the geometry's outputs are 0.
    pub outputs: [CtiOutput; MAX_OUTPUTS],
}

impl CtiCoeffs {
    /// Bytes the section takes for `outputs` outputs.
    pub const fn encoded_len(outputs: usize) -> usize {
        CTI_HEADER_LEN + CTI_OUTPUT_LEN * outputs
    }

    /// Reads the section for a geometry of `outputs` outputs. Errors: the length does not
    /// match (`Length`), a reserved field is not 0 (`Reserved`), the reference flux is 0
    /// (`Range`).
    pub(crate) fn parse(b: &[u8], outputs: u8) -> Result<Self, CtiFormatError> {
        let n = usize::from(outputs).min(MAX_OUTPUTS);
        if b.len() != Self::encoded_len(n) {
            return Err(CtiFormatError::Length);
        }
        let reference_flux_e = u32_at(b, 0).ok_or(CtiFormatError::Length)?;
        if reference_flux_e == 0 {
            return Err(CtiFormatError::Range);
        }
        let flux_offset_e = u32_at(b, 4).ok_or(CtiFormatError::Length)?;
        let alpha = U0F16::from_bits(u16_at(b, 8).ok_or(CtiFormatError::Length)?);
        if u16_at(b, 10) != Some(0) {
            return Err(CtiFormatError::Reserved);
        }
        let mut out = [CtiOutput::default(); MAX_OUTPUTS];
        for (i, o) in out.iter_mut().enumerate().take(n) {
            let at = CTI_HEADER_LEN + CTI_OUTPUT_LEN * i;
            *o = CtiOutput {
                parallel_px: U0F32::from_bits(u32_at(b, at).ok_or(CtiFormatError::Length)?),
                serial_px: U0F32::from_bits(u32_at(b, at + 4).ok_or(CtiFormatError::Length)?),
            };
        }
        Ok(Self {
            reference_flux_e,
            flux_offset_e,
            alpha,
            outputs: out,
        })
    }

    /// Appends the section's bytes for `outputs` outputs to `put`.
    pub(crate) fn write(&self, outputs: u8, mut put: impl FnMut(&[u8])) {
        put(&self.reference_flux_e.to_le_bytes());
        put(&self.flux_offset_e.to_le_bytes());
        put(&self.alpha.to_bits().to_le_bytes());
        put(&0u16.to_le_bytes());
        for o in self
            .outputs
            .iter()
            .take(usize::from(outputs).min(MAX_OUTPUTS))
        {
            put(&o.parallel_px.to_bits().to_le_bytes());
            put(&o.serial_px.to_bits().to_le_bytes());
        }
    }
}

/// What is wrong with a CTI section (mapped to [`super::TableError`] by the parser).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum CtiFormatError {
    Length,
    Reserved,
    Range,
}
