//! The founding paper's Figures 1-6, computed with the core's own centroid and calibration
//! code (the code the firmware runs) on the simulated CCD47-20, written as CSV (parameters in
//! a `#` header comment) and PNG.
//!
//! - [`fig1`] / [`fig4`]: RMS of the noise-free systematic shift of the CoG, power 1 / 2, over
//!   true positions spread uniformly over the central pixel, against the 80 % radius `a`.
//! - [`fig2`] / [`fig3`]: that shift against the true position inside the central pixel, 5x5
//!   box, large / small images.
//! - [`fig5`] / [`fig6`]: the paper's dark non-uniformity experiment (Monte Carlo), with the
//!   paper's perimeter background and with our dark pre-calculation; error and detection rate
//!   against DSNU.
//!
//! Figures 1-4 share [`systematic`]; PNGs are drawn by [`plot`].

pub mod csv;
pub mod fig1;
pub mod fig2;
pub mod fig3;
pub mod fig4;
pub mod fig5;
pub mod fig6;
pub mod plot;
pub mod systematic;

use std::path::{Path, PathBuf};

/// How much work a run does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effort {
    /// Coarse grids and a few hundred Monte Carlo trials: under a minute.
    Quick,
    /// The full figures: fine grids and a few thousand trials per point.
    Full,
}

/// What a run wrote.
#[derive(Clone, Debug, Default)]
pub struct Written {
    /// Files written, in order.
    pub files: Vec<PathBuf>,
    /// PNGs that could not be drawn, with why (the CSVs are still written).
    pub skipped_png: Vec<String>,
}

/// An error of a figures run: the file and what went wrong.
#[derive(Debug)]
pub struct FigureError {
    /// The file being written.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

impl std::fmt::Display for FigureError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.message)
    }
}

impl std::error::Error for FigureError {}

/// One figure's two files: `fig{number}.csv` (the rows under their `#` header and column
/// names, [`csv::write_csv`]) and `fig{number}.png` (the chart of `series`, [`plot::lines`]).
#[derive(Clone, Debug)]
pub struct FigureFiles {
    /// The figure's number in the paper.
    pub number: u8,
    /// The CSV's parameter header, one comment line each.
    pub header: Vec<String>,
    /// The CSV's column names, comma-separated.
    pub columns: &'static str,
    /// The CSV's rows, comma-separated.
    pub rows: Vec<String>,
    /// The PNG's texts and axes.
    pub chart: plot::Chart,
    /// The PNG's curves.
    pub series: Vec<plot::Series>,
}

impl FigureFiles {
    /// Writes the CSV, then the PNG, into `out` (a missing font skips only the PNG).
    pub fn write(&self, out: &Path, written: &mut Written) -> Result<(), FigureError> {
        let n = self.number;
        csv::write_csv(
            out,
            &format!("fig{n}.csv"),
            &self.header,
            self.columns,
            &self.rows,
            written,
        )?;
        plot::lines(
            out,
            &format!("fig{n}.png"),
            &self.chart,
            &self.series,
            written,
        )
    }
}

/// Writes fig1..fig6 (CSV and PNG) into `out`, creating it; `progress` shows a progress bar
/// on the Monte Carlo figures.
pub fn run_all(out: &Path, effort: Effort, progress: bool) -> Result<Written, FigureError> {
    std::fs::create_dir_all(out).map_err(|e| FigureError {
        path: out.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut w = Written::default();
    fig1::write(out, effort, &mut w)?;
    fig2::write(out, effort, &mut w)?;
    fig3::write(out, effort, &mut w)?;
    fig4::write(out, effort, &mut w)?;
    let exp = fig5::run(&fig5::Fig5Params::for_effort(effort), progress);
    fig5::write(out, &exp, &mut w)?;
    fig6::write(out, &exp, &mut w)?;
    Ok(w)
}

/// `n` values from `lo` to `hi` evenly spaced on a log scale.
pub fn log_space(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let (l0, l1) = (lo.ln(), hi.ln());
    (0..n)
        .map(|i| {
            if n < 2 {
                lo
            } else {
                (l0 + (l1 - l0) * i as f64 / (n - 1) as f64).exp()
            }
        })
        .collect()
}

/// `m` true positions inside the central pixel, relative to its centre: the midpoints of
/// `m` equal cells of `-1/2 .. 1/2` (uniform, never on a pixel edge).
pub fn phases(m: usize) -> Vec<f64> {
    (0..m).map(|k| -0.5 + (k as f64 + 0.5) / m as f64).collect()
}
