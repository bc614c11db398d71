//! A simulated e2v CCD47-20 that models no more than a scene needs.
//!
//! Every raw sample is a pure function of (seed, frame, raw column, raw line): nothing is
//! stored per pixel, so a pixel costs time only when the pipeline reads it, and a window
//! rendered alone equals the same pixels of a full-frame render, bit for bit. The sensor's
//! fixed patterns (column bias, relative dark, flat) are pure functions of (seed, pixel) in
//! the same way; [`truth`] turns them into calibration tables.
//!
//! Physics (each term switchable through [`SensorParams`]): pixel-integrated Gaussian stars
//! (paper eq. 3 and 5) with Poisson photon noise, dark charge with DSNU collected by active
//! and covered pixels alike (Poisson), PRNU on the photon signal only, bias per output plus a
//! per-column pattern, output gains, Gaussian read noise, full-well clipping, an optional
//! quadratic response non-linearity per output (`nonlinearity_at_full_well`, off by default),
//! 16-bit ADC rounding and saturation. Optional, in [`effects`]: defocus or coma PSFs, a dark
//! temperature law, hot pixels with their own law, telegraph pixels, cosmic rays and CTI
//! trails. [`bright`]: the Moon, the Earth's limb, the Sun's stray light, proton hits
//! ([`protons`]) and the blooming of saturated columns. [`measured`] gives calibration maps
//! measured from simulated dark and flat frames.

pub mod bright;
pub mod effects;
pub mod measured;
pub mod params;
pub mod protons;
pub mod psf;
pub mod render;
pub mod rng;
pub mod truth;

pub use effects::Effects;
pub use params::{SensorParams, Star};
pub use render::{SaturationLimit, Simulator};
