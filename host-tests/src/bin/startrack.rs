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
    /// Write the simulated sensor's true calibration as a table file (for bring-up on a board:
    /// flash it into the CALIB sector, see the README).
    Table {
        /// Output file.
        #[arg(long)]
        out: std::path::PathBuf,
        /// Seed of the simulated sensor.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Map tiles of 2^N pixels; 3 (8x8) fits the 128 KB CALIB sector.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(0..=10))]
        tile_log2: u8,
    },
    /// The founding paper's Figures 1-6 (CSV with parameters, PNG) from the core's code.
    Figures(startrack_host::cli::figures::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Figures(args) => startrack_host::cli::figures::run(&args),
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
        Command::Table {
            out,
            seed,
            tile_log2,
        } => {
            let params = startrack_host::sim::SensorParams {
                seed,
                ..Default::default()
            };
            let sim = startrack_host::sim::Simulator::new(params, Vec::new());
            let sections = startrack_host::sim::truth::TruthSections::ALL;
            let written = sim
                .truth_table_tiled(sections, tile_log2)
                .map_err(|e| e.to_string())
                .and_then(|t| {
                    std::fs::write(&out, &t)
                        .map(|()| t.len())
                        .map_err(|e| e.to_string())
                });
            match written {
                Ok(n) => {
                    println!("wrote {} ({n} bytes)", out.display());
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("startrack table: {}: {e}", out.display());
                    ExitCode::FAILURE
                }
            }
        }
    }
}
