//! The PNGs of the trade-off run, drawn with `plotters` on the bitmap backend (text through
//! `ab_glyph` and the font [`crate::figures::plot::ensure_font`] loads; without a font the
//! PNGs are skipped with a reason and the CSVs are still written).
//!
//! - [`tradeoff`]: one panel per scene (rows SNR, columns a): M7 instructions per star (log)
//!   against RMS / CRLB (log), one colour per method, the Pareto frontier joined in black.
//! - [`heatmap`]: one method's failure map: the SNR x a grid, and one strip per sweep; a cell
//!   is green when it passes, red for bias, orange for RMS > 2 CRLB, grey for detection, and
//!   shows RMS / CRLB.

use super::chart::TradeRow;
use super::failures::FailCell;
use crate::figures::plot::ensure_font;
use crate::figures::{FigureError, Written};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// Distinct colours for up to 20 methods (matplotlib's tab20, dark and light pairs).
const COLORS: [RGBColor; 20] = [
    RGBColor(31, 119, 180),
    RGBColor(174, 199, 232),
    RGBColor(255, 127, 14),
    RGBColor(255, 187, 120),
    RGBColor(44, 160, 44),
    RGBColor(152, 223, 138),
    RGBColor(214, 39, 40),
    RGBColor(255, 152, 150),
    RGBColor(148, 103, 189),
    RGBColor(197, 176, 213),
    RGBColor(140, 86, 75),
    RGBColor(196, 156, 148),
    RGBColor(227, 119, 194),
    RGBColor(247, 182, 210),
    RGBColor(127, 127, 127),
    RGBColor(199, 199, 199),
    RGBColor(188, 189, 34),
    RGBColor(219, 219, 141),
    RGBColor(23, 190, 207),
    RGBColor(158, 218, 229),
];

fn color(k: usize) -> RGBColor {
    COLORS.get(k % COLORS.len()).copied().unwrap_or(BLACK)
}

fn err(path: &Path) -> impl Fn(String) -> FigureError + '_ {
    move |message| FigureError {
        path: path.to_path_buf(),
        message,
    }
}

fn font(size: i32) -> TextStyle<'static> {
    ("sans-serif", size).into_font().color(&BLACK)
}

fn centred(size: i32) -> TextStyle<'static> {
    font(size).pos(Pos::new(HPos::Center, VPos::Center))
}

/// Skips (with a reason) when there is no font; else draws with `f` and records the file.
fn with_font(
    path: &Path,
    written: &mut Written,
    f: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), FigureError> {
    if let Err(why) = ensure_font() {
        written
            .skipped_png
            .push(format!("{}: {why}", path.display()));
        return Ok(());
    }
    f(path).map_err(err(path))?;
    written.files.push(path.to_path_buf());
    Ok(())
}

/// Draws tradeoff.png from the rows (x: M7 instructions; rows without one are left out).
pub fn tradeoff(
    out: &Path,
    rows: &[TradeRow],
    methods: &[String],
    widths: &[f64],
    snrs: &[f64],
    written: &mut Written,
) -> Result<(), FigureError> {
    let path = out.join("tradeoff.png");
    with_font(&path, written, |path| {
        let e = |x: &dyn std::fmt::Display| x.to_string();
        let root = BitMapBackend::new(path, (1600, 1150)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let (top, legend) = root.split_vertically(960);
        let top = top
            .titled(
                "Speed against accuracy: Cortex-M7 instructions per star vs RMS / CRLB (black: Pareto frontier)",
                ("sans-serif", 22),
            )
            .map_err(|x| e(&x))?;
        let panels = top.split_evenly((snrs.len(), widths.len()));
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .filter_map(|r| Some((r.m7_instructions?, r.cell.rms_px / r.cell.crlb_px)))
            .filter(|p| p.0 > 0.0 && p.1 > 0.0 && p.1.is_finite())
            .collect();
        let lx = |v: f64| v.log10();
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &(x, y) in &pts {
            x0 = x0.min(lx(x));
            x1 = x1.max(lx(x));
            y0 = y0.min(lx(y));
            y1 = y1.max(lx(y));
        }
        if x0 > x1 {
            (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
        }
        let (x0, x1) = (x0 - 0.1, x1 + 0.1);
        let (y0, y1) = ((y0 - 0.05).min(-0.02), y1 + 0.1);
        for (i, area) in panels.iter().enumerate() {
            let (si, ai) = (i / widths.len(), i % widths.len());
            let (Some(&snr), Some(&a)) = (snrs.get(si), widths.get(ai)) else {
                continue;
            };
            let mut c = ChartBuilder::on(area)
                .caption(format!("SNR {snr}, a = {a} px"), ("sans-serif", 16))
                .margin(6)
                .x_label_area_size(28)
                .y_label_area_size(40)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(|x| e(&x))?;
            c.configure_mesh()
                .x_labels(5)
                .y_labels(5)
                .x_label_formatter(&|v| format!("{:.0}", 10f64.powf(*v)))
                .y_label_formatter(&|v| format!("{:.2}", 10f64.powf(*v)))
                .draw()
                .map_err(|x| e(&x))?;
            let scene: Vec<&TradeRow> = rows
                .iter()
                .filter(|r| r.cell.snr == snr && r.cell.a_px == a && r.m7_instructions.is_some())
                .collect();
            let mut front: Vec<(f64, f64)> = scene
                .iter()
                .filter(|r| r.pareto_m7)
                .filter_map(|r| Some((lx(r.m7_instructions?), lx(r.cell.rms_px / r.cell.crlb_px))))
                .collect();
            front.sort_by(|p, q| p.0.total_cmp(&q.0));
            c.draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(2)))
                .map_err(|x| e(&x))?;
            for r in &scene {
                let Some(m7) = r.m7_instructions else {
                    continue;
                };
                let ratio = r.cell.rms_px / r.cell.crlb_px;
                if !(ratio > 0.0 && ratio.is_finite()) {
                    continue;
                }
                let k = methods.iter().position(|m| *m == r.cell.method.name());
                let color = color(k.unwrap_or(0));
                let p = (lx(m7), lx(ratio));
                c.draw_series(std::iter::once(Circle::new(p, 5, color.filled())))
                    .map_err(|x| e(&x))?;
                if r.pareto_m7 {
                    c.draw_series(std::iter::once(Circle::new(p, 7, BLACK.stroke_width(2))))
                        .map_err(|x| e(&x))?;
                }
            }
        }
        // Legend: method colours in columns.
        let per_col = methods.len().div_ceil(4).max(1);
        for (k, m) in methods.iter().enumerate() {
            let (col, row) = ((k / per_col) as i32, (k % per_col) as i32);
            let (x, y) = (30 + 390 * col, 20 + 30 * row);
            let color = color(k);
            legend
                .draw(&Circle::new((x, y + 8), 6, color.filled()))
                .map_err(|x| e(&x))?;
            legend
                .draw(&Text::new(m.clone(), (x + 14, y), font(17)))
                .map_err(|x| e(&x))?;
        }
        root.present().map_err(|x| e(&x))?;
        Ok(())
    })
}

fn cell_color(c: &FailCell) -> RGBColor {
    match &c.stats {
        None => RGBColor(235, 235, 235),
        Some(s) => {
            let r = s.reasons();
            if r.contains(&"detect") {
                RGBColor(150, 150, 150)
            } else if r.contains(&"bias") {
                RGBColor(230, 90, 80)
            } else if r.contains(&"rms") {
                RGBColor(245, 175, 80)
            } else {
                RGBColor(140, 210, 140)
            }
        }
    }
}

fn cell_text(c: &FailCell) -> String {
    match &c.stats {
        None => "n/a".into(),
        Some(s) => {
            let q = s.rms_px / s.crlb_px;
            if q.is_finite() {
                format!("{q:.1}")
            } else {
                "-".into()
            }
        }
    }
}

/// Draws one method's failure map into `out/name`: `grid` (SNR-major rows over `snrs`,
/// columns over `widths`) and `sweeps` (name, cells).
#[allow(clippy::too_many_arguments)]
pub fn heatmap(
    out: &Path,
    name: &str,
    title: &str,
    grid: &[&FailCell],
    snrs: &[f64],
    widths: &[f64],
    sweeps: &[(String, Vec<&FailCell>)],
    written: &mut Written,
) -> Result<(), FigureError> {
    let path = out.join(name);
    with_font(&path, written, |path| {
        let e = |x: &dyn std::fmt::Display| x.to_string();
        let root = BitMapBackend::new(path, (1500, 760)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        let d = |el: &dyn Fn(&DrawingArea<BitMapBackend, _>) -> Result<(), String>| el(&root);
        d(&|r| {
            r.draw(&Text::new(title.to_string(), (20, 10), font(22)))
                .map_err(|x| e(&x))
        })?;
        d(&|r| {
            r.draw(&Text::new(
                "green pass, red |bias| > 0.05 px, orange RMS > 2 CRLB, grey detection < 90 %; numbers: RMS / CRLB"
                    .to_string(),
                (20, 40),
                font(15),
            ))
            .map_err(|x| e(&x))
        })?;
        // Grid: left, 640 x 560 px.
        let (gx, gy, gw, gh) = (90i32, 90i32, 640i32, 560i32);
        let (nc, nr) = (widths.len().max(1) as i32, snrs.len().max(1) as i32);
        let (cw, ch) = (gw / nc, gh / nr);
        for (k, c) in grid.iter().enumerate() {
            let (row, col) = ((k as i32) / nc, (k as i32) % nc);
            // Highest SNR at the top.
            let y = gy + (nr - 1 - row) * ch;
            let x = gx + col * cw;
            root.draw(&Rectangle::new(
                [(x, y), (x + cw - 1, y + ch - 1)],
                cell_color(c).filled(),
            ))
            .map_err(|x| e(&x))?;
            root.draw(&Text::new(
                cell_text(c),
                (x + cw / 2, y + ch / 2),
                centred(13),
            ))
            .map_err(|x| e(&x))?;
        }
        for (i, a) in widths.iter().enumerate() {
            let x = gx + i as i32 * cw + cw / 2;
            root.draw(&Text::new(
                format!("{a:.2}"),
                (x, gy + gh + 14),
                centred(13),
            ))
            .map_err(|x| e(&x))?;
        }
        root.draw(&Text::new(
            "PSF 80 % radius a, px".to_string(),
            (gx + gw / 2, gy + gh + 40),
            centred(16),
        ))
        .map_err(|x| e(&x))?;
        for (i, s) in snrs.iter().enumerate() {
            let y = gy + (nr - 1 - i as i32) * ch + ch / 2;
            root.draw(&Text::new(format!("{s:.1}"), (gx - 30, y), centred(13)))
                .map_err(|x| e(&x))?;
        }
        root.draw(&Text::new("SNR".to_string(), (20, gy - 20), font(16)))
            .map_err(|x| e(&x))?;
        // Sweeps: right, one strip each.
        let (sx, sw) = (800i32, 680i32);
        let sh = 88i32;
        for (j, (label, cells)) in sweeps.iter().enumerate() {
            let y = gy + j as i32 * sh;
            root.draw(&Text::new(label.clone(), (sx, y), font(15)))
                .map_err(|x| e(&x))?;
            let n = cells.len().max(1) as i32;
            let w = sw / n;
            for (k, c) in cells.iter().enumerate() {
                let x = sx + k as i32 * w;
                root.draw(&Rectangle::new(
                    [(x, y + 20), (x + w - 1, y + 55)],
                    cell_color(c).filled(),
                ))
                .map_err(|x| e(&x))?;
                root.draw(&Text::new(cell_text(c), (x + w / 2, y + 37), centred(13)))
                    .map_err(|x| e(&x))?;
                let v = c.scene.perturb.sweep().1;
                root.draw(&Text::new(format!("{v}"), (x + w / 2, y + 67), centred(12)))
                    .map_err(|x| e(&x))?;
            }
        }
        root.present().map_err(|x| e(&x))?;
        Ok(())
    })
}
