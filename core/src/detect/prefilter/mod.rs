//! The streaming scan with a raw-domain pre-filter: calibrate-and-detect a frame line by line
//! while calibrating only the pixels that can be above the detection threshold.
//!
//! # Method
//! Calibration is monotone: with the gain and the inverse flat positive, a pixel's electrons
//! never decrease when its raw sample grows (`calib::formula`'s formula, floor shifts and the
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
//! The scan then reads the raw active samples in chunks of [`CHUNK_PX`]. The fast test
//! (`window_quiet`) takes two samples per 32-bit word: with a power-of-two window
//! `base..=R` fixed per tile row, `word - base * 0x10001` keeps every lane inside the
//! window's low bits exactly when both samples lie in it, so load, subtract and OR per two
//! samples prove a chunk quiet. A chunk that fails it (a sample above `R`, or one below
//! `base`, under `R / 2`) gets the exact test, a bit mask of the samples above `R`
//! (`above_mask`); only those samples are calibrated (the regular formula with the line's
//! constants hoisted, bit for bit as `FrameCalibration::calibrate_regular` and
//! `calibrate_span`; on a row where the table lists a hot or telegraph pixel, by
//! `calibrate_span` itself, defects included) and thresholded exactly as
//! [`LineDetector::push_line`] does, runs taken from consecutive set bits. Pixels of
//! the other chunks are provably not above the threshold (hot, telegraph and saturated
//! pixels included: `R` is below the saturation level, and listed defects never join a
//! blob), so **the candidates are exactly those of a [`LineDetector`] with the same
//! background stride fed every calibrated line**; the host test `scan` checks it bit for bit
//! on simulated frames and random tables.
//!
//! The background needs every pixel of a line: rows with `y % background_stride == 0` (and
//! the first row, and the warm-up rows of [`ScanDetector::with_background_warmup`]) are
//! calibrated whole and go through [`LineDetector::push_line`].
//!
//! # Cost
//! On the M7 (`cargo m7-bench`, `scan_detect`, 128 rows, 10 stars, stride 64), per pixel:
//! a quiet chunk ~46 instructions (24 for its 16 samples, ~22 of bound, window and loop:
//! ~2.9 a pixel); the bounds, per tile row and chunk ~300 (two dark and two flat tiles, the
//! f32 inverse and one or two exact evaluations: ~2.3 a pixel at 8-row tiles); the chunks
//! noise sends to the exact path (~9 % at the 2.5-sigma join level) ~4 a pixel (mask,
//! ~75 a calibrated sample, runs and blobs); background rows (calibrated whole at ~74 a
//! pixel, two selections per block) ~2.5 a pixel at stride 64.
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

mod bounds;
mod line;

use super::background::MAX_BLOCKS;
use super::{DetectConfig, DetectError, Detection, LineDetector};
use crate::calib::{CalibError, FrameCalibration, FrameConditions, LineLevels, PixelFlags};
use crate::units::Electrons;
use bounds::{ChunkBound, NO_FILTER};

/// Samples tested together by the pre-filter.
pub(crate) const CHUNK_PX: usize = 16;
/// Widest active line the scan filters (wider lines are rejected with an error).
pub(crate) const MAX_SCAN_PX: usize = 2048;

/// Why a raw line was not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ScanError {
    /// The detector refused the line (row order).
    Detect(DetectError),
    /// Calibration failed (line length, row outside the active area).
    Calib(CalibError),
    /// The active line is wider than `MAX_SCAN_PX` (2048).
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
    /// First chunk read by the second output (its chunks take output 1's bias; the chunk
    /// the outputs share is not filtered).
    split_chunk: usize,
    /// Tile row (`y >> tile_log2` of both maps) the bounds were computed for, and whether the
    /// background changed since.
    bounds_key: Option<(u32, u32)>,
    /// Each block's join threshold, valid until the background changes.
    thr: [i64; MAX_BLOCKS],
    thr_valid: bool,
    calibrated_px: u32,
    /// Row `defect_from`'s `FrameCalibration::row_has_defects`, and the first row after
    /// it where the table lists a hot or telegraph pixel (`u32::MAX`: none): the rows
    /// between have none, so the searches of the defect lists run once per listed row
    /// instead of once per row.
    defect_from: u32,
    defect_from_has: bool,
    next_defect: u32,
    /// The last line pushed was calibrated whole (a background row): `e` and `flags` hold
    /// it (see [`Self::whole_line`]).
    whole: bool,
}

// The scan of one raw line (`push_raw_line`) is in line.rs, the chunks' bounds in bounds.rs.
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
            dcb: NO_FILTER,
            c1: 0,
            outside: u32::MAX,
        }; MAX_CHUNKS];
        let mut split_chunk = MAX_CHUNKS;
        for (c, bound) in chunks.iter_mut().enumerate() {
            let x0 = c * CHUNK_PX;
            if x0 >= width {
                break;
            }
            let x1 = (x0 + CHUNK_PX).min(width);
            let (c0, c1) = (g.raw_col_of_x(x0), g.raw_col_of_x(x1 - 1));
            let (o0, o1) = (g.output_of_col(c0), g.output_of_col(c1));
            bound.output = (o0 == o1).then_some(o0.0);
            if o0.0 != 0 {
                split_chunk = split_chunk.min(c);
            }
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
            split_chunk,
            bounds_key: None,
            thr: [0; MAX_BLOCKS],
            thr_valid: false,
            calibrated_px: 0,
            defect_from: u32::MAX,
            defect_from_has: false,
            next_defect: 0,
            whole: false,
        }
    }

    /// The calibration the following lines use: the same table with new frame conditions
    /// (the firmware's first frame calibrates each line with the running dark-scale
    /// estimate). The chunks' bounds are recomputed on the next line when the dark scale
    /// changed (they depend on it through the dark term); the table, hence the column-bias
    /// minima, is kept. Cost: a compare when nothing changed.
    pub fn set_conditions(&mut self, conditions: FrameConditions) {
        if *self.cal.conditions() == conditions {
            return;
        }
        let cal = FrameCalibration::new(*self.cal.table(), conditions);
        if cal.dark_scale_bits() != self.cal.dark_scale_bits() {
            self.bounds_key = None;
        }
        self.cal = cal;
    }

    /// The last line pushed, calibrated (electrons and flags of every active pixel), when it
    /// was calibrated whole: a background row (`y % background_stride == 0`, the first row
    /// and the warm-up rows: [`LineDetector::background_due`]); `None` after any other line, whose quiet pixels were never calibrated.
    pub fn whole_line(&self) -> Option<(&[Electrons], &[PixelFlags])> {
        if !self.whole {
            return None;
        }
        Some((self.e.get(..self.width)?, self.flags.get(..self.width)?))
    }

    /// [`Self::push_raw_line`], then writes into `closed` the candidates that this line
    /// completed and the list kept, exactly as [`LineDetector::push_line_closed`] does with
    /// the calibrated line (a new candidate, or one that replaced a fainter one; a candidate
    /// the full list refused is not reported, it is counted in [`LineDetector::dropped`]).
    /// On an error `closed` is empty. Cost: a copy of the candidate list per line.
    pub fn push_raw_line_closed(
        &mut self,
        y: u16,
        raw_line: &[u16],
        levels: &LineLevels,
        closed: &mut heapless::Vec<Detection, N>,
    ) -> Result<(), ScanError> {
        closed.clear();
        let before = self.candidate_copy();
        self.push_raw_line(y, raw_line, levels)?;
        self.changed_since(&before, closed);
        Ok(())
    }

    /// [`Self::finish`], reporting the candidates it completed like
    /// [`Self::push_raw_line_closed`] (as [`LineDetector::finish_closed`]).
    pub fn finish_closed(&mut self, closed: &mut heapless::Vec<Detection, N>) {
        closed.clear();
        let before = self.candidate_copy();
        self.finish();
        self.changed_since(&before, closed);
    }

    /// The candidate list as it is (same capacity: the copy is whole).
    fn candidate_copy(&self) -> heapless::Vec<Detection, N> {
        let mut v = heapless::Vec::new();
        for c in self.det.candidates() {
            // Same capacity as the detector's list: cannot fail.
            let _ = v.push(*c);
        }
        v
    }

    /// The candidates that differ from `before` at their index (as
    /// `LineDetector::changed_since`: the list only grows or replaces in place).
    fn changed_since(
        &self,
        before: &heapless::Vec<Detection, N>,
        closed: &mut heapless::Vec<Detection, N>,
    ) {
        for (i, c) in self.det.candidates().iter().enumerate() {
            if before.get(i) != Some(c) {
                // `closed` has the list's capacity, so this cannot fail.
                let _ = closed.push(*c);
            }
        }
    }

    /// Also updates the background on every row `y < rows` (those are calibrated whole):
    /// [`LineDetector::with_background_warmup`]. With a long stride the background otherwise
    /// rests on the first row's own noise estimate for hundreds of rows, and noise
    /// candidates multiply (host test `scan`); 16 rows cost 16 whole-row calibrations a
    /// frame.
    pub fn with_background_warmup(mut self, rows: u16) -> Self {
        self.det = self.det.with_background_warmup(rows);
        self
    }

    /// The detector (candidates, dropped counts, background).
    pub fn detector(&self) -> &LineDetector<N> {
        &self.det
    }

    /// The candidates found so far (complete after [`Self::finish`]).
    pub fn candidates(&self) -> &[Detection] {
        self.det.candidates()
    }

    /// [`LineDetector::forget`].
    pub fn forget(&mut self, d: &Detection) -> bool {
        self.det.forget(d)
    }

    /// Pixels calibrated so far (whole background rows plus the chunks that passed).
    pub fn calibrated_px(&self) -> u32 {
        self.calibrated_px
    }

    /// Completes every open blob: call after the last row.
    pub fn finish(&mut self) {
        self.det.finish();
    }
}
