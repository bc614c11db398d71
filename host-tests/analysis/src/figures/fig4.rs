//! Figure 4: as Figure 1 with the power-2 CoG (eq. 6): less truncation error for large
//! images, more pixelisation error for small ones.

use super::{Effort, FigureError, Written, fig1};
use std::path::Path;

/// Writes fig4.csv and fig4.png.
pub fn write(out: &Path, effort: Effort, written: &mut Written) -> Result<(), FigureError> {
    fig1::write_rms_figure(out, effort, 2, written)
}
