//! Why a lab or sky tool failed, as one line a user can act on: the file, and what was wrong
//! with it. Nothing in this crate panics on a bad input file; every reader returns this.

use startrack_core::table::{TableError, WriteError};
use startrack_sim::fits::FitsError;
use std::fmt;
use std::path::{Path, PathBuf};

/// Why a lab or sky tool failed.
#[derive(Clone, Debug, PartialEq)]
pub enum LabError {
    /// A file could not be read or written.
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        msg: String,
    },
    /// A FITS input was unusable.
    Fits(FitsError),
    /// A calibration table is corrupt or of another format.
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
    /// An input, an option's value or a combination of inputs is unusable.
    Invalid(String),
}

impl fmt::Display for LabError {
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
            Self::Invalid(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for LabError {}

impl From<FitsError> for LabError {
    fn from(e: FitsError) -> Self {
        Self::Fits(e)
    }
}

/// Reads a whole file.
pub fn read_file(path: &Path) -> Result<Vec<u8>, LabError> {
    std::fs::read(path).map_err(|e| LabError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// Writes a whole file.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), LabError> {
    std::fs::write(path, bytes).map_err(|e| LabError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}
