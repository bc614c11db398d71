//! The simulated sensor and sky on the host: the CCD47-20's frames with their noise and
//! defects (`sim`), its charge-transfer model (`ccd_model`), star fields from the catalog
//! (`sky`), trailed stars with their Cramer-Rao bound (`trail`), the H7 flash the table store runs over (`flash_model`), FITS frame files (`fits`)
//! and the pixel-phase curves the truth tables carry (`pixcorr`). It depends on the core
//! only, so every other host crate can build on it; it costs the bundled CFITSIO's C build.

pub mod ccd_model;
pub mod fits;
pub mod flash_model;
pub mod pixcorr;
pub mod sim;
pub mod sky;
pub mod trail;
