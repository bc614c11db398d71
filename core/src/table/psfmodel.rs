//! The field PSF model of table section 9: the PSF's 80 %-energy radius `a` as a smooth
//! function of the position, so that flight code can take a star's width from the model
//! (and fit fewer parameters) where it is good, and flag a star whose measured width
//! departs from it by more than the model's scatter allows.
//!
//! The model is a 2-D polynomial of total degree `d` (0..=3) in normalised active
//! coordinates `u = (2 x + 1) / cols - 1`, `v = (2 y + 1) / rows - 1` (both in `(-1, 1)`
//! over the active area; pixel centres at integers):
//! `a(u, v) = sum c_k u^i v^j`, terms ordered by total degree, then by the power of `v`:
//! `1, u, v, u^2, u v, v^2, u^3, u^2 v, u v^2, v^3`.
//! The host fits it to the stars of processed frames (`startrack calib psf-model`).
//!
//! # Format (read once into [`PsfModel`], 8 + 4 x terms bytes)
//! ```text
//! 0  u8   degree d (0..=3); terms = (d + 1)(d + 2) / 2
//! 1  u8   reserved, 0
//! 2  u16  scatter of the stars' widths about the model (RMS), U8F8 px
//! 4  u16  number of stars the model was fitted from (> 0)
//! 6  u16  reserved, 0
//! 8  terms x i32  coefficients, I16F16 px (step 1.5e-5 px)
//! ```
//! The parser also checks that the width is in `(0, 256)` px on a 5 x 5 grid of the field
//! (corners, edge midpoints, centre and the points between), so a model that goes negative
//! or absurd inside the field is rejected rather than used.
//!
//! Cost of [`PsfModel::a_px`]: two divisions, at most 10 multiply-adds and 4 products (f32).

use super::bytes::{u16_at, u32_at};
use fixed::types::{I16F16, U8F8};

/// Highest polynomial degree of the model.
pub const MAX_PSF_DEGREE: u8 = 3;
/// Most coefficients a model holds (degree 3).
pub const MAX_PSF_TERMS: usize = 10;
/// Size of the section's own header.
pub const PSF_MODEL_HEADER_LEN: usize = 8;

/// Number of terms of a polynomial of total degree `degree`.
pub const fn psf_terms(degree: u8) -> usize {
    let d = degree as usize;
    (d + 1) * (d + 2) / 2
}

/// The field PSF model (section 9).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PsfModel {
    /// Total degree of the polynomial (0..=3).
    pub degree: u8,
    /// RMS scatter of the fitted stars' widths about the model, px (U8F8).
    pub scatter_px: U8F8,
    /// Number of stars the model was fitted from.
    pub stars: u16,
    /// Coefficients in term order, px (I16F16); entries past [`psf_terms`]`(degree)` are 0.
    pub coeffs: [I16F16; MAX_PSF_TERMS],
}

/// What is wrong with a PSF model section (mapped to [`super::TableError`] by the parser).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum PsfFormatError {
    /// Degree above [`MAX_PSF_DEGREE`].
    Degree,
    /// The length does not match the degree.
    Length,
    /// A reserved field is not 0.
    Reserved,
    /// No stars, or the width leaves `(0, 256)` px at grid point `index` (row-major 5 x 5).
    Range(u32),
}

/// The normalised coordinate of pixel `p` on an axis of `n` pixels: `(2 p + 1) / n - 1`.
fn norm(p: f32, n: u16) -> f32 {
    (2.0 * p + 1.0) / f32::from(n.max(1)) - 1.0
}

impl PsfModel {
    /// Bytes the section takes for a model of `degree`.
    pub const fn encoded_len(degree: u8) -> usize {
        PSF_MODEL_HEADER_LEN + 4 * psf_terms(degree)
    }

    /// The model's width `a` at normalised coordinates (`u`, `v`), px.
    pub fn a_at(&self, u: f32, v: f32) -> f32 {
        let up = [1.0, u, u * u, u * u * u];
        let vp = [1.0, v, v * v, v * v * v];
        let mut sum = 0.0f32;
        let mut k = 0usize;
        for total in 0..=usize::from(self.degree.min(MAX_PSF_DEGREE)) {
            for j in 0..=total {
                let c = self.coeffs.get(k).map_or(0.0, |c| c.to_num::<f32>());
                let ui = up.get(total - j).copied().unwrap_or(0.0);
                let vj = vp.get(j).copied().unwrap_or(0.0);
                sum += c * ui * vj;
                k += 1;
            }
        }
        sum
    }

    /// The model's width `a` at active pixel (`x_px`, `y_px`) of an active area of `cols` x
    /// `rows`, px.
    pub fn a_px(&self, x_px: f32, y_px: f32, cols: u16, rows: u16) -> f32 {
        self.a_at(norm(x_px, cols), norm(y_px, rows))
    }

    /// Reads and checks the section.
    pub(crate) fn parse(b: &[u8]) -> Result<Self, PsfFormatError> {
        let degree = *b.first().ok_or(PsfFormatError::Length)?;
        if degree > MAX_PSF_DEGREE {
            return Err(PsfFormatError::Degree);
        }
        if b.len() != Self::encoded_len(degree) {
            return Err(PsfFormatError::Length);
        }
        if b.get(1) != Some(&0) || u16_at(b, 6) != Some(0) {
            return Err(PsfFormatError::Reserved);
        }
        let scatter_px = U8F8::from_bits(u16_at(b, 2).ok_or(PsfFormatError::Length)?);
        let stars = u16_at(b, 4).ok_or(PsfFormatError::Length)?;
        if stars == 0 {
            return Err(PsfFormatError::Range(0));
        }
        let mut coeffs = [I16F16::ZERO; MAX_PSF_TERMS];
        for (i, c) in coeffs.iter_mut().enumerate().take(psf_terms(degree)) {
            let at = PSF_MODEL_HEADER_LEN + 4 * i;
            *c = I16F16::from_bits(u32_at(b, at).ok_or(PsfFormatError::Length)? as i32);
        }
        let m = Self {
            degree,
            scatter_px,
            stars,
            coeffs,
        };
        for (i, (u, v)) in GRID
            .iter()
            .flat_map(|v| GRID.iter().map(move |u| (*u, *v)))
            .enumerate()
        {
            let a = m.a_at(u, v);
            if !(a > 0.0 && a < 256.0) {
                return Err(PsfFormatError::Range(i as u32));
            }
        }
        Ok(m)
    }

    /// Appends the section's bytes to `put`.
    pub(crate) fn write(&self, mut put: impl FnMut(&[u8])) {
        let degree = self.degree.min(MAX_PSF_DEGREE);
        // A degree past the limit is written as is: parsing it back rejects the table.
        put(&[self.degree, 0]);
        put(&self.scatter_px.to_bits().to_le_bytes());
        put(&self.stars.to_le_bytes());
        put(&0u16.to_le_bytes());
        for c in self.coeffs.iter().take(psf_terms(degree)) {
            put(&c.to_bits().to_le_bytes());
        }
    }
}

/// The normalised coordinates of the check grid, per axis.
const GRID: [f32; 5] = [-1.0, -0.5, 0.0, 0.5, 1.0];
