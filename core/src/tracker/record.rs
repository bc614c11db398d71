//! What the tracker reports: one [`StarRecord`] per star per frame with one flag layout
//! ([`StarFlags`]), one [`FrameSummary`] per frame with every loss counted, a
//! [`LineSummary`] for every `line_summary_every`th line, and [`Event`]s (mode changes,
//! table changes). These are the telemetry records of every home: the firmware's log and
//! its link, `stars.csv` of `startrack process`, and the software-in-the-loop's CSV.
//!
//! Cost: a record is 36 bytes, a summary under 100; nothing here allocates.

use crate::calib::PixelFlags;
use crate::centroid::gauss_fit::PsfFit;
use crate::centroid::{Centroid, CentroidFlags};
use crate::detect::{DetectionFlags, TrackFlags};
use crate::units::{BiasAdu, Electrons, Kelvin};

/// The tracker's mode for one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// Lines are levelled and the dark scale measured; no stars are looked for.
    Standby,
    /// Whole-frame detection, a centroid per detected star.
    Acquisition,
    /// Only windows around the last frame's stars, or the catalog's stars the attitude
    /// stage predicts, are read and measured.
    Tracking,
}

impl Mode {
    /// The mode's name as telemetry and the CSV files write it.
    pub const fn name(self) -> &'static str {
        match self {
            Self::Standby => "standby",
            Self::Acquisition => "acquisition",
            Self::Tracking => "tracking",
        }
    }
}

bitflags::bitflags! {
    /// The quality of a reported star, one bit a fact: 0 is a clean measurement. How the
    /// star was found and measured is its [`Provenance`], apart. The bit numbers are stable:
    /// telemetry, `stars.csv` and the SIL's CSV carry them as a `u32`.
    ///
    /// Bits 0-5 come from the detector that found the star (the line detector in
    /// acquisition, the window test in tracking), 8-15 and 22-24 from the centroid method,
    /// 16 from calibration, 17, 20 and 21 from the tracker itself; 6-7, 14 and 18-19 are
    /// unused.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct StarFlags: u32 {
        /// Detection: a saturated pixel in the blob (acquisition) or the window's interior
        /// (tracking).
        const DETECT_SATURATED = 1 << 0;
        /// Detection: the blob touches the active area's edge, or the tracking window was
        /// clipped there or its peak sits next to its border.
        const DETECT_EDGE = 1 << 1;
        /// Detection: probably a close pair.
        const DETECT_BLENDED = 1 << 2;
        /// Detection: SNR between the detection minimum and the low-SNR level.
        const DETECT_LOW_SNR = 1 << 3;
        /// Detection: blob truncated (a run or blob table was full).
        const DETECT_TRUNCATED = 1 << 4;
        /// Tracking detection: the window held an excluded pixel.
        const DETECT_EXCLUDED = 1 << 5;
        /// Centroid: a saturated pixel in the window.
        const SATURATED = 1 << 8;
        /// Centroid: the window or the method's box was clipped at an edge.
        const EDGE_CLIPPED = 1 << 9;
        /// Centroid: the window holds an excluded (hot or telegraph) pixel.
        const EXCLUDED_PIXEL = 1 << 10;
        /// Centroid: SNR below 3.
        const LOW_SNR = 1 << 11;
        /// Centroid: degenerate, no position (the window's centre is reported).
        const DEGENERATE = 1 << 12;
        /// Centroid: an iterative method did not converge.
        const NOT_CONVERGED = 1 << 13;
        /// Centroid: the position fell outside the window and was clamped.
        const CLAMPED = 1 << 15;
        /// Calibration: the window holds a hot pixel corrected by its own dark law.
        const HOT_CORRECTED = 1 << 16;
        /// A CoG without a pixel-phase curve for its power, box and the PSF width: the
        /// position carries the CoG's pixelisation bias.
        const UNCORRECTED = 1 << 17;
        /// The window's top rows had left the line ring: position and flux are the
        /// detector's, not a centroid.
        const RING_LOST = 1 << 20;
        /// The window could not be calibrated: position and flux are the detector's.
        const CALIB_FAILED = 1 << 21;
        /// Centroid: the fitted PSF does not describe the window (`chi2_dof` above the
        /// chi-square limit: a blend, a cosmic ray, a PSF the Gaussian cannot follow). The
        /// position is reported but is not a clean measurement.
        const POOR_FIT = 1 << 22;
        /// Centroid: the method's `sigma_x_px`, `sigma_y_px` are known to be wrong by more
        /// than 10 % in this configuration (docs/accuracy.md, the pull table).
        const SIGMA_UNRELIABLE = 1 << 23;
        /// Centroid: the star's own PSF width disagrees with the table's field PSF model
        /// beyond the model's scatter and the fit's width error; the position is the
        /// width-free fit's.
        const PSF_MISMATCH = 1 << 24;
        /// Its trail during the exposure is unknown or guessed, so the position is a smeared
        /// star's, kept to place the next window but not used for the attitude. Tracking:
        /// the star moved at least `TRAIL_MIN_PX` since the last frame before two tracking
        /// frames measured its motion; acquisition: a star the trailed test does not call
        /// trailed whose fitted width exceeds the configured PSF's by
        /// `SMEARED_WIDTH_RATIO`, a trailed star whose fitted trail ends within
        /// `TRAIL_END_MARGIN_PX` of its window's border (a trail the window may cut), or,
        /// in a frame whose stars share a common trail (`detect::CommonMotion`), a round
        /// blob off it, brighter than the median of those on it and fitted narrower than
        /// `OFF_MOTION_WIDTH_FRACTION` of the PSF (a proton hit: a star that bright would
        /// show the frame's trail, and a trail only widens a star).
        const TRAIL_UNKNOWN = 1 << 25;
        /// Tracking: its trail during the exposure is longer than its tracking window holds
        /// (a component beyond the window's side less 1 px, the capture's largest window
        /// being `CAPTURE_MAX_SIDE`): the trailed fit sees no end of it and the position
        /// along it is not measured; kept to place the next window, not used for the
        /// attitude.
        const TRAIL_CLIPPED = 1 << 26;
    }
}

bitflags::bitflags! {
    /// How a reported star was found and measured: provenance, saying nothing of its
    /// quality (that is [`StarFlags`]). The bit numbers are stable: telemetry, `stars.csv`
    /// and the SIL's CSV carry them as a `u8`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Provenance: u8 {
        /// Found in a tracking frame, in a window placed on the last frame's star or on a
        /// catalog star the attitude stage predicted (else by acquisition's scan of the
        /// whole frame).
        const TRACKED = 1 << 0;
        /// Measured by the fused raw-window CoG (tracking), background carried from the
        /// star's last full measurement.
        const FUSED = 1 << 1;
        /// Measured by the trailed-star fit: in tracking on the whole tracking window, the
        /// trail taken from the star's prediction or else its last motion; in acquisition on
        /// the blob's window, the trail fitted (length, angle and width free) and the star
        /// found trailed by the test against the round model: the position is at
        /// mid-exposure.
        const TRAILED = 1 << 2;
    }
}

bitflags::bitflags! {
    /// What in the field took stars from a frame, one bit a cause (0: nothing). The bit
    /// numbers are stable: housekeeping and the attitude report's validity flags carry them.
    /// Each bit is measured in the frame it is in, in acquisition and tracking alike, from
    /// the image alone ([`crate::tracker`]'s frame end): the Moon and the Earth by the width
    /// of the saturated columns (acquisition: the largest saturated region; tracking: the
    /// probe row it reads besides its windows), the Sun by the sky background (the whole
    /// rows', or the windows' borders), radiation by the particle hits counted per pixel
    /// and second read over the last second's frames.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Obstructions: u8 {
        /// Saturated columns of the Moon's width in this frame (its bloomed columns).
        const MOON = 1 << 0;
        /// Saturated columns wider than the Moon can make in this frame: the Earth.
        const EARTH = 1 << 1;
        /// This frame's sky background above the stray-light limit: the Sun's stray light.
        const SUN = 1 << 2;
        /// A particle-hit rate above the radiation limit: the hits counted over the frames
        /// of the last second, up to and with this one, per pixel and second read.
        const RADIATION = 1 << 3;
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Obstructions {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "Obstructions({=u8:#x})", self.bits())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Provenance {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "Provenance({=u8:#x})", self.bits())
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for StarFlags {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "StarFlags({=u32:#x})", self.bits())
    }
}

const DETECTION_BITS: [(DetectionFlags, StarFlags); 5] = [
    (DetectionFlags::SATURATED, StarFlags::DETECT_SATURATED),
    (DetectionFlags::EDGE, StarFlags::DETECT_EDGE),
    (DetectionFlags::BLENDED, StarFlags::DETECT_BLENDED),
    (DetectionFlags::LOW_SNR, StarFlags::DETECT_LOW_SNR),
    (DetectionFlags::TRUNCATED, StarFlags::DETECT_TRUNCATED),
];

const TRACK_BITS: [(TrackFlags, StarFlags); 5] = [
    (TrackFlags::SATURATED, StarFlags::DETECT_SATURATED),
    (TrackFlags::EDGE, StarFlags::DETECT_EDGE),
    (TrackFlags::BLENDED, StarFlags::DETECT_BLENDED),
    (TrackFlags::LOW_SNR, StarFlags::DETECT_LOW_SNR),
    (TrackFlags::EXCLUDED_PIXEL, StarFlags::DETECT_EXCLUDED),
];

const CENTROID_BITS: [(CentroidFlags, StarFlags); 10] = [
    (CentroidFlags::SATURATED, StarFlags::SATURATED),
    (CentroidFlags::EDGE_CLIPPED, StarFlags::EDGE_CLIPPED),
    (CentroidFlags::EXCLUDED_PIXEL, StarFlags::EXCLUDED_PIXEL),
    (CentroidFlags::LOW_SNR, StarFlags::LOW_SNR),
    (CentroidFlags::DEGENERATE, StarFlags::DEGENERATE),
    (CentroidFlags::NOT_CONVERGED, StarFlags::NOT_CONVERGED),
    (CentroidFlags::CLAMPED, StarFlags::CLAMPED),
    (CentroidFlags::POOR_FIT, StarFlags::POOR_FIT),
    (CentroidFlags::SIGMA_UNRELIABLE, StarFlags::SIGMA_UNRELIABLE),
    (CentroidFlags::PSF_MISMATCH, StarFlags::PSF_MISMATCH),
];

impl StarFlags {
    /// The bits of a line detector's flags.
    pub fn from_detection(d: DetectionFlags) -> Self {
        map(&DETECTION_BITS, |f| d.contains(f))
    }

    /// The bits of a tracking window test's flags (its "no background" and "bad input" mean
    /// nothing was detected: such a window reports no star).
    pub(crate) fn from_track(t: TrackFlags) -> Self {
        map(&TRACK_BITS, |f| t.contains(f))
    }

    /// The bits of a centroid's flags.
    pub(crate) fn from_centroid(c: CentroidFlags) -> Self {
        map(&CENTROID_BITS, |f| c.contains(f))
    }

    /// The bits of a window's OR-ed calibration flags (saturation and exclusion reach the
    /// centroid's own flags; a corrected hot pixel is reported here).
    pub fn from_pixels(p: PixelFlags) -> Self {
        if p.contains(PixelFlags::HOT_CORRECTED) {
            Self::HOT_CORRECTED
        } else {
            Self::empty()
        }
    }
}

fn map<F: Copy>(table: &[(F, StarFlags)], has: impl Fn(F) -> bool) -> StarFlags {
    table
        .iter()
        .filter(|(f, _)| has(*f))
        .fold(StarFlags::empty(), |m, (_, s)| m | *s)
}

/// One star as reported, active-area pixels (0-based, pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StarRecord {
    /// Column, px.
    pub x_px: f32,
    /// Row, px.
    pub y_px: f32,
    /// Background-subtracted signal, e- (the CoG box's; the Gauss fit's whole PSF).
    pub flux_e: f32,
    /// SNR of `flux_e` (eq. 8 with the measured noise; the fit's `N / sigma_N`).
    pub snr: f32,
    /// Estimated 1-sigma error of `x_px`, px.
    pub sigma_x_px: f32,
    /// Estimated 1-sigma error of `y_px`, px.
    pub sigma_y_px: f32,
    /// Covariance of the errors of `x_px` and `y_px`, px^2: a trailed star's (the trailed fit
    /// knows it worse along its trail than across, and a trail at an angle to the rows
    /// correlates the two); 0 for the other methods (a round star's are independent).
    /// Not carried by the link's star list.
    pub cov_xy_px2: f32,
    /// Its quality (0: a clean measurement).
    pub flags: StarFlags,
    /// How it was found and measured.
    pub provenance: Provenance,
    /// The star's own PSF 80 %-energy radius from the width-free fit, px; 0 when the
    /// method does not measure it (the CoG, the fit of a given width) or the fit failed.
    pub psf_a_px: f32,
    /// The width-free fit's `chi2 / (n - 4)` (about 1 when the Gaussian describes the
    /// window; [`StarFlags::POOR_FIT`] above the chi-square limit); 0 when not measured.
    pub chi2_dof: f32,
}

impl StarRecord {
    /// Whether the fitted PSF describes the window and the fit's sigmas hold (none of
    /// [`StarFlags::POOR_FIT`], [`StarFlags::SIGMA_UNRELIABLE`], [`StarFlags::NOT_CONVERGED`]):
    /// the star list, the choice of tracking windows and identification rank such a star
    /// above every other, then by flux. A particle hit or a star beside a hot pixel the table
    /// does not list fits poorly; a lone hot pixel or a noise peak fits narrower than any
    /// star, its sigma unreliable.
    pub fn fit_is_clean(&self) -> bool {
        !self.flags.intersects(
            StarFlags::POOR_FIT
                .union(StarFlags::SIGMA_UNRELIABLE)
                .union(StarFlags::NOT_CONVERGED),
        )
    }

    /// A centroid as a record, with `flags` added to the centroid's own (no PSF measured:
    /// `psf_a_px` and `chi2_dof` 0; found by acquisition: no provenance bit).
    pub(crate) fn from_centroid(c: &Centroid, flags: StarFlags) -> Self {
        Self {
            x_px: c.x_px,
            y_px: c.y_px,
            flux_e: c.flux_e,
            snr: c.snr,
            sigma_x_px: c.sigma_x_px,
            sigma_y_px: c.sigma_y_px,
            cov_xy_px2: 0.0,
            flags: flags | StarFlags::from_centroid(c.flags),
            provenance: Provenance::empty(),
            psf_a_px: 0.0,
            chi2_dof: 0.0,
        }
    }

    /// A width-free fit as a record, with `flags` added to the centroid's own.
    pub fn from_psf_fit(f: &PsfFit, flags: StarFlags) -> Self {
        Self {
            psf_a_px: f.psf_a_px,
            chi2_dof: f.chi2_dof,
            ..Self::from_centroid(&f.centroid, flags)
        }
    }

    /// True when the position is a centroid that may be used (for attitude, and to place
    /// the next frame's tracking window): neither the detector's stand-in
    /// ([`StarFlags::RING_LOST`], [`StarFlags::CALIB_FAILED`]) nor degenerate.
    pub fn is_centroid(&self) -> bool {
        !self
            .flags
            .intersects(StarFlags::RING_LOST | StarFlags::CALIB_FAILED | StarFlags::DEGENERATE)
    }
}

/// Where a frame's sensor temperature came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TemperatureSource {
    /// The home's thermometer.
    Sensor,
    /// No reading: the table's hot-pixel reference temperature was used (only hot pixels
    /// with their own dark law depend on it).
    TableReference,
    /// No reading and no table.
    None,
}

/// What a frame produced besides its stars: its conditions and every loss, counted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameSummary {
    /// The tracker's frame number (0 at start-up, one more each frame).
    pub frame: u32,
    /// The frame's mode.
    pub mode: Mode,
    /// The mode the rules give the next frame (a command, or a missing table at its start,
    /// may overrule it: see the tracker's mode rules).
    pub next_mode: Mode,
    /// The home clock at the frame's start, us.
    pub start_us: u64,
    /// A calibration table was in force (without one no star is looked for).
    pub calibrated: bool,
    /// The sensor temperature used for hot pixels, K.
    pub temperature_k: Kelvin,
    /// Where `temperature_k` came from.
    pub temperature_source: TemperatureSource,
    /// This frame's dark scale from its covered pixels, e- (`None`: no table or no covered
    /// pixel read). The next frame's lines are calibrated with it.
    pub dark_scale_e: Option<Electrons>,
    /// Lines taken.
    pub lines: u16,
    /// Lines refused: wrong length, out of order, or their over-scan unusable.
    pub lines_refused: u16,
    /// Stars reported (at most the configured `max_stars`).
    pub stars: u16,
    /// Reported stars whose position is a usable centroid ([`StarRecord::is_centroid`]).
    pub centroids: u16,
    /// Acquisition: candidates the detector's full list lost.
    pub candidates_dropped: u32,
    /// Acquisition: windows that could not wait for their rows (pending list full).
    pub windows_dropped: u16,
    /// Acquisition: windows whose rows had left the line ring.
    pub ring_lost: u16,
    /// Windows that could not be calibrated.
    pub calib_failed: u16,
    /// Tracking: windows placed.
    pub track_windows: u16,
    /// Tracking: windows that could not be placed (outside the area, too many).
    pub track_refused: u16,
    /// Tracking: windows without a star (or with missing rows).
    pub track_lost: u16,
    /// Stars not reported because the star list was full (the brightest are kept).
    pub stars_dropped: u16,
    /// The running dark ratio after this frame (covered pixels against the dark law).
    pub dark_drift: super::drift::DarkDrift,
    /// Pixels confirmed in flight that the table in force does not list yet (the overlay).
    pub defects_pending: u16,
    /// Detections and tracking windows holding a saturated pixel: a bright object or its
    /// bloomed columns, masked (never reported as stars).
    pub masked: u16,
    /// Windows sharper than any star the optics make, particle hits
    /// ([`crate::detect::is_particle_hit`] at `HIT_MONITOR_FRACTION` of the PSF; those past
    /// `HIT_WIDTH_FRACTION` are rejected): the frame's radiation monitor.
    pub hits: u16,
    /// Acquisition: pixels of the largest saturated region (0: none).
    pub saturated_px: u32,
    /// Tracking: the widest run of saturated columns on the frame's probe row, the one full
    /// row it reads besides its windows (a bloomed column crosses every row); `None` when
    /// the row was not read (acquisition, standby, a lost line).
    pub probe_saturated_cols: Option<u16>,
    /// Active pixels the frame read: the whole area (acquisition), else its windows' and
    /// its probe row's (what its particle hits are counted on).
    pub read_px: u32,
    /// The mean sky background of the frame (acquisition: its whole rows; tracking: its
    /// windows' borders), e- per pixel, dark removed; 0 when not measured.
    pub sky_e: f32,
    /// Tracking: windows whose border background `sky_e` averages.
    pub sky_windows: u16,
    /// What took stars from the frame.
    pub obstructions: Obstructions,
}

impl FrameSummary {
    /// A frame `frame` in `mode` started at `start_us` (us) with nothing measured yet:
    /// no table, no temperature, every count zero; the next mode is `mode`.
    pub fn empty(frame: u32, mode: Mode, start_us: u64) -> Self {
        Self {
            frame,
            mode,
            next_mode: mode,
            start_us,
            calibrated: false,
            temperature_k: Kelvin::ZERO,
            temperature_source: TemperatureSource::None,
            dark_scale_e: None,
            lines: 0,
            lines_refused: 0,
            stars: 0,
            centroids: 0,
            candidates_dropped: 0,
            windows_dropped: 0,
            ring_lost: 0,
            calib_failed: 0,
            track_windows: 0,
            track_refused: 0,
            track_lost: 0,
            stars_dropped: 0,
            dark_drift: super::drift::DarkDrift {
                ratio_u8f8: 0,
                frames: 0,
                out_of_band: false,
            },
            defects_pending: 0,
            masked: 0,
            hits: 0,
            saturated_px: 0,
            probe_saturated_cols: None,
            read_px: 0,
            sky_e: 0.0,
            sky_windows: 0,
            obstructions: Obstructions::empty(),
        }
    }
}

/// What was made of one line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LineOutcome {
    /// An active row calibrated whole (an acquisition background row).
    Calibrated {
        /// Mean of the row's active pixels that are not excluded, e-.
        mean_e: Electrons,
        /// Flags of the row's pixels, OR-ed.
        flags: PixelFlags,
        /// Pixels at or above the table's saturation level.
        saturated: u16,
    },
    /// An active acquisition row streamed raw through the pre-filtered scan (only chunks
    /// that may hold a star were calibrated: there is no row mean).
    Scanned,
    /// A tracking row: only the pixels of the windows it crosses were kept.
    Tracked {
        /// Windows whose last row this was (measured now).
        windows_done: u8,
    },
    /// No table: only the bias was taken off.
    Uncalibrated {
        /// Mean of the active samples above their output's bias, ADU.
        mean_above_bias_adu: f32,
    },
    /// A line with no active row (store-section rows read after the image), or an active
    /// row in standby.
    Levels,
    /// The line was refused (see [`FrameSummary::lines_refused`]).
    Refused,
}

/// The record of one line, reported every `line_summary_every`th line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineSummary {
    /// The tracker's frame number.
    pub frame: u32,
    /// Raw line index within the frame.
    pub line: u16,
    /// Bias level of each output from the line's over-scan, ADU (zero when refused).
    pub bias_adu: [BiasAdu; crate::geometry::MAX_OUTPUTS],
    /// The dark scale the line was calibrated with, e- (zero without a table).
    pub dark_scale_e: Electrons,
    /// What was made of the line.
    pub outcome: LineOutcome,
}

/// Why the mode changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ModeReason {
    /// The tracker's first frame.
    Start,
    /// A command asked for it.
    Command,
    /// Acquisition found enough stars to track.
    Acquired,
    /// Too few stars were left in tracking (or found in acquisition after tracking).
    TooFewStars,
    /// The periodic acquisition frame that picks up stars entering the field.
    Reacquire,
    /// No calibration table: stars cannot be measured.
    NoTable,
    /// A calibration table is in force again after a standby for want of one.
    TableAvailable,
    /// The attitude stage predicted the frame's stars from the catalog, where the last
    /// frame's stars alone would have sent the tracker to acquisition.
    Predicted,
}

/// Something that happened between frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The mode changes from the frame `frame` on.
    ModeChange {
        /// First frame in the new mode.
        frame: u32,
        /// The mode before.
        from: Mode,
        /// The mode from `frame` on.
        to: Mode,
        /// Why.
        reason: ModeReason,
    },
    /// The calibration table in force changed at frame `frame` (`len_bytes` 0: none).
    TableChanged {
        /// First frame with the new table.
        frame: u32,
        /// The new table's length, bytes; 0 when there is none.
        len_bytes: u32,
    },
    /// A configuration was accepted; it applies from frame `frame` on.
    ConfigApplied {
        /// First frame with the new configuration.
        frame: u32,
    },
}
