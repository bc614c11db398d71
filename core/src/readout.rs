//! What a frame reads from the sensor ([`ReadoutRequest`]): every pixel, or only the pixels of
//! a set of windows. The tracker asks for one each frame; the CCD sequencer's plan, the
//! board's line source and the simulated sensor all serve it.
//!
//! Cost: [`ReadoutRequest::reads_line`] and [`ReadoutRequest::reads_pixel`] are O(windows).

use crate::geometry::ReadoutGeometry;
use crate::window::Rect;

/// What a frame reads: the whole sensor, or only the pixels of some windows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadoutRequest<'a> {
    /// Every line, every element (standby and acquisition).
    FullFrame,
    /// Only the lines that cross these windows (active-area coordinates, increasing
    /// `y0`), and of those only the windows' pixels plus the line's over-scan and covered
    /// columns (the bias and the dark scale). Other lines may be skipped; other samples
    /// of a line are not looked at.
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

    /// Whether active pixel (`x`, `y`) is needed (over-scan and covered columns always
    /// are, on every line read).
    pub fn reads_pixel(&self, x: u16, y: u16) -> bool {
        match self {
            Self::FullFrame => true,
            Self::Windows(rects) => rects.iter().any(|r| r.contains(x, y)),
        }
    }
}
