//! `startrack figures --out DIR [--quick]`: the founding paper's Figures 1-6 as CSV and PNG
//! (see [`startrack_analysis::figures`]).

use startrack_analysis::figures::{Effort, run_all};
use std::io::IsTerminal;
use std::process::ExitCode;

/// Arguments of `startrack figures`.
#[derive(clap::Args, Debug, Clone)]
pub struct FiguresArgs {
    /// Directory for fig1..fig6 .csv and .png (created if missing).
    #[arg(long)]
    pub out: std::path::PathBuf,
    /// Coarse grids and 300 trials per Monte Carlo point (under a minute).
    #[arg(long)]
    pub quick: bool,
}

/// Runs the subcommand.
pub fn run(args: &FiguresArgs) -> ExitCode {
    let effort = if args.quick {
        Effort::Quick
    } else {
        Effort::Full
    };
    let progress = std::io::stderr().is_terminal();
    match run_all(&args.out, effort, progress) {
        Ok(w) => {
            for f in &w.files {
                println!("wrote {}", f.display());
            }
            for s in &w.skipped_png {
                eprintln!("startrack figures: skipped {s}");
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("startrack figures: {e}");
            ExitCode::FAILURE
        }
    }
}
