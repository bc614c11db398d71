//! Speed against accuracy of every centroid method, and where each fails
//! (`startrack tradeoff --out DIR [--quick] [--m7 FILE]`).
//!
//! - [`chart`]: tradeoff.csv (and tradeoff.png, drawn by [`png`]), cost per star (Cortex-M7
//!   instructions from a `cargo m7-bench` CSV, host ns timed here: [`cost`]) against RMS
//!   error and RMS / CRLB (from [`crate::accuracy::run_cell`]), the Pareto frontier
//!   ([`pareto`]) marked per scene.
//! - [`failures`]: failures.csv, and one heatmap PNG per method ([`png`]): a grid over SNR x
//!   PSF width and sweeps of DSNU, a hot pixel, a telegraph pixel, saturation, the distance
//!   to an edge, a close pair's separation and the star's true width against the width the
//!   method is configured for; a cell fails on bias, RMS over the bound or detection.
//! - [`shapes`]: psf-shapes.csv, each method's position bias on the simulator's defocus
//!   ring and coma against the PSF's centroid (`--psf-shapes` runs only this part).
//!
//! The methods ([`methods`]) are every CoG, the Gauss fit told the width and the width-free
//! fit of the flight configuration.
//!
//! Everything but the host-ns column is seeded and deterministic: two runs write identical
//! files apart from that column. `--quick` runs fewer stars on a coarser grid, a fraction
//! of the full run's time; `time startrack tradeoff --out DIR [--quick]` measures both.

pub mod chart;
pub mod cost;
pub mod failures;
pub mod pareto;
pub mod png;
pub mod shapes;

use crate::accuracy::{Method, Noise};
use crate::figures::{FigureError, Written, csv::write_csv};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::Path;

/// What a run does.
#[derive(Clone, Debug, PartialEq)]
pub struct Options {
    /// Coarse: fewer stars and grid points.
    pub quick: bool,
    /// The M7 costs (`cargo m7-bench` output).
    pub m7: cost::M7Table,
    /// Where they came from (for the CSV header).
    pub m7_source: String,
    /// Passes of the host timing (0: no host timing, the column is left empty).
    pub host_passes: usize,
    /// Draw a progress bar on stderr.
    pub progress: bool,
    /// Only the non-Gaussian PSF experiment ([`shapes`]): psf-shapes.csv.
    pub psf_shapes_only: bool,
}

/// The methods of the chart and the maps: [`Method::all`] (every CoG and the Gauss fit of
/// known width) and the width-free fit as the flight configuration runs it
/// ([`Method::GaussFitWidth`], border-median background, not told the width) on 5x5 and
/// 7x7 windows.
pub fn methods() -> Vec<Method> {
    let mut v = Method::all();
    v.push(Method::GaussFitWidth { window: 5 });
    v.push(Method::GaussFitWidth { window: 7 });
    v
}

/// The accuracy experiment of the chart: [`Noise::default`] (2000 stars), 300 with `quick`.
pub fn chart_noise(quick: bool) -> Noise {
    Noise {
        trials: if quick { 300 } else { 2000 },
        ..Noise::default()
    }
}

/// A file-name-safe form of a method's name: `cog2 5x5 corrected` -> `cog2-5x5-corrected`.
pub fn slug(method: &Method) -> String {
    method
        .name()
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect()
}

/// Writes tradeoff.csv/.png, failures.csv, failures-METHOD.png and psf-shapes.csv into `out`
/// (created); only psf-shapes.csv with [`Options::psf_shapes_only`].
pub fn run_all(out: &Path, opts: &Options) -> Result<Written, FigureError> {
    std::fs::create_dir_all(out).map_err(|e| FigureError {
        path: out.to_path_buf(),
        message: e.to_string(),
    })?;
    let mut w = Written::default();
    let methods = methods();
    let shape_spec = shapes::ShapeSpec::new(opts.quick);
    if opts.psf_shapes_only {
        let cells = shapes::run(&methods, &shape_spec);
        shapes::write(out, &shape_spec, &cells, &mut w)?;
        return Ok(w);
    }
    let spec = failures::MapSpec::new(opts.quick);
    let noise = chart_noise(opts.quick);
    let chart_cells = chart::SNRS.len() * chart::WIDTHS_A_PX.len() * methods.len();
    let total = (chart_cells + spec.scenes().len()) as u64;
    let bar = if opts.progress {
        let b = ProgressBar::new(total);
        if let Ok(style) =
            ProgressStyle::with_template("tradeoff {bar:40} {pos}/{len} cells+scenes, eta {eta}")
        {
            b.set_style(style);
        }
        b
    } else {
        ProgressBar::hidden()
    };
    let costs = chart::costs(&methods, &opts.m7, opts.host_passes);
    let rows = chart::rows(&methods, &costs, &noise, || bar.inc(1));
    write_chart(out, &rows, &methods, &noise, &opts.m7_source, &mut w)?;
    let cells = failures::run(&methods, &spec, || bar.inc(1));
    bar.finish_and_clear();
    write_failures(out, &methods, &spec, &cells, &mut w)?;
    let shape_cells = shapes::run(&methods, &shape_spec);
    shapes::write(out, &shape_spec, &shape_cells, &mut w)?;
    Ok(w)
}

/// Writes tradeoff.csv and tradeoff.png.
pub fn write_chart(
    out: &Path,
    rows: &[chart::TradeRow],
    methods: &[Method],
    noise: &Noise,
    m7_source: &str,
    w: &mut Written,
) -> Result<(), FigureError> {
    chart::write_csv(out, rows, noise, m7_source, w)?;
    let names: Vec<String> = methods.iter().map(Method::name).collect();
    png::tradeoff(out, rows, &names, &chart::WIDTHS_A_PX, &chart::SNRS, w)
}

/// Writes failures.csv and the heatmaps.
pub fn write_failures(
    out: &Path,
    methods: &[Method],
    spec: &failures::MapSpec,
    cells: &[failures::FailCell],
    w: &mut Written,
) -> Result<(), FigureError> {
    let header = vec![
        "Failure maps of every centroid method (startrack tradeoff); definitions in host-tests/analysis/src/tradeoff/failures.rs".to_string(),
        format!(
            "{} stars per scene, uniform pixel phase, background {} e-/px, read noise {} e-, seed {}; SNR by eq. 8 in 5x5; sweeps at a = {} px, SNR {}",
            spec.trials,
            failures::BACKGROUND_E,
            failures::READ_NOISE_E,
            spec.seed,
            spec.sweep_a_px,
            spec.sweep_snr
        ),
        "a_px: the width the method is configured for, and the star's except in the true_a_px sweep (value = the star's true a; the width-free fit is told no width)".to_string(),
        format!(
            "fail: bias (bias_px > {}: RMS error on the noise-free image), rms (rms_px > {} crlb_px), detect (detect_rate < {}: no degenerate/not-converged/low-SNR flag and within 1 px); pass; n/a = no correction curve for this a",
            failures::BIAS_LIMIT_PX,
            failures::RMS_OVER_CRLB_LIMIT,
            failures::DETECT_LIMIT
        ),
    ];
    let lines: Vec<String> = cells.iter().map(failures::csv_row).collect();
    write_csv(out, "failures.csv", &header, failures::COLUMNS, &lines, w)?;
    for m in methods {
        let mine: Vec<&failures::FailCell> = cells.iter().filter(|c| c.method == *m).collect();
        let grid: Vec<&failures::FailCell> = mine
            .iter()
            .copied()
            .filter(|c| c.scene.perturb == failures::Perturb::None)
            .collect();
        let mut sweeps: Vec<(String, Vec<&failures::FailCell>)> = Vec::new();
        for c in mine
            .iter()
            .copied()
            .filter(|c| c.scene.perturb != failures::Perturb::None)
        {
            let name = c.scene.perturb.sweep().0;
            let told = if matches!(c.scene.perturb, failures::Perturb::TrueWidth(_)) {
                "configured for a"
            } else {
                "a"
            };
            match sweeps.iter_mut().find(|(n, _)| n.starts_with(name)) {
                Some((_, v)) => v.push(c),
                None => sweeps.push((
                    format!("{name} ({told} = {}, SNR {})", c.scene.a_px, c.scene.snr),
                    vec![c],
                )),
            }
        }
        png::heatmap(
            out,
            &format!("failures-{}.png", slug(m)),
            &format!("Where {} fails", m.name()),
            &grid,
            &spec.grid_snr,
            &spec.grid_a_px,
            &sweeps,
            w,
        )?;
    }
    Ok(())
}
