//! `startrack calib cti` and `startrack calib psf-model`: the two model sections of the table
//! (CTI coefficients, field PSF model) from measurements, as JSON files that `calib build
//! --cti` and `--psf-model` take.
//!
//! - `calib cti --out-dir DIR [--traps FILE]`: the CTI centroid bias of the flight method
//!   against signal and transfer distance on the simulator ([`startrack_lab::cti`]), written as
//!   `cti_bias.csv`; the coefficients fitted to it as `cti.json`; and the paired Monte Carlo
//!   of the correction against the simulator's trap law as `cti_residual.csv`, summarised per
//!   SNR on stdout (the CTI rows of the accuracy docs). `--traps` takes a trap law measured
//!   from lab flats by EPER (`calib frames` writes `cti_traps.json`): the coefficients then
//!   come from the measurement, and the Monte Carlo still checks them against the simulator's
//!   own law.
//! - `calib psf-model STARS.csv... --out FILE [--degree D]`: the field PSF model fitted to the
//!   stars' measured widths ([`startrack_lab::psf_model`]).
//!
//! Cost: `calib cti` under a second (0.3 s in the test profile) (256 noise-free windows for the fit, 125 cells
//! of 40-400 pairs for the Monte Carlo); `calib psf-model` one small SVD per clipping round.

use super::{CliError, LabError, read_file, write_file};
use startrack_core::geometry::ReadoutGeometry;
use startrack_lab::cti::{
    CTI_FIT_FLUXES_E, CtiCoeffsJson, CtiExperiment, DEFAULT_TRAPS, McCell, bias_csv, mc_csv,
    summarize,
};
use startrack_lab::psf_model::{fit, read_stars_csv};
use startrack_sim::sim::effects::ChargeTraps;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The SNRs of the Monte Carlo.
pub const CTI_SNRS: [f64; 5] = [10.0, 20.0, 50.0, 100.0, 200.0];

/// Pairs per Monte Carlo cell at `snr` (the paired residual's scatter falls as 1 / SNR):
/// 400 at SNR 10, 40 from SNR 32 up.
pub fn cti_trials(snr: f64) -> usize {
    ((40_000.0 / (snr * snr)) as usize).max(40)
}

/// Options of `startrack calib cti`.
#[derive(Clone, Debug, clap::Args)]
pub struct CalibCtiArgs {
    /// Output folder (created if needed): cti_bias.csv, cti.json, cti_residual.csv.
    #[arg(long)]
    pub out_dir: PathBuf,
    /// Trap law to fit the coefficients to (JSON, `calib frames`' cti_traps.json); default:
    /// the simulator's own law.
    #[arg(long)]
    pub traps: Option<PathBuf>,
    /// Seed of the Monte Carlo.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
}

/// Options of `startrack calib psf-model`.
#[derive(Clone, Debug, clap::Args)]
pub struct PsfModelArgs {
    /// CSV files with a header naming x_px, y_px and psf_a_px (`process`'s stars.csv).
    #[arg(required = true)]
    pub stars: Vec<PathBuf>,
    /// Output JSON file.
    #[arg(long)]
    pub out: PathBuf,
    /// Total degree of the polynomial, 0 to 3.
    #[arg(long, default_value_t = 2)]
    pub degree: u8,
}

/// What `calib cti` measured.
#[derive(Clone, Debug)]
pub struct CtiRun {
    /// The fitted coefficients.
    pub coeffs: CtiCoeffsJson,
    /// The Monte Carlo cells.
    pub cells: Vec<McCell>,
    /// The summary table (markdown), one row per SNR and one for all.
    pub summary: String,
}

fn read_traps(path: &Path) -> Result<ChargeTraps, CliError> {
    let bytes = read_file(path)?;
    serde_json::from_slice(&bytes).map_err(|e| CliError::Usage(format!("{}: {e}", path.display())))
}

/// The summary of `cells` as a markdown table: per SNR, the bias and residual RMS over the
/// cells (both axes) and the share removed.
pub fn cti_summary(cells: &[McCell]) -> String {
    let mut s = String::from(
        "| SNR | CTI bias RMS, px | residual RMS, px | removed |\n|---|---|---|---|\n",
    );
    let row = |s: &mut String, label: &str, v: &[McCell]| {
        let (b, r, _) = summarize(v);
        let _ = writeln!(
            s,
            "| {label} | {b:.4} | {r:.5} | {:.1} % |",
            100.0 * (1.0 - r / b)
        );
    };
    for snr in CTI_SNRS {
        let v: Vec<McCell> = cells.iter().filter(|c| c.snr == snr).copied().collect();
        row(&mut s, &format!("{snr}"), &v);
    }
    row(&mut s, "all", cells);
    s
}

/// Runs the measurement, the fit and the Monte Carlo (nothing written).
pub fn measure_cti(args: &CalibCtiArgs) -> Result<(CtiRun, String), CliError> {
    let truth = CtiExperiment::flight(DEFAULT_TRAPS);
    let fit_law = args.traps.as_deref().map(read_traps).transpose()?;
    let fit_exp = CtiExperiment::flight(fit_law.unwrap_or(DEFAULT_TRAPS));
    let points = fit_exp.bias_grid(&CTI_FIT_FLUXES_E, &fit_exp.positions(4));
    let coeffs = fit_exp
        .fit(&points)
        .ok_or_else(|| CliError::Usage("CTI: too few measurable biases to fit".into()))?;
    let cells: Vec<McCell> = CTI_SNRS
        .iter()
        .flat_map(|&snr| {
            truth.monte_carlo(
                &coeffs,
                &[snr],
                &truth.positions(5),
                cti_trials(snr),
                args.seed,
            )
        })
        .collect();
    let g: ReadoutGeometry = truth.geometry;
    Ok((
        CtiRun {
            coeffs: CtiCoeffsJson::from_coeffs(&coeffs, g.outputs),
            summary: cti_summary(&cells),
            cells,
        },
        bias_csv(&points),
    ))
}

/// Runs `startrack calib cti`: writes the three files and prints the summary.
pub fn run_cti(args: &CalibCtiArgs) -> Result<CtiRun, CliError> {
    let (run, bias) = measure_cti(args)?;
    std::fs::create_dir_all(&args.out_dir).map_err(|e| LabError::Io {
        path: args.out_dir.clone(),
        msg: e.to_string(),
    })?;
    let json = serde_json::to_string_pretty(&run.coeffs)
        .map_err(|e| CliError::Usage(format!("cti.json: {e}")))?;
    write_file(&args.out_dir.join("cti_bias.csv"), bias.as_bytes())?;
    write_file(&args.out_dir.join("cti.json"), json.as_bytes())?;
    write_file(
        &args.out_dir.join("cti_residual.csv"),
        mc_csv(&run.cells).as_bytes(),
    )?;
    println!("{}", run.summary);
    println!(
        "wrote cti_bias.csv, cti.json, cti_residual.csv to {}",
        args.out_dir.display()
    );
    Ok(run)
}

/// Runs `startrack calib psf-model`: fits and writes the model, prints its summary.
pub fn run_psf_model(
    args: &PsfModelArgs,
) -> Result<startrack_lab::psf_model::PsfModelFit, CliError> {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let mut stars = Vec::new();
    for p in &args.stars {
        let text = String::from_utf8_lossy(&read_file(p)?).into_owned();
        stars.extend(read_stars_csv(&text).map_err(|(line, msg)| LabError::Csv {
            path: p.clone(),
            line,
            msg,
        })?);
    }
    let m = fit(&stars, args.degree, g.active_cols, g.active_rows)
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let json = serde_json::to_string_pretty(&m).map_err(|e| CliError::Usage(format!("{e}")))?;
    write_file(&args.out, json.as_bytes())?;
    println!(
        "PSF model degree {}: {} stars kept, {} rejected, scatter {:.3} px; wrote {}",
        m.degree,
        m.stars,
        m.rejected,
        m.scatter_px,
        args.out.display()
    );
    Ok(m)
}
