//! Real night-sky images to attitudes: what `startrack solve-image` runs. A plain image
//! (FITS, TIFF, PNG, JPEG; no over-scan, no covered pixels, one output) goes through the
//! core's stages as a frame does on the board, with the host doing what a plain image needs
//! first and last:
//!
//! - [`picture`]: the file to one channel of values, its saturation level;
//! - [`stars`]: a background map (real skies have gradients), then the core's line detector
//!   and centroids (the width-free Gaussian fit; saturated stars flagged, not fitted);
//! - [`solve`]: the core's lost-in-space identification over a ladder of focal lengths (the
//!   field of view known to a stated error), then the core's q-method from every matched star
//!   with the focal length refit;
//! - [`wcs`]: the solution as a FITS TAN WCS, and the annotated PNG.

pub mod picture;
pub mod solve;
pub mod stars;
pub mod wcs;
