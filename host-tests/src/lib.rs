//! Host side of the star tracker: the simulated CCD47-20 and what the `startrack` command
//! and the tests share. The core runs here unchanged, exactly as on the Cortex-M7.

pub mod accuracy;
pub mod calib_frames;
pub mod ccd_model;
pub mod cli;
pub mod cti;
pub mod demo;
pub mod figures;
pub mod fits;
pub mod flash_home;
pub mod flash_model;
pub mod frame_accuracy;
pub mod ground;
pub mod home;
pub mod link_home;
pub mod optics;
pub mod pixcorr;
pub mod psf_model;
pub mod sil;
pub mod sim;
pub mod sky;
pub mod tradeoff;
