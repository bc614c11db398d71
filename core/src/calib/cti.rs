//! Charge-transfer (CTI) correction of star positions: charge traps in the image, store and
//! serial registers hold back part of each pixel's charge and release it into pixels read
//! later, so a star's centroid moves away from the output amplifier along both axes. The
//! shift grows with the number of transfers and shrinks with the signal (a faint star
//! loses a larger fraction of its charge). This module removes that shift from a measured
//! centroid, from the coefficients of table section 8 ([`crate::table::CtiCoeffs`]).
//!
//! # Model
//! For a star of measured flux `F` (e-) at active pixel (`x`, `y`), read by output `o`:
//! ```text
//! L  = ((F + F_0) / F_ref)^-alpha                                      (signal law)
//! dy = n_par L s_par(o)         n_par = y + 1                          (lines to the register)
//! dx = n_ser L s_ser(o) k(x)    n_ser = c + 1 (left output, c the raw column),
//!                               n_ser = line_len - c (right output)
//! ```
//! `dy` is along +y (lines read later); `dx` is along +x for the left output and -x for the
//! right one (away from each amplifier). `F_0` stands for the background, which fills traps
//! too: a faint star's shift levels off instead of growing without bound. With two outputs a
//! star near the split is read partly by each, whose trails point at each other: `k(x) =
//! erf(d / (sigma sqrt 2))`, `d` the distance from the split (the pixel edge between the
//! halves) and `sigma` the PSF's Gaussian sigma, is the own side's share of the flux minus the
//! other side's (1 away from the split, 0 on it). [`CtiCorrection::corrected`] subtracts them. The
//! host measures `s_par`, `s_ser` and `alpha` for the flight centroid method against the
//! simulator's trap law, or derives them from EPER coefficients of lab flats
//! (`startrack calib frames`).
//!
//! Formats: coefficients as stored (U0F32 px per transfer, U0F16 exponent, u32 e-), the
//! arithmetic in f32. The signal factor is bounded: `(F + F_0) / F_ref` is clamped to
//! `MIN_FLUX_RATIO`..=`MAX_FLUX_RATIO` (a non-finite or non-positive flux gives no
//! correction), so a noise-level flux cannot produce a runaway shift.
//!
//! Cost: one `powf` and one `erff` (libm), about 15 flops and a few integer operations per
//! star.

use crate::clamp::clamp;
use crate::geometry::{Output, ReadoutGeometry};
use crate::table::{CalibTable, CtiCoeffs};

/// Smallest flux ratio `(F + F_0) / F_ref` the signal law is evaluated at.
pub(crate) const MIN_FLUX_RATIO: f32 = 1.0e-3;
/// Largest flux ratio `(F + F_0) / F_ref` the signal law is evaluated at.
pub(crate) const MAX_FLUX_RATIO: f32 = 1.0e6;

/// A measured star position the correction applies to: its position and flux in, the same
/// measurement at the corrected position out (the centroid stage's result implements it).
pub trait MeasuredPosition: Copy {
    /// Column and row coordinates, px.
    fn position_px(&self) -> (f32, f32);
    /// The measured flux, e-.
    fn flux_e(&self) -> f32;
    /// The same measurement at (`x_px`, `y_px`).
    fn at_px(self, x_px: f32, y_px: f32) -> Self;
}

/// The CTI correction of a table, for its geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CtiCorrection {
    coeffs: CtiCoeffs,
    geometry: ReadoutGeometry,
    psf_sigma_px: f32,
}

impl CtiCorrection {
    /// The correction with `coeffs` on `geometry`, for stars of Gaussian sigma `psf_sigma_px`
    /// (used only near the split of a two-output readout; a non-finite or non-positive sigma
    /// counts as a point source there).
    pub const fn new(coeffs: CtiCoeffs, geometry: ReadoutGeometry, psf_sigma_px: f32) -> Self {
        Self {
            coeffs,
            geometry,
            psf_sigma_px,
        }
    }

    /// The correction of `table`'s CTI section, or `None` when it has none.
    pub fn from_table(table: &CalibTable<'_>, psf_sigma_px: f32) -> Option<Self> {
        table
            .cti()
            .map(|c| Self::new(c, *table.geometry(), psf_sigma_px))
    }

    /// The own side's share of the flux minus the other side's, for a star at `x_px` of a
    /// two-output readout (1 with one output).
    fn split_factor(&self, x_px: f32) -> f32 {
        let g = &self.geometry;
        if g.outputs < 2 {
            return 1.0;
        }
        let d = (x_px - (f32::from(g.active_cols / 2) - 0.5)).abs();
        let s = self.psf_sigma_px;
        if !(s.is_finite() && s > 0.0) {
            return 1.0;
        }
        libm::erff(d / (s * core::f32::consts::SQRT_2))
    }

    /// Transfers (parallel, serial) of the charge of active pixel (`x_px`, `y_px`) (rounded to
    /// the nearest pixel, clamped to the active area), and the serial direction (+1 away from
    /// the left output, -1 from the right one) and the output.
    fn transfers(&self, x_px: f32, y_px: f32) -> (f32, f32, f32, Output) {
        let g = &self.geometry;
        let last_x = f32::from(g.active_cols.saturating_sub(1));
        let last_y = f32::from(g.active_rows.saturating_sub(1));
        let limit = |v: f32, hi: f32| {
            if v.is_finite() {
                clamp(v, 0.0, hi)
            } else {
                0.0
            }
        };
        let x = (limit(x_px, last_x) + 0.5) as usize;
        let y = limit(y_px, last_y) + 0.5;
        let col = g.raw_col_of_x(x);
        let out = g.output_of_col(col);
        let n_par = (g.raw_line_of_y(y as usize) + 1) as f32;
        let (n_ser, dir) = if out.0 == 0 {
            ((col + 1) as f32, 1.0)
        } else {
            (g.line_len().saturating_sub(col) as f32, -1.0)
        };
        (n_par, n_ser, dir, out)
    }

    /// The shift (dx, dy) px that the traps add to the centroid of a star of measured flux
    /// `flux_e` at (`x_px`, `y_px`); (0, 0) for a non-finite or non-positive flux.
    pub fn shift_px(&self, flux_e: f32, x_px: f32, y_px: f32) -> (f32, f32) {
        if !(flux_e.is_finite() && flux_e > 0.0) {
            return (0.0, 0.0);
        }
        let ratio = ((flux_e + self.coeffs.flux_offset_e as f32)
            / self.coeffs.reference_flux_e as f32)
            .clamp(MIN_FLUX_RATIO, MAX_FLUX_RATIO);
        let law = libm::powf(ratio, -self.coeffs.alpha.to_num::<f32>());
        let (n_par, n_ser, dir, out) = self.transfers(x_px, y_px);
        let k = self
            .coeffs
            .outputs
            .get(usize::from(out.0))
            .copied()
            .unwrap_or_default();
        let split = if x_px.is_finite() {
            self.split_factor(x_px)
        } else {
            1.0
        };
        (
            dir * n_ser * law * split * k.serial_px.to_num::<f32>(),
            n_par * law * k.parallel_px.to_num::<f32>(),
        )
    }

    /// `c` with the trap shift of its flux and position removed (flags, flux and sigmas
    /// unchanged).
    pub fn corrected<P: MeasuredPosition>(&self, c: P) -> P {
        let (x_px, y_px) = c.position_px();
        let (dx, dy) = self.shift_px(c.flux_e(), x_px, y_px);
        c.at_px(x_px - dx, y_px - dy)
    }
}
