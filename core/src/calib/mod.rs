//! Raw ADC words to electrons, the way the founding paper prescribes.
//!
//! - [`cti`]: the charge-transfer (trap) shift of a star's centroid, removed from the table's
//!   coefficients.
//! - [`formula`]: the calibration formula on fixed-point bits and why it cannot overflow,
//!   shared by everything that calibrates.
//! - `levels.rs`: per-line bias from the over-scan (per output, [`LineLevels`]) and the
//!   frame's dark scale from the covered columns ([`DarkScaleEstimator`]).
//! - [`hot`]: the dark signal of a hot pixel from its own rate and temperature law.
//! - `pixel.rs`: the per-pixel formula ([`FrameCalibration`]), applied only to the pixels the
//!   pipeline reads (a line span or a star window), with the flags it raises.
//! - [`refresh`]: new hot and telegraph pixels found in flight, and the overlay that
//!   excludes them until a table lists them.

pub mod cti;
pub mod formula;
pub mod hot;
pub(crate) mod levels;
pub(crate) mod pixel;
pub mod refresh;

pub use levels::{DarkScaleEstimator, LineError, LineLevels};
pub use pixel::{CalibError, FrameCalibration, FrameConditions, PixelFlags};
