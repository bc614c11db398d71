//! PNG line charts with `plotters` (bitmap backend, text through `ab_glyph`).
//!
//! `ab_glyph` needs the bytes of a TrueType font and there is no font inside the crates, so
//! the first of [`FONT_PATHS`] that exists is loaded once (Debian/Ubuntu package
//! `fonts-dejavu-core`, which .ci/run installs when missing). Without any font the PNGs are
//! skipped with a reason and the CSVs are still written. Log axes are drawn as log10 of the
//! values on a linear axis, labelled with the values themselves.

use super::{FigureError, Written};
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// Where a sans-serif TrueType font is looked for.
pub const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

/// One curve.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// (x, y) points in data units.
    pub points: Vec<(f64, f64)>,
    /// Colour: an index into a fixed palette of distinct colours.
    pub color: usize,
    /// Dashed line (e.g. a second method in the same colour).
    pub dashed: bool,
}

impl Series {
    /// A solid curve in colour `color`.
    pub fn solid(label: String, points: Vec<(f64, f64)>, color: usize) -> Self {
        Self {
            label,
            points,
            color,
            dashed: false,
        }
    }
}

/// One solid curve per key of `keys`, coloured in their order, labelled `label(key)`: the
/// points `point(row, key)` of `rows`, in row order (`None`: the row is not on that curve).
pub fn solid_per_key<R, K: Copy>(
    keys: &[K],
    label: impl Fn(K) -> String,
    rows: &[R],
    point: impl Fn(&R, K) -> Option<(f64, f64)>,
) -> Vec<Series> {
    keys.iter()
        .enumerate()
        .map(|(i, &k)| {
            Series::solid(
                label(k),
                rows.iter().filter_map(|r| point(r, k)).collect(),
                i,
            )
        })
        .collect()
}

/// Distinct colours that read on white.
const PALETTE: [RGBColor; 8] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0xe3, 0x77, 0xc2),
    RGBColor(0x17, 0xbe, 0xcf),
];

fn color_of(i: usize) -> RGBColor {
    PALETTE.get(i % PALETTE.len()).copied().unwrap_or(BLACK)
}

/// A chart's texts and axes.
#[derive(Clone, Debug)]
pub struct Chart {
    /// Caption.
    pub title: String,
    /// X axis label.
    pub x_label: String,
    /// Y axis label.
    pub y_label: String,
    /// Logarithmic x axis (points with x <= 0 are dropped).
    pub log_x: bool,
    /// Logarithmic y axis (points with y <= 0 are dropped).
    pub log_y: bool,
}

/// Loads and registers the font once; the error says why there is none.
pub fn ensure_font() -> Result<(), String> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let path = FONT_PATHS
            .iter()
            .find(|p| Path::new(p).exists())
            .ok_or_else(|| {
                format!(
                    "no TrueType font found (looked for {}); install fonts-dejavu-core",
                    FONT_PATHS.join(", ")
                )
            })?;
        let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| format!("{path}: not a usable TrueType font"))
    })
    .clone()
}

fn tr(v: f64, log: bool) -> Option<f64> {
    if log {
        (v > 0.0).then(|| v.log10())
    } else {
        v.is_finite().then_some(v)
    }
}

fn tick_label(v: f64, log: bool) -> String {
    let x = if log { 10f64.powf(v) } else { v };
    if x.abs() < 1e-9 {
        "0".into()
    } else if x.abs() >= 0.01 && x.abs() < 1000.0 {
        let s = format!("{x:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{x:.0e}")
    }
}

/// Draws `series` into `out/name`; a missing font records a skip instead of failing.
pub fn lines(
    out: &Path,
    name: &str,
    chart: &Chart,
    series: &[Series],
    written: &mut Written,
) -> Result<(), FigureError> {
    let path = out.join(name);
    if let Err(why) = ensure_font() {
        written
            .skipped_png
            .push(format!("{}: {why}", path.display()));
        return Ok(());
    }
    draw(&path, chart, series).map_err(|message| FigureError {
        path: path.clone(),
        message,
    })?;
    written.files.push(path);
    Ok(())
}

fn draw(path: &Path, chart: &Chart, series: &[Series]) -> Result<(), String> {
    let pts: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .filter_map(|&(x, y)| Some((tr(x, chart.log_x)?, tr(y, chart.log_y)?)))
                .collect()
        })
        .collect();
    let all = pts.iter().flatten();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    let pad = |lo: f64, hi: f64| {
        let d = if hi > lo { 0.05 * (hi - lo) } else { 0.5 };
        (lo - d, hi + d)
    };
    let (x0, x1) = pad(x0, x1);
    let (y0, y1) = pad(y0, y1);
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let root = BitMapBackend::new(path, (1150, 620)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let (left, right) = root.split_horizontally(880);
    let mut c = ChartBuilder::on(&left)
        .caption(&chart.title, ("sans-serif", 21))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|x| e(&x))?;
    let (lx, ly) = (chart.log_x, chart.log_y);
    c.configure_mesh()
        .x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .x_label_formatter(&|v| tick_label(*v, lx))
        .y_label_formatter(&|v| tick_label(*v, ly))
        .draw()
        .map_err(|x| e(&x))?;
    for (s, p) in series.iter().zip(&pts) {
        let style = color_of(s.color).stroke_width(2);
        if s.dashed {
            c.draw_series(DashedLineSeries::new(p.iter().copied(), 8, 5, style))
                .map_err(|x| e(&x))?;
        } else {
            c.draw_series(LineSeries::new(p.iter().copied(), style))
                .map_err(|x| e(&x))?;
            c.draw_series(
                p.iter()
                    .map(|&(x, y)| Circle::new((x, y), 2, color_of(s.color).filled())),
            )
            .map_err(|x| e(&x))?;
        }
    }
    // The legend, in its own panel so that it never hides a curve.
    let font = ("sans-serif", 15).into_font().color(&BLACK);
    for (i, s) in series.iter().enumerate() {
        let y = 60 + 24 * i as i32;
        let style = color_of(s.color).stroke_width(2);
        if s.dashed {
            for k in 0..3 {
                right
                    .draw(&PathElement::new(
                        vec![(10 + 11 * k, y), (17 + 11 * k, y)],
                        style,
                    ))
                    .map_err(|x| e(&x))?;
            }
        } else {
            right
                .draw(&PathElement::new(vec![(10, y), (40, y)], style))
                .map_err(|x| e(&x))?;
        }
        right
            .draw(&Text::new(s.label.clone(), (48, y - 8), font.clone()))
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
