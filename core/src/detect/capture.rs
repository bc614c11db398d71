//! Getting a star's window of raw pixels out of a line stream, without keeping a frame.
//!
//! A raw CCD47-20 frame (1072 x 1033 x 2 bytes = 2.2 MB) does not fit in the STM32H743's
//! RAM, and the readout delivers each line once. Two ways to still have a window's raw pixels
//! (and each row's bias levels, which [`crate::calib::FrameCalibration::calibrate_window`]
//! needs) when its last row has arrived:
//!
//! - [`LineRing`] (acquisition): the last `R` raw lines in a ring, slot `y % R`. When the
//!   line detector closes a blob, the window around its peak is copied out of the ring once
//!   its last row is in; rows that were already overwritten are reported
//!   ([`RingError::RowGone`]), never silently replaced. Memory: `R * W * 2` bytes (16 lines
//!   of 1072 samples: 34 KB). Cost: a copy of the window's samples.
//! - [`WindowCapture`] (tracking): a list of windows known before the frame (predicted from
//!   the last frame's stars); each line's samples that fall in a window are copied into that
//!   window's buffer as the line passes, and [`WindowCapture::push_line`] reports the windows
//!   whose last row has arrived. Memory: [`CAPTURE_MAX_PX`] samples and [`CAPTURE_MAX_SIDE`]
//!   levels per window (~550 B). Cost per line: a row test per window, a copy of the
//!   window's row when it is in.
//!
//! Both take lines in increasing active-row order, as the readout delivers them; a skipped
//! line leaves a hole that is reported (a window with missing rows must not be used). Neither
//! allocates nor panics; both are plain data that the firmware fills from the DMA'd line
//! buffer after the DMA has handed it over.

use crate::calib::LineLevels;
use crate::geometry::ReadoutGeometry;
use crate::units::BiasAdu;
use crate::window::Rect;

/// Largest window side [`WindowCapture`] holds.
pub const CAPTURE_MAX_SIDE: u16 = 15;
/// Samples per [`WindowCapture`] window buffer.
pub(crate) const CAPTURE_MAX_PX: usize = CAPTURE_MAX_SIDE as usize * CAPTURE_MAX_SIDE as usize;
/// Most windows a [`WindowCapture`] tracks (the completion mask is 64 bits).
pub(crate) const CAPTURE_MAX_WINDOWS: usize = 64;

const ZERO_LEVELS: LineLevels = LineLevels {
    bias_adu: [BiasAdu::ZERO; crate::geometry::MAX_OUTPUTS],
};

/// Why the ring could not take a line or give a window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum RingError {
    /// The raw line is longer than the ring's lines (or the ring holds no lines).
    LineLength,
    /// The output buffers do not match the window's size.
    BufferLength,
    /// The window's columns reach past the line.
    OutsideLine,
    /// A row of the window has not been pushed yet.
    RowNotYet,
    /// A row of the window was already overwritten (it left the ring) or was never pushed.
    RowGone,
}

impl core::fmt::Display for RingError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::LineLength => "line ring: raw line longer than the ring's",
            Self::BufferLength => "line ring: buffers do not match the window",
            Self::OutsideLine => "line ring: window outside the line",
            Self::RowNotYet => "line ring: a row of the window has not arrived yet",
            Self::RowGone => "line ring: a row of the window has left the ring",
        })
    }
}

impl core::error::Error for RingError {}

/// The last `R` raw lines of at most `W` samples and their levels, by active row (a geometry
/// with shorter lines, e.g. a binned or narrower readout, uses the start of each slot).
#[derive(Clone, Debug)]
pub struct LineRing<const R: usize, const W: usize> {
    lines: [[u16; W]; R],
    levels: [LineLevels; R],
    rows: [Option<u16>; R],
    /// Samples held in each slot (`<= W`).
    lens: [u16; R],
    first_active_col: usize,
    newest: Option<u16>,
}

impl<const R: usize, const W: usize> LineRing<R, W> {
    /// An empty ring for raw lines whose active pixel `x` is sample `first_active_col + x`.
    pub const fn new(first_active_col: usize) -> Self {
        Self {
            lines: [[0; W]; R],
            levels: [ZERO_LEVELS; R],
            rows: [None; R],
            lens: [0; R],
            first_active_col,
            newest: None,
        }
    }

    /// Forgets every line and sets where a raw line's active pixels start (buffers made
    /// with a placeholder, e.g. all-zero statics, are set up in place).
    pub(crate) fn reset_for(&mut self, first_active_col: usize) {
        self.first_active_col = first_active_col;
        self.clear();
    }

    /// Forgets every line (at a frame start).
    pub fn clear(&mut self) {
        self.rows = [None; R];
        self.lens = [0; R];
        self.newest = None;
    }

    /// Stores raw line `raw_line` (at most `W` samples) of active row `y` with its levels,
    /// replacing row `y - R`.
    pub fn push(&mut self, y: u16, raw_line: &[u16], levels: &LineLevels) -> Result<(), RingError> {
        let n = raw_line.len();
        let Ok(n16) = u16::try_from(n) else {
            return Err(RingError::LineLength);
        };
        if n > W || R == 0 {
            return Err(RingError::LineLength);
        }
        let slot = usize::from(y) % R;
        if let (Some(line), Some(lv), Some(row), Some(len)) = (
            self.lines.get_mut(slot),
            self.levels.get_mut(slot),
            self.rows.get_mut(slot),
            self.lens.get_mut(slot),
        ) {
            if let Some(dst) = line.get_mut(..n) {
                dst.copy_from_slice(raw_line);
            }
            *lv = *levels;
            *row = Some(y);
            *len = n16;
        }
        self.newest = Some(y);
        Ok(())
    }

    /// Whether every row of `rect` is in the ring now.
    pub(crate) fn holds(&self, rect: Rect) -> Result<(), RingError> {
        if R == 0 {
            return Err(RingError::RowGone);
        }
        for y in rect.y0..rect.y0.saturating_add(rect.height) {
            match self.rows.get(usize::from(y) % R).copied().flatten() {
                Some(held) if held == y => {}
                Some(held) if held > y => return Err(RingError::RowGone),
                _ if self.newest.is_some_and(|n| n >= y) => return Err(RingError::RowGone),
                _ => return Err(RingError::RowNotYet),
            }
        }
        Ok(())
    }

    /// Copies the raw samples of `rect` (row-major) into `raw_out` and its rows' levels into
    /// `levels_out` (the inputs of `calibrate_window`).
    pub fn copy_window(
        &self,
        rect: Rect,
        raw_out: &mut [u16],
        levels_out: &mut [LineLevels],
    ) -> Result<(), RingError> {
        let w = usize::from(rect.width);
        if raw_out.len() != rect.len() || levels_out.len() != usize::from(rect.height) {
            return Err(RingError::BufferLength);
        }
        let start = self.first_active_col + usize::from(rect.x0);
        if start + w > W {
            return Err(RingError::OutsideLine);
        }
        self.holds(rect)?;
        if w == 0 {
            return Ok(());
        }
        for ((out, lv), y) in raw_out
            .chunks_exact_mut(w)
            .zip(levels_out.iter_mut())
            .zip(rect.y0..)
        {
            let slot = usize::from(y) % R;
            let (Some(line), Some(l), Some(&len)) = (
                self.lines.get(slot),
                self.levels.get(slot),
                self.lens.get(slot),
            ) else {
                return Err(RingError::RowGone);
            };
            let src = line
                .get(..usize::from(len))
                .and_then(|held| held.get(start..start + w))
                .ok_or(RingError::OutsideLine)?;
            out.copy_from_slice(src);
            *lv = *l;
        }
        Ok(())
    }
}

/// Why a window or a line was refused by [`WindowCapture`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CaptureError {
    /// The window is empty or a side exceeds [`CAPTURE_MAX_SIDE`].
    WindowSize,
    /// The window reaches outside the active area.
    OutsideActiveArea,
    /// The window list is full.
    Full,
    /// The window starts on a row already streamed in this frame.
    TooLate,
    /// The raw line's length differs from the geometry's.
    LineLength,
    /// Lines must come in increasing row order.
    RowOrder,
}

impl core::fmt::Display for CaptureError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::WindowSize => "capture: window empty or larger than the maximum side",
            Self::OutsideActiveArea => "capture: window outside the active area",
            Self::Full => "capture: window list full",
            Self::TooLate => "capture: window starts on a row already streamed",
            Self::LineLength => "capture: raw line length differs from the geometry",
            Self::RowOrder => "capture: lines must come in increasing row order",
        })
    }
}

impl core::error::Error for CaptureError {}

#[derive(Clone, Debug)]
struct Slot {
    rect: Rect,
    clipped: bool,
    raw: [u16; CAPTURE_MAX_PX],
    levels: [LineLevels; CAPTURE_MAX_SIDE as usize],
    rows_got: u16,
    done: bool,
}

/// One captured window: the inputs of `calibrate_window`.
#[derive(Clone, Copy, Debug)]
pub struct CapturedWindow<'a> {
    /// Where the window lies (active coordinates).
    pub rect: Rect,
    /// The window was clipped by the active area's edge when it was placed.
    pub clipped: bool,
    /// `rect.len()` raw samples, row-major.
    pub raw: &'a [u16],
    /// The levels of each of its rows.
    pub levels: &'a [LineLevels],
    /// Some rows never arrived (a skipped line, or the frame ended): do not use the window.
    pub missing_rows: bool,
    /// All rows have been streamed (or the frame ended).
    pub complete: bool,
}

/// Indices of the windows completed by one line, in increasing order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Completed(u64);

impl Completed {
    /// No window completed.
    pub fn is_empty(&self) -> bool {
        self.0 == 0
    }
}

impl Iterator for Completed {
    type Item = usize;
    fn next(&mut self) -> Option<usize> {
        if self.0 == 0 {
            return None;
        }
        let i = self.0.trailing_zeros();
        self.0 &= self.0 - 1;
        Some(i as usize)
    }
}

/// Raw pixels of up to `N` (at most `CAPTURE_MAX_WINDOWS`, 64) windows, filled line by line.
#[derive(Clone, Debug)]
pub struct WindowCapture<const N: usize> {
    slots: heapless::Vec<Slot, N>,
    geometry: ReadoutGeometry,
    next_y: u16,
}

impl<const N: usize> WindowCapture<N> {
    /// An empty list for lines of `geometry`.
    pub const fn new(geometry: ReadoutGeometry) -> Self {
        Self {
            slots: heapless::Vec::new(),
            geometry,
            next_y: 0,
        }
    }

    /// Forgets every window and takes lines of `geometry` from now on (a list made with a
    /// placeholder geometry, e.g. an all-zero static, is set up in place).
    pub(crate) fn reset_for(&mut self, geometry: ReadoutGeometry) {
        self.geometry = geometry;
        self.reset();
    }

    /// Forgets every window and starts a new frame.
    pub fn reset(&mut self) {
        self.slots.clear();
        self.next_y = 0;
    }

    /// True when no window is listed.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Lists `rect` for capture (before its first row streams); returns its index.
    pub fn add(&mut self, rect: Rect, clipped: bool) -> Result<usize, CaptureError> {
        if rect.is_empty() || rect.width > CAPTURE_MAX_SIDE || rect.height > CAPTURE_MAX_SIDE {
            return Err(CaptureError::WindowSize);
        }
        if u32::from(rect.x0) + u32::from(rect.width) > u32::from(self.geometry.active_cols)
            || u32::from(rect.y0) + u32::from(rect.height) > u32::from(self.geometry.active_rows)
        {
            return Err(CaptureError::OutsideActiveArea);
        }
        if rect.y0 < self.next_y {
            return Err(CaptureError::TooLate);
        }
        let index = self.slots.len();
        if index >= CAPTURE_MAX_WINDOWS {
            return Err(CaptureError::Full);
        }
        self.slots
            .push(Slot {
                rect,
                clipped,
                raw: [0; CAPTURE_MAX_PX],
                levels: [ZERO_LEVELS; CAPTURE_MAX_SIDE as usize],
                rows_got: 0,
                done: false,
            })
            .map_err(|_| CaptureError::Full)?;
        Ok(index)
    }

    /// Takes raw line `raw_line` of active row `y` and its levels: copies the samples of the
    /// windows that cover row `y`, and returns the windows whose last row is `y` or before.
    pub fn push_line(
        &mut self,
        y: u16,
        raw_line: &[u16],
        levels: &LineLevels,
    ) -> Result<Completed, CaptureError> {
        if raw_line.len() != self.geometry.line_len() {
            return Err(CaptureError::LineLength);
        }
        if y < self.next_y {
            return Err(CaptureError::RowOrder);
        }
        let first = self.geometry.first_active_col();
        let mut done = 0u64;
        for (i, s) in self.slots.iter_mut().enumerate() {
            if s.done {
                continue;
            }
            let r = s.rect;
            let w = usize::from(r.width);
            if y >= r.y0 && y - r.y0 < r.height {
                let row = usize::from(y - r.y0);
                let start = first + usize::from(r.x0);
                if let (Some(dst), Some(src), Some(lv)) = (
                    s.raw.get_mut(row * w..row * w + w),
                    raw_line.get(start..start + w),
                    s.levels.get_mut(row),
                ) {
                    dst.copy_from_slice(src);
                    *lv = *levels;
                    s.rows_got += 1;
                }
            }
            if u32::from(y) + 1 >= u32::from(r.y0) + u32::from(r.height) {
                s.done = true;
                done |= 1 << i;
            }
        }
        self.next_y = y.saturating_add(1);
        Ok(Completed(done))
    }

    /// Ends the frame: every window not yet complete completes now, with missing rows.
    pub fn finish(&mut self) -> Completed {
        let mut done = 0u64;
        for (i, s) in self.slots.iter_mut().enumerate() {
            if !s.done {
                s.done = true;
                done |= 1 << i;
            }
        }
        self.next_y = u16::MAX;
        Completed(done)
    }

    /// Window `i` as captured so far.
    pub fn window(&self, i: usize) -> Option<CapturedWindow<'_>> {
        let s = self.slots.get(i)?;
        Some(CapturedWindow {
            rect: s.rect,
            clipped: s.clipped,
            raw: s.raw.get(..s.rect.len()).unwrap_or(&[]),
            levels: s.levels.get(..usize::from(s.rect.height)).unwrap_or(&[]),
            missing_rows: s.rows_got < s.rect.height,
            complete: s.done,
        })
    }
}
