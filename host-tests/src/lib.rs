//! Host side of the star tracker: the tracker's ports bound on the host (the homes and the
//! SIL), lab calibration, the analyses and what the `startrack` command and the tests share.
//! The core runs here unchanged, exactly as on the Cortex-M7; the simulated sensor it runs on
//! is `startrack-sim`, the ground client `startrack-ground`.

pub mod accuracy;
pub mod calib_frames;
pub mod cli;
pub mod cti;
pub mod demo;
pub mod figures;
pub mod flash_home;
pub mod frame_accuracy;
pub mod home;
pub mod link_home;
pub mod optics;
pub mod pil;
pub mod psf_model;
pub mod sil;
pub mod tradeoff;
