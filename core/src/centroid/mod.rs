//! Star centroids from a window of calibrated pixels: the methods, their shared output type,
//! the background and noise model, and the flag policy.
//!
//! | method | module | cost | systematic error, noise-free (RMS over phases) | random error |
//! |---|---|---|---|---|
//! | centre of gravity, power 1 (eq. 2) and 2 (eq. 6) | [`cog`] | ~10 flops/pixel | 5x5: 0.049 px at a = 0.5, < 0.001 at a = 1, 0.047 at a = 2 (power 1) | 0.86..1.1 of the CRLB-limited scatter |
//! | pixel-integrated Gaussian fit | [`gauss_fit`] | ~200 flops/pixel for 4 steps | < 1e-5 px (model exact) | efficiency 0.97..1.00 |
//!
//! (a = the paper's 80 %-energy radius, s = sqrt(0.31) a; numbers from the host tests
//! `centroid_cog`, `centroid_cog_noise`, `centroid_gauss_fit` run with
//! `--nocapture`; costs are operation counts, not M7 measurements.) None of them yet applies the paper's pixelisation correction table.
//!
//! (The 3-point peak fits, parabolic and log-parabolic, and the Gaussian-windowed IWC
//! centroid were removed: on the Cortex-M7 they sat on the speed/accuracy frontier in no
//! scene; see the README's method list.)
//!
//! # Arithmetic: f32, with an exact integer background subtraction
//! Every method works in `f32`, the Cortex-M7's hardware float type for the
//! `thumbv7em-none-eabihf` target (`f64` would be soft-float there). The only step where f32
//! would lose information is `pixel - background` for large equal values, so that difference
//! is taken on the `I26F6` bits in `i64` (exact: |difference| < 2^33 LSB) and converted to f32
//! once per pixel. Positions are accumulated relative to an anchor pixel inside the window
//! (offsets below [`MAX_SIDE`]), so sums such as `sum(dx * F)` keep their relative precision.
//!
//! Range: a background-subtracted value is below 2^26 e- in magnitude (pixels within ±2^25 e-,
//! the calibrated bound); its square below 2^52; a sum of squares over the largest window
//! ([`MAX_SIDE`]^2 = 961 pixels) below 2^62, and the error propagation divides by the weight
//! sum twice rather than by its square, so no f32 intermediate exceeds ~2^100 (f32 holds
//! 2^127). A fixed-point power-2 sum would need more than 64 bits; f32 needs no care.
//!
//! # Background and noise
//! The background is either measured on the window's perimeter (the one-pixel border ring,
//! excluded pixels skipped: its mean or median, the paper's way) or given by the caller (the
//! detector's estimate). The perimeter also gives the per-pixel background variance (sample
//! variance about the mean, or the scaled MAD about the median): read noise, sky and dark shot
//! noise and dark non-uniformity together. The noise model of a background-subtracted pixel
//! `F` is `var = max(F, 0) + var_bg` (e-^2; shot noise of the star, since pixels are
//! calibrated electrons) plus the error of the background estimate itself, `var_bg / n`
//! (mean) or `pi/2 var_bg / n` (median), shared by all pixels. A perimeter only measures the
//! background when the star is well inside it: use a window two pixels wider than the
//! centroid box (e.g. a 7x7 window for a 5x5 box).
//!
//! # Flags and degenerate windows
//! Every method returns a [`Centroid`], never an error and never a NaN. A window it cannot
//! measure (empty, bigger than [`MAX_SIDE`], a pixel slice of the wrong length, flat, negative
//! after background subtraction, all pixels excluded, no usable perimeter) gives
//! [`CentroidFlags::DEGENERATE`], the position of the window's centre pixel, zero flux and SNR,
//! and a position error of half the window size. Any computed position is clamped to the
//! window's extent (pixel edges: `x0 - 1/2 ..= x0 + width - 1/2`), with
//! [`CentroidFlags::CLAMPED`] when the clamp acted.

pub mod cog;
pub mod gauss_fit;
pub(crate) mod math;
pub mod pixcorr;
pub mod raw_cog;

/// The f32 functions of the centroid methods (`centroid::math`: square root, exponential,
/// `erfc`, the Gaussian's pixel fractions), reachable from outside the crate only for the
/// host accuracy tests (`host-tests/tests/centroid_math.rs`, which compare them with f64):
/// not part of the API.
#[doc(hidden)]
pub mod test_only_math {
    pub use super::math::{EdgeGrid, erfc, erfc_abs_and_gauss, exp, pixel_fraction, sqrt};
}

use crate::calib::PixelFlags;
use crate::window::Window;

/// The largest window side any method accepts (31 pixels: the perimeter median's buffer).
pub const MAX_SIDE: u16 = 31;

/// Below this SNR (paper eq. 8) a centroid gets [`CentroidFlags::LOW_SNR`]: the paper's
/// detection threshold.
pub const LOW_SNR_LIMIT: f32 = 3.0;

/// Largest perimeter length: `2 * MAX_SIDE + 2 * (MAX_SIDE - 2)`.
const MAX_PERIMETER: usize = 4 * MAX_SIDE as usize - 4;

bitflags::bitflags! {
    /// What a centroid method noticed; several may be set.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct CentroidFlags: u16 {
        /// A pixel of the window is saturated: its value is a lower bound, the centroid is
        /// pulled towards the saturated core's centre and the flux is too low.
        const SATURATED = 1;
        /// The window (or the method's box inside it) is smaller than requested, usually at
        /// the edge of the active area: truncation bias.
        const EDGE_CLIPPED = 2;
        /// The window held an excluded pixel (hot or telegraph): it was skipped, which biases
        /// the centroid away from it.
        const EXCLUDED_PIXEL = 4;
        /// SNR (eq. 8) below [`LOW_SNR_LIMIT`].
        const LOW_SNR = 8;
        /// No position could be computed: the position is the window's centre pixel.
        const DEGENERATE = 16;
        /// Reserved for detection: the window holds more than one star.
        const BLENDED = 32;
        /// An iterative method did not converge within its iterations, or diverged and fell
        /// back to its starting point.
        const NOT_CONVERGED = 64;
        /// Set by no method now (it was the removed 3-point peak fit's: the brightest pixel
        /// lay on the window border, so the fit had no neighbour on one side). The bit stays
        /// reserved, not reused or renumbered, because telemetry and `stars.csv` carry the
        /// flag bits.
        const PEAK_AT_EDGE = 128;
        /// The computed position fell outside the window and was clamped to its edge.
        const CLAMPED = 256;
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for CentroidFlags {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "CentroidFlags({=u16:#x})", self.bits())
    }
}

/// One star's measured position, in active-area pixels (pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Centroid {
    /// Column coordinate, px.
    pub x_px: f32,
    /// Row coordinate, px.
    pub y_px: f32,
    /// Background-subtracted signal in the method's box, e-.
    pub flux_e: f32,
    /// Signal-to-noise ratio of `flux_e` (paper eq. 8 with the measured noise).
    pub snr: f32,
    /// Estimated 1-sigma random error of `x_px` from the noise model, px.
    pub sigma_x_px: f32,
    /// Estimated 1-sigma random error of `y_px`, px.
    pub sigma_y_px: f32,
    /// What the method noticed.
    pub flags: CentroidFlags,
}

/// The input of every method: a window and what calibration and detection know about it.
#[derive(Clone, Copy, Debug)]
pub struct CentroidInput<'a> {
    /// The calibrated pixels.
    pub window: Window<'a>,
    /// Per-pixel calibration flags, row-major like the pixels; empty when none are known.
    /// Any other length than 0 or `window.rect.len()` makes the window degenerate.
    pub pixel_flags: &'a [PixelFlags],
    /// True when the window is smaller than requested (e.g. from
    /// [`crate::window::Rect::centred_clipped`]): sets [`CentroidFlags::EDGE_CLIPPED`].
    pub clipped: bool,
}

impl<'a> CentroidInput<'a> {
    /// A window without pixel flags, not clipped.
    pub fn new(window: Window<'a>) -> Self {
        Self {
            window,
            pixel_flags: &[],
            clipped: false,
        }
    }

    /// Adds the per-pixel calibration flags.
    pub fn with_pixel_flags(self, pixel_flags: &'a [PixelFlags]) -> Self {
        Self {
            pixel_flags,
            ..self
        }
    }

    /// Records whether the window was clipped.
    pub fn with_clipped(self, clipped: bool) -> Self {
        Self { clipped, ..self }
    }
}

/// Where the background level and its per-pixel variance come from.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Background {
    /// Mean and sample variance of the window's border pixels (excluded pixels skipped).
    PerimeterMean,
    /// Median of the border pixels, variance from their median absolute deviation
    /// (`(1.4826 MAD)^2`): robust to a star's wing or a cosmic ray on the border.
    PerimeterMedian,
    /// Given by the caller (the detector's estimate), taken as exact.
    Given {
        /// Background level, e- per pixel.
        level_e: f32,
        /// Per-pixel variance of the background (read noise, sky and dark noise), e-^2.
        variance_e2: f32,
    },
}

/// A background estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BackgroundEstimate {
    /// Level, e- per pixel, in `Electrons` bits (1/64 e-; [`Self::level_e`] outside the
    /// crate).
    pub(crate) level_bits: i64,
    /// Per-pixel variance of the background, e-^2.
    pub variance_e2: f32,
    /// Variance of the level estimate itself (shared by every pixel), e-^2.
    pub level_variance_e2: f32,
}

impl BackgroundEstimate {
    /// Level in e-.
    pub fn level_e(&self) -> f32 {
        self.level_bits as f32 / 64.0
    }
}

/// A validated window with its background: what the methods work on. Coordinates are
/// window-relative (`col`, `row`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Prepared<'a> {
    pub(crate) width: u16,
    pub(crate) height: u16,
    x0: u16,
    y0: u16,
    pixels: &'a [crate::units::Electrons],
    pixel_flags: &'a [PixelFlags],
    pub(crate) bg: BackgroundEstimate,
    pub(crate) flags: CentroidFlags,
}

/// The window's centre pixel as a degenerate centroid.
pub(crate) fn degenerate(window: &Window<'_>, flags: CentroidFlags) -> Centroid {
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

/// f32 level in e- to `Electrons` bits, saturating, NaN to 0.
pub(crate) fn level_to_bits(level_e: f32) -> i64 {
    let b = level_e * 64.0;
    let r = if b >= 0.0 { b + 0.5 } else { b - 0.5 };
    // `as` saturates at the i32 range and maps NaN to 0.
    i64::from(r as i32)
}

/// `max(v, 0)` (0 for NaN, as `f32::max`) by a compare: without `-C target-cpu=cortex-m7`
/// (the Cortex-M4 FPU, no `vmaxnm`) `f32::max` is a call to `fmaxf`.
#[inline(always)]
pub(crate) fn pos(v: f32) -> f32 {
    if v > 0.0 { v } else { 0.0 }
}

/// A finite, non-negative f32 or 0.
pub(crate) fn sanitize_var(v: f32) -> f32 {
    if v.is_finite() && v > 0.0 { v } else { 0.0 }
}

/// The two middle order statistics of a non-empty slice, `(v[(n-1)/2], v[n/2])` of the
/// sorted order (equal for an odd length), found by selection (`select_nth_unstable`,
/// introselect: O(n) on average, no full sort), reordering `v`.
fn middle_pair<T: Ord + Copy>(v: &mut [T]) -> Option<(T, T)> {
    let n = v.len();
    if n == 0 {
        return None;
    }
    let (left, hi, _) = v.select_nth_unstable(n / 2);
    let hi = *hi;
    // For an even length the lower middle value is the largest of the left part.
    let lo = if n.is_multiple_of(2) {
        left.iter().copied().max().unwrap_or(hi)
    } else {
        hi
    };
    Some((lo, hi))
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
        let (mut n, mut sum) = (0i64, 0i64);
        for b in self.perimeter() {
            n += 1;
            sum += b;
        }
        if n == 0 {
            return None;
        }
        let mean = sum.div_euclid(n) + i64::from(2 * sum.rem_euclid(n) >= n);
        let ss: f32 = self
            .perimeter()
            .map(|b| {
                let d = (b - mean) as f32 / 64.0;
                d * d
            })
            .sum();
        let var = if n > 1 {
            sanitize_var(ss / (n - 1) as f32)
        } else {
            0.0
        };
        Some(BackgroundEstimate {
            level_bits: mean,
            variance_e2: var,
            level_variance_e2: var / n as f32,
        })
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
        let (lo, hi) = middle_pair(v)?;
        // Mean of the middle two, rounded towards minus infinity.
        let med = (i64::from(lo) + i64::from(hi)).div_euclid(2);
        // Absolute deviations in place (saturated at i32::MAX bits, 33.5 M e-: beyond the
        // calibrated range, and a MAD that large marks the window as useless anyway).
        for x in v.iter_mut() {
            *x = i32::try_from((i64::from(*x) - med).unsigned_abs()).unwrap_or(i32::MAX);
        }
        let (dlo, dhi) = middle_pair(v)?;
        let (dlo, dhi) = (dlo.unsigned_abs(), dhi.unsigned_abs());
        let mad_bits = (u64::from(dlo) + u64::from(dhi)) / 2;
        let mad = mad_bits as f32 / 64.0 * 1.4826;
        let var = if n > 1 { sanitize_var(mad * mad) } else { 0.0 };
        let level_var = var * core::f32::consts::FRAC_PI_2 / n as f32;
        Some(BackgroundEstimate {
            level_bits: med,
            variance_e2: var,
            level_variance_e2: level_var,
        })
    }

    /// The brightest usable pixel (on ties, the one nearest the window's centre pixel, then
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
        let mut put = |e: &crate::units::Electrons| {
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
        let area = crate::window::Rect {
            x0: self.x0,
            y0: self.y0,
            width: self.width,
            height: self.height,
        };
        finish_in(area, &m, half, self.flags | extra).unwrap_or_else(|| self.degenerate(extra))
    }

    /// Iterates the usable pixels of the box `col0..=col1`, `row0..=row1` (window-relative,
    /// already inside the window) as `(col, row, signal_e)`.
    pub(crate) fn box_pixels(&self, b: PixelBox) -> BoxPixels<'_, 'a> {
        BoxPixels {
            p: self,
            b,
            col: b.col0,
            row: b.row0,
            done: b.col0 > b.col1 || b.row0 > b.row1,
        }
    }

    /// A box of odd side `2 * (side / 2) + 1` centred on (col, row), clipped to the window;
    /// the flag tells whether clipping removed any pixel.
    pub(crate) fn box_around(&self, col: u16, row: u16, side: u8) -> (PixelBox, bool) {
        let half = u16::from(side / 2);
        let col0 = col.saturating_sub(half);
        let row0 = row.saturating_sub(half);
        let col1 = col.saturating_add(half).min(self.width - 1);
        let row1 = row.saturating_add(half).min(self.height - 1);
        let clipped = col1 - col0 != 2 * half || row1 - row0 != 2 * half;
        (
            PixelBox {
                col0,
                row0,
                col1,
                row1,
            },
            clipped,
        )
    }
}

/// Iterator of [`Prepared::box_pixels`]: a plain row-major walk (the `flat_map` /
/// `filter_map` chain it replaces cost ~3x more per pixel on the M7).
pub(crate) struct BoxPixels<'p, 'a> {
    p: &'p Prepared<'a>,
    b: PixelBox,
    col: u16,
    row: u16,
    done: bool,
}

impl Iterator for BoxPixels<'_, '_> {
    type Item = (u16, u16, f32);

    #[inline]
    fn next(&mut self) -> Option<Self::Item> {
        while !self.done {
            let (c, r) = (self.col, self.row);
            if c >= self.b.col1 {
                self.col = self.b.col0;
                if r >= self.b.row1 {
                    self.done = true;
                } else {
                    self.row = r + 1;
                }
            } else {
                self.col = c + 1;
            }
            if let Some(f) = self.p.signal(c, r) {
                return Some((c, r, f));
            }
        }
        None
    }
}

/// Iterator of [`Prepared::perimeter`]: the border ring, row-major, usable pixels' bits.
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
    area: crate::window::Rect,
    m: &Measured,
    half: f32,
    flags: CentroidFlags,
) -> Option<Centroid> {
    if !(m.col.is_finite() && m.row.is_finite()) {
        return None;
    }
    let mut flags = flags;
    let (wmax, hmax) = (f32::from(area.width) - 0.5, f32::from(area.height) - 0.5);
    let col = m.col.clamp(-0.5, wmax);
    let row = m.row.clamp(-0.5, hmax);
    if col != m.col || row != m.row {
        flags |= CentroidFlags::CLAMPED;
    }
    let sigma = |v: f32| {
        if v.is_finite() {
            v.clamp(0.0, 2.0 * half)
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

/// An inclusive rectangle of window-relative pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PixelBox {
    pub(crate) col0: u16,
    pub(crate) row0: u16,
    pub(crate) col1: u16,
    pub(crate) row1: u16,
}

/// Estimates the background of a window the way the methods do (useful to callers that want
/// to report it); `None` for a window the methods would call degenerate.
pub fn estimate_background(
    input: &CentroidInput<'_>,
    background: Background,
) -> Option<BackgroundEstimate> {
    Prepared::new(input, background).ok().map(|p| p.bg)
}
