//! The camera-model section (kind 10): the [`Camera`] that `startrack optics fit` measured,
//! in fixed point, so the firmware turns centroids into directions with the fitted focal
//! length, principal point, distortion and lateral colour. Reading it costs nine integer
//! loads and conversions; the parse-time invertibility check about 160 undistortions.
//!
//! # Layout (36 bytes, little-endian)
//!
//! | offset | type | field | format, range, resolution |
//! |---|---|---|---|
//! | 0 | u32 | focal length | U16F16 px, > 0, 1.5e-5 px |
//! | 4 | i32 | principal point column | I16F16 px, +-32768, 1.5e-5 px |
//! | 8 | i32 | principal point row | I16F16 px |
//! | 12 | i32 | `k1` | I4F28 normalised, +-8, 3.7e-9 |
//! | 16 | i32 | `k2` | I4F28 |
//! | 20 | i32 | `p1` | I4F28 |
//! | 24 | i32 | `p2` | I4F28 |
//! | 28 | i32 | lateral colour scale | I1F31 per mag, +-1, 4.7e-10 |
//! | 32 | i16 | colour reference B-V | millimagnitudes |
//! | 34 | u16 | reserved | 0 |
//!
//! The resolutions are far below what a fit resolves: at the corner of the CCD47-20's 15
//! degree field one step of `k1` moves a star by 3e-8 px, one step of the colour scale by
//! 3e-7 px per magnitude.

use super::bytes::{u16_at, u32_at};
use super::error::{SectionKind, TableError};
use crate::attitude::{Camera, CameraError};
use fixed::types::{I1F31, I4F28, I16F16, U16F16};

/// Bytes of the camera-model section.
pub const CAMERA_SECTION_LEN: usize = 36;

/// The colours a stored model must be invertible for, B-V mag (the Hipparcos stars the
/// catalog holds lie within it).
pub const COLOUR_RANGE_BV_MAG: [f64; 2] = [-0.5, 3.0];

/// The section's bytes for `cam`, or [`CameraError::BadParameter`] when a value does not fit
/// its format (or is not finite, or the focal length is not positive).
pub fn encode(cam: &Camera) -> Result<[u8; CAMERA_SECTION_LEN], CameraError> {
    let bad = CameraError::BadParameter;
    if cam.focal_length_px.is_nan() || cam.focal_length_px <= 0.0 {
        return Err(bad);
    }
    let f = U16F16::checked_from_num(cam.focal_length_px).ok_or(bad)?;
    let q16 = |v: f64| I16F16::checked_from_num(v).ok_or(bad);
    let q28 = |v: f64| I4F28::checked_from_num(v).ok_or(bad);
    let q31 = I1F31::checked_from_num(cam.colour_scale_per_mag).ok_or(bad)?;
    let bv = cam.colour_ref_bv_mag * 1000.0;
    if !(bv.is_finite() && bv.abs() <= f64::from(i16::MAX)) {
        return Err(bad);
    }
    let words: [u32; 8] = [
        f.to_bits(),
        q16(cam.principal_point_px[0])?.to_bits() as u32,
        q16(cam.principal_point_px[1])?.to_bits() as u32,
        q28(cam.k1)?.to_bits() as u32,
        q28(cam.k2)?.to_bits() as u32,
        q28(cam.p1)?.to_bits() as u32,
        q28(cam.p2)?.to_bits() as u32,
        q31.to_bits() as u32,
    ];
    let mut out = [0u8; CAMERA_SECTION_LEN];
    for (chunk, w) in out.chunks_exact_mut(4).zip(words) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    // In range (checked above), so the cast neither wraps nor saturates.
    let bv_mmag = libm::round(bv) as i16;
    if let Some(s) = out.get_mut(32..34) {
        s.copy_from_slice(&bv_mmag.to_le_bytes());
    }
    Ok(out)
}

/// The camera stored in a section's bytes, without the invertibility check.
pub fn decode(b: &[u8]) -> Result<Camera, TableError> {
    let k = SectionKind::CameraModel;
    if b.len() != CAMERA_SECTION_LEN {
        return Err(TableError::SectionLength(k));
    }
    let w = |off: usize| u32_at(b, off).ok_or(TableError::SectionLength(k));
    let i = |off: usize| w(off).map(|v| v as i32);
    if u16_at(b, 34) != Some(0) {
        return Err(TableError::Reserved);
    }
    let bv_mmag = u16_at(b, 32).ok_or(TableError::SectionLength(k))? as i16;
    Ok(Camera {
        focal_length_px: U16F16::from_bits(w(0)?).to_num(),
        principal_point_px: [
            I16F16::from_bits(i(4)?).to_num(),
            I16F16::from_bits(i(8)?).to_num(),
        ],
        k1: I4F28::from_bits(i(12)?).to_num(),
        k2: I4F28::from_bits(i(16)?).to_num(),
        p1: I4F28::from_bits(i(20)?).to_num(),
        p2: I4F28::from_bits(i(24)?).to_num(),
        colour_scale_per_mag: I1F31::from_bits(i(28)?).to_num(),
        colour_ref_bv_mag: f64::from(bv_mmag) / 1000.0,
    })
}

/// Decodes a section and checks that its model is usable over a `cols` x `rows` active
/// area: a positive focal length and a distortion invertible for every colour in
/// [`COLOUR_RANGE_BV_MAG`] ([`Camera::check_over`]).
pub(crate) fn parse(b: &[u8], cols: u16, rows: u16) -> Result<Camera, TableError> {
    let cam = decode(b)?;
    if cam.focal_length_px.is_nan() || cam.focal_length_px <= 0.0 {
        return Err(TableError::CameraModel(CameraError::BadParameter));
    }
    cam.check_over(cols, rows, COLOUR_RANGE_BV_MAG)
        .map_err(TableError::CameraModel)?;
    Ok(cam)
}
