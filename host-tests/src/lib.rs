//! The `startrack` command and the lab calibration behind it: building calibration tables from
//! raw lab frames ([`calib_frames`]), the charge-trap and PSF-model fits ([`cti`],
//! [`psf_model`]), the camera-model fit ([`optics`]), and each command's options and output
//! ([`cli`]). The frame cycle's host ports live in `startrack-homes`, the analyses in
//! `startrack-analysis`, the simulated sensor in `startrack-sim`, the ground client in
//! `startrack-ground`.

pub mod calib_frames;
pub mod cli;
pub mod cti;
pub mod exposure_chart;
pub mod first_attitude;
pub mod optics;
pub mod psf_model;
pub mod realsky;
pub mod sil_rates;
