//! The window every method works on: [`Prepared::new`] validates a [`CentroidInput`] (size,
//! buffers, flags), gathers its flags and estimates its background; the methods then read
//! background-subtracted pixels, the peak and boxes from it, and turn their window-relative
//! result into a [`Centroid`] through one output step ([`finish_in`]: clamp, finite values,
//! `LOW_SNR`). A window that cannot be measured becomes the degenerate centroid of its
//! centre pixel.
//!
//! # Cost
//! Validation: one pass over the pixel flags; the background: one or two passes over the
//! border ring (and its median's selections, see [`super::background`]); the peak: one walk
//! of the pixels. ~390 instructions on the M7 for a 7x7 window with a given background
//! (part of the Gauss fit's breakdown in `gauss_fit`).

use super::background::{
    Background, BackgroundEstimate, level_to_bits, mean_estimate, median_estimate, sanitize_var,
};
use super::math::pos;
use super::{Centroid, CentroidFlags, CentroidInput, LOW_SNR_LIMIT, MAX_SIDE};
use crate::calib::PixelFlags;
use crate::clamp::clamp;
use crate::units::Electrons;
use crate::window::{Rect, Window};

/// Largest perimeter length: `2 * MAX_SIDE + 2 * (MAX_SIDE - 2)`.
const MAX_PERIMETER: usize = 4 * MAX_SIDE as usize - 4;

/// A validated window with its background: what the methods work on. Coordinates are
/// window-relative (`col`, `row`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Prepared<'a> {
    pub(crate) width: u16,
    pub(crate) height: u16,
    x0: u16,
    y0: u16,
    pub(crate) pixels: &'a [Electrons],
    pixel_flags: &'a [PixelFlags],
    pub(crate) bg: BackgroundEstimate,
    pub(crate) flags: CentroidFlags,
}

/// The window's centre pixel as a degenerate centroid.
fn degenerate(window: &Window<'_>, flags: CentroidFlags) -> Centroid {
    let r = window.rect;
    degenerate_in(r.x0, r.y0, r.width, r.height, flags)
}

/// The centre pixel of the `width` x `height` rectangle at (`x0`, `y0`) as a degenerate
/// centroid, with an error of half the rectangle's larger side.
fn degenerate_in(x0: u16, y0: u16, width: u16, height: u16, flags: CentroidFlags) -> Centroid {
    let half = f32::from(width.max(height)) * 0.5;
    Centroid {
        x_px: f32::from(x0) + f32::from(width.saturating_sub(1) / 2),
        y_px: f32::from(y0) + f32::from(height.saturating_sub(1) / 2),
        flux_e: 0.0,
        snr: 0.0,
        sigma_x_px: half,
        sigma_y_px: half,
        flags: flags | CentroidFlags::DEGENERATE,
    }
}

impl<'a> Prepared<'a> {
    /// Validates the window and estimates the background; a degenerate centroid on failure.
    pub(crate) fn new(input: &CentroidInput<'a>, background: Background) -> Result<Self, Centroid> {
        let w = input.window;
        let r = w.rect;
        let mut flags = CentroidFlags::empty();
        if input.clipped {
            flags |= CentroidFlags::EDGE_CLIPPED;
        }
        let n = r.len();
        let flags_ok = input.pixel_flags.is_empty() || input.pixel_flags.len() == n;
        if r.is_empty()
            || r.width > MAX_SIDE
            || r.height > MAX_SIDE
            || w.pixels_e.len() != n
            || !flags_ok
        {
            return Err(degenerate(&w, flags));
        }
        for f in input.pixel_flags {
            if f.contains(PixelFlags::SATURATED) {
                flags |= CentroidFlags::SATURATED;
            }
            if f.is_excluded() {
                flags |= CentroidFlags::EXCLUDED_PIXEL;
            }
        }
        let mut p = Self {
            width: r.width,
            height: r.height,
            x0: r.x0,
            y0: r.y0,
            pixels: w.pixels_e,
            pixel_flags: input.pixel_flags,
            bg: BackgroundEstimate {
                level_bits: 0,
                variance_e2: 0.0,
                level_variance_e2: 0.0,
            },
            flags,
        };
        p.bg = match background {
            Background::Given {
                level_e,
                variance_e2,
            } => BackgroundEstimate {
                level_bits: level_to_bits(level_e),
                variance_e2: sanitize_var(variance_e2),
                level_variance_e2: 0.0,
            },
            Background::PerimeterMean => p.perimeter_mean().ok_or_else(|| degenerate(&w, flags))?,
            Background::PerimeterMedian => {
                p.perimeter_median().ok_or_else(|| degenerate(&w, flags))?
            }
        };
        Ok(p)
    }

    /// The raw bits of usable pixel (col, row): `None` outside or excluded.
    fn bits(&self, col: u16, row: u16) -> Option<i64> {
        if col >= self.width || row >= self.height {
            return None;
        }
        let i = usize::from(row) * usize::from(self.width) + usize::from(col);
        if self.pixel_flags.get(i).is_some_and(|f| f.is_excluded()) {
            return None;
        }
        self.pixels.get(i).map(|e| i64::from(e.to_bits()))
    }

    /// True unless pixel `i` (row-major index) is flagged excluded.
    pub(crate) fn usable(&self, i: usize) -> bool {
        !self.pixel_flags.get(i).is_some_and(|f| f.is_excluded())
    }

    /// Background-subtracted signal of usable pixel (col, row), e-.
    pub(crate) fn signal(&self, col: u16, row: u16) -> Option<f32> {
        self.bits(col, row)
            .map(|b| (b - self.bg.level_bits) as f32 / 64.0)
    }

    /// The noise variance of a pixel whose background-subtracted signal is `f`, e-^2 (without
    /// the shared background-level term).
    pub(crate) fn variance(&self, f: f32) -> f32 {
        pos(f) + self.bg.variance_e2
    }

    /// The number of usable border pixels (the background variance's sample).
    pub(crate) fn perimeter_usable(&self) -> u16 {
        u16::try_from(self.perimeter().count()).unwrap_or(u16::MAX)
    }

    /// The usable border pixels' bits, row-major.
    fn perimeter(&self) -> Perimeter<'_, 'a> {
        Perimeter {
            p: self,
            col: 0,
            row: 0,
            done: self.width == 0 || self.height == 0,
        }
    }

    fn perimeter_mean(&self) -> Option<BackgroundEstimate> {
        mean_estimate(self.perimeter())
    }

    fn perimeter_median(&self) -> Option<BackgroundEstimate> {
        // Pixel bits are `Electrons` (i32), so the buffer holds i32 (cheaper to compare on
        // the M7 than i64); deviations from the median can reach 2^32, so they are u32.
        let mut buf = [0i32; MAX_PERIMETER];
        let n = if self.flags.contains(CentroidFlags::EXCLUDED_PIXEL) {
            let mut n = 0usize;
            for (slot, b) in buf.iter_mut().zip(self.perimeter()) {
                *slot = i32::try_from(b).unwrap_or(if b < 0 { i32::MIN } else { i32::MAX });
                n += 1;
            }
            n
        } else {
            self.perimeter_clean(&mut buf)
        };
        let v = buf.get_mut(..n)?;
        median_estimate(v)
    }

    /// the first in row-major order), or `None` when every pixel is excluded.
    pub(crate) fn peak(&self) -> Option<(u16, u16)> {
        let (cc, cr) = self.centre();
        let dist2 = |c: u16, r: u16| {
            let (dc, dr) = (u32::from(c.abs_diff(cc)), u32::from(r.abs_diff(cr)));
            dc * dc + dr * dr
        };
        if !self.flags.contains(CentroidFlags::EXCLUDED_PIXEL) {
            return self.peak_clean();
        }
        let mut best: Option<(i64, u32, u16, u16)> = None;
        for row in 0..self.height {
            for col in 0..self.width {
                if let Some(b) = self.bits(col, row) {
                    let d = dist2(col, row);
                    if best.is_none_or(|(bb, bd, _, _)| b > bb || (b == bb && d < bd)) {
                        best = Some((b, d, col, row));
                    }
                }
            }
        }
        best.map(|(_, _, c, r)| (c, r))
    }

    /// The border ring's bits of a window without excluded pixels, copied straight from the
    /// pixel rows into `buf` (top row, the side pixels of the middle rows, bottom row);
    /// returns how many (the values [`Self::perimeter`] gives, in another order).
    fn perimeter_clean(&self, buf: &mut [i32; MAX_PERIMETER]) -> usize {
        let w = usize::from(self.width);
        let h = usize::from(self.height);
        let mut slots = buf.iter_mut();
        let mut n = 0usize;
        let mut put = |e: &Electrons| {
            if let Some(s) = slots.next() {
                *s = e.to_bits();
                n += 1;
            }
        };
        let mut rows = self.pixels.chunks_exact(w.max(1)).take(h);
        if let Some(top) = rows.next() {
            top.iter().for_each(&mut put);
        }
        let mut last = None;
        for row in rows {
            if let Some(prev) = last.replace(row) {
                if let Some(e) = prev.first() {
                    put(e);
                }
                if let Some(e) = prev.last().filter(|_| w > 1) {
                    put(e);
                }
            }
        }
        if let Some(bottom) = last {
            bottom.iter().for_each(&mut put);
        }
        n
    }

    /// [`Self::peak`] for a window without excluded pixels: one walk of the pixel slice,
    /// the distance computed only for a candidate at least as bright as the best so far.
    fn peak_clean(&self) -> Option<(u16, u16)> {
        let (cc, cr) = self.centre();
        let w = usize::from(self.width).max(1);
        let mut best_v = i32::MIN;
        let mut best_d = u32::MAX;
        let mut best = None;
        for (row, line) in (0u16..).zip(self.pixels.chunks_exact(w)) {
            for (col, e) in (0u16..).zip(line) {
                let b = e.to_bits();
                if b >= best_v {
                    let (dc, dr) = (u32::from(col.abs_diff(cc)), u32::from(row.abs_diff(cr)));
                    let d = dc * dc + dr * dr;
                    if b > best_v || d < best_d || best.is_none() {
                        best_v = b;
                        best_d = d;
                        best = Some((col, row));
                    }
                }
            }
        }
        best
    }

    /// The window's centre pixel (window-relative).
    pub(crate) fn centre(&self) -> (u16, u16) {
        ((self.width - 1) / 2, (self.height - 1) / 2)
    }

    /// The degenerate centroid of this window, with the flags gathered so far plus `extra`.
    pub(crate) fn degenerate(&self, extra: CentroidFlags) -> Centroid {
        degenerate_in(
            self.x0,
            self.y0,
            self.width,
            self.height,
            self.flags | extra,
        )
    }

    /// Builds the output from a window-relative measurement: clamps the position to the
    /// window, replaces any non-finite value, sets `LOW_SNR` ([`finish_in`]).
    pub(crate) fn finish(&self, m: Measured, extra: CentroidFlags) -> Centroid {
        let half = f32::from(self.width.max(self.height)) * 0.5;
        let area = Rect {
            x0: self.x0,
            y0: self.y0,
            width: self.width,
            height: self.height,
        };
        finish_in(area, &m, half, self.flags | extra).unwrap_or_else(|| self.degenerate(extra))
    }
}

/// Iterator of [`Prepared::perimeter`]: the border ring, row-major, usable pixels' bits.
#[derive(Clone)]
struct Perimeter<'p, 'a> {
    p: &'p Prepared<'a>,
    col: u16,
    row: u16,
    done: bool,
}

impl Iterator for Perimeter<'_, '_> {
    type Item = i64;

    #[inline]
    fn next(&mut self) -> Option<i64> {
        let (w, h) = (self.p.width, self.p.height);
        while !self.done {
            let (c, r) = (self.col, self.row);
            let border_row = r == 0 || r + 1 == h;
            // Next border cell: along a border row, or from the left to the right column.
            let next_col = if border_row { c + 1 } else { w - 1 };
            if next_col < w && next_col > c {
                self.col = next_col;
            } else if r + 1 < h {
                self.col = 0;
                self.row = r + 1;
            } else {
                self.done = true;
            }
            if let Some(b) = self.p.bits(c, r) {
                return Some(b);
            }
        }
        None
    }
}

/// Every method's output step: `m`'s position (relative to `area`'s corner) clamped to
/// `area`'s pixel edges, `x0 - 1/2 ..= x0 + width - 1/2` ([`CentroidFlags::CLAMPED`] when the
/// clamp acted), each sigma bounded to `0..=2 half` (`half` when not finite), a non-finite
/// flux or SNR replaced by 0, [`CentroidFlags::LOW_SNR`] below [`LOW_SNR_LIMIT`]; `None` for
/// a non-finite position (the caller returns its degenerate centroid).
#[inline(always)]
pub(crate) fn finish_in(
    area: Rect,
    m: &Measured,
    half: f32,
    flags: CentroidFlags,
) -> Option<Centroid> {
    if !(m.col.is_finite() && m.row.is_finite()) {
        return None;
    }
    let mut flags = flags;
    let (wmax, hmax) = (f32::from(area.width) - 0.5, f32::from(area.height) - 0.5);
    let col = clamp(m.col, -0.5, wmax);
    let row = clamp(m.row, -0.5, hmax);
    if col != m.col || row != m.row {
        flags |= CentroidFlags::CLAMPED;
    }
    let sigma = |v: f32| {
        if v.is_finite() {
            clamp(v, 0.0, 2.0 * half)
        } else {
            half
        }
    };
    let snr = if m.snr.is_finite() { m.snr } else { 0.0 };
    if snr < LOW_SNR_LIMIT {
        flags |= CentroidFlags::LOW_SNR;
    }
    Some(Centroid {
        x_px: f32::from(area.x0) + col,
        y_px: f32::from(area.y0) + row,
        flux_e: if m.flux_e.is_finite() { m.flux_e } else { 0.0 },
        snr,
        sigma_x_px: sigma(m.sigma_col),
        sigma_y_px: sigma(m.sigma_row),
        flags,
    })
}

/// A method's result in window-relative coordinates, before [`Prepared::finish`].
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Measured {
    pub(crate) col: f32,
    pub(crate) row: f32,
    pub(crate) flux_e: f32,
    pub(crate) snr: f32,
    pub(crate) sigma_col: f32,
    pub(crate) sigma_row: f32,
}

/// Estimates the background of a window the way the methods do (useful to callers that want
/// to report it); `None` for a window the methods would call degenerate.
pub fn estimate_background(
    input: &CentroidInput<'_>,
    background: Background,
) -> Option<BackgroundEstimate> {
    Prepared::new(input, background).ok().map(|p| p.bg)
}
