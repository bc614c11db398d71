//! Readout geometry: which element of a raw line is over-scan, covered or active, and which
//! output amplifier read it.
//!
//! A raw line is what the serial register delivers, in physical column order (column 0 is
//! the left-most element, whichever amplifier read it):
//! `over-scan | covered (dark reference) | active | covered | over-scan`.
//! With two outputs the left half (up to the middle of the active area) is read by the
//! left amplifier and the right half by the right one; each half has its own bias and gain.
//!
//! Coordinates: raw lines and columns are 0-based over the whole readout. Active-area
//! coordinates are 0-based too, `x` = column, `y` = row, with pixel centres at integers.

/// Which part of the serial register a column belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Segment {
    /// Over-scan: empty register elements, they measure the bias of the line.
    OverScan,
    /// Covered (dark-reference) pixels: they collect dark charge but no light.
    Covered,
    /// Light-sensitive pixels.
    Active,
}

/// An output amplifier; index 0 is the left one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Output(pub u8);

/// Largest number of outputs a geometry may describe.
pub const MAX_OUTPUTS: usize = 2;
/// Largest raw line length (elements) a geometry may describe.
pub(crate) const MAX_LINE_LEN: u16 = 8192;
/// Largest number of lines a geometry may describe.
pub(crate) const MAX_LINES: u16 = 8192;

/// The layout of one raw line and of the frame, as data, so other sensors and readout modes
/// (windowed, binned) can be described.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReadoutGeometry {
    /// Over-scan elements at each end of a line (left and right alike).
    pub overscan_px: u16,
    /// Covered dark-reference columns on each side of the active area.
    pub covered_px: u16,
    /// Active columns per line.
    pub active_cols: u16,
    /// Active rows (image lines that hold light).
    pub active_rows: u16,
    /// Lines read per frame (at least `active_rows`; the extra ones are store-section rows).
    pub lines: u16,
    /// Number of output amplifiers, 1 or 2.
    pub outputs: u8,
}

/// Why a geometry cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum GeometryError {
    /// `outputs` is not 1 or 2.
    Outputs,
    /// No active columns or rows, or more active rows than lines read.
    EmptyActiveArea,
    /// Fewer than one over-scan element per output, so no bias can be measured.
    NoOverScan,
    /// The line or the frame is larger than this crate's limits.
    TooLarge,
    /// Two outputs need an even number of active columns to split the line in halves.
    OddSplit,
}

impl core::fmt::Display for GeometryError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Outputs => "geometry: outputs must be 1 or 2",
            Self::EmptyActiveArea => "geometry: empty active area or more active rows than lines",
            Self::NoOverScan => "geometry: no over-scan elements to measure the bias",
            Self::TooLarge => "geometry: line or frame larger than supported",
            Self::OddSplit => "geometry: two outputs need an even number of active columns",
        })
    }
}

impl core::error::Error for GeometryError {}

impl ReadoutGeometry {
    /// The e2v CCD47-20 read through both outputs: 8 + 16 + 1024 + 16 + 8 = 1072 elements per
    /// line, 1033 lines of which 1024 are active rows.
    pub const CCD47_20_DUAL: Self = Self {
        overscan_px: 8,
        covered_px: 16,
        active_cols: 1024,
        active_rows: 1024,
        lines: 1033,
        outputs: 2,
    };

    /// The CCD47-20 read through one output (all 1072 elements through the left amplifier).
    pub const CCD47_20_SINGLE: Self = Self {
        outputs: 1,
        ..Self::CCD47_20_DUAL
    };

    /// Checks the invariants every other function relies on.
    pub fn validate(&self) -> Result<(), GeometryError> {
        if self.outputs == 0 || usize::from(self.outputs) > MAX_OUTPUTS {
            return Err(GeometryError::Outputs);
        }
        if self.active_cols == 0 || self.active_rows == 0 || self.active_rows > self.lines {
            return Err(GeometryError::EmptyActiveArea);
        }
        if self.overscan_px == 0 {
            return Err(GeometryError::NoOverScan);
        }
        let len = 2 * u32::from(self.overscan_px)
            + 2 * u32::from(self.covered_px)
            + u32::from(self.active_cols);
        if len > u32::from(MAX_LINE_LEN) || self.lines > MAX_LINES {
            return Err(GeometryError::TooLarge);
        }
        if self.outputs == 2 && !self.active_cols.is_multiple_of(2) {
            return Err(GeometryError::OddSplit);
        }
        Ok(())
    }

    /// Elements per raw line. Valid geometries keep this at most `MAX_LINE_LEN` (8192).
    pub const fn line_len(&self) -> usize {
        2 * self.overscan_px as usize + 2 * self.covered_px as usize + self.active_cols as usize
    }

    /// Raw column of active column 0.
    pub const fn first_active_col(&self) -> usize {
        self.overscan_px as usize + self.covered_px as usize
    }

    /// What the raw column `col` is, or `None` past the end of the line.
    pub const fn segment(&self, col: usize) -> Option<Segment> {
        let os = self.overscan_px as usize;
        let cov = self.covered_px as usize;
        let act = self.active_cols as usize;
        if col < os {
            Some(Segment::OverScan)
        } else if col < os + cov {
            Some(Segment::Covered)
        } else if col < os + cov + act {
            Some(Segment::Active)
        } else if col < os + 2 * cov + act {
            Some(Segment::Covered)
        } else if col < 2 * os + 2 * cov + act {
            Some(Segment::OverScan)
        } else {
            None
        }
    }

    /// The output amplifier that read raw column `col` (valid for any `col` of the line).
    pub const fn output_of_col(&self, col: usize) -> Output {
        if self.outputs == 2 && col >= self.line_len() / 2 {
            Output(1)
        } else {
            Output(0)
        }
    }

    /// Raw column range `[start, end)` of the over-scan elements read by `output`.
    /// With one output both over-scan strips belong to it; this returns the left one and
    /// [`Self::overscan_cols_extra`] the right one.
    pub const fn overscan_cols(&self, output: Output) -> (usize, usize) {
        let os = self.overscan_px as usize;
        if output.0 == 1 {
            (self.line_len() - os, self.line_len())
        } else {
            (0, os)
        }
    }

    /// With a single output, the right over-scan strip, also read by output 0.
    pub const fn overscan_cols_extra(&self) -> Option<(usize, usize)> {
        if self.outputs == 1 {
            let os = self.overscan_px as usize;
            Some((self.line_len() - os, self.line_len()))
        } else {
            None
        }
    }

    /// Raw column ranges `[start, end)` of the covered columns: left strip, right strip.
    pub const fn covered_cols(&self) -> [(usize, usize); 2] {
        let os = self.overscan_px as usize;
        let cov = self.covered_px as usize;
        let act = self.active_cols as usize;
        [(os, os + cov), (os + cov + act, os + 2 * cov + act)]
    }

    /// Raw column of active column `x`.
    pub const fn raw_col_of_x(&self, x: usize) -> usize {
        self.first_active_col() + x
    }

    /// Raw line of active row `y` (active rows are read first).
    pub const fn raw_line_of_y(&self, y: usize) -> usize {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ccd47_20_layout() {
        let g = ReadoutGeometry::CCD47_20_DUAL;
        assert_eq!(g.validate(), Ok(()));
        assert_eq!(g.line_len(), 1072);
        assert_eq!(g.segment(0), Some(Segment::OverScan));
        assert_eq!(g.segment(7), Some(Segment::OverScan));
        assert_eq!(g.segment(8), Some(Segment::Covered));
        assert_eq!(g.segment(23), Some(Segment::Covered));
        assert_eq!(g.segment(24), Some(Segment::Active));
        assert_eq!(g.segment(1047), Some(Segment::Active));
        assert_eq!(g.segment(1048), Some(Segment::Covered));
        assert_eq!(g.segment(1064), Some(Segment::OverScan));
        assert_eq!(g.segment(1071), Some(Segment::OverScan));
        assert_eq!(g.segment(1072), None);
        assert_eq!(g.output_of_col(535), Output(0));
        assert_eq!(g.output_of_col(536), Output(1));
        // The split falls in the middle of the active area: 512 active columns per output.
        assert_eq!(g.output_of_col(g.raw_col_of_x(511)), Output(0));
        assert_eq!(g.output_of_col(g.raw_col_of_x(512)), Output(1));
        assert_eq!(g.overscan_cols(Output(1)), (1064, 1072));
        assert_eq!(
            ReadoutGeometry::CCD47_20_SINGLE.output_of_col(1071),
            Output(0)
        );
    }

    #[test]
    fn rejects_bad_geometries() {
        let g = ReadoutGeometry::CCD47_20_DUAL;
        assert_eq!(
            ReadoutGeometry { outputs: 3, ..g }.validate(),
            Err(GeometryError::Outputs)
        );
        assert_eq!(
            ReadoutGeometry {
                overscan_px: 0,
                ..g
            }
            .validate(),
            Err(GeometryError::NoOverScan)
        );
        assert_eq!(
            ReadoutGeometry {
                active_rows: 2000,
                ..g
            }
            .validate(),
            Err(GeometryError::EmptyActiveArea)
        );
        assert_eq!(
            ReadoutGeometry {
                active_cols: 9000,
                ..g
            }
            .validate(),
            Err(GeometryError::TooLarge)
        );
        assert_eq!(
            ReadoutGeometry {
                active_cols: 1023,
                ..g
            }
            .validate(),
            Err(GeometryError::OddSplit)
        );
    }
}
