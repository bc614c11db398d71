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
    if x == 0.0 {
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
    let root = BitMapBackend::new(path, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, ("sans-serif", 22))
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
    for (i, (s, p)) in series.iter().zip(&pts).enumerate() {
        let color = Palette99::pick(i).to_rgba();
        c.draw_series(LineSeries::new(p.iter().copied(), color.stroke_width(2)))
            .map_err(|x| e(&x))?
            .label(&s.label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        c.draw_series(
            p.iter()
                .map(|&(x, y)| Circle::new((x, y), 2, color.filled())),
        )
        .map_err(|x| e(&x))?;
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
