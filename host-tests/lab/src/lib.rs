//! The ground side's calibration and sky tools, as a library the `startrack` command calls:
//! calibration tables from raw lab frames ([`calib_frames`]) and from measured maps
//! ([`table_build`]), the charge-trap and field-PSF fits ([`cti`], [`psf_model`]), the camera
//! model from identified star fields ([`optics`]), and real night-sky images solved to
//! attitudes with a WCS and an annotated picture ([`realsky`]). Every tool returns a typed
//! [`LabError`] for a bad input; none prints or exits (the command does).

mod error;

pub mod calib_frames;
pub mod cti;
pub mod optics;
pub mod psf_model;
pub mod realsky;
pub mod table_build;

pub use error::{LabError, read_file, write_file};
