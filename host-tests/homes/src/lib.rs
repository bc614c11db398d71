//! The host's homes of the core's frame cycle ([`startrack_core::cycle`]): each binds the
//! cycle's ports (lines, clock, temperature, telemetry, link, health) to the simulated sensor
//! and holds no processing of its own, so what runs here is what runs on the board.
//!
//! - [`home`]: the ports every host home shares, and one recorded frame through the tracker;
//! - [`sil`]: software in the loop, frame after frame on the simulated sky;
//! - [`link_home`]: the SIL serving its command and telemetry link on TCP;
//! - [`memory_tables`]: the SIL's table store in memory;
//! - [`flash_home`]: the served SIL's table store over the H7 flash model;
//! - [`sim_windows`]: the simulated sensor as the link's diagnostic window source;
//! - [`pps`]: the spacecraft's PPS line and time-set, as the SIL and the served SIL drive them;
//! - [`pil`]: the same scene fed to the flight image on QEMU's Cortex-M7 (processor in the loop);
//! - [`demo`]: `cargo demo`'s frame, compared with the simulator's truth.

pub mod demo;
pub mod flash_home;
pub mod home;
pub mod link_home;
pub mod memory_tables;
pub mod pil;
pub mod pps;
pub mod sil;
pub mod sim_windows;
