//! The paper's correction of pixelisation and window bounding for the centre of gravity: a
//! tabulated function of the *measured* position inside the central pixel.
//!
//! # What it corrects
//! A noise-free CoG (power 1 or 2, box `n x n` anchored on the brightest pixel) of a star of
//! PSF width `a` at true phase `p` (true centre minus the anchor pixel's centre, in
//! `[-1/2, 1/2]`) reads the phase `m(p)`: an S-curve from pixelisation (small `a`) and a
//! pull towards the box centre from truncation (large `a`) and from a background estimate
//! that holds part of the star (perimeter backgrounds). For a separable PSF and a square box
//! each axis depends only on its own phase. Where `m` is strictly increasing it can be
//! inverted: the table stores `c(m) = p(m) - m`, and the corrected position is `x + c(m)`.
//! The host builds the table from the exact pixel-integrated Gaussian in f64
//! (`startrack_sim::pixcorr`) for one `(a, box, power, background)` and stores it with the
//! calibration (table section kind 7): the curve's byte format, its checks and its
//! evaluation `c(m)` are in [`crate::table::pixcorr`]; this module applies a curve to a
//! centroid.
//!
//! # Cost
//! `m = x - round(x)` per axis and the curve's `c(m)` and slope (about 20 flops and four
//! knot reads, [`PixCorr::correction`]); no division. Measured inside `centroid_cog1c_7x7`
//! and `centroid_cog1c_raw_7x7` of `cargo m7-bench`.
//!
//! # Accuracy (host test `pixcorr`, 33 knots, true phases over the pixel in both axes)
//! With a given background the corrected CoG's systematic error is at most 5e-5 px RMS for
//! every a = 0.5..3 px, box 3/5/7 and power 1 (uncorrected: up to 0.24 px), and for power 2
//! from a = 0.75 px. With a perimeter background it is below 0.003 px RMS wherever the host
//! builder accepts a curve (below 0.0022 px; single phases up to 0.007 px).
//!
//! # Where it fails
//! - Only for the curve's `(a, box, power, background)` and for a box anchored on the peak
//!   ([`super::cog::Anchor::Peak`]); another PSF width leaves a residual proportional to the
//!   difference of the two curves.
//! - Where `m(p)` is not strictly increasing, or nearly flat, the curve cannot be built (the
//!   host builder refuses a slope below 0.05): power 2 at a = 0.5 px (slope 0.048 at p = 0,
//!   the centre pixel holds nearly all the weight). Where the slope is small the correction
//!   multiplies the noise by `dp/dm`, which the error estimate shows.
//! - Perimeter backgrounds are not exactly separable (the ring's level depends on both
//!   phases): the curve is the mean over the other axis' phase, and the builder refuses it
//!   when more than 0.002 px RMS would be left: with a 3x3 box from a = 1.25 px (power 1,
//!   mean), 1.5 px (power 1 median, power 2 mean), 2 px (power 2 median); with a 5x5 box and
//!   the median from a = 2.5 px (power 1) and 3 px (power 2). Use a given background there.
//! - Under noise, the peak pixel can be a neighbour of the true one: not corrected; the
//!   correction is non-linear, so at low SNR `E[c(m)] != c(E[m])` (the `startrack accuracy`
//!   table measures the net effect).

use super::{Background, Centroid, CentroidFlags, MAX_SIDE};
use crate::table::pixcorr::{MAX_CURVE_BOX_SIDE, PixCorr, PixCorrBackground};

// A curve's box must fit any window the centroid methods accept.
const _: () = assert!(MAX_CURVE_BOX_SIDE as u16 == MAX_SIDE);

impl PixCorr<'_> {
    /// The corrected centroid: each coordinate `x + c(x - round(x))`, each error estimate
    /// times `1 + c'`. A degenerate centroid is returned unchanged.
    pub fn apply(&self, c: Centroid) -> Centroid {
        if c.flags.contains(CentroidFlags::DEGENERATE) {
            return c;
        }
        let axis = |x: f32, sigma: f32| {
            let (dx, slope) = self.correction(x);
            (x + dx, sigma * (1.0 + slope).max(0.0))
        };
        let (x_px, sigma_x_px) = axis(c.x_px, c.sigma_x_px);
        let (y_px, sigma_y_px) = axis(c.y_px, c.sigma_y_px);
        Centroid {
            x_px,
            y_px,
            sigma_x_px,
            sigma_y_px,
            ..c
        }
    }
}

impl From<Background> for PixCorrBackground {
    /// The kind of curve made for a centroid's background source.
    fn from(background: Background) -> Self {
        match background {
            Background::Given { .. } => Self::Given,
            Background::PerimeterMean => Self::PerimeterMean,
            Background::PerimeterMedian => Self::PerimeterMedian,
        }
    }
}
