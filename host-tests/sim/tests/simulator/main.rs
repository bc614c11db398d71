//! The simulator: its optional physics and measured maps, its truth tables, stars that move
//! during the exposure, and FITS frame files.
//!
//! One module per subject, each with its own module docs.

mod fits_io;
mod sim_effects;
mod sim_motion;
mod sim_truth;
