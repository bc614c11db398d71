//! One raw line of the scan ([`ScanDetector::push_raw_line`]): a background row is
//! calibrated whole and fed to the detector; any other row is read in chunks of
//! [`CHUNK_PX`] samples, a quiet chunk is skipped by the window test of [`super::bounds`],
//! and only the samples of the other chunks that are above their `R` are calibrated (the
//! line's constants hoisted, bit for bit as `FrameCalibration::calibrate_regular`) and
//! thresholded exactly as `LineDetector::push_line` does, runs carried across chunks.
//!
//! # Cost
//! On the M7 (`cargo m7-bench`, `scan_detect`): a quiet chunk ~46 instructions (~2.9 a
//! pixel); the chunks noise sends to the exact path ~4 a pixel (mask, ~75 a calibrated
//! sample, runs and blobs); background rows ~74 a pixel (calibrated whole, two selections
//! per block), ~2.5 a pixel at stride 64. A row with a listed defect calibrates its exact
//! chunks through `calibrate_span`, defects included.

use super::bounds::{
    ChunkBound, above_mask, raw_threshold, tile_log2, tile_row_start, window_quiet,
};
use super::{CHUNK_PX, MAX_SCAN_PX, ScanDetector, ScanError};
use crate::calib::formula::{dark_16ths, pixel_bits_d as pixel_bits};
use crate::calib::pixel::saturation_flag;
use crate::calib::{CalibError, FrameCalibration, LineLevels, PixelFlags};
use crate::detect::LineDetector;
use crate::detect::background::MAX_BLOCKS;
use crate::detect::blobs::{above_thr, px_above_thr};
use crate::table::MapView;
use crate::units::{BiasAdu, DarkRel, Electrons, FlatInv, GainEPerAdu};

impl<'t, const N: usize> ScanDetector<'t, N> {
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
