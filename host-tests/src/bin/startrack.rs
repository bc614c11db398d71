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
        /// The frame shows the sky instead (the on-board catalog's stars at a seeded
        /// attitude; `--stars` is not used), and the demo ends with the attitude's error.
        #[arg(long)]
        sky: bool,
    },
    /// Write the simulated sensor's true calibration as a table file (for bring-up on a board:
    /// with --slot-image, the bank-2 slot to flash, see the README).
    Table {
        /// Output file.
        #[arg(long)]
        out: std::path::PathBuf,
        /// Seed of the simulated sensor.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Map tiles of 2^N pixels; 3 (8x8) fits the firmware's 192 KB table.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(0..=10))]
        tile_log2: u8,
        /// Write the calibration slot's image instead (slot header, then the table; flash it
        /// at 0x08100000, the start of bank 2).
        #[arg(long)]
        slot_image: bool,
    },
    /// Find and centroid the stars of a raw frame (FITS) with a calibration table; CSV out.
    Process(startrack_host::cli::process::ProcessArgs),
    /// Calibration tables from calibration maps.
    #[command(subcommand)]
    Calib(CalibCommand),
    /// Run the tracker application live on the simulated sensor over a drifting scene
    /// (software in the loop); telemetry and truth as CSV.
    Sil(startrack_host::cli::sil::SilArgs),
    /// The flight firmware on QEMU's emulated Cortex-M7 (mps2-an500) fed by the simulated
    /// sensor (processor in the loop): per frame mode, stars, attitude, emulated time.
    Pil(startrack_host::cli::pil::PilArgs),
    /// The ground tool: command a tracker's link (`startrack sil --port P`) and read it.
    Gse(startrack_host::cli::gse::GseArgs),
    /// Write a simulated raw frame, its star truth and the true calibration maps to a folder.
    Simulate(startrack_host::cli::simulate::SimulateArgs),
    /// Every centroid method's RMS error over the Cramer-Rao bound, by Monte Carlo (markdown).
    Accuracy(startrack_host::cli::accuracy::AccuracyArgs),
    /// RMS error over the Cramer-Rao bound end to end on simulated frames of mixed PSF widths
    /// (simulate, calib build, process with defaults; without and with a field PSF model).
    AccuracyFrames(startrack_host::cli::accuracy_frames::AccuracyFramesArgs),
    /// The founding paper's Figures 1-6 (CSV with parameters, PNG) from the core's code.
    Figures(startrack_host::cli::figures::FiguresArgs),
    /// Cost per star against accuracy (Pareto frontier) and failure maps of every centroid method.
    Tradeoff(startrack_host::cli::tradeoff::TradeoffArgs),
    /// One frame of the CCD sequencer: rows clocked, pixels digitised, frame time and update
    /// rate, computed from the compiled program (CSV).
    ReadoutPlan(startrack_host::cli::readout_plan::ReadoutPlanArgs),
    /// The on-board star catalog, and solve cases rendered from it.
    #[command(subcommand)]
    Catalog(CatalogCommand),
    /// Identify the stars of every field of a case and write each attitude with its covariance.
    Solve(startrack_host::cli::solve::SolveArgs),
    /// Solve real night-sky images (FITS, TIFF, PNG, JPEG): attitude, matched stars.
    SolveImage(startrack_host::cli::solve_image::SolveImageArgs),
    /// The camera model (focal length, principal point, distortion, lateral colour) fitted
    /// from identified stars over many frames.
    #[command(subcommand)]
    Optics(OpticsCommand),
}

// Parsed once per run: the size of the largest variant does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum OpticsCommand {
    /// Write simulated frames through distorted optics with lateral colour, and the truth.
    Case(startrack_host::cli::optics::OpticsCaseArgs),
    /// Fit the camera model to a case's or to real images' identified stars and write it as
    /// JSON.
    Fit(startrack_host::cli::optics::OpticsFitArgs),
}

#[derive(Subcommand)]
enum CatalogCommand {
    /// Build the catalog (stars and identification database) from the Hipparcos list.
    Build(startrack_host::cli::catalog::CatalogBuildArgs),
    /// Write a `solve` case: fields rendered at random attitudes, and the true attitudes.
    Case(startrack_host::cli::catalog::CatalogCaseArgs),
}

// Parsed once per run: the size of the largest variant does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum CalibCommand {
    /// Build a table from bias, dark and flat FITS maps, gains and a hot-pixel CSV.
    Build(startrack_lab::table_build::CalibBuildArgs),
    /// Build a table and a report from raw lab frames (bias, flat pairs, darks).
    Frames(startrack_host::cli::calib_frames::CalibFramesArgs),
    /// Write a simulated lab set of raw frames (to try `calib frames` on).
    LabSet(startrack_host::cli::calib_frames::LabSetArgs),
    /// CTI centroid bias vs signal and transfer distance, fitted coefficients, residual.
    Cti(startrack_host::cli::calib_models::CalibCtiArgs),
    /// Fit the field PSF model to the stars' measured widths (stars.csv).
    PsfModel(startrack_host::cli::calib_models::PsfModelArgs),
}

/// Prints `startrack NAME: error` on one line and fails.
fn fail(name: &str, e: &dyn std::fmt::Display) -> ExitCode {
    eprintln!("startrack {name}: {e}");
    ExitCode::FAILURE
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Process(args) => match startrack_host::cli::process::run(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => fail("process", &e),
        },
        Command::Calib(CalibCommand::Build(args)) => {
            match startrack_host::cli::calib_build::run(&args) {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) => fail("calib build", &e),
            }
        }
        Command::Calib(CalibCommand::Frames(args)) => {
            match startrack_host::cli::calib_frames::run(&args) {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) => fail("calib frames", &e),
            }
        }
        Command::Calib(CalibCommand::Cti(args)) => {
            match startrack_host::cli::calib_models::run_cti(&args) {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) => fail("calib cti", &e),
            }
        }
        Command::Calib(CalibCommand::PsfModel(args)) => {
            match startrack_host::cli::calib_models::run_psf_model(&args) {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) => fail("calib psf-model", &e),
            }
        }
        Command::Calib(CalibCommand::LabSet(args)) => {
            match startrack_host::cli::calib_frames::run_lab_set(&args) {
                Ok(_) => ExitCode::SUCCESS,
                Err(e) => fail("calib lab-set", &e),
            }
        }
        Command::Simulate(args) => match startrack_host::cli::simulate::run(&args) {
            Ok(files) => {
                println!(
                    "wrote {}, {}, {}, {}, {}, {}",
                    files.frame.display(),
                    files.truth.display(),
                    files.bias.display(),
                    files.dark.display(),
                    files.flat.display(),
                    files.hot.display()
                );
                ExitCode::SUCCESS
            }
            Err(e) => fail("simulate", &e),
        },
        Command::Accuracy(args) => match startrack_host::cli::accuracy::run(&args) {
            Ok(table) => {
                print!("{table}");
                ExitCode::SUCCESS
            }
            Err(e) => fail("accuracy", &e),
        },
        Command::AccuracyFrames(args) => match startrack_host::cli::accuracy_frames::run(&args) {
            Ok((_, table)) => {
                print!("{table}");
                ExitCode::SUCCESS
            }
            Err(e) => fail("accuracy-frames", &e),
        },
        Command::Sil(args) if args.port.is_some() => match startrack_host::cli::sil::serve(&args) {
            Ok(r) if r.power_cut => {
                eprintln!(
                    "startrack sil: power cut at flash step {} (--power-cut-at-write); the flash file holds the flash as cut",
                    args.power_cut_at_write.unwrap_or(0)
                );
                ExitCode::from(startrack_host::cli::sil::POWER_CUT_EXIT_CODE)
            }
            Ok(_) => ExitCode::SUCCESS,
            Err(e) => fail("sil", &e),
        },
        Command::Gse(args) => {
            match startrack_host::cli::gse::run(&args, &mut std::io::stdout().lock()) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("startrack gse: {e}");
                    ExitCode::from(e.exit_code())
                }
            }
        }
        Command::Pil(args) => match startrack_host::cli::pil::run(&args) {
            Ok(_) => ExitCode::SUCCESS,
            Err(e) => fail("pil", &e),
        },
        Command::Sil(args) => match startrack_host::cli::sil::run(&args) {
            Ok(_) => ExitCode::SUCCESS,
            Err(e) => fail("sil", &e),
        },
        Command::Catalog(CatalogCommand::Build(args)) => {
            match startrack_host::cli::catalog::run_build(&args) {
                Ok(b) => {
                    println!(
                        "wrote {}: {} bytes, {} stars, {} pattern stars, {} pairs, at most {} stars in a field cone",
                        args.out.display(),
                        b.bytes.len(),
                        b.stars,
                        b.pattern_stars,
                        b.pairs,
                        b.max_field_stars
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => fail("catalog build", &e),
            }
        }
        Command::Catalog(CatalogCommand::Case(args)) => {
            match startrack_host::cli::catalog::run_case(&args) {
                Ok(()) => {
                    println!("wrote {} fields to {}", args.fields, args.out.display());
                    ExitCode::SUCCESS
                }
                Err(e) => fail("catalog case", &e),
            }
        }
        Command::Solve(args) => match startrack_host::cli::solve::run(&args) {
            Ok(s) => {
                println!(
                    "{} of {} fields solved; time per field: median {:.0} us, p99 {:.0} us",
                    s.solved, s.fields, s.median_us, s.p99_us
                );
                ExitCode::SUCCESS
            }
            Err(e) => fail("solve", &e),
        },
        Command::SolveImage(args) => match startrack_host::cli::solve_image::run(&args) {
            Ok(s) => {
                for i in &s.images {
                    if let Err(e) = &i.result {
                        eprintln!("startrack solve-image: {e}");
                    }
                }
                println!(
                    "{} of {} images solved; wrote {}",
                    s.solved(),
                    s.images.len(),
                    args.out.join("solutions.csv").display()
                );
                if s.solved() == s.images.len() {
                    ExitCode::SUCCESS
                } else {
                    ExitCode::FAILURE
                }
            }
            Err(e) => fail("solve-image", &e),
        },
        Command::Optics(OpticsCommand::Case(args)) => {
            match startrack_host::cli::optics::run_case(&args) {
                Ok(()) => {
                    println!("wrote {} frames to {}", args.frames, args.out.display());
                    ExitCode::SUCCESS
                }
                Err(e) => fail("optics case", &e),
            }
        }
        Command::Optics(OpticsCommand::Fit(args)) => {
            match startrack_host::cli::optics::run_fit(&args) {
                Ok(r) => {
                    print!("{}", r.text);
                    println!("wrote {}", args.out.display());
                    ExitCode::SUCCESS
                }
                Err(e) => fail("optics fit", &e),
            }
        }
        Command::Figures(args) => startrack_host::cli::figures::run(&args),
        Command::Tradeoff(args) => startrack_host::cli::tradeoff::run(&args),
        Command::ReadoutPlan(args) => match startrack_host::cli::readout_plan::run(&args) {
            Ok(text) => {
                print!("{text}");
                ExitCode::SUCCESS
            }
            Err(e) => fail("readout-plan", &e),
        },
        Command::Demo { seed, stars, sky } => match startrack_homes::demo::run_scene(
            seed,
            if sky {
                startrack_homes::demo::DemoScene::Sky
            } else {
                startrack_homes::demo::DemoScene::Random(stars)
            },
        ) {
            Ok(report) => {
                startrack_homes::demo::print(&report);
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
            slot_image,
        } => {
            let params = startrack_sim::sim::SensorParams {
                seed,
                ..Default::default()
            };
            let sim = startrack_sim::sim::Simulator::new(params, Vec::new());
            let sections = startrack_sim::sim::truth::TruthSections::ALL;
            let written = sim
                .truth_table_tiled(sections, tile_log2)
                .map_err(|e| e.to_string())
                .and_then(|t| {
                    if slot_image {
                        startrack_sim::flash_model::slot_image(
                            startrack_core::store::TableKind::Calibration,
                            &t,
                        )
                        .map_err(|e| e.to_string())
                    } else {
                        Ok(t)
                    }
                })
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
