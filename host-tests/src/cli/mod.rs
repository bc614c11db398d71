//! The `startrack` subcommands that read and write user files: one module per subcommand,
//! each with its clap `Args` struct and a `run` that returns a typed [`CliError`] (the binary
//! prints it as one line and exits non-zero; nothing here panics on bad input).

pub mod accuracy;
pub mod accuracy_frames;
pub mod calib_build;
pub mod calib_frames;
pub mod calib_models;
pub mod catalog;
pub mod figures;
pub mod first_attitude;
pub mod gse;
pub mod optics;
pub mod pil;
pub mod process;
pub mod readout_plan;
pub mod sil;
pub mod simulate;
pub mod solve;
pub mod solve_image;
pub mod tradeoff;

pub use startrack_lab::LabError;
use std::fmt;

/// Why a subcommand failed: what the lab and sky tools report (a file that could not be read
/// or written, a FITS input, a table, a CSV line: [`LabError`]), or an option's value or a
/// combination of inputs that is unusable.
#[derive(Clone, Debug, PartialEq)]
pub enum CliError {
    /// A file, a FITS input, a calibration table or a CSV line ([`LabError`], never its
    /// `Invalid`, which is [`Self::Usage`]).
    Lab(LabError),
    /// An option's value or a combination of inputs is unusable.
    Usage(String),
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Lab(e) => e.fmt(f),
            Self::Usage(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for CliError {}

impl From<LabError> for CliError {
    fn from(e: LabError) -> Self {
        match e {
            LabError::Invalid(m) => Self::Usage(m),
            e => Self::Lab(e),
        }
    }
}

impl From<startrack_sim::fits::FitsError> for CliError {
    fn from(e: startrack_sim::fits::FitsError) -> Self {
        Self::Lab(LabError::Fits(e))
    }
}

/// Reads a whole file.
pub fn read_file(path: &std::path::Path) -> Result<Vec<u8>, CliError> {
    Ok(startrack_lab::read_file(path)?)
}

/// Writes a whole file.
pub fn write_file(path: &std::path::Path, bytes: &[u8]) -> Result<(), CliError> {
    Ok(startrack_lab::write_file(path, bytes)?)
}
