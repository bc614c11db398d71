//! Star centroids from a window of calibrated pixels: the methods, their shared output type,
//! the background and noise model, and the flag policy.
//!
//! | method | module | M7 cost, 7x7 (`cargo m7-bench`) | systematic error, noise-free (RMS over phases) | random error |
//! |---|---|---|---|---|
//! | centre of gravity, power 1 (eq. 2) and 2 (eq. 6) | [`cog`] | ~6,500 and ~11,700 (`centroid_cog1_7x7`, `centroid_cog2_7x7`; ~3,900 with a given background) | 5x5: 0.049 px at a = 0.5, < 0.001 at a = 1, 0.047 at a = 2 (power 1); removed by the table's pixel-phase curve ([`pixcorr`]) | 0.86..1.1 of the CRLB-limited scatter |
//! | the same, power 1 fused with calibration on the raw window | [`raw_cog`] | ~2,600 a frame with its plan (`centroid_cog1c_raw_planned_7x7`) | as the corrected CoG | as the CoG |
//! | pixel-integrated Gaussian fit | [`gauss_fit`] | ~7,000 held background (`centroid_gauss_fit_given_bg_7x7`), ~22,000 fitted | < 1e-5 px (model exact) | efficiency 0.97..1.00 |
//! | the same with the PSF width free, reporting `psf_a_px` and `chi2_dof` ([`gauss_fit::gauss_fit_width`]) | [`gauss_fit`] | ~13,700 held background (`centroid_gauss_fit_width_7x7`; ~7,400 on 5x5) | < 1e-5 px (model exact) | pull RMS 0.99..1.08 (host test `centroid_gauss_fit_width`) |
//! | Gaussian convolved with the motion segment, trail held ([`trail_fit`]) | [`trail_fit`] | ~24,000 and ~47,000 held background, 5x5 and 7x7 (`centroid_trail_fit_5x5`, `centroid_trail_fit_7x7`) | model error of the pixel's 1/12 px^2 (host test `centroid_trail_fit`) | within 1.2x the trailed CRLB, trails 0-20 px |
//!
//! (a = the paper's 80 %-energy radius, s = sqrt(0.31) a; the errors from the host tests
//! `centroid_cog`, `centroid_cog_noise`, `centroid_gauss_fit` run with `--nocapture`; the
//! exact counts are in docs/speed.md, checked against the bench's CSV.) A method stays only
//! where it sits on the speed/accuracy frontier for some scene (docs/speed.md).
//!
//! # Arithmetic: f32, with an exact integer background subtraction
//! Every method works in `f32`, the Cortex-M7's hardware float type for the
//! `thumbv7em-none-eabihf` target (`f64` would be soft-float there). The only step where f32
//! would lose information is `pixel - background` for large equal values, so that difference
//! is taken on the `I26F6` bits in `i64` (exact: |difference| < 2^33 LSB) and converted to f32
//! once per pixel. Positions are accumulated relative to an anchor pixel inside the window
//! (offsets below `MAX_SIDE`), so sums such as `sum(dx * F)` keep their relative precision.
//!
//! Range: a background-subtracted value is below 2^26 e- in magnitude (pixels within ±2^25 e-,
//! the calibrated bound); its square below 2^52; a sum of squares over the largest window
//! (`MAX_SIDE`^2 = 961 pixels) below 2^62, and the error propagation divides by the weight
//! sum twice rather than by its square, so no f32 intermediate exceeds ~2^100 (f32 holds
//! 2^127). A fixed-point power-2 sum would need more than 64 bits; f32 needs no care.
//!
//! # Background and noise
//! The background is either measured on the window's perimeter (the one-pixel border ring,
//! excluded pixels skipped: its mean or median, the paper's way) or given by the caller (the
//! detector's estimate). The perimeter also gives the per-pixel background variance (sample
//! variance about the mean, or the scaled MAD about the median): read noise, sky and dark shot
//! noise and dark non-uniformity together. The noise model of a background-subtracted pixel
//! `F` is `var = max(F, 0) + var_bg` (e-^2; shot noise of the star, since pixels are
//! calibrated electrons) plus the error of the background estimate itself, `var_bg / n`
//! (mean) or `pi/2 var_bg / n` (median), shared by all pixels. A perimeter only measures the
//! background when the star is well inside it: use a window two pixels wider than the
//! centroid box (e.g. a 7x7 window for a 5x5 box).
//!
//! # Flags and degenerate windows
//! Every method returns a [`Centroid`], never an error and never a NaN. A window it cannot
//! measure (empty, bigger than `MAX_SIDE` (31), a pixel slice of the wrong length, flat, negative
//! after background subtraction, all pixels excluded, no usable perimeter) gives
//! [`CentroidFlags::DEGENERATE`], the position of the window's centre pixel, zero flux and SNR,
//! and a position error of half the window size. Any computed position is clamped to the
//! window's extent (pixel edges: `x0 - 1/2 ..= x0 + width - 1/2`), with
//! [`CentroidFlags::CLAMPED`] when the clamp acted.

mod background;
pub mod cog;
pub mod gauss_fit;
pub(crate) mod math;
pub mod pixcorr;
mod pixel_box;
mod prepared;
pub mod raw_cog;
pub mod trail_fit;

pub use background::{Background, BackgroundEstimate};
pub use prepared::estimate_background;

/// The f32 functions of the centroid methods (`centroid::math`: square root, exponential,
/// `erfc`, the Gaussian's pixel fractions), reachable from outside the crate only for the
/// host accuracy tests (`host-tests/tests/centroids/centroid_math.rs`, which compare them with f64):
/// not part of the API.
#[doc(hidden)]
pub mod test_only_math {
    pub use super::math::{EdgeGrid, erfc, erfc_abs_and_gauss, exp, pixel_fraction, sqrt};
}

use crate::calib::PixelFlags;
use crate::calib::cti::MeasuredPosition;
use crate::window::Window;

/// The largest window side any method accepts (31 pixels: the perimeter median's buffer).
pub(crate) const MAX_SIDE: u16 = 31;

/// Below this SNR (paper eq. 8) a centroid gets [`CentroidFlags::LOW_SNR`]: the paper's
/// detection threshold.
pub(crate) const LOW_SNR_LIMIT: f32 = 3.0;

bitflags::bitflags! {
    /// What a centroid method noticed; several may be set.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct CentroidFlags: u16 {
        /// A pixel of the window is saturated: its value is a lower bound, the centroid is
        /// pulled towards the saturated core's centre and the flux is too low.
        const SATURATED = 1;
        /// The window (or the method's box inside it) is smaller than requested, usually at
        /// the edge of the active area: truncation bias.
        const EDGE_CLIPPED = 2;
        /// The window held an excluded pixel (hot or telegraph): it was skipped, which biases
        /// the centroid away from it.
        const EXCLUDED_PIXEL = 4;
        /// SNR (eq. 8) below [`LOW_SNR_LIMIT`].
        const LOW_SNR = 8;
        /// No position could be computed: the position is the window's centre pixel.
        const DEGENERATE = 16;
        /// Reserved for detection: the window holds more than one star.
        const BLENDED = 32;
        /// An iterative method did not converge within its iterations, or diverged and fell
        /// back to its starting point.
        const NOT_CONVERGED = 64;
        /// Reserved: set by no method (the brightest pixel on the window border, where a
        /// 3-point peak fit has no neighbour on one side). Telemetry and `stars.csv` carry
        /// the flag bits, so the bit is neither reused nor renumbered.
        const PEAK_AT_EDGE = 128;
        /// The computed position fell outside the window and was clamped to its edge.
        const CLAMPED = 256;
        /// The fitted model does not describe the window: `chi2_dof` above the limit of
        /// [`gauss_fit::chi2_dof_limit`] ([`gauss_fit::chi2_dof_limit_border`] with the
        /// variance from the window's border) (a blend, a cosmic ray, a PSF the Gaussian cannot
        /// follow). The position is reported but is not a clean measurement.
        const POOR_FIT = 512;
        /// The method's own error estimate (`sigma_x_px`, `sigma_y_px`) is known to be
        /// wrong by more than 10 % in this configuration (docs/accuracy.md, the pull
        /// table): use it only as an order of magnitude.
        const SIGMA_UNRELIABLE = 1024;
        /// The star's own PSF width disagrees with the field PSF model's beyond what the
        /// model's scatter and the fit's width error allow (a blend, a cosmic ray, a PSF the
        /// model does not describe): the result is the width-free fit's.
        const PSF_MISMATCH = 2048;
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for CentroidFlags {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "CentroidFlags({=u16:#x})", self.bits())
    }
}

/// One star's measured position, in active-area pixels (pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Centroid {
    /// Column coordinate, px.
    pub x_px: f32,
    /// Row coordinate, px.
    pub y_px: f32,
    /// Background-subtracted signal in the method's box, e-.
    pub flux_e: f32,
    /// Signal-to-noise ratio of `flux_e` (paper eq. 8 with the measured noise).
    pub snr: f32,
    /// Estimated 1-sigma random error of `x_px` from the noise model, px.
    pub sigma_x_px: f32,
    /// Estimated 1-sigma random error of `y_px`, px.
    pub sigma_y_px: f32,
    /// What the method noticed.
    pub flags: CentroidFlags,
}

/// The charge-transfer correction moves a centroid (flags, flux and sigmas unchanged).
impl MeasuredPosition for Centroid {
    fn position_px(&self) -> (f32, f32) {
        (self.x_px, self.y_px)
    }

    fn flux_e(&self) -> f32 {
        self.flux_e
    }

    fn at_px(self, x_px: f32, y_px: f32) -> Self {
        Self { x_px, y_px, ..self }
    }
}

/// The input of every method: a window and what calibration and detection know about it.
#[derive(Clone, Copy, Debug)]
pub struct CentroidInput<'a> {
    /// The calibrated pixels.
    pub window: Window<'a>,
    /// Per-pixel calibration flags, row-major like the pixels; empty when none are known.
    /// Any other length than 0 or `window.rect.len()` makes the window degenerate.
    pub pixel_flags: &'a [PixelFlags],
    /// True when the window is smaller than requested (e.g. from
    /// [`crate::window::Rect::centred_clipped`]): sets [`CentroidFlags::EDGE_CLIPPED`].
    pub clipped: bool,
}

impl<'a> CentroidInput<'a> {
    /// A window without pixel flags, not clipped.
    pub fn new(window: Window<'a>) -> Self {
        Self {
            window,
            pixel_flags: &[],
            clipped: false,
        }
    }

    /// Adds the per-pixel calibration flags.
    pub fn with_pixel_flags(self, pixel_flags: &'a [PixelFlags]) -> Self {
        Self {
            pixel_flags,
            ..self
        }
    }

    /// Records whether the window was clipped.
    pub fn with_clipped(self, clipped: bool) -> Self {
        Self { clipped, ..self }
    }
}
