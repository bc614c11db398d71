//! What a frame reads ([`ReadoutPlan`]): the tracker's [`ReadoutRequest`] on a readout
//! geometry, with a binning and an exposure time, and the two questions the compiler asks of
//! it: is a row group read ([`ReadoutPlan::group_read`]), and which register shifts of a read
//! row group are digitised ([`ReadoutPlan::shift_runs`]).
//!
//! Coordinates: a row group is `binning` raw lines (`g * binning ..`); a shift distance `k`
//! counts binned register elements from an output (`k = 0` is read first). With two outputs
//! the left half is raw columns `[k b, (k+1) b)` and the right half `[L - (k+1) b, L - k b)`,
//! both read at the same shift; with one output the whole line is read through the left
//! one. The over-scan and the covered columns the request reads
//! ([`ReadoutRequest::covered_cols`]) at each end are read on every row read.
//! Cost: `shift_runs` is O(windows x log windows) a row group; no allocation.

use crate::geometry::ReadoutGeometry;
use crate::readout::ReadoutRequest;
use crate::window::Rect;

/// Largest number of windows a plan accepts.
pub const MAX_WINDOWS: usize = 64;

/// Runs of shift distances `[start, end)` that one row group digitises.
pub type ShiftRuns = heapless::Vec<(u16, u16), { 2 * MAX_WINDOWS + 2 }>;

/// Binning: `n` x `n` pixels summed on the chip (rows in the register, columns in the
/// summing well).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Binning {
    /// No binning.
    X1,
    /// 2 x 2.
    X2,
    /// 4 x 4.
    X4,
}

impl Binning {
    /// Pixels summed along each axis.
    pub(crate) const fn factor(self) -> u16 {
        match self {
            Self::X1 => 1,
            Self::X2 => 2,
            Self::X4 => 4,
        }
    }

    /// From a factor of 1, 2 or 4.
    pub const fn from_factor(n: u16) -> Option<Self> {
        match n {
            1 => Some(Self::X1),
            2 => Some(Self::X2),
            4 => Some(Self::X4),
            _ => None,
        }
    }
}

/// Why a plan cannot be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PlanError {
    /// The geometry is invalid.
    Geometry(crate::geometry::GeometryError),
    /// More than [`MAX_WINDOWS`] windows.
    TooManyWindows,
    /// A window is empty or leaves the active area.
    WindowOutside(Rect),
    /// The register (each half with two outputs) is not a whole number of binned elements.
    Binning,
}

impl core::fmt::Display for PlanError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Geometry(e) => write!(f, "readout plan: {e}"),
            Self::TooManyWindows => write!(f, "readout plan: more than {MAX_WINDOWS} windows"),
            Self::WindowOutside(r) => write!(
                f,
                "readout plan: window {}x{} at ({}, {}) empty or outside the active area",
                r.width, r.height, r.x0, r.y0
            ),
            Self::Binning => {
                f.write_str("readout plan: register length not a multiple of the binning")
            }
        }
    }
}

impl core::error::Error for PlanError {}

/// What one frame reads, checked.
#[derive(Clone, Copy, Debug)]
pub struct ReadoutPlan<'a> {
    geometry: ReadoutGeometry,
    request: ReadoutRequest<'a>,
    binning: Binning,
    exposure_us: u32,
}

impl<'a> ReadoutPlan<'a> {
    /// Checks the geometry, the windows and the binning. `exposure_us` is the time the image
    /// section integrates between two frame transfers; it overlaps the store's readout.
    pub fn new(
        geometry: ReadoutGeometry,
        request: ReadoutRequest<'a>,
        binning: Binning,
        exposure_us: u32,
    ) -> Result<Self, PlanError> {
        geometry.validate().map_err(PlanError::Geometry)?;
        if let ReadoutRequest::Windows(rects) = request {
            if rects.len() > MAX_WINDOWS {
                return Err(PlanError::TooManyWindows);
            }
            for r in rects {
                let inside = u32::from(r.x0) + u32::from(r.width)
                    <= u32::from(geometry.active_cols)
                    && u32::from(r.y0) + u32::from(r.height) <= u32::from(geometry.active_rows);
                if r.is_empty() || !inside {
                    return Err(PlanError::WindowOutside(*r));
                }
            }
        }
        let plan = Self {
            geometry,
            request,
            binning,
            exposure_us,
        };
        if plan.shifts_per_line() * binning.factor() != plan.register_len() {
            return Err(PlanError::Binning);
        }
        Ok(plan)
    }

    /// The geometry.
    pub(crate) const fn geometry(&self) -> &ReadoutGeometry {
        &self.geometry
    }

    /// The binning.
    pub(crate) const fn binning(&self) -> Binning {
        self.binning
    }

    /// The exposure, us.
    pub(crate) const fn exposure_us(&self) -> u32 {
        self.exposure_us
    }

    /// Register elements each output reads (half the line with two outputs).
    const fn register_len(&self) -> u16 {
        let len = self.geometry.line_len() as u16;
        if self.geometry.outputs == 2 {
            len / 2
        } else {
            len
        }
    }

    /// Binned shifts that empty the register (per output).
    pub(crate) const fn shifts_per_line(&self) -> u16 {
        self.register_len() / self.binning.factor()
    }

    /// Row groups of a full frame (`lines / binning`; a last partial group is left in the
    /// store and flushed by the next frame transfer).
    pub(crate) const fn row_groups(&self) -> u16 {
        self.geometry.lines / self.binning.factor()
    }

    /// Rows the frame transfer moves: the store's depth, so the first active row ends next
    /// to the register.
    pub(crate) const fn frame_transfer_rows(&self) -> u16 {
        self.geometry.lines
    }

    /// Raw rows `[start, end)` of row group `g`.
    pub(crate) const fn group_rows(&self, g: u16) -> (u16, u16) {
        let b = self.binning.factor();
        (g * b, g * b + b)
    }

    /// Whether row group `g` is digitised.
    pub(crate) fn group_read(&self, g: u16) -> bool {
        let (r0, r1) = self.group_rows(g);
        match self.request {
            ReadoutRequest::FullFrame => r1 <= self.geometry.lines,
            ReadoutRequest::Windows(rects) => rects
                .iter()
                .any(|r| r.y0 < r1 && u32::from(r.y0) + u32::from(r.height) > u32::from(r0)),
        }
    }

    /// The shift distances row group `g` digitises, as sorted disjoint runs `[start, end)`
    /// (binned elements from the output); empty when the group is not read.
    pub(crate) fn shift_runs(&self, g: u16, runs: &mut ShiftRuns) {
        runs.clear();
        if !self.group_read(g) {
            return;
        }
        let n = self.shifts_per_line();
        let rects = match self.request {
            ReadoutRequest::FullFrame => {
                // Capacity is at least 2: cannot fail.
                let _ = runs.push((0, n));
                return;
            }
            ReadoutRequest::Windows(rects) => rects,
        };
        let b = self.binning.factor();
        let len = self.geometry.line_len() as u16;
        let prefix = self.geometry.first_active_col() as u16;
        // The over-scan and the covered columns the request reads, at each end.
        let edge = self.request.edge_px(&self.geometry) as u16;
        let _ = runs.push((0, edge.div_ceil(b).min(n)));
        if self.geometry.outputs == 1 {
            // The far end's covered and over-scan columns, read through the left output.
            let _ = runs.push(((len - edge) / b, n));
        }
        let (r0, r1) = self.group_rows(g);
        let half = len / 2;
        for r in rects {
            if !(r.y0 < r1 && u32::from(r.y0) + u32::from(r.height) > u32::from(r0)) {
                continue;
            }
            let c0 = prefix + r.x0;
            let c1 = c0 + r.width;
            if self.geometry.outputs == 1 {
                let _ = runs.push((c0 / b, c1.div_ceil(b)));
                continue;
            }
            if c0 < half {
                let _ = runs.push((c0 / b, c1.min(half).div_ceil(b)));
            }
            if c1 > half {
                let lo = c0.max(half);
                // Right half: raw column c is at distance (len - 1 - c) / b.
                let _ = runs.push(((len - c1) / b, (len - 1 - lo) / b + 1));
            }
        }
        crate::small_sort::sort_by(runs, Ord::cmp);
        // Merge in place.
        let mut merged = ShiftRuns::new();
        for &(s, e) in runs.iter() {
            match merged.last_mut() {
                Some(last) if s <= last.1 => last.1 = last.1.max(e),
                _ => {
                    let _ = merged.push((s, e));
                }
            }
        }
        *runs = merged;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_share_rows_and_map_to_both_halves() {
        let g = ReadoutGeometry::CCD47_20_DUAL;
        let rects = [
            Rect {
                x0: 10,
                y0: 100,
                width: 11,
                height: 11,
            },
            Rect {
                x0: 1000,
                y0: 105,
                width: 11,
                height: 11,
            },
        ];
        let plan = ReadoutPlan::new(g, ReadoutRequest::Windows(&rects), Binning::X1, 0);
        assert!(plan.is_ok());
        let Ok(plan) = plan else { return };
        assert!(!plan.group_read(99));
        assert!(plan.group_read(100) && plan.group_read(115) && !plan.group_read(116));
        let mut runs = ShiftRuns::new();
        plan.shift_runs(106, &mut runs);
        // The over-scan and the outer 8 covered columns 0..16, left window raw 34..45, right
        // window raw 1024..1035 -> 37..48 (1072 - 1035, 1071 - 1024 + 1).
        assert_eq!(runs.as_slice(), &[(0, 16), (34, 48)]);
        // A full frame reads every covered column.
        let full = ReadoutPlan::new(g, ReadoutRequest::FullFrame, Binning::X1, 0);
        assert!(full.is_ok_and(|p| {
            p.shift_runs(3, &mut runs);
            runs.as_slice() == [(0, 536)]
        }));
        let bad = Rect {
            x0: 1020,
            y0: 0,
            width: 5,
            height: 1,
        };
        assert!(matches!(
            ReadoutPlan::new(g, ReadoutRequest::Windows(&[bad]), Binning::X1, 0),
            Err(PlanError::WindowOutside(_))
        ));
    }
}
