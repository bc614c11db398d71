//! `startrack`: the star tracker's host command.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "startrack",
    version,
    about = "Star tracker processing on the host, on simulated or recorded CCD47-20 frames"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a CCD47-20 star field, calibrate it with the core, compare with the truth.
    Demo {
        /// Seed of the simulation (reruns with the same seed print the same numbers).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Number of stars.
        #[arg(long, default_value_t = 12)]
        stars: usize,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Demo { seed, stars } => match startrack_host::demo::run(seed, stars) {
            Ok(report) => {
                startrack_host::demo::print(&report);
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("startrack demo: {e}");
                ExitCode::FAILURE
            }
        },
    }
}
