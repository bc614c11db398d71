//! Star tracker image processing for the e2v CCD47-20, for a Cortex-M7 and the host alike.
//!
//! Raw ADC words go in, calibrated electrons, detections and star centroids come out. The
//! crate is `no_std`, allocates nothing, and returns a typed error or a flag for every bad
//! input instead of panicking.
//!
//! Data flow (each stage a module):
//! raw readout line/window ([`geometry`]) -> per-line bias and per-frame dark scale
//! ([`calib::LineLevels`], [`calib::DarkScaleEstimator`]) -> per-pixel electrons, applied
//! only to the pixels read ([`calib::FrameCalibration`]) with the maps and defect lists of a
//! calibration table ([`table`]) -> detections ([`detect`]) -> centroids ([`centroid`]) -> the frame's attitude from the
//! identified stars ([`solver`], with [`catalog`], [`ident`] and [`attitude`]). The tracker
//! application ([`tracker`]) runs these stages frame after frame; the frame cycle ([`cycle`])
//! adds the link ([`link`]), the attitude stage, the catalog's prediction of the next frame's
//! windows ([`predict`]) and housekeeping ([`safe`]) around each frame.
//!
//! Every fixed-point quantity has its format and range stated in [`units`].
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]
#![deny(
    clippy::panic,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing
)]

pub mod attitude;
pub mod calib;
pub mod catalog;
pub mod centroid;
mod clamp;
pub mod cycle;
pub mod detect;
pub mod geometry;
pub mod ident;
pub mod link;
pub mod predict;
pub mod readout;
pub mod safe;
pub mod sequencer;
mod small_sort;
pub mod solver;
pub mod store;
pub mod table;
pub mod time;
pub mod tracker;
pub mod units;
pub mod window;
