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

use startrack_core::table::{TableError, WriteError};
use startrack_lab::LabError;
use startrack_sim::fits::FitsError;
use std::fmt;
use std::path::{Path, PathBuf};

/// Why a subcommand failed.
#[derive(Clone, Debug, PartialEq)]
pub enum CliError {
    /// A file could not be read or written.
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        msg: String,
    },
    /// A FITS input was unusable.
    Fits(FitsError),
    /// The calibration table is corrupt or of another format.
    Table {
        /// The file.
        path: PathBuf,
        /// What the parser found.
        err: TableError,
    },
    /// The table could not be encoded.
    TableWrite(WriteError),
    /// A line of a CSV input is malformed.
    Csv {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        msg: String,
    },
    /// An option's value or a combination of inputs is unusable.
    Usage(String),
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, msg } => write!(f, "{}: {msg}", path.display()),
            Self::Fits(e) => write!(f, "{e}"),
            Self::Table { path, err } => {
                write!(
                    f,
                    "{}: not a usable calibration table: {err}",
                    path.display()
                )
            }
            Self::TableWrite(e) => write!(f, "cannot encode the table: {e}"),
            Self::Csv { path, line, msg } => write!(f, "{}:{line}: {msg}", path.display()),
            Self::Usage(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for CliError {}

impl From<LabError> for CliError {
    fn from(e: LabError) -> Self {
        match e {
            LabError::Io { path, msg } => Self::Io { path, msg },
            LabError::Fits(e) => Self::Fits(e),
            LabError::Table { path, err } => Self::Table { path, err },
            LabError::TableWrite(e) => Self::TableWrite(e),
            LabError::Csv { path, line, msg } => Self::Csv { path, line, msg },
            LabError::Invalid(m) => Self::Usage(m),
        }
    }
}

impl From<FitsError> for CliError {
    fn from(e: FitsError) -> Self {
        Self::Fits(e)
    }
}

/// Reads a whole file.
pub fn read_file(path: &Path) -> Result<Vec<u8>, CliError> {
    std::fs::read(path).map_err(|e| CliError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// Writes a whole file.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), CliError> {
    std::fs::write(path, bytes).map_err(|e| CliError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}
