//! Figure 1: RMS of the noise-free systematic shift of the power-1 CoG (eq. 2) against the
//! image size `a` (0.25..8 px, log scale), for 3x3, 5x5 and 7x7 boxes. The paper finds a
//! minimum (pixelisation below, truncation above); for the 5x5 box it lies near a ~ 1 px
//! (checked by `figures_pixelisation`: between 0.7 and 1.6 px).

use super::{Effort, FigureError, FigureFiles, Written, log_space, plot, systematic};
use std::path::Path;

/// One point of Figure 1 or 4.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RmsRow {
    /// 80 % radius, px.
    pub a_px: f64,
    /// Box side, px.
    pub window: u8,
    /// RMS shift over the central pixel, px.
    pub rms_px: f64,
}

/// The boxes of Figures 1 and 4.
pub const WINDOWS: [u8; 3] = [3, 5, 7];

/// Grid sizes for `effort`: (number of a values, phases per axis).
pub fn grid(effort: Effort) -> (usize, usize) {
    match effort {
        Effort::Quick => (20, 8),
        Effort::Full => (40, 20),
    }
}

/// The rows of Figure 1 (`power` 1) or 4 (`power` 2).
pub fn rows(power: u8, n_a: usize, m: usize) -> Vec<RmsRow> {
    let mut out = Vec::new();
    for window in WINDOWS {
        for a_px in log_space(0.25, 8.0, n_a) {
            out.push(RmsRow {
                a_px,
                window,
                rms_px: systematic::rms_shift(a_px, window, power, m),
            });
        }
    }
    out
}

/// Writes fig1.csv / fig4.csv and the PNG for `power`.
pub fn write_rms_figure(
    out: &Path,
    effort: Effort,
    power: u8,
    written: &mut Written,
) -> Result<(), FigureError> {
    let fig = if power == 1 { 1 } else { 4 };
    let (n_a, m) = grid(effort);
    let rows = rows(power, n_a, m);
    let header = vec![
        format!(
            "Figure {fig}: RMS of the noise-free systematic shift of the core's CoG power {power} (paper eq. {})",
            if power == 1 { 2 } else { 6 }
        ),
        format!(
            "true positions: {m} x {m} cell midpoints over the central pixel; rms_px = sqrt(mean((dx^2+dy^2)/2))"
        ),
        format!(
            "PSF: pixel-integrated Gaussian, sigma = sqrt(0.31) a (eq. 3, 5); {} e-, no noise, no background; box = window, centred on the central pixel",
            systematic::SIGNAL_E
        ),
        format!("a_px: {n_a} values log-spaced 0.25..8"),
    ];
    let lines: Vec<String> = rows
        .iter()
        .map(|r| format!("{:.6},{},{:.6e}", r.a_px, r.window, r.rms_px))
        .collect();
    FigureFiles {
        number: fig,
        header,
        columns: "a_px,window,rms_px",
        rows: lines,
        chart: plot::Chart {
            title: format!("Fig. {fig}: CoG power {power}, systematic error vs image size"),
            x_label: "a, px (80 % radius)".into(),
            y_label: "RMS shift, px".into(),
            log_x: true,
            log_y: true,
        },
        series: plot::solid_per_key(
            &WINDOWS,
            |w| format!("{w}x{w} box"),
            &rows,
            |r, w| (r.window == w && r.rms_px > 0.0).then_some((r.a_px, r.rms_px)),
        ),
    }
    .write(out, written)
}

/// Writes fig1.csv and fig1.png.
pub fn write(out: &Path, effort: Effort, written: &mut Written) -> Result<(), FigureError> {
    write_rms_figure(out, effort, 1, written)
}
