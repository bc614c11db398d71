//! Figure 3: as Figure 2 for small images: pixelisation makes an S-curve in the pixel phase
//! (the estimate sticks to the pixel centre as the image shrinks below a pixel).

use super::{Effort, FigureError, Written, fig2};
use std::path::Path;

/// Image sizes of Figure 3, px.
pub const SMALL_A_PX: [f64; 5] = [0.25, 0.5, 0.75, 1.0, 1.25];

/// Writes fig3.csv and fig3.png.
pub fn write(out: &Path, effort: Effort, written: &mut Written) -> Result<(), FigureError> {
    fig2::write_shift_figure(
        out,
        3,
        "small",
        &SMALL_A_PX,
        fig2::positions(effort),
        written,
    )
}
