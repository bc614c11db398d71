//! The tracker's configuration: one typed struct, every unit stated, with the flight
//! defaults and the checks a configuration must pass before it is used (a command or a
//! host option that fails them gets a [`ConfigError`], never a half-applied setting).

use crate::centroid::MAX_SIDE;
use crate::centroid::raw_cog::MAX_BOX_SIDE;
use crate::detect::capture::CAPTURE_MAX_SIDE;
use crate::detect::{DetectConfig, TrackConfig};
use crate::table::pixcorr::CogPower;

/// How a star's position is measured in its window.
///
/// The window is [`TrackerConfig::window_px`] square around the star's brightest pixel;
/// its one-pixel border gives the background (median) and the box inside it
/// (`window_px - 2`) the star.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CentroidMethod {
    /// Fit of the pixel-integrated Gaussian of the configured PSF width over the window,
    /// background held at the border median: within 1.04 x the Cramer-Rao bound in every
    /// scene of the trade-off chart (docs/accuracy.md), ~7,000 M7 instructions for a 7x7
    /// window (`cargo m7-bench`, `centroid_gauss_fit_given_bg_7x7`).
    GaussFit,
    /// Fit of the pixel-integrated Gaussian with the PSF width free (each star's own: the
    /// width changes across the field and from star to star), background held at the
    /// border median; reports `psf_a_px` and `chi2_dof` and flags a window the Gaussian
    /// cannot describe ([`super::StarFlags::POOR_FIT`]). ~13,700 M7 instructions for a 7x7
    /// window (`cargo m7-bench`, `centroid_gauss_fit_width_7x7`); the configured `psf_a_px`
    /// is not used.
    GaussFitWidth,
    /// Centre of gravity, power 1, in the box, corrected with the table's pixel-phase curve
    /// for this box and the PSF width (flagged [`super::StarFlags::UNCORRECTED`] without
    /// one). The cheapest method; 1.05-1.6 x the bound for a 3x3 box.
    Cog1,
    /// Centre of gravity, power 2 (noise-unbiased), corrected like [`Self::Cog1`].
    Cog2,
    /// Tracking only: the power-1 CoG computed on the raw window with the calibration
    /// folded into per-cell sums, the star's background carried from its last full
    /// measurement, through a plan kept per star (`centroid::raw_cog`); falls back to
    /// [`Self::Cog1`] on anything it flags. The cheapest tracking path (~2,600 M7
    /// instructions a 7x7 box).
    FusedCog1,
}

impl CentroidMethod {
    /// The method's name, as the host options spell it.
    pub const fn name(self) -> &'static str {
        match self {
            Self::GaussFit => "gauss-fit",
            Self::GaussFitWidth => "gauss-fit-width",
            Self::Cog1 => "cog1",
            Self::Cog2 => "cog2",
            Self::FusedCog1 => "fused-cog1",
        }
    }

    /// The power of a CoG method (whose position the pixel-phase curve corrects); `None` for
    /// the Gauss fit.
    pub const fn cog_power(self) -> Option<CogPower> {
        match self {
            Self::Cog1 | Self::FusedCog1 => Some(CogPower::One),
            Self::Cog2 => Some(CogPower::Two),
            Self::GaussFit | Self::GaussFitWidth => None,
        }
    }
}

/// Everything the tracker application can be told. Units in the names; defaults are the
/// flight configuration ([`TrackerConfig::FLIGHT`]).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackerConfig {
    /// Centroid method in acquisition frames (not [`CentroidMethod::FusedCog1`]).
    pub acquisition_method: CentroidMethod,
    /// Centroid method in tracking frames.
    pub tracking_method: CentroidMethod,
    /// Side of the centroid window, px: odd, 5 to 13 (the box is `window_px - 2`; at most
    /// 11 with [`CentroidMethod::FusedCog1`], whose box is at most 9).
    pub window_px: u16,
    /// Tracking windows are `window_px + 2 track_margin_px` square, so a star may move this
    /// far between frames and still have its whole centroid window read, px (the capture
    /// window is at most 15 px).
    pub track_margin_px: u16,
    /// The optics' PSF 80 %-energy radius `a`, px: the Gauss fit's width
    /// (`sigma = sqrt(0.31) a`) and which pixel-phase curve a CoG uses.
    pub psf_a_px: f32,
    /// A pixel-phase curve is used only if its width is within this fraction of
    /// `psf_a_px` (0.1): a curve for another width leaves a residual of the two curves'
    /// difference.
    pub pixcorr_tolerance: f32,
    /// Acquisition detection thresholds.
    pub detect: DetectConfig,
    /// Tracking window test.
    pub track: TrackConfig,
    /// Acquisition updates its background estimate on every this-many-th row (and the
    /// first `background_warmup_rows`); the other rows are only pre-filtered in raw ADU.
    /// 16 in flight; 1 updates it on every row. Each background row is calibrated whole
    /// (~74 M7 instructions a pixel); a longer stride saves that but holds a noisier
    /// noise estimate longer: on 16 simulated frames of 40 stars, 10 noise candidates at
    /// stride 64, 6 at 32, 4 at 16, 3 at 8 (every one flagged or degenerate).
    pub background_stride: u16,
    /// Rows at the top of an acquisition frame that all update the background (16).
    pub background_warmup_rows: u16,
    /// Most stars reported per frame (the brightest are kept), at most the tracker's
    /// capacity `N`.
    pub max_stars: u16,
    /// Most stars tracked, at most `TRACK_WINDOWS` (32).
    pub max_tracked: u16,
    /// Fewest usable centroids for the next frame to be a tracking frame.
    pub min_track_stars: u16,
    /// After this many tracking frames in a row on the tracker's own stars, one acquisition
    /// frame (to pick up stars entering the field); frames on the attitude stage's predicted
    /// windows do not count (the catalog brings the stars entering the field).
    pub reacquire_every: u32,
    /// Exposure time, ms: the time the sequencer holds between frame transfers at least (a
    /// readout longer than it integrates for the readout), and the hot pixels' own dark law.
    pub exposure_ms: u32,
    /// A [`super::LineSummary`] is reported for every line whose index is a multiple of
    /// this.
    pub line_summary_every: u16,
}

impl TrackerConfig {
    /// The flight configuration. The width-free Gauss fit in both modes: a real field does
    /// not give one PSF width (defocus, field curvature, coma), and the fit of a given width
    /// loses up to 2.5x the Cramer-Rao bound on stars of another width (docs/accuracy.md,
    /// "width unknown"); fitting each star's own costs ~13,700 M7 instructions a 7x7 star
    /// against ~7,000 for the given width and ~2,600 for the fused CoG, a small part of a
    /// 30-star tracking frame (`cargo m7-bench`, `tracker_tracking_frame`, three fifths of it
    /// the bias and dark scale of every line); the other methods stay for budgets that need
    /// them and for a field whose width is known. A 39 ms exposure: the longest whole
    /// number of ms that keeps the 30-window tracking cycle within the 50 ms of 20 Hz (its
    /// 10.4 ms frame transfer and 38.6 ms readout at 1 MHz, docs/sequencer.md), and within
    /// the exposures that keep an attitude to 2 deg/s (docs/tracker.md, the exposure chart).
    pub const FLIGHT: Self = Self {
        acquisition_method: CentroidMethod::GaussFitWidth,
        tracking_method: CentroidMethod::GaussFitWidth,
        window_px: 7,
        track_margin_px: 2,
        psf_a_px: 1.2,
        pixcorr_tolerance: 0.1,
        detect: DetectConfig::DEFAULT,
        track: TrackConfig::DEFAULT,
        background_stride: 16,
        background_warmup_rows: 16,
        max_stars: 32,
        max_tracked: 32,
        min_track_stars: 3,
        reacquire_every: 16,
        exposure_ms: 39,
        line_summary_every: 64,
    };

    /// The centroid box side, px (`window_px - 2`).
    pub fn box_px(&self) -> u8 {
        u8::try_from(self.window_px.saturating_sub(2)).unwrap_or(u8::MAX)
    }

    /// The configured exposure, s.
    pub fn exposure_s(&self) -> f32 {
        self.exposure_ms as f32 * 1e-3
    }

    /// The tracking capture window's side, px.
    pub fn track_window_px(&self) -> u16 {
        self.window_px
            .saturating_add(self.track_margin_px.saturating_mul(2))
    }

    /// The Gaussian sigma of the PSF, px (`sqrt(0.31) a`).
    pub fn psf_sigma_px(&self) -> f32 {
        // sqrt(0.31), the 80 %-energy radius of a 2-D Gaussian in sigmas.
        0.556_776_4 * self.psf_a_px
    }

    /// Checks every field for a tracker of capacity `capacity` stars.
    pub fn validate(&self, capacity: usize) -> Result<(), ConfigError> {
        let w = self.window_px;
        if !(5..=13).contains(&w) || w.is_multiple_of(2) || w > MAX_SIDE {
            return Err(ConfigError::Window(w));
        }
        let fused = self.tracking_method == CentroidMethod::FusedCog1;
        if self.acquisition_method == CentroidMethod::FusedCog1 {
            return Err(ConfigError::FusedInAcquisition);
        }
        if fused && self.box_px() > MAX_BOX_SIDE {
            return Err(ConfigError::Window(w));
        }
        if self.track_window_px() > CAPTURE_MAX_SIDE {
            return Err(ConfigError::TrackMargin(self.track_margin_px));
        }
        if !(self.psf_a_px.is_finite() && (0.2..=10.0).contains(&self.psf_a_px)) {
            return Err(ConfigError::PsfWidth);
        }
        if !(self.pixcorr_tolerance.is_finite() && (0.0..=1.0).contains(&self.pixcorr_tolerance)) {
            return Err(ConfigError::PixcorrTolerance);
        }
        let d = &self.detect;
        let t = &self.track;
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let thresholds_ok = [
            d.pixel_sigmas,
            d.peak_sigmas,
            d.min_snr,
            d.low_snr,
            t.pixel_sigmas,
            t.min_snr,
            t.low_snr,
            t.test_sigmas,
        ]
        .into_iter()
        .all(positive)
            && t.min_sharpness.is_finite()
            && t.min_sharpness >= 0.0
            && t.box_side > 0
            && u16::from(t.box_side) <= self.track_window_px().saturating_sub(2);
        if !thresholds_ok {
            return Err(ConfigError::Thresholds);
        }
        if self.background_stride == 0 {
            return Err(ConfigError::BackgroundStride);
        }
        let cap = u16::try_from(capacity).unwrap_or(u16::MAX);
        if self.max_stars == 0 || self.max_stars > cap {
            return Err(ConfigError::MaxStars {
                max_stars: self.max_stars,
                capacity: cap,
            });
        }
        let track_cap = u16::try_from(super::TRACK_WINDOWS).unwrap_or(u16::MAX);
        if self.max_tracked == 0 || self.max_tracked > track_cap {
            return Err(ConfigError::MaxTracked(self.max_tracked));
        }
        if self.min_track_stars == 0 || self.min_track_stars > self.max_tracked {
            return Err(ConfigError::MinTrackStars(self.min_track_stars));
        }
        if self.reacquire_every == 0 || self.line_summary_every == 0 {
            return Err(ConfigError::Period);
        }
        Ok(())
    }
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self::FLIGHT
    }
}

/// Why a configuration was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ConfigError {
    /// The centroid window is not odd and 5 to 13 px (11 for the fused CoG).
    Window(u16),
    /// The fused raw-window CoG needs a star's carried background: tracking only.
    FusedInAcquisition,
    /// The tracking window (`window_px + 2 margin`) exceeds the capture's 15 px.
    TrackMargin(u16),
    /// The PSF width is not finite and 0.2 to 10 px.
    PsfWidth,
    /// The pixel-phase tolerance is not 0 to 1.
    PixcorrTolerance,
    /// A detection or tracking threshold is not finite and positive, or the tracking test's
    /// box does not fit its window's interior.
    Thresholds,
    /// The background stride is 0.
    BackgroundStride,
    /// `max_stars` is 0 or above the tracker's capacity.
    MaxStars {
        /// The value asked for.
        max_stars: u16,
        /// The tracker's capacity.
        capacity: u16,
    },
    /// `max_tracked` is 0 or above the tracking window list's capacity.
    MaxTracked(u16),
    /// `min_track_stars` is 0 or above `max_tracked`.
    MinTrackStars(u16),
    /// `reacquire_every` or `line_summary_every` is 0.
    Period,
    /// The readout geometry is invalid or its lines are longer than the line ring's.
    Geometry,
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Window(w) => write!(
                f,
                "window {w} px: must be odd, 5 to 13 (11 with the fused CoG)"
            ),
            Self::FusedInAcquisition => {
                f.write_str("the fused CoG needs a carried background: tracking only")
            }
            Self::TrackMargin(m) => write!(
                f,
                "tracking margin {m} px: window + 2 margin must be at most {CAPTURE_MAX_SIDE} px"
            ),
            Self::PsfWidth => f.write_str("PSF 80 % radius must be finite, 0.2 to 10 px"),
            Self::PixcorrTolerance => f.write_str("pixel-phase tolerance must be 0 to 1"),
            Self::Thresholds => f.write_str(
                "detection and tracking thresholds must be finite and positive, the tracking box inside its window",
            ),
            Self::BackgroundStride => f.write_str("background stride must be at least 1"),
            Self::MaxStars {
                max_stars,
                capacity,
            } => write!(f, "max stars {max_stars}: must be 1 to {capacity}"),
            Self::MaxTracked(n) => write!(
                f,
                "max tracked {n}: must be 1 to {}",
                super::TRACK_WINDOWS
            ),
            Self::MinTrackStars(n) => {
                write!(f, "min track stars {n}: must be 1 to max tracked")
            }
            Self::Period => f.write_str("reacquire and line-summary periods must be at least 1"),
            Self::Geometry => f.write_str(
                "readout geometry invalid or its lines longer than the tracker's line ring",
            ),
        }
    }
}

impl core::error::Error for ConfigError {}
