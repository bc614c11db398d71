//! The streaming scan with a raw-domain pre-filter: calibrate-and-detect a frame line by line
//! while calibrating only the pixels that can be above the detection threshold.
//!
//! # Method
//! Calibration is monotone: with the gain and the inverse flat positive, a pixel's electrons
//! never decrease when its raw sample grows (`calib::pixel`'s formula, floor shifts and the
//! final clamp are all monotone). So for each chunk of [`CHUNK_PX`] columns there is a raw
//! level `R` at or below which no regular pixel of the chunk can exceed the join threshold
//! `T = background + k sigma` (the chunk lies in one background block). It comes from the
//! chunk's worst case: the smallest column bias, the smallest dark term and the largest
//! inverse flat of its tiles on this row. With `d = 16 raw - offset`, an f32 inverse of the
//! formula gives a `D` that the exact integer formula then confirms, `e(D) <= T` (stepping
//! down until it does: safe whatever the float error), and `R = floor((D + offset_min) / 16)`.
//! `D` changes only when the background or the tile row changes; `R` follows each line's
//! bias with one add and one shift per chunk.
//!
//! The scan then reads the raw active samples in chunks of [`CHUNK_PX`]: `OR` of `R - raw`
//! over the chunk (3 instructions a pixel: load, subtract, or) is negative exactly when one
//! sample exceeds `R`. In such a chunk only the samples above `R` are calibrated (by the
//! regular formula, bit for bit as `FrameCalibration::calibrate_span`; on a row where the
//! table lists a hot or telegraph pixel, by `calibrate_span` itself, defects included) and
//! thresholded exactly as [`LineDetector::push_line`] does. Pixels of
//! the other chunks are provably not above the threshold (hot, telegraph and saturated
//! pixels included: `R` is below the saturation level, and listed defects never join a
//! blob), so **the candidates are exactly those of a [`LineDetector`] with the same
//! background stride fed every calibrated line**; the host test `scan` checks it bit for bit
//! on simulated frames.
//!
//! The background needs every pixel of a line: rows with `y % background_stride == 0` (and
//! the first row) are calibrated whole and go through [`LineDetector::push_line`].
//!
//! # Cost
//! Quiet pixel: ~3 instructions; per chunk and line: the `R` update; per tile row and chunk:
//! the tile look-ups and the inversion (one exact evaluation when the estimate holds); per background row: a full calibration and the
//! background sort. `cargo m7-bench` reports `scan_detect` per pixel (README).
//!
//! # Where it fails (is slow, never wrong)
//! A chunk whose threshold is at or below 0 e- or that two outputs read is not filtered
//! (always calibrated); a line wider than [`MAX_SCAN_PX`] is an error. A spread of column
//! bias, dark or flat inside a chunk lowers `R` below the pixels' true limits, so more chunks
//! pass to the exact path: the result is the same, only slower. Per-pixel maps with the
//! CCD47-20's DSNU (10 % of 250 e-: the smallest of 16 dark values sits ~1.8 sigma, 45 e-,
//! below the mean, more than twice the noise) make nearly every chunk pass: the pre-filter
//! pays with tiled maps (the 8x8 table of internal flash), where the dark and flat are
//! constant over the chunk's two tiles.

use super::background::MAX_BLOCKS;
use super::blobs::above_thr;
use super::{DetectConfig, DetectError, Detection, LineDetector};
use crate::calib::pixel::{dark_16ths, pixel_bits_d as pixel_bits};
use crate::calib::{CalibError, FrameCalibration, LineLevels, PixelFlags};
use crate::units::{BiasAdu, Electrons, FlatInv, GainEPerAdu};

/// Samples tested together by the pre-filter.
pub const CHUNK_PX: usize = 16;
/// Widest active line the scan filters (wider lines are rejected with an error).
pub const MAX_SCAN_PX: usize = 2048;

/// Why a raw line was not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ScanError {
    /// The detector refused the line (row order).
    Detect(DetectError),
    /// Calibration failed (line length, row outside the active area).
    Calib(CalibError),
    /// The active line is wider than [`MAX_SCAN_PX`].
    TooWide,
}

impl core::fmt::Display for ScanError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Detect(e) => write!(f, "{e}"),
            Self::Calib(e) => write!(f, "{e}"),
            Self::TooWide => f.write_str("scan: active line wider than MAX_SCAN_PX"),
        }
    }
}

impl core::error::Error for ScanError {}

impl From<DetectError> for ScanError {
    fn from(e: DetectError) -> Self {
        Self::Detect(e)
    }
}

impl From<CalibError> for ScanError {
    fn from(e: CalibError) -> Self {
        Self::Calib(e)
    }
}

/// Most chunks of a line.
const MAX_CHUNKS: usize = MAX_SCAN_PX / CHUNK_PX;

/// Per chunk: the worst-case calibration constants of the current tile row and `D`.
#[derive(Clone, Copy, Debug)]
struct ChunkBound {
    /// Smallest column bias of the chunk, 1/16 ADU.
    cb_min_16: i32,
    /// Output of the chunk; `None` when two outputs read it (not filtered).
    output: Option<u8>,
    /// Largest `d = 16 raw - offset` that cannot exceed the threshold; `None`: no filtering.
    d_max: Option<i32>,
}

/// The streaming calibrate-and-detect pass with the raw pre-filter (see the module docs);
/// `N` is the candidate list's capacity.
#[derive(Clone, Debug)]
pub struct ScanDetector<'t, const N: usize> {
    cal: FrameCalibration<'t>,
    det: LineDetector<N>,
    width: usize,
    e: [Electrons; MAX_SCAN_PX],
    flags: [PixelFlags; MAX_SCAN_PX],
    chunks: [ChunkBound; MAX_CHUNKS],
    /// Tile row (`y >> tile_log2` of both maps) the bounds were computed for, and whether the
    /// background changed since.
    bounds_key: Option<(u32, u32)>,
    /// Each block's join threshold, valid until the background changes.
    thr: [i64; MAX_BLOCKS],
    thr_valid: bool,
    calibrated_px: u32,
}

impl<'t, const N: usize> ScanDetector<'t, N> {
    /// A scan of the frame calibrated by `cal`, detecting with `config`, updating the
    /// background every `background_stride` rows.
    pub fn new(cal: FrameCalibration<'t>, config: DetectConfig, background_stride: u16) -> Self {
        let g = *cal.table().geometry();
        let width = usize::from(g.active_cols);
        let det = LineDetector::new(config, g.active_cols, g.active_rows)
            .with_background_stride(background_stride);
        let mut chunks = [ChunkBound {
            cb_min_16: 0,
            output: None,
            d_max: None,
        }; MAX_CHUNKS];
        for (c, bound) in chunks.iter_mut().enumerate() {
            let x0 = c * CHUNK_PX;
            if x0 >= width {
                break;
            }
            let x1 = (x0 + CHUNK_PX).min(width);
            let (c0, c1) = (g.raw_col_of_x(x0), g.raw_col_of_x(x1 - 1));
            let (o0, o1) = (g.output_of_col(c0), g.output_of_col(c1));
            bound.output = (o0 == o1).then_some(o0.0);
            bound.cb_min_16 = (c0..=c1)
                .map(|c| i32::from(cal.table().column_bias(c).to_bits()))
                .min()
                .unwrap_or(0);
        }
        Self {
            cal,
            det,
            width,
            e: [Electrons::ZERO; MAX_SCAN_PX],
            flags: [PixelFlags::empty(); MAX_SCAN_PX],
            chunks,
            bounds_key: None,
            thr: [0; MAX_BLOCKS],
            thr_valid: false,
            calibrated_px: 0,
        }
    }

    /// The detector (candidates, dropped counts, background).
    pub fn detector(&self) -> &LineDetector<N> {
        &self.det
    }

    /// The candidates found so far (complete after [`Self::finish`]).
    pub fn candidates(&self) -> &[Detection] {
        self.det.candidates()
    }

    /// Pixels calibrated so far (whole background rows plus the chunks that passed).
    pub fn calibrated_px(&self) -> u32 {
        self.calibrated_px
    }

    /// Completes every open blob: call after the last row.
    pub fn finish(&mut self) {
        self.det.finish();
    }

    /// Takes raw line of active row `y` (the whole raw line of the geometry) and its levels.
    pub fn push_raw_line(
        &mut self,
        y: u16,
        raw_line: &[u16],
        levels: &LineLevels,
    ) -> Result<(), ScanError> {
        let w = self.width;
        if w > MAX_SCAN_PX {
            return Err(ScanError::TooWide);
        }
        let (Some(e), Some(f)) = (self.e.get_mut(..w), self.flags.get_mut(..w)) else {
            return Err(ScanError::TooWide);
        };
        if self.det.background_due(y) {
            self.cal.calibrate_span(y, 0, raw_line, levels, e, f)?;
            self.calibrated_px += w as u32;
            self.det.push_line(y, e, f)?;
            // The background changed: the thresholds and bounds must be recomputed.
            self.bounds_key = None;
            self.thr_valid = false;
            return Ok(());
        }
        let g = *self.cal.table().geometry();
        if raw_line.len() != g.line_len() {
            return Err(CalibError::Line(crate::calib::LineError::Length {
                expected: g.line_len() as u16,
                got: u32::try_from(raw_line.len()).unwrap_or(u32::MAX),
            })
            .into());
        }
        if y >= g.active_rows {
            return Err(CalibError::OutsideActiveArea.into());
        }
        self.det.begin_line(y)?;
        self.update_bounds(y);
        let first = g.first_active_col();
        let active = raw_line.get(first..first + w).unwrap_or(&[]);
        let k = self.det.config().pixel_sigmas;
        // The open run's start, carried across chunks.
        let mut run: Option<usize> = None;
        let sat = self.cal.table().saturation_adu();
        let defects = self.cal.row_has_defects(y);
        if !self.thr_valid {
            self.thr = self.det.background().thresholds(k);
            self.thr_valid = true;
        }
        let thr = self.thr;
        for (c, (chunk, bound)) in active.chunks(CHUNK_PX).zip(self.chunks.iter()).enumerate() {
            let x0 = c * CHUNK_PX;
            if !chunk_passes(chunk, raw_threshold(bound, levels, sat)) {
                if let Some(s) = run.take() {
                    self.det
                        .add_run(y, s as u16, (x0 - 1) as u16, &self.e, &self.flags);
                }
                continue;
            }
            let r = raw_threshold(bound, levels, sat);
            if defects {
                // A row with listed defects: the whole exact path, from the first to the last
                // sample above R (the others are quiet).
                let first = chunk.iter().position(|&v| i32::from(v) > r).unwrap_or(0);
                let last = chunk.iter().rposition(|&v| i32::from(v) > r).unwrap_or(0);
                let (a, b) = (x0 + first, x0 + last + 1);
                let (Some(ce), Some(cf)) = (self.e.get_mut(a..b), self.flags.get_mut(a..b)) else {
                    continue;
                };
                self.cal
                    .calibrate_span(y, a as u16, raw_line, levels, ce, cf)?;
                self.calibrated_px += (b - a) as u32;
            } else {
                // No defect on the row: only the samples above R, one by one.
                for (x, &v) in (x0..).zip(chunk.iter()) {
                    if i32::from(v) > r
                        && let (Some(e), Some(f)) = (self.e.get_mut(x), self.flags.get_mut(x))
                    {
                        (*e, *f) = self.cal.calibrate_regular(x as u16, y, v, levels);
                        self.calibrated_px += 1;
                    }
                }
            }
            for (x, &v) in (x0..).zip(chunk.iter()) {
                let t = thr
                    .get(self.det.background().block_of(x))
                    .copied()
                    .unwrap_or(i64::MAX);
                let up = i32::from(v) > r && above_thr(t, &self.e, &self.flags, x);
                match (up, run) {
                    (true, None) => run = Some(x),
                    (false, Some(s)) => {
                        run = None;
                        self.det
                            .add_run(y, s as u16, (x - 1) as u16, &self.e, &self.flags);
                    }
                    _ => {}
                }
            }
        }
        if let Some(s) = run {
            self.det
                .add_run(y, s as u16, (w - 1) as u16, &self.e, &self.flags);
        }
        self.det.end_line(y);
        Ok(())
    }

    /// Recomputes each block's `D` when the tile row changed or the background was updated.
    fn update_bounds(&mut self, y: u16) {
        let t = self.cal.table();
        let dl = t.dark_map().map_or(16, |m| m.header().tile_log2.min(16));
        let fl = t.flat_map().map_or(16, |m| m.header().tile_log2.min(16));
        let key = (u32::from(y) >> dl, u32::from(y) >> fl);
        if self.bounds_key == Some(key) {
            return;
        }
        self.bounds_key = Some(key);
        if !self.thr_valid {
            self.thr = self
                .det
                .background()
                .thresholds(self.det.config().pixel_sigmas);
            self.thr_valid = true;
        }
        let thr = self.thr;
        let ds = self.cal.dark_scale_bits();
        let width = self.width;
        for (c, bound) in self.chunks.iter_mut().enumerate() {
            let x0 = c * CHUNK_PX;
            if x0 >= width {
                break;
            }
            let x1 = (x0 + CHUNK_PX).min(width);
            let Some(out) = bound.output else {
                bound.d_max = None;
                continue;
            };
            // Worst case over the block's tiles on this row: smallest dark term, largest
            // inverse flat.
            let dstep = 1usize << dl.min(15);
            let fstep = 1usize << fl.min(15);
            let dark_min = (x0..x1)
                .step_by(dstep)
                .map(|x| dark_16ths(t.dark_rel(x as u16, y), ds))
                .min()
                .unwrap_or(0);
            let flat_max = (x0..x1)
                .step_by(fstep)
                .map(|x| t.flat_inv(x as u16, y))
                .max()
                .unwrap_or(FlatInv::ONE);
            let thr = thr
                .get(self.det.background().block_of(x0))
                .copied()
                .unwrap_or(i64::MAX);
            let gain = t.gain(crate::geometry::Output(out));
            bound.d_max = largest_quiet_d(thr, gain, dark_min, flat_max);
        }
    }
}

/// The raw level at or below which no pixel of the block can be above the threshold, as
/// i32 in `-1..sat` (-1: every sample passes).
#[inline(always)]
fn raw_threshold(bound: &ChunkBound, levels: &LineLevels, sat: u16) -> i32 {
    let (Some(d), Some(o)) = (bound.d_max, bound.output) else {
        return -1;
    };
    let bias: BiasAdu = levels.bias(crate::geometry::Output(o));
    // offset = 16 bias + column bias; bias16 < 2^20, |cb| < 2^15, |d| <= 2^21: no overflow.
    let off_min = (bias.to_bits().min(65535 * 16) as i32) + bound.cb_min_16;
    // raw <= floor((d + off_min) / 16) implies 16 raw - offset <= d for every column.
    ((d + off_min) >> 4).clamp(-1, i32::from(sat) - 1)
}

/// True when some sample of `chunk` is above `r`: `r - s` is negative for it (both fit
/// i32, so the difference is exact), and OR keeps the sign bit.
#[inline(always)]
fn chunk_passes(chunk: &[u16], r: i32) -> bool {
    // A whole chunk as an array: fully unrolled, ldrh / sub / orr per sample on the M7. A
    // short last chunk always passes (it is calibrated).
    let Ok(a) = <&[u16; CHUNK_PX]>::try_from(chunk) else {
        return true;
    };
    let mut acc = 0i32;
    for &s in a {
        acc |= r - i32::from(s);
    }
    acc < 0
}

/// The largest `d` in the calibration's range (|d| < 2^21) with
/// `pixel_bits(d, gain, dark, flat) <= thr`, or `None` when the threshold is not positive
/// (a pixel at 0 e- or below might pass) or even the smallest `d` exceeds it.
///
/// Monotonicity makes every smaller `d` quiet too. A pixel with a larger dark term or a
/// smaller inverse flat (for a positive signal) calibrates lower, so `d` quiet for the worst
/// case is quiet for every pixel of the block; with a negative signal the result is at most
/// 0 <= `thr`.
fn largest_quiet_d(thr: i64, gain: GainEPerAdu, dark: i64, flat: FlatInv) -> Option<i32> {
    const D_MIN: i32 = -(1 << 21);
    const D_MAX: i32 = (1 << 21) - 1;
    if thr <= 0 {
        return None;
    }
    let e = |d: i32| i64::from(pixel_bits(d, gain, dark, flat));
    if e(D_MIN) > thr {
        return None;
    }
    if e(D_MAX) <= thr {
        return Some(D_MAX);
    }
    // The f32 inverse of the formula without its roundings,
    // d* = (thr 2^24 / flat + dark) 2^16 / gain, is where e(d) reaches thr; step below it
    // until the exact formula confirms (each failure doubles the step), so the result is
    // exact-safe whatever the float error, and at most ~1/2 ADU below the true limit.
    let est = ((thr as f32 * 16_777_216.0 / f32::from(flat.to_bits()).max(1.0)) + dark as f32)
        * 65_536.0
        / (gain.to_bits() as f32).max(1.0);
    let mut d = if est.is_finite() {
        (est as i32).clamp(D_MIN, D_MAX)
    } else {
        D_MIN
    };
    let mut step = 8i32;
    loop {
        d = d.saturating_sub(step).max(D_MIN);
        if d == D_MIN || e(d) <= thr {
            return Some(d);
        }
        step = step.saturating_mul(2);
    }
}
