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

use super::background::MAX_BLOCKS;
use super::blobs::{above_thr, px_above_thr};
use super::{DetectConfig, DetectError, Detection, LineDetector};
use crate::calib::formula::{dark_16ths, pixel_bits_d as pixel_bits};
use crate::calib::pixel::saturation_flag;
use crate::calib::{CalibError, FrameCalibration, FrameConditions, LineLevels, PixelFlags};
use crate::table::MapView;
use crate::units::{BiasAdu, DarkRel, Electrons, FlatInv, GainEPerAdu};

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

/// `ChunkBound::dcb` of a chunk that is not filtered: with any bias (< 2^20 in 1/16 ADU) its
/// `R` stays below -1, so every sample passes.
const NO_FILTER: i32 = i32::MIN / 2;

/// Per chunk: the worst-case bound of the current tile row and background.
#[derive(Clone, Copy, Debug)]
struct ChunkBound {
    /// Smallest column bias of the chunk, 1/16 ADU (|cb| < 2^15).
    cb_min_16: i32,
    /// Output of the chunk; `None` when two outputs read it (not filtered).
    output: Option<u8>,
    /// `d_max + cb_min_16` in 1/16 ADU, `d_max` the largest `d = 16 raw - offset` that cannot
    /// exceed the threshold (|.| < 2^22), or [`NO_FILTER`]: the line's
    /// `R = (dcb + 16 bias) >> 4` then costs one add and one shift.
    dcb: i32,
    /// `1 - 2^k` of the quiet test's window (see [`window_quiet`]), with `2^k` the largest
    /// power of two at most half of `R + 1` for the line the bound was computed on, so the
    /// window stays valid while the bias moves by less than `R / 2`.
    c1: i32,
    /// `!((2^k - 1) * 0x10001)`: the bits outside the window's low bits in both 16-bit
    /// lanes.
    outside: u32,
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

    /// The calibration in use.
    pub fn calibration(&self) -> &FrameCalibration<'t> {
        &self.cal
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
        self.whole = false;
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
            self.whole = true;
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
        // Each output's 16 bias, clamped as the bound's range needs (< 2^20).
        let bias16 = |o: u8| {
            let b: BiasAdu = levels.bias(crate::geometry::Output(o));
            b.to_bits().min(65535 * 16) as i32
        };
        let bias_pair = [bias16(0), bias16(1)];
        let sat_m1 = i32::from(self.cal.table().saturation_adu()) - 1;
        self.update_bounds(y, bias_pair, sat_m1);
        let first = g.first_active_col();
        let active = raw_line.get(first..first + w).unwrap_or(&[]);
        let Self {
            cal,
            det,
            e,
            flags,
            chunks,
            thr,
            calibrated_px,
            split_chunk,
            defect_from,
            defect_from_has,
            next_defect,
            ..
        } = self;
        let t = cal.table();
        let yu = u32::from(y);
        if yu < *defect_from || yu >= *next_defect {
            // The next listed row after y: the first entry at or after (0, y + 1).
            let after = y.saturating_add(1);
            let (hot, tel) = (t.hot_pixels(), t.telegraph_pixels());
            let h = hot
                .get(hot.lower_bound(0, after))
                .map_or(u32::MAX, |h| u32::from(h.y));
            let g = tel
                .get(tel.lower_bound(0, after))
                .map_or(u32::MAX, |(_, ty)| u32::from(ty));
            *defect_from = yu;
            *defect_from_has = cal.row_has_defects(y);
            *next_defect = if y == u16::MAX { u32::MAX } else { h.min(g) };
        }
        let defects = yu == *defect_from && *defect_from_has;
        let (dmap, fmap) = (t.dark_map(), t.flat_map());
        let (dl, fl) = (tile_log2(dmap), tile_log2(fmap));
        let consts = LineConsts {
            bias16: bias_pair,
            gain: [
                t.gain(crate::geometry::Output(0)),
                t.gain(crate::geometry::Output(1)),
            ],
            dmap,
            fmap,
            drow: tile_row_start(dmap, dl, y),
            frow: tile_row_start(fmap, fl, y),
            dl,
            fl,
            ds: cal.dark_scale_bits(),
            sat: t.saturation_adu(),
            first_col: first,
        };
        let mut line = LineScan {
            y,
            raw_line,
            levels,
            consts,
            defects,
            run: None,
            cal,
            det,
            e,
            flags,
            thr,
            calibrated_px,
        };
        let (full, tail) = active.as_chunks::<CHUNK_PX>();
        // Each output's chunks with its bias: no per-chunk output select.
        let split = (*split_chunk).min(full.len());
        let (full0, full1) = full.split_at(split);
        let (bounds0, bounds1) = chunks.split_at(split);
        let [bias0, bias1] = bias_pair;
        line.scan_chunks(0, full0, bounds0, bias0, sat_m1)?;
        line.scan_chunks(split * CHUNK_PX, full1, bounds1, bias1, sat_m1)?;
        let x0 = full.len() * CHUNK_PX;
        if !tail.is_empty() {
            // A short last chunk is not tested: its samples above R go the exact way.
            let bias = if full.len() < *split_chunk {
                bias0
            } else {
                bias1
            };
            let r = chunks
                .get(x0 / CHUNK_PX)
                .map_or(-1, |b| raw_threshold(b, bias, sat_m1));
            let mut above = 0u32;
            for (i, &v) in tail.iter().enumerate().take(CHUNK_PX) {
                above |= u32::from(i32::from(v) > r) << i;
            }
            let output = chunks.get(x0 / CHUNK_PX).and_then(|b| b.output);
            line.exact_chunk(x0, tail, above, output)?;
        }
        if let Some(s) = line.run {
            line.det
                .add_run(y, s as u16, (w - 1) as u16, line.e, line.flags);
        }
        self.det.end_line(y);
        Ok(())
    }

    /// Recomputes each chunk's bound when the tile row changed or the background was updated.
    fn update_bounds(&mut self, y: u16, [bias0, bias1]: [i32; 2], sat_m1: i32) {
        let t = self.cal.table();
        let (dl, fl) = (tile_log2(t.dark_map()), tile_log2(t.flat_map()));
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
        let ds = self.cal.dark_scale_bits();
        let width = self.width;
        let gains = [
            t.gain(crate::geometry::Output(0)),
            t.gain(crate::geometry::Output(1)),
        ];
        // First tile of row y in each map (row-major tiles).
        let (dmap, fmap) = (t.dark_map(), t.flat_map());
        let (drow, frow) = (tile_row_start(dmap, dl, y), tile_row_start(fmap, fl, y));
        for (c, bound) in self.chunks.iter_mut().enumerate() {
            let x0 = c * CHUNK_PX;
            if x0 >= width {
                break;
            }
            let x1 = (x0 + CHUNK_PX).min(width);
            let Some(out) = bound.output else {
                bound.dcb = NO_FILTER;
                (bound.c1, bound.outside) = (0, u32::MAX);
                continue;
            };
            // Worst case over the chunk's tiles on this row: smallest dark term, largest
            // inverse flat. The tiles by index, `x0 >> l ..= (x1 - 1) >> l` in the row's tile
            // range (x < active columns and y < active rows: the values `dark_rel` /
            // `flat_inv` give, without their per-pixel index and range checks).
            let (dt0, dt1) = (drow + (x0 >> dl), drow + ((x1 - 1) >> dl));
            let dark_min = (dt0..=dt1)
                .map(|i| {
                    let rel = dmap
                        .and_then(|m| m.tile_bits(i))
                        .map_or(DarkRel::ONE, |b| DarkRel::from_bits(b as u8));
                    dark_16ths(rel, ds)
                })
                .min()
                .unwrap_or(0);
            let (ft0, ft1) = (frow + (x0 >> fl), frow + ((x1 - 1) >> fl));
            let flat_max = (ft0..=ft1)
                .map(|i| {
                    fmap.and_then(|m| m.tile_bits(i))
                        .map_or(FlatInv::ONE, |b| FlatInv::from_bits(b as u16))
                })
                .max()
                .unwrap_or(FlatInv::ONE);
            let thr = self
                .thr
                .get(self.det.background().block_of(x0))
                .copied()
                .unwrap_or(i64::MAX);
            let [g0, g1] = gains;
            let gain = if out == 0 { g0 } else { g1 };
            bound.dcb = largest_quiet_d(thr, gain, dark_min, flat_max)
                .map_or(NO_FILTER, |d| d + bound.cb_min_16);
            // The quiet test's window for this line's R (any window is exact; one too wide
            // for a later line's R only sends its chunks to the exact mask).
            let bias = if c < self.split_chunk { bias0 } else { bias1 };
            let r = raw_threshold(bound, bias, sat_m1);
            let half = u32::try_from(r).map_or(0, |r| r.div_ceil(2));
            let span = if half == 0 {
                1
            } else {
                1u32 << (31 - half.leading_zeros())
            };
            bound.c1 = 1 - span as i32;
            bound.outside = !((span - 1) * 0x1_0001);
        }
    }
}

/// The calibration constants of one line that `FrameCalibration::calibrate_regular` looks
/// up for every pixel: each output's bias (1/16 ADU, clamped as `offset_16ths`) and gain,
/// the maps and the first tile of this row in each, the dark scale, the saturation level
/// and the first active raw column.
#[derive(Clone, Copy)]
struct LineConsts<'t> {
    bias16: [i32; 2],
    gain: [GainEPerAdu; 2],
    dmap: Option<MapView<'t>>,
    fmap: Option<MapView<'t>>,
    drow: usize,
    frow: usize,
    dl: u8,
    fl: u8,
    ds: i32,
    sat: u16,
    first_col: usize,
}

/// A map's `tile_log2` (16 without a map: every column in one tile).
fn tile_log2(m: Option<MapView<'_>>) -> u8 {
    m.map_or(16, |m| m.header().tile_log2.min(16))
}

/// Index of the first tile of active row `y`'s tile row (row-major tiles; 0 without a map).
fn tile_row_start(m: Option<MapView<'_>>, l: u8, y: u16) -> usize {
    m.map_or(0, |m| {
        (usize::from(y) >> l) * usize::from(m.header().tiles_x)
    })
}

/// One non-background line's state while its chunks are scanned, and the scan's parts it
/// updates.
struct LineScan<'a, 't, const N: usize> {
    y: u16,
    raw_line: &'a [u16],
    levels: &'a LineLevels,
    consts: LineConsts<'t>,
    /// The table lists a hot or telegraph pixel on this row.
    defects: bool,
    /// The open run's start, carried across chunks.
    run: Option<usize>,
    cal: &'a FrameCalibration<'t>,
    det: &'a mut LineDetector<N>,
    e: &'a mut [Electrons; MAX_SCAN_PX],
    flags: &'a mut [PixelFlags; MAX_SCAN_PX],
    thr: &'a [i64; MAX_BLOCKS],
    calibrated_px: &'a mut u32,
}

impl<const N: usize> LineScan<'_, '_, N> {
    /// Active pixel `x` of this row (no listed defect on the row), read by `output`, with
    /// raw sample `raw`: the same look-ups and [`pixel_bits`] as
    /// `FrameCalibration::calibrate_regular`, so the same bits and flags (the `scan` tests
    /// check it), with the per-line constants of [`LineConsts`]: ~70 instructions on the M7
    /// instead of ~140.
    #[inline(always)]
    fn calibrate(&self, x: usize, raw: u16, output: u8) -> (Electrons, PixelFlags) {
        let k = &self.consts;
        let [b0, b1] = k.bias16;
        let [g0, g1] = k.gain;
        let (bias16, gain) = if output == 0 { (b0, g0) } else { (b1, g1) };
        let cb = self.cal.table().column_bias(k.first_col + x);
        let rel = k
            .dmap
            .and_then(|m| m.tile_bits(k.drow + (x >> k.dl)))
            .map_or(DarkRel::ONE, |b| DarkRel::from_bits(b as u8));
        let flat = k
            .fmap
            .and_then(|m| m.tile_bits(k.frow + (x >> k.fl)))
            .map_or(FlatInv::ONE, |b| FlatInv::from_bits(b as u16));
        let d = (i32::from(raw) << 4) - (bias16 + i32::from(cb.to_bits()));
        let e = pixel_bits(d, gain, dark_16ths(rel, k.ds), flat);
        (Electrons::from_bits(e), saturation_flag(raw, k.sat))
    }

    /// The full chunks `data` of one output, from column `x0`, with their bounds and the
    /// output's bias (1/16 ADU): per chunk `R`, the window test, and for a chunk that fails
    /// it the exact mask and [`Self::exact_chunk`].
    fn scan_chunks(
        &mut self,
        mut x0: usize,
        data: &[[u16; CHUNK_PX]],
        bounds: &[ChunkBound],
        bias: i32,
        sat_m1: i32,
    ) -> Result<(), ScanError> {
        for (a, bound) in data.iter().zip(bounds) {
            let r = raw_threshold(bound, bias, sat_m1);
            // base = R + 1 - span; negative (R far below the bound's line, or no filter):
            // the exact mask decides.
            let base = r + bound.c1;
            let quiet = u32::try_from(base).is_ok_and(|b| window_quiet(a, b, bound.outside));
            let above = if quiet { 0 } else { above_mask(a, r) };
            if above == 0 {
                // Test before taking: `take` would store `None` on every quiet chunk.
                if let Some(s) = self.run {
                    self.run = None;
                    self.det
                        .add_run(self.y, s as u16, (x0 - 1) as u16, self.e, self.flags);
                }
            } else {
                self.exact_chunk(x0, a, above, bound.output)?;
            }
            x0 += CHUNK_PX;
        }
        Ok(())
    }

    /// A chunk (at column `x0`, at most 16 samples) with samples above its `R` (bit `i` of
    /// `above` set for sample `i`): calibrates those samples (on a row with listed defects,
    /// the span from the first to the last of them through `calibrate_span`, defects
    /// included) and adds the runs of those above the join threshold, exactly as
    /// [`LineDetector::push_line`] would.
    ///
    /// Cost: per set bit one calibration and one threshold test, per run of set bits one
    /// `add_run`.
    fn exact_chunk(
        &mut self,
        x0: usize,
        a: &[u16],
        above: u32,
        output: Option<u8>,
    ) -> Result<(), ScanError> {
        let y = self.y;
        // The chunk lies in one background block (BLOCK_PX is a multiple of CHUNK_PX).
        let t = self
            .thr
            .get(self.det.background().block_of(x0))
            .copied()
            .unwrap_or(i64::MAX);
        // Bit i: sample i joins a blob (above R, and above the join threshold once
        // calibrated).
        let mut up = 0u32;
        if above != 0 && self.defects {
            // A row with listed defects: the whole exact path, from the first to the last
            // sample above R (the others are quiet).
            let (lo, hi) = (above.trailing_zeros(), 32 - above.leading_zeros());
            let (ax, bx) = (x0 + lo as usize, x0 + hi as usize);
            if let (Some(ce), Some(cf)) = (self.e.get_mut(ax..bx), self.flags.get_mut(ax..bx)) {
                self.cal
                    .calibrate_span(y, ax as u16, self.raw_line, self.levels, ce, cf)?;
                *self.calibrated_px += (bx - ax) as u32;
            }
            let mut m = above;
            while m != 0 {
                let i = m.trailing_zeros();
                m &= m - 1;
                if above_thr(t, self.e.as_slice(), self.flags.as_slice(), x0 + i as usize) {
                    up |= 1 << i;
                }
            }
        } else {
            // No defect on the row: only the samples above R, one by one, thresholded as
            // they are calibrated.
            let mut m = above;
            while m != 0 {
                let i = m.trailing_zeros();
                m &= m - 1;
                let x = x0 + i as usize;
                let Some(&v) = a.get(i as usize) else {
                    continue;
                };
                let (ev, fv) = match output {
                    Some(o) => self.calibrate(x, v, o),
                    None => self.cal.calibrate_regular(x as u16, y, v, self.levels),
                };
                if let (Some(e), Some(f)) = (self.e.get_mut(x), self.flags.get_mut(x)) {
                    (*e, *f) = (ev, fv);
                    *self.calibrated_px += 1;
                    up |= u32::from(px_above_thr(t, ev, fv)) << i;
                }
            }
        }
        // Runs of consecutive set bits; a run open at the chunk's start continues when bit 0
        // is set and stays open when it reaches the chunk's end.
        let n = a.len().min(CHUNK_PX) as u32;
        if up & 1 == 0
            && let Some(start) = self.run.take()
        {
            self.det
                .add_run(y, start as u16, (x0 - 1) as u16, self.e, self.flags);
        }
        let mut m = up;
        while m != 0 {
            let lo = m.trailing_zeros();
            let len = (!(m >> lo)).trailing_zeros();
            let hi = lo + len;
            let start = match (lo, self.run.take()) {
                (0, Some(open)) => open,
                _ => x0 + lo as usize,
            };
            if hi >= n {
                self.run = Some(start);
                break;
            }
            self.det.add_run(
                y,
                start as u16,
                (x0 + hi as usize - 1) as u16,
                self.e,
                self.flags,
            );
            m = m.checked_shr(hi).unwrap_or(0).checked_shl(hi).unwrap_or(0);
        }
        Ok(())
    }
}

/// The raw level at or below which no pixel of the chunk can be above the threshold, at
/// most `sat_m1` (below -1, or -1: every sample passes). `bias`: the chunk's output's bias
/// in 1/16 ADU.
#[inline(always)]
fn raw_threshold(bound: &ChunkBound, bias: i32, sat_m1: i32) -> i32 {
    // offset = 16 bias + column bias; |dcb| < 2^22 or NO_FILTER, bias < 2^20: no overflow.
    // raw <= floor((d + off_min) / 16) implies 16 raw - offset <= d for every column.
    ((bound.dcb + bias) >> 4).min(sat_m1)
}

/// The pre-filter's fast test: true when every sample of `a` lies in
/// `base..=base + span - 1`, with `outside = !((span - 1) * 0x10001)`, `span` a power of two
/// and `base + span <= 65536`; so the chunk is quiet when `base + span - 1 <= R`.
///
/// Two samples per 32-bit word: `word - base * 0x10001` has each 16-bit lane equal to
/// `sample - base` when every sample lies in the window, and a lane bit at or above `k`
/// (`span = 2^k`) set otherwise (a lane above the window is at least `span`; a lane below
/// `base` borrows and wraps to at least `65536 - base >= span`; a borrow only disturbs a
/// lane that is already flagged). So an OR of those differences without a bit outside the
/// two lanes' low `k` bits proves every sample in the window: load, subtract and OR per
/// two samples.
#[inline(always)]
fn window_quiet(a: &[u16; CHUNK_PX], base: u32, outside: u32) -> bool {
    let bb = base | (base << 16);
    let mut acc = 0u32;
    for p in a.as_chunks::<2>().0 {
        let [s0, s1] = *p;
        acc |= (u32::from(s0) | (u32::from(s1) << 16)).wrapping_sub(bb);
    }
    acc & outside == 0
}

/// The exact test: bit `i` set when sample `i` is above `r` (the sign of `r - sample`, both
/// fit i32). Out of line: inlined, the compiler kept the words loaded for
/// [`window_quiet`] on the stack for it (~8 stores a chunk).
#[inline(never)]
fn above_mask(a: &[u16; CHUNK_PX], r: i32) -> u32 {
    let mut m = 0u32;
    for (i, &s) in a.iter().enumerate() {
        m |= ((r - i32::from(s)) as u32 >> 31) << i;
    }
    m
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
    // The f32 inverse of the formula without its roundings,
    // d* = (thr 2^24 / flat + dark) 2^16 / gain, is where e(d) reaches thr; step below it
    // until the exact formula confirms (each failure doubles the step), so the result is
    // exact-safe whatever the float error. One or two exact evaluations when the estimate
    // holds. i64 to f32 is a library call on the M7, so
    // both go through i32 (saturated): a saturated estimate is only further from the limit,
    // which the stepping absorbs (the exact check decides, never the estimate).
    let to_f32 =
        |v: i64| i32::try_from(v).unwrap_or(if v < 0 { i32::MIN } else { i32::MAX }) as f32;
    let est = ((to_f32(thr) * 16_777_216.0 / f32::from(flat.to_bits()).max(1.0)) + to_f32(dark))
        * 65_536.0
        / (gain.to_bits() as f32).max(1.0);
    let d_est = if est.is_finite() {
        (est as i32).clamp(D_MIN, D_MAX)
    } else {
        D_MIN
    };
    // The estimate is within a unit or two of the limit (the f32 error and the formula's
    // roundings are each below one unit of d, 1/16 ADU): try just above it, then just
    // below, before stepping down (the first try that holds is the bound: the closer to the
    // limit, the fewer quiet chunks fail the pre-filter).
    for d in [
        d_est.saturating_add(1).min(D_MAX),
        d_est.saturating_sub(1).max(D_MIN),
    ] {
        if e(d) <= thr {
            return Some(d);
        }
    }
    let mut d = d_est;
    let mut step = 8i32;
    loop {
        d = d.saturating_sub(step).max(D_MIN);
        if e(d) <= thr {
            return Some(d);
        }
        if d == D_MIN {
            // Even the smallest d exceeds the threshold.
            return None;
        }
        step = step.saturating_mul(2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `window_quiet` and `above_mask` against their definitions on chunks around the edges
    /// of power-of-two windows ending at `r`: samples at `base - 1`, `base`, `r`, `r + 1`, 0
    /// and 65535 in either lane of a word, for `r` over the whole range.
    #[test]
    #[allow(clippy::indexing_slicing)]
    fn quiet_tests_are_exact() {
        let mut state = 0x1234_5678u32;
        let mut next = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            state >> 8
        };
        let mut checked = 0u32;
        let fixed: [i32; 14] = [
            -3, -1, 0, 1, 2, 3, 62, 63, 64, 1000, 1023, 1024, 65_533, 65_534,
        ];
        for i in 0..fixed.len() + 200 {
            // The edge cases, then random levels below the saturation level.
            let r = fixed
                .get(i)
                .copied()
                .unwrap_or_else(|| (next() % 65_535) as i32);
            let ru = r.max(0) as u32;
            // Any power-of-two window ending at r: the largest, or a random smaller one.
            let k_max = 31 - (ru + 1).leading_zeros();
            let k = if i % 2 == 0 {
                k_max
            } else {
                next() % (k_max + 1)
            };
            let span = 1u32 << k;
            let base = (ru + 1 - span) as i32;
            let keep = (span - 1) * 0x1_0001;
            let specials = [base - 1, base, base + 1, r - 1, r, r + 1, 0, 65_535];
            for _ in 0..200 {
                // Mostly inside the window, a few specials at random places.
                let mut a = [0u16; CHUNK_PX];
                for s in a.iter_mut() {
                    let v = if r >= 0 {
                        base + (next() % span) as i32
                    } else {
                        0
                    };
                    *s = v.clamp(0, 65_535) as u16;
                }
                for _ in 0..(next() % 3) {
                    let i = (next() as usize) % CHUNK_PX;
                    let v = specials[(next() as usize) % specials.len()];
                    a[i] = v.clamp(0, 65_535) as u16;
                }
                let want = a.iter().all(|&s| i32::from(s) <= r);
                let mask = a
                    .iter()
                    .enumerate()
                    .fold(0u32, |m, (i, &s)| m | (u32::from(i32::from(s) > r) << i));
                assert_eq!(above_mask(&a, r), mask, "r {r} chunk {a:?}");
                if r >= 0 {
                    // The fast test calls a chunk quiet exactly when every sample lies in
                    // base..=r (so never with a sample above r).
                    let quiet = window_quiet(&a, base as u32, !keep);
                    assert!(!quiet || want, "r {r} chunk {a:?}");
                    let inside = a.iter().all(|&s| (base..=r).contains(&i32::from(s)));
                    assert_eq!(quiet, inside, "r {r} span {span} chunk {a:?}");
                }
                checked += 1;
            }
        }
        assert_eq!(checked, 214 * 200);
    }
}
