//! `startrack accuracy-frames`: the end-to-end accuracy Monte Carlo on whole simulated frames
//! of mixed PSF widths ([`monte_carlo`]): simulate, `calib build`, `process` with
//! defaults, without and with a field PSF model in the table; prints the markdown table and
//! optionally writes its CSV. Cost: about 3 s of CPU per frame in the dev profile (the full
//! table, 20 frames: a minute of CPU).

pub mod monte_carlo;

use super::CliError;
use monte_carlo::{FrameMc, FrameMcRun, csv, markdown, run as run_mc};
use std::path::PathBuf;

/// Options of `startrack accuracy-frames`.
#[derive(Clone, Debug, clap::Args)]
pub struct AccuracyFramesArgs {
    /// Folder for the frames' files (created; each frame's files deleted once measured).
    #[arg(long)]
    pub work_dir: PathBuf,
    /// Frames.
    #[arg(long, default_value_t = 20)]
    pub frames: usize,
    /// Stars per frame.
    #[arg(long, default_value_t = 300)]
    pub stars: usize,
    /// Seed of the first frame (frame i has seed + i).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// PSF widths (80 %-energy radius) each star's is drawn from, px.
    #[arg(long, value_delimiter = ',', default_values_t = [0.6, 0.8, 1.0, 1.5, 2.0])]
    pub a: Vec<f64>,
    /// Instead of drawing each star's width from --a: the width a smooth function of its
    /// place, "CENTRE,CORNER" px (`simulate --psf-a-field`); --a are then the bins.
    #[arg(long, value_delimiter = ',')]
    pub field_a: Vec<f64>,
    /// Also write the table's cells as CSV to this file.
    #[arg(long)]
    pub csv: Option<PathBuf>,
}

/// Runs the Monte Carlo; returns the run and its markdown table.
pub fn run(args: &AccuracyFramesArgs) -> Result<(FrameMcRun, String), CliError> {
    let field_a_px = match args.field_a.as_slice() {
        [] => None,
        &[c, k] => Some([c, k]),
        v => {
            return Err(CliError::Usage(format!(
                "--field-a {v:?}: need CENTRE,CORNER"
            )));
        }
    };
    let mc = FrameMc {
        field_a_px,
        frames: args.frames,
        stars: args.stars,
        seed: args.seed,
        widths_a_px: args.a.clone(),
        ..FrameMc::full(args.work_dir.clone())
    };
    let r = run_mc(&mc)?;
    if let Some(p) = &args.csv {
        super::write_file(p, csv(&r.bins).as_bytes())?;
    }
    let table = format!("{}\n\n{}", r.model_note, markdown(&r.bins));
    Ok((r, table))
}
