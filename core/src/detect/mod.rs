//! Star detection on calibrated lines, streaming: the detector sees each line once, in
//! readout order, and keeps only the previous line's runs and the blobs still open, a few KB
//! for a 1024-pixel line, never a frame.
//!
//! - `background.rs`: local background and noise per block of columns, measured on the lines
//!   already seen (robust to stars: lower-half quantiles).
//! - `blobs/`: connected above-threshold pixels (8-connectivity) grouped into blobs, and
//!   the candidate list with its overflow policy.
//! - `track.rs` ([`track_detect`]): tracking mode, one window predicted from the last
//!   frame: is the star there? Background and noise from the window's border, the same
//!   eq. 8 SNR test.
//! - `prefilter/`: the raw-domain pre-filtered scan ([`ScanDetector`]): quiet pixels are
//!   compared in raw ADU against a per-tile level and never calibrated.
//! - `motion.rs` ([`CommonMotion`]): the frame's common trail (a turning spacecraft's stars
//!   all trail the same way, proton tracks at random), by which the bounded lists rank.
//! - `hits.rs` ([`is_particle_hit`]): is a measured window sharper than the optics can make
//!   (a proton's charge, spread only by diffusion)?
//! - `capture.rs`: copies the raw pixels of a list of windows (tracking, [`WindowCapture`])
//!   out of the streamed lines, and keeps a ring of the last raw lines (acquisition,
//!   [`LineRing`]) so that a blob's window can be calibrated and centroided when the blob
//!   closes.
//!
//! Thresholds work with hysteresis: pixels above 2.5 local sigmas form blobs, and a blob
//! counts only with a peak above 5 sigmas and at least 2 pixels (see [`DetectConfig`]).
//! A counted blob becomes a candidate when its measured SNR (the paper's eq. 8 with the measured
//! noise: `S / sqrt(S + n sigma^2)`, `S` the background-subtracted signal of its `n` pixels)
//! exceeds the configured minimum (3, as the paper). Pixels flagged by calibration as hot
//! (corrected or excluded) or telegraph never exceed the threshold, so they never create a
//! detection; a saturated pixel always does.

mod background;
mod blobs;
pub(crate) mod capture;
mod hits;
mod motion;
mod prefilter;
pub(crate) mod track;

pub use blobs::{Detection, DetectionFlags, LineDetector};
pub use capture::{CAPTURE_MAX_SIDE, CaptureError, LineRing, RingError, WindowCapture};
pub use hits::{HIT_SIGMAS, HitLimits, is_particle_hit};
pub use motion::{Agreement, CommonMotion, MIN_ACROSS_PX2, MIN_TRAIL_PX, MotionKey};
pub use prefilter::{ScanDetector, ScanError};
pub use track::{TrackConfig, TrackFlags, TrackResult, track_detect};

/// Detection settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DetectConfig {
    /// A pixel joins a blob when it exceeds the local background by this many local noise
    /// sigmas (2.5: the faint wings of compact stars still join).
    pub pixel_sigmas: f32,
    /// A blob counts only if its brightest pixel exceeds the background by this many sigmas
    /// (5: a 1024 x 1024 scan then sees about 0.3 noise peaks per frame)...
    pub peak_sigmas: f32,
    /// ...and it has at least this many pixels (2: a lone pixel is a cosmic ray, an unlisted
    /// hot pixel or noise; a 5-sigma pixel with a 2.5-sigma neighbour happens by chance about
    /// 1e-8 of the time). Saturated blobs always count.
    pub min_pixels: u32,
    /// A blob is a star candidate when its measured SNR (eq. 8) exceeds this.
    pub min_snr: f32,
    /// Blobs with an SNR below this (but above `min_snr`) are flagged low-SNR.
    pub low_snr: f32,
}

impl DetectConfig {
    /// The defaults: join at 2.5 sigma, a peak above 5 sigma, at least 2 pixels, SNR above 3,
    /// low-SNR flag below 5.
    pub(crate) const DEFAULT: Self = Self {
        pixel_sigmas: 2.5,
        peak_sigmas: 5.0,
        min_pixels: 2,
        min_snr: 3.0,
        low_snr: 5.0,
    };
}

impl Default for DetectConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a line was not taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum DetectError {
    /// The pixel and flag slices differ in length from the detector's line width.
    LineLength,
    /// Lines must come in increasing row order.
    RowOrder,
}

impl core::fmt::Display for DetectError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::LineLength => "detector: line length differs from the configured width",
            Self::RowOrder => "detector: lines must come in increasing row order",
        })
    }
}

impl core::error::Error for DetectError {}
