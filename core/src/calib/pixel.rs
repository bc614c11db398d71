//! The per-pixel calibration, applied lazily: only to the pixels the pipeline reads (a span
//! of a line being scanned, or a star window), never as a full-frame pass.
//!
//! The formula, its fixed-point arithmetic and why it cannot overflow are in
//! [`super::formula`]. A hot pixel with the `Correct` policy uses its own law instead of the
//! dark map ([`super::hot`]); an excluded hot pixel or a telegraph pixel yields 0 e- and a
//! flag, and must not be used.
//!
//! # Cost
//! A row segment is cut into runs that share the output amplifier, the dark tile and the
//! flat tile (8 pixels with the 8x8-tiled table); the bias, gain, dark term and inverse
//! flat are looked up once per run. Per pixel: the column-bias look-up, one 32x32->64
//! multiply, one 64x16 multiply, shifts and the saturation test (no clamp: the formula's bound).
//! A window up to [`WINDOW_SETUP_COLS`] wide looks its per-column constants up once per
//! window and the dark and flat terms once per tile row. Defect lists are
//! searched once per row (binary search), not per pixel. Measured by `cargo m7-bench`
//! (`line_calibrate`, `window_calibrate`; docs/speed.md).

use super::formula::{dark_16ths, offset_16ths, pixel_bits};
use super::hot::{HOT_DARK_LIMIT_E, hot_dark_e};
use super::levels::{LineError, LineLevels, check_len};
use crate::table::{CalibTable, HotPolicy};
use crate::units::{ColumnBiasAdu, DARK_SCALE_LIMIT_E, Electrons, FlatInv, GainEPerAdu, Kelvin};
use crate::window::Rect;

bitflags::bitflags! {
    /// What calibration noticed about a pixel (or, OR-ed, about a span or window).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct PixelFlags: u8 {
        /// The raw sample is at or above the table's saturation level: its value is a lower
        /// bound.
        const SATURATED = 1;
        /// A hot pixel whose own dark law was subtracted.
        const HOT_CORRECTED = 2;
        /// A hot pixel excluded by policy: value 0, do not use.
        const HOT_EXCLUDED = 4;
        /// A telegraph (RTS) pixel: always excluded, value 0, do not use.
        const TELEGRAPH = 8;
        /// A defect found in flight ([`super::refresh`]) that the table does not list yet:
        /// value 0, do not use.
        const FOUND_IN_FLIGHT = 16;
    }
}

impl PixelFlags {
    /// True when the pixel's value must not be used.
    pub fn is_excluded(self) -> bool {
        self.intersects(Self::HOT_EXCLUDED | Self::TELEGRAPH | Self::FOUND_IN_FLIGHT)
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for PixelFlags {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "PixelFlags({=u8:#x})", self.bits())
    }
}

/// Why a span or window could not be calibrated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CalibError {
    /// The raw line is unusable.
    Line(LineError),
    /// The span or window reaches outside the active area.
    OutsideActiveArea,
    /// The raw, levels or output buffers do not match the span or window size.
    BufferLength,
}

impl core::fmt::Display for CalibError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Line(e) => write!(f, "{e}"),
            Self::OutsideActiveArea => f.write_str("span or window outside the active area"),
            Self::BufferLength => f.write_str("buffer length does not match the span or window"),
        }
    }
}

impl core::error::Error for CalibError {}

impl From<LineError> for CalibError {
    fn from(e: LineError) -> Self {
        Self::Line(e)
    }
}

/// What the frame's processing knows beyond the table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameConditions {
    /// The covered pixels' mean dark signal (from [`super::DarkScaleEstimator`]), e-;
    /// clamped to ±[`DARK_SCALE_LIMIT_E`].
    pub dark_scale_e: Electrons,
    /// Exposure (integration) time, ms; used only by hot pixels.
    pub exposure_ms: u32,
    /// Sensor temperature, K; used only by hot pixels.
    pub temperature_k: Kelvin,
}

/// A table together with one frame's conditions: everything needed to calibrate any pixel of
/// that frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameCalibration<'t> {
    table: CalibTable<'t>,
    conditions: FrameConditions,
    dark_scale_bits: i32,
}

/// A calibrated pixel's own flag: [`PixelFlags::SATURATED`] when the raw sample is at or
/// above the table's saturation level `sat`, else none.
#[inline(always)]
pub(crate) fn saturation_flag(raw: u16, sat: u16) -> PixelFlags {
    if raw >= sat {
        PixelFlags::SATURATED
    } else {
        PixelFlags::empty()
    }
}

/// End (exclusive) of the run starting at active column `x`: the next dark or flat tile
/// boundary, the output split, or `end`, whichever comes first; always `> x` when `x < end`.
#[inline(always)]
fn run_end(x: u32, end: u32, dark_log2: Option<u8>, flat_log2: Option<u8>, split: u32) -> u32 {
    // x < 2^16 and tile_log2 <= 16, so the next boundary is below 2^17.
    let next = |l: Option<u8>| {
        l.map_or(end, |l| {
            let l = u32::from(l.min(16));
            ((x >> l) + 1) << l
        })
    };
    let mut stop = end.min(next(dark_log2)).min(next(flat_log2));
    if x < split {
        stop = stop.min(split);
    }
    stop
}

/// Widest window [`FrameCalibration::calibrate_window`] calibrates with per-window set-up
/// (wider ones go row by row through the span path; both give the same bits).
pub(crate) const WINDOW_SETUP_COLS: usize = 16;

impl<'t> FrameCalibration<'t> {
    /// Binds `table` to one frame's conditions.
    pub fn new(table: CalibTable<'t>, conditions: FrameConditions) -> Self {
        let lim = DARK_SCALE_LIMIT_E.to_bits();
        let dark_scale_bits = conditions.dark_scale_e.to_bits().clamp(-lim, lim);
        Self {
            table,
            conditions,
            dark_scale_bits,
        }
    }

    /// The dark scale in use, I26F6 bits (clamped to ±`DARK_SCALE_LIMIT_E`).
    pub(crate) fn dark_scale_bits(&self) -> i32 {
        self.dark_scale_bits
    }

    /// The table in use.
    pub(crate) fn table(&self) -> &CalibTable<'t> {
        &self.table
    }

    /// The frame's conditions (the dark scale as given, before clamping).
    pub(crate) fn conditions(&self) -> &FrameConditions {
        &self.conditions
    }

    /// Calibrates active pixels `x0 .. x0 + out_e.len()` of active row `y` from a whole raw
    /// line and its levels, writing electrons and per-pixel flags; returns the flags OR-ed.
    pub fn calibrate_span(
        &self,
        y: u16,
        x0: u16,
        raw_line: &[u16],
        levels: &LineLevels,
        out_e: &mut [Electrons],
        out_flags: &mut [PixelFlags],
    ) -> Result<PixelFlags, CalibError> {
        let g = self.table.geometry();
        check_len(g, raw_line)?;
        let start = g.raw_col_of_x(usize::from(x0));
        let raw = raw_line
            .get(start..start + out_e.len())
            .ok_or(CalibError::OutsideActiveArea)?;
        self.calibrate_row((y, x0), raw, levels, out_e, out_flags, true)
    }

    /// Calibrates the pixels of `rect` from its raw samples (`raw`, row-major, `rect.len()`
    /// values) and the levels of each of its rows (`levels[r]` for row `rect.y0 + r`).
    pub fn calibrate_window(
        &self,
        rect: Rect,
        raw: &[u16],
        levels: &[LineLevels],
        out_e: &mut [Electrons],
        out_flags: &mut [PixelFlags],
    ) -> Result<PixelFlags, CalibError> {
        let n = rect.len();
        if raw.len() != n
            || out_e.len() != n
            || out_flags.len() != n
            || levels.len() != usize::from(rect.height)
        {
            return Err(CalibError::BufferLength);
        }
        let w = usize::from(rect.width);
        let mut flags = PixelFlags::empty();
        if w == 0 {
            return Ok(flags);
        }
        // One search of the defect lists for the whole window instead of one per row.
        let defects = self.rows_have_defects(rect.y0, rect.y0.saturating_add(rect.height));
        if w <= WINDOW_SETUP_COLS {
            return self.calibrate_window_narrow(rect, raw, levels, out_e, out_flags, defects);
        }
        let rows = raw
            .chunks_exact(w)
            .zip(out_e.chunks_exact_mut(w))
            .zip(out_flags.chunks_exact_mut(w));
        for (((raw_row, e_row), f_row), (lv, y)) in rows.zip(levels.iter().zip(rect.y0..)) {
            flags |= self.calibrate_row((y, rect.x0), raw_row, lv, e_row, f_row, defects)?;
        }
        Ok(flags)
    }

    /// [`Self::calibrate_window`] for a window at most [`WINDOW_SETUP_COLS`] wide (buffers
    /// already checked): the per-column constants (output, gain, column bias) are looked up
    /// once per window, the dark and flat terms once per tile row of the window (and within
    /// it once per tile), the line bias once per row; the pixels then take the same
    /// [`pixel_bits`] with the same values as [`Self::calibrate_row`], so the bits and flags
    /// are identical.
    fn calibrate_window_narrow(
        &self,
        rect: Rect,
        raw: &[u16],
        levels: &[LineLevels],
        out_e: &mut [Electrons],
        out_flags: &mut [PixelFlags],
        defects: bool,
    ) -> Result<PixelFlags, CalibError> {
        let t = &self.table;
        let g = t.geometry();
        let w = usize::from(rect.width);
        if u32::from(rect.y0) + u32::from(rect.height) > u32::from(g.active_rows)
            || usize::from(rect.x0) + w > usize::from(g.active_cols)
        {
            return Err(CalibError::OutsideActiveArea);
        }
        let sat = t.saturation_adu();
        // Per column: on output 1 (else 0), column bias (1/16 ADU), gain.
        let mut on_out1 = [false; WINDOW_SETUP_COLS];
        let mut cb16 = [0i32; WINDOW_SETUP_COLS];
        let mut gain = [GainEPerAdu::ONE; WINDOW_SETUP_COLS];
        for (x, ((o, c), gn)) in (usize::from(rect.x0)..)
            .zip(on_out1.iter_mut().zip(cb16.iter_mut()).zip(gain.iter_mut()))
            .take(w)
        {
            let col = g.raw_col_of_x(x);
            let out = g.output_of_col(col);
            *o = out.0 == 1;
            *c = i32::from(t.column_bias(col).to_bits());
            *gn = t.gain(out);
        }
        let shift =
            |m: Option<crate::table::MapView<'_>>| m.map_or(16, |m| m.header().tile_log2.min(16));
        let (dl, fl) = (shift(t.dark_map()), shift(t.flat_map()));
        let mut dark = [0i64; WINDOW_SETUP_COLS];
        let mut flat = [FlatInv::ONE; WINDOW_SETUP_COLS];
        let mut tile_row: Option<(u32, u32)> = None;
        let mut offset = [0i32; WINDOW_SETUP_COLS];
        let mut flags = PixelFlags::empty();
        let rows = raw
            .chunks_exact(w)
            .zip(out_e.chunks_exact_mut(w))
            .zip(out_flags.chunks_exact_mut(w));
        for (((raw_row, e_row), f_row), (lv, y)) in rows.zip(levels.iter().zip(rect.y0..)) {
            // Dark and flat of each column, again only when the row enters a new tile row.
            let key = (u32::from(y) >> dl, u32::from(y) >> fl);
            if tile_row != Some(key) {
                tile_row = Some(key);
                let mut last: Option<(u32, u32)> = None;
                let mut cur = (0i64, FlatInv::ONE);
                for (x, (d, f)) in (rect.x0..)
                    .zip(dark.iter_mut().zip(flat.iter_mut()))
                    .take(w)
                {
                    let k = (u32::from(x) >> dl, u32::from(x) >> fl);
                    if last != Some(k) {
                        last = Some(k);
                        cur = (
                            dark_16ths(t.dark_rel(x, y), self.dark_scale_bits),
                            t.flat_inv(x, y),
                        );
                    }
                    (*d, *f) = cur;
                }
            }
            let b0 = offset_16ths(lv.bias(crate::geometry::Output(0)), ColumnBiasAdu::ZERO);
            let b1 = offset_16ths(lv.bias(crate::geometry::Output(1)), ColumnBiasAdu::ZERO);
            for (o, (c, is1)) in offset
                .iter_mut()
                .zip(cb16.iter().zip(on_out1.iter()))
                .take(w)
            {
                *o = if *is1 { b1 } else { b0 } + *c;
            }
            let consts = offset
                .iter()
                .zip(gain.iter())
                .zip(dark.iter().zip(flat.iter()));
            for ((r, (e, f)), ((off, gn), (d, fl))) in raw_row
                .iter()
                .zip(e_row.iter_mut().zip(f_row.iter_mut()))
                .zip(consts)
            {
                *e = Electrons::from_bits(pixel_bits(*r, *off, *gn, *d, *fl));
                *f = saturation_flag(*r, sat);
                flags |= *f;
            }
            if defects {
                flags |= self.apply_defects(y, rect.x0, raw_row, lv, e_row, f_row);
            }
        }
        Ok(flags)
    }

    /// One pixel by the regular formula, without the defect lists: the same bits and flags
    /// as `calibrate_span` gives a pixel of a row where [`Self::row_has_defects`] is false
    /// (same look-ups, same [`pixel_bits`]). Active (x, y) is not checked: outside the area
    /// the maps read as neutral. Cost: four look-ups and the formula, no per-call set-up.
    #[inline]
    pub(crate) fn calibrate_regular(
        &self,
        x: u16,
        y: u16,
        raw: u16,
        levels: &LineLevels,
    ) -> (Electrons, PixelFlags) {
        let t = &self.table;
        let g = t.geometry();
        let col = g.raw_col_of_x(usize::from(x));
        let out = g.output_of_col(col);
        let offset = offset_16ths(levels.bias(out), t.column_bias(col));
        let dark = dark_16ths(t.dark_rel(x, y), self.dark_scale_bits);
        let e = pixel_bits(raw, offset, t.gain(out), dark, t.flat_inv(x, y));
        (
            Electrons::from_bits(e),
            saturation_flag(raw, t.saturation_adu()),
        )
    }

    /// True when the table lists a hot or telegraph pixel on active row `y`.
    pub(crate) fn row_has_defects(&self, y: u16) -> bool {
        self.rows_have_defects(y, y.saturating_add(1))
    }

    /// True when the table lists a hot or telegraph pixel inside `rect`: one binary search
    /// per list, then a walk over the listed pixels of the rectangle's rows (none on most
    /// rows).
    pub(crate) fn rect_has_defects(&self, rect: Rect) -> bool {
        let (y0, y1) = (rect.y0, rect.y0.saturating_add(rect.height));
        if !self.rows_have_defects(y0, y1) {
            return false;
        }
        let in_x = |x: u16| x >= rect.x0 && x - rect.x0 < rect.width;
        let hot = self.table.hot_pixels();
        let tel = self.table.telegraph_pixels();
        (hot.lower_bound(0, y0)..hot.len())
            .map_while(|i| hot.get(i))
            .take_while(|h| h.y < y1)
            .any(|h| in_x(h.x))
            || (tel.lower_bound(0, y0)..tel.len())
                .map_while(|i| tel.get(i))
                .take_while(|(_, ty)| *ty < y1)
                .any(|(x, _)| in_x(x))
    }

    /// True when the table lists a hot or telegraph pixel on a row of `y0..y1`: the first
    /// entry at or after (0, y0) in (y, x) order is on a row before `y1`.
    fn rows_have_defects(&self, y0: u16, y1: u16) -> bool {
        let hot = self.table.hot_pixels();
        let tel = self.table.telegraph_pixels();
        hot.get(hot.lower_bound(0, y0)).is_some_and(|h| h.y < y1)
            || tel
                .get(tel.lower_bound(0, y0))
                .is_some_and(|(_, ty)| ty < y1)
    }

    /// Calibrates one row segment: `raw` holds the samples of active pixels `x0..`; the
    /// defect lists are applied unless the caller knows the row has none (`defects` false).
    fn calibrate_row(
        &self,
        (y, x0): (u16, u16),
        raw: &[u16],
        levels: &LineLevels,
        out_e: &mut [Electrons],
        out_flags: &mut [PixelFlags],
        defects: bool,
    ) -> Result<PixelFlags, CalibError> {
        let g = self.table.geometry();
        let n = raw.len();
        if out_e.len() != n || out_flags.len() != n {
            return Err(CalibError::BufferLength);
        }
        if y >= g.active_rows || usize::from(x0) + n > usize::from(g.active_cols) {
            return Err(CalibError::OutsideActiveArea);
        }
        let t = &self.table;
        let sat = t.saturation_adu();
        let mut flags = PixelFlags::empty();
        // Runs of pixels that share the output, the dark tile and the flat tile: their
        // look-ups are made once per run, only the column bias once per pixel.
        let end = u32::from(x0) + n as u32;
        let dark_log2 = t.dark_map().map(|m| m.header().tile_log2);
        let flat_log2 = t.flat_map().map(|m| m.header().tile_log2);
        // First active column read by output 1 (none with one output).
        let split = if g.outputs == 2 {
            (g.line_len() / 2).saturating_sub(g.first_active_col()) as u32
        } else {
            u32::MAX
        };
        let mut x = u32::from(x0);
        while x < end {
            let stop = run_end(x, end, dark_log2, flat_log2, split);
            // x < end <= active_cols <= 8192: fits u16.
            let xu = x as u16;
            let col0 = g.raw_col_of_x(x as usize);
            let out = g.output_of_col(col0);
            let bias16 = offset_16ths(levels.bias(out), ColumnBiasAdu::ZERO);
            let gain = t.gain(out);
            let dark = dark_16ths(t.dark_rel(xu, y), self.dark_scale_bits);
            let flat = t.flat_inv(xu, y);
            let (i0, i1) = (
                (x - u32::from(x0)) as usize,
                (stop - u32::from(x0)) as usize,
            );
            let (Some(r), Some(e), Some(f)) = (
                raw.get(i0..i1),
                out_e.get_mut(i0..i1),
                out_flags.get_mut(i0..i1),
            ) else {
                break;
            };
            for (col, (raw, (e, f))) in (col0..).zip(r.iter().zip(e.iter_mut().zip(f.iter_mut()))) {
                let offset = bias16 + i32::from(t.column_bias(col).to_bits());
                *e = Electrons::from_bits(pixel_bits(*raw, offset, gain, dark, flat));
                *f = saturation_flag(*raw, sat);
                flags |= *f;
            }
            x = stop;
        }
        if defects {
            flags |= self.apply_defects(y, x0, raw, levels, out_e, out_flags);
        }
        Ok(flags)
    }

    /// Re-does the listed hot and telegraph pixels of a row segment.
    fn apply_defects(
        &self,
        y: u16,
        x0: u16,
        raw: &[u16],
        levels: &LineLevels,
        out_e: &mut [Electrons],
        out_flags: &mut [PixelFlags],
    ) -> PixelFlags {
        let t = &self.table;
        let g = t.geometry();
        let x_end = usize::from(x0) + raw.len();
        let mut flags = PixelFlags::empty();
        let hot = t.hot_pixels();
        for h in (hot.lower_bound(x0, y)..hot.len()).map_while(|i| hot.get(i)) {
            if h.y != y || usize::from(h.x) >= x_end {
                break;
            }
            let i = usize::from(h.x - x0);
            let (Some(r), Some(e), Some(f)) = (raw.get(i), out_e.get_mut(i), out_flags.get_mut(i))
            else {
                break;
            };
            match h.policy {
                HotPolicy::Correct => {
                    let c = self.conditions;
                    let hot_e = hot_dark_e(
                        &h,
                        t.hot_pixels().reference_temperature_k(),
                        c.temperature_k,
                        c.exposure_ms,
                    );
                    let hot_16 = i64::from(hot_e.min(HOT_DARK_LIMIT_E).to_bits()) << 10;
                    let col = g.raw_col_of_x(usize::from(h.x));
                    let out = g.output_of_col(col);
                    let offset = offset_16ths(levels.bias(out), t.column_bias(col));
                    *e = Electrons::from_bits(pixel_bits(
                        *r,
                        offset,
                        t.gain(out),
                        hot_16,
                        t.flat_inv(h.x, y),
                    ));
                    *f |= PixelFlags::HOT_CORRECTED;
                }
                HotPolicy::Exclude => {
                    *e = Electrons::ZERO;
                    *f |= PixelFlags::HOT_EXCLUDED;
                }
            }
            flags |= *f;
        }
        let tel = t.telegraph_pixels();
        for (x, ty) in (tel.lower_bound(x0, y)..tel.len()).map_while(|i| tel.get(i)) {
            if ty != y || usize::from(x) >= x_end {
                break;
            }
            let i = usize::from(x - x0);
            if let (Some(e), Some(f)) = (out_e.get_mut(i), out_flags.get_mut(i)) {
                *e = Electrons::ZERO;
                *f |= PixelFlags::TELEGRAPH;
                flags |= *f;
            }
        }
        flags
    }
}
