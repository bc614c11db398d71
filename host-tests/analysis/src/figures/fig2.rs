//! Figure 2: the power-1 CoG's noise-free shift (estimate minus truth, x) against the true
//! position inside the central pixel (y at the pixel centre), 5x5 box, large images: the box
//! truncates the wings and pulls the estimate towards the box centre.

use super::{Effort, FigureError, FigureFiles, Written, plot, systematic};
use std::path::Path;

/// One point of Figure 2 or 3.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShiftRow {
    /// 80 % radius, px.
    pub a_px: f64,
    /// True x relative to the central pixel's centre, px.
    pub true_x_px: f64,
    /// Estimate minus truth, px.
    pub shift_px: f64,
}

/// The box of Figures 2 and 3.
pub const WINDOW: u8 = 5;
/// Image sizes of Figure 2, px.
pub const LARGE_A_PX: [f64; 5] = [1.5, 2.0, 2.5, 3.0, 4.0];

/// Positions per curve for `effort`.
pub fn positions(effort: Effort) -> usize {
    match effort {
        Effort::Quick => 21,
        Effort::Full => 101,
    }
}

/// The rows for image sizes `a_values` at `n` positions from -1/2 to 1/2 (ends included;
/// the central pixel stays the window centre since the box is centred on it explicitly).
pub fn rows(a_values: &[f64], n: usize) -> Vec<ShiftRow> {
    let mut out = Vec::new();
    for &a_px in a_values {
        for k in 0..n {
            let true_x_px = -0.5 + k as f64 / (n.max(2) - 1) as f64;
            if let Some((dx, _)) = systematic::core_shift(a_px, WINDOW, 1, true_x_px, 0.0) {
                out.push(ShiftRow {
                    a_px,
                    true_x_px,
                    shift_px: dx,
                });
            }
        }
    }
    out
}

/// Writes `figN.csv` and `figN.png` for `a_values`.
pub fn write_shift_figure(
    out: &Path,
    fig: u8,
    what: &str,
    a_values: &[f64],
    n: usize,
    written: &mut Written,
) -> Result<(), FigureError> {
    let rows = rows(a_values, n);
    let header = vec![
        format!(
            "Figure {fig}: noise-free shift of the core's CoG power 1 (eq. 2, 4), {WINDOW}x{WINDOW} box, {what} images"
        ),
        format!(
            "true_x_px: offset of the true centre from the central pixel's centre ({n} values, -0.5..0.5); y at the pixel centre"
        ),
        format!(
            "PSF: pixel-integrated Gaussian, sigma = sqrt(0.31) a; {} e-, no noise, no background; a_px in {a_values:?}",
            systematic::SIGNAL_E
        ),
    ];
    let lines: Vec<String> = rows
        .iter()
        .map(|r| format!("{},{:.6},{:.6e}", r.a_px, r.true_x_px, r.shift_px))
        .collect();
    FigureFiles {
        number: fig,
        header,
        columns: "a_px,true_x_px,shift_px",
        rows: lines,
        chart: plot::Chart {
            title: format!("Fig. {fig}: CoG shift, {what} images, 5x5 box"),
            x_label: "true position in the central pixel, px".into(),
            y_label: "shift, px".into(),
            log_x: false,
            log_y: false,
        },
        series: plot::solid_per_key(
            a_values,
            |a| format!("a = {a} px"),
            &rows,
            |r, a| (r.a_px == a).then_some((r.true_x_px, r.shift_px)),
        ),
    }
    .write(out, written)
}

/// Writes fig2.csv and fig2.png.
pub fn write(out: &Path, effort: Effort, written: &mut Written) -> Result<(), FigureError> {
    write_shift_figure(out, 2, "large", &LARGE_A_PX, positions(effort), written)
}
