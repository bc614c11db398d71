//! What a frame reads from the sensor ([`ReadoutRequest`]): every pixel, or only the pixels of
//! a set of windows. The tracker asks for one each frame; the CCD sequencer's plan, the
//! board's line source and the simulated sensor all serve it.
//!
//! Every line read also reads elements at both ends for the line's levels: the over-scan
//! (each output's bias) and covered columns (the frame's dark scale). A full frame reads every
//! covered column; a windowed readout reads the outer half of each covered strip, next to
//! the over-scan ([`ReadoutRequest::covered_cols`]): on the CCD47-20 at 1 MHz that is 8
//! pixels of 1 us read and 8 elements of 150 ns skipped a side instead of 16 read, 2.2 ms of
//! a 30-window frame (docs/sequencer.md). The dark scale of a windowed frame then averages
//! 16 covered pixels a line instead of 32; its error is an offset nearly uniform over the
//! frame, which each window's border-median background takes out.
//!
//! Cost: [`ReadoutRequest::reads_line`] and [`ReadoutRequest::reads_pixel`] are O(windows);
//! the edge and covered ranges O(1).

use crate::geometry::ReadoutGeometry;
use crate::window::Rect;

/// What a frame reads: the whole sensor, or only the pixels of some windows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadoutRequest<'a> {
    /// Every line, every element (standby and acquisition).
    FullFrame,
    /// Only the lines that cross these windows (active-area coordinates, increasing
    /// `y0`), and of those only the windows' pixels plus the line's over-scan and the outer
    /// half of its covered columns (the bias and the dark scale, [`Self::covered_cols`]).
    /// Other lines may be skipped; other samples of a line are not looked at.
    Windows(&'a [Rect]),
}

impl ReadoutRequest<'_> {
    /// Whether raw line `line` of `geometry` is needed.
    pub fn reads_line(&self, geometry: &ReadoutGeometry, line: u16) -> bool {
        match self {
            Self::FullFrame => true,
            Self::Windows(rects) => {
                line < geometry.active_rows && rects.iter().any(|r| r.contains(r.x0, line))
            }
        }
    }

    /// Raw elements read at each end of every line read: the over-scan and the covered
    /// columns [`Self::covered_cols`] gives.
    pub const fn edge_px(&self, geometry: &ReadoutGeometry) -> usize {
        geometry.overscan_px as usize + self.covered_read_px(geometry)
    }

    /// Covered columns read at each end of a line: all of a strip for a full frame, its
    /// outer half (rounded up) for windows.
    const fn covered_read_px(&self, geometry: &ReadoutGeometry) -> usize {
        let cov = geometry.covered_px as usize;
        match self {
            Self::FullFrame => cov,
            Self::Windows(_) => cov.div_ceil(2),
        }
    }

    /// Raw column ranges `[start, end)` of the covered columns this request reads on every
    /// line read (left strip, right strip): [`ReadoutGeometry::covered_cols`] for a full
    /// frame, the outer half of each strip (next to the over-scan) for windows.
    pub const fn covered_cols(&self, geometry: &ReadoutGeometry) -> [(usize, usize); 2] {
        let [(l0, _), (_, r1)] = geometry.covered_cols();
        let n = self.covered_read_px(geometry);
        [(l0, l0 + n), (r1 - n, r1)]
    }

    /// Whether active pixel (`x`, `y`) is needed (the over-scan and the covered columns of
    /// [`Self::covered_cols`] always are, on every line read).
    pub fn reads_pixel(&self, x: u16, y: u16) -> bool {
        match self {
            Self::FullFrame => true,
            Self::Windows(rects) => rects.iter().any(|r| r.contains(x, y)),
        }
    }
}
