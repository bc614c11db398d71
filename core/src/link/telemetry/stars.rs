//! A frame's star list `TM[134,1]`: its field table ([`STAR_FIELDS`]) and its encoder
//! ([`encode_stars`]), with the fixed-point units of its width and goodness-of-fit fields.
//! A few stores a field; a full list is [`MAX_LINK_STARS`] stars of
//! [`STAR_BYTES`](super::super::protocol::STAR_BYTES) each.

use super::super::command::mode_number;
use super::super::protocol::{MAX_LINK_STARS, STAR_LIST_FORMAT};
use super::fields::Writer;
use crate::tracker::{Mode, StarRecord};

/// Every field of one star in a star list: name, type, meaning.
pub const STAR_FIELDS: [(&str, &str, &str); 10] = [
    ("x_px", "f32", "column, px"),
    ("y_px", "f32", "row, px"),
    ("flux_e", "f32", "background-subtracted signal, e-"),
    ("snr", "f32", "SNR of flux_e"),
    ("sigma_x_px", "f32", "1-sigma error of x_px, px"),
    ("sigma_y_px", "f32", "1-sigma error of y_px, px"),
    (
        "flags",
        "u32",
        "StarFlags bits: quality, 0 = clean (docs/formats.md)",
    ),
    (
        "provenance",
        "u8",
        "Provenance bits: how it was found and measured (docs/formats.md)",
    ),
    (
        "psf_a_mpx",
        "u16",
        "the star's fitted PSF 80 % radius, 0.001 px (0 to 65.535 px, saturating; 0: not measured)",
    ),
    (
        "chi2_dof_centi",
        "u16",
        "the fit's chi2 per degree of freedom, 0.01 (0 to 655.35, saturating; 0: not measured)",
    ),
];

/// `v / unit` rounded to a `u16`, saturating (0 for NaN or negative): the star list's
/// fixed-point fields.
fn to_u16(v: f32, unit: f32) -> u16 {
    let q = v / unit + 0.5;
    if q.is_nan() || q < 0.0 {
        0
    } else if q >= 65_535.0 {
        u16::MAX
    } else {
        q as u16
    }
}

/// Units of the star list's fixed-point fields.
pub(super) const PSF_A_UNIT_PX: f32 = 0.001;
pub(super) const CHI2_DOF_UNIT: f32 = 0.01;

/// Writes a star list's source data: frame u32, mode u8, format u8
/// ([`STAR_LIST_FORMAT`](super::super::protocol::STAR_LIST_FORMAT)), count u8, the stars.
pub fn encode_stars(frame: u32, mode: Mode, stars: &[StarRecord], out: &mut [u8]) -> Option<usize> {
    let stars = stars.get(..stars.len().min(MAX_LINK_STARS))?;
    let mut w = Writer::new(out);
    w.u32(frame)
        .u8(mode_number(mode))
        .u8(STAR_LIST_FORMAT)
        .u8(u8::try_from(stars.len()).ok()?);
    for s in stars {
        w.f32(s.x_px)
            .f32(s.y_px)
            .f32(s.flux_e)
            .f32(s.snr)
            .f32(s.sigma_x_px)
            .f32(s.sigma_y_px)
            .u32(s.flags.bits())
            .u8(s.provenance.bits())
            .u16(to_u16(s.psf_a_px, PSF_A_UNIT_PX))
            .u16(to_u16(s.chi2_dof, CHI2_DOF_UNIT));
    }
    w.finish()
}
