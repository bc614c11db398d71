//! `startrack tradeoff --out DIR [--quick] [--m7 FILE] [--psf-shapes]`: every centroid
//! method's cost against its accuracy with the Pareto frontier, its failure maps and its
//! position bias on non-Gaussian PSFs (see [`startrack_analysis::tradeoff`]).

use startrack_analysis::tradeoff::{Options, cost::M7Table, run_all};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

/// The committed `cargo m7-bench` output, relative to the workspace root.
pub const DEFAULT_M7: &str = "host-tests/m7-costs.csv";

/// Arguments of `startrack tradeoff`.
#[derive(clap::Args, Debug, Clone)]
pub struct TradeoffArgs {
    /// Directory for tradeoff.csv/.png, failures.csv, failures-METHOD.png and psf-shapes.csv
    /// (created).
    #[arg(long)]
    pub out: PathBuf,
    /// Coarse: 300 stars per accuracy cell, a 5 x 5 failure grid, 150 stars per scene, 300
    /// stars per PSF shape.
    #[arg(long)]
    pub quick: bool,
    /// `cargo m7-bench` CSV (stage,unit,instructions_per_unit); default: host-tests/m7-costs.csv,
    /// regenerated with `cargo m7-bench > host-tests/m7-costs.csv`.
    #[arg(long)]
    pub m7: Option<PathBuf>,
    /// Leave the host-ns column empty (then the outputs are fully deterministic).
    #[arg(long)]
    pub no_host_time: bool,
    /// Only the position bias on the simulator's defocus and coma PSFs: psf-shapes.csv.
    #[arg(long)]
    pub psf_shapes: bool,
}

/// Reads the M7 CSV: the given file, or the committed copy from the workspace root or from
/// host-tests/.
fn load_m7(arg: Option<&PathBuf>) -> Result<(M7Table, String), String> {
    let path = match arg {
        Some(p) => p.clone(),
        None => [
            PathBuf::from(DEFAULT_M7),
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("m7-costs.csv"),
        ]
        .into_iter()
        .find(|p| p.exists())
        .unwrap_or_else(|| PathBuf::from(DEFAULT_M7)),
    };
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let t = M7Table::parse(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok((t, path.display().to_string()))
}

/// Runs the subcommand.
pub fn run(args: &TradeoffArgs) -> ExitCode {
    let (m7, m7_source) = match load_m7(args.m7.as_ref()) {
        Ok(v) => v,
        Err(e) => {
            eprintln!("startrack tradeoff: {e}");
            return ExitCode::FAILURE;
        }
    };
    let opts = Options {
        quick: args.quick,
        m7,
        m7_source,
        host_passes: if args.no_host_time { 0 } else { 5 },
        progress: std::io::stderr().is_terminal(),
        psf_shapes_only: args.psf_shapes,
    };
    match run_all(&args.out, &opts) {
        Ok(w) => {
            for f in &w.files {
                println!("wrote {}", f.display());
            }
            for s in &w.skipped_png {
                eprintln!("startrack tradeoff: skipped {s}");
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("startrack tradeoff: {e}");
            ExitCode::FAILURE
        }
    }
}
