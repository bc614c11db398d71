//! The star tracker application: the frame loop, its modes and the rules that change them,
//! in one piece of `no_std` code that the board, the host tools and the software-in-the-loop
//! run alike. A home binds its hardware (or files, or the simulator) to the ports ([`Ports`]) and
//! calls [`Tracker::run_frame`] once a frame; everything from a raw line to a reported star
//! happens here.
//!
//! # A frame
//! ```text
//! begin_frame   the table in force, the sensor temperature, the mode (rules below),
//!               what to read ([`ReadoutRequest`]: full frame, or the tracking windows)
//! push_line     per raw line in readout order: bias of each output from its over-scan,
//!               covered pixels into the frame's dark scale, then by mode:
//!   acquisition   the raw line into the 16-line ring and the pre-filtered scan
//!                 (detect::prefilter), which calibrates only 16-pixel chunks that may
//!                 pass the threshold and every background row whole; each closed blob's
//!                 centroid window is cut from the ring once its last row is in,
//!                 calibrated and measured (acquire.rs)
//!   tracking      the rows of the windows placed on the catalog's stars the attitude
//!                 stage predicted ([`Tracker::predict_next`]), else on the last frame's
//!                 stars, are copied;
//!                 a window whose last row is in is calibrated, tested for its star
//!                 (detect::track) and the centroid window around the star's peak
//!                 measured (track.rs)
//!   standby       nothing more
//! end_frame     open windows served, the star list (the brightest `max_stars`) and the
//!               frame summary reported, the next mode decided
//! ```
//! A line is calibrated with the previous frame's complete dark scale (the dark signal
//! follows the temperature, slow against a frame); the very first frame uses its own
//! running estimate, which already holds the line's covered pixels.
//!
//! Every star is measured the same way in both modes (`measure`): the configured method
//! on a `window_px` window around its brightest pixel, the border median as background,
//! the table's pixel-phase curve chosen by one rule for a CoG ([`select_curve`]).
//!
//! # Mode rules
//! All in `modes.rs`, asked by [`Tracker::begin_frame`] and [`Tracker::end_frame`]: a
//! command takes effect at the next frame; no table means standby; acquisition hands over
//! to tracking with at least `min_track_stars` usable centroids, tracking goes back with
//! fewer or every `reacquire_every` frames on its own stars; a prediction of the next
//! frame's stars from the attitude stage ([`Tracker::predict_next`]) keeps it tracking on
//! the catalog's stars and never reacquires. Every change is an [`Event::ModeChange`] with
//! its [`ModeReason`].
//!
//! # Memory
//! [`TrackerBuffers`] (the line ring, the tracking windows, the fused CoG's plans) lives
//! where the home puts it (`.bss` on the board); the [`Tracker`] itself holds the scan
//! detector (its line buffers and `N` candidates), the pending windows, the star list, one
//! window's scratch, the last frame's stars, the in-flight defect watch ([`Watch`]) and the
//! dark-drift monitor ([`DarkDrift`] reports it). The sizes of both are tabled in docs/tracker.md
//! (`## Memory`) and bounded by the host test `tracker_memory`.
//!
//! # Cost
//! Every line: its bias levels and covered pixels (the floor of any frame). Per acquisition
//! line, the pre-filtered scan (`scan_detect`) and a copy into the ring; per tracking line,
//! a row test per window and the copy of the rows in windows; per star, the window's
//! calibration, in tracking the window test and the defect watch, and the method
//! (`measure`). Whole frames as the board runs them are `cargo m7-bench`'s
//! `tracker_*_frame` stages: docs/speed.md gives the counts, docs/tracker.md breaks them
//! down.

mod acquire;
mod config;
mod drift;
mod list;
mod measure;
mod modes;
mod ports;
mod predicted;
mod record;
mod track;

pub use acquire::{SMEARED_WIDTH_RATIO, TRAIL_MARGIN_PX, TRAIL_SCREEN_PX};
pub use config::{CentroidMethod, ConfigError, TrackerConfig};
pub use drift::DarkDrift;
pub use measure::{HIT_MONITOR_FRACTION, HIT_WIDTH_FRACTION, TRAIL_END_MARGIN_PX, select_curve};
pub use modes::CommandError;
pub use ports::{
    Clock, FixedTable, FixedTemperature, Integration, LineSource, Ports, SourceLine, TableStore,
    TelemetrySink, Thermometer,
};
pub use predicted::{PredictedStar, predicted_window_side};
pub use record::{
    Event, FrameSummary, LineOutcome, LineSummary, Mode, ModeReason, Obstructions, Provenance,
    StarFlags, StarRecord, TemperatureSource,
};
pub use track::TRAIL_SETTLE_FRAMES;

/// A saturated region of at least this many whole columns of pixels is the Moon's: its disc,
/// 35 px across on the 15 degree camera, blooms every column it crosses; a planet or a
/// bright star blooms 1-3 columns, partly. Fewer: a bright object masked, no cause.
pub const MOON_MIN_COLUMNS: u32 = 8;
/// A saturated region of more than this many whole columns is larger than the Moon's
/// (35 px and the PSF): the Earth. The image cannot tell a thin sliver of the Earth's limb
/// from the Moon; the flag then says Moon.
pub const EARTH_MIN_COLUMNS: u32 = 48;
/// A sky background above this, e- per pixel (dark removed), is the Sun's stray light: its
/// shot noise (22 e-) then passes the CCD47-20's read and dark noise and the faint stars'
/// SNR falls.
pub const STRAY_LIGHT_LIMIT_E: f32 = 500.0;
/// The radiation limit, particle hits counted per whole active area and 100 ms read: a
/// quiet orbit's rate (~1 cm^-2 s^-1) gives a 1.77 cm^2 sensor about 0.2 hits a 100 ms
/// frame, the South Atlantic Anomaly ~190, of which the monitor counts about one in six.
/// A tracking frame reads ~0.5 % of the area: its hits are scaled by the area and the
/// exposure read, over the last [`RADIATION_FRAMES`] frames.
pub const RADIATION_HITS: u16 = 5;
/// Frames whose hits and read area the radiation rate sums: the last second at 20 Hz.
pub const RADIATION_FRAMES: usize = 20;
/// Fewest hits over [`RADIATION_FRAMES`] that can flag radiation: one hit (or an unlisted
/// hot pixel's spike seen once) in a tracking frame's small area is no rate.
pub const RADIATION_MIN_HITS: u32 = 2;

use crate::calib::refresh::{Defect, DefectWatch};
use crate::calib::{DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels};
use crate::centroid::raw_cog::RawCogPlan;
use crate::detect::{LineRing, WindowCapture};
use crate::geometry::ReadoutGeometry;
use crate::readout::ReadoutRequest;
use crate::table::{CalibTable, DarkLaw};
use crate::units::{BiasAdu, Electrons, Kelvin};
use acquire::Acquisition;
use list::StarList;
use measure::{Policy, Scratch};
use modes::Modes;
use track::Tracking;

/// Raw lines the acquisition ring keeps: a centroid window completes a few rows after its
/// blob closes, so 16 leaves room for blobs up to ~8 rows below their peak.
pub(crate) const RING_LINES: usize = 16;
/// Longest raw line the ring holds (the CCD47-20's 1072 elements).
pub(crate) const RING_LINE_LEN: usize = ReadoutGeometry::CCD47_20_DUAL.line_len();
/// Most stars tracked at once (tracking windows, fused CoG plans).
pub(crate) const TRACK_WINDOWS: usize = 32;

/// Candidates the in-flight defect watch keeps.
pub(crate) const WATCH_CANDIDATES: usize = 64;
/// Confirmed in-flight defects the overlay holds.
pub(crate) const WATCH_CONFIRMED: usize = 32;
/// The in-flight defect watch of tracking ([`crate::calib::refresh`]).
pub type Watch = DefectWatch<WATCH_CANDIDATES, WATCH_CONFIRMED>;

/// The line ring of acquisition.
pub type Ring = LineRing<RING_LINES, RING_LINE_LEN>;
/// The window list of tracking.
pub type Capture = WindowCapture<TRACK_WINDOWS>;

/// The tracker's large buffers, apart so that a home can place them (the board: a static
/// in `.bss`, all zero until [`Tracker::new`] sets them up in place).
pub struct TrackerBuffers {
    ring: Ring,
    capture: Capture,
    plans: [RawCogPlan; TRACK_WINDOWS],
}

impl TrackerBuffers {
    /// Empty buffers (every byte zero, so a static of them costs no flash).
    pub const fn new() -> Self {
        Self {
            ring: LineRing::new(0),
            capture: WindowCapture::new(ReadoutGeometry {
                overscan_px: 0,
                covered_px: 0,
                active_cols: 0,
                active_rows: 0,
                lines: 0,
                outputs: 0,
            }),
            plans: [RawCogPlan::EMPTY; TRACK_WINDOWS],
        }
    }
}

impl Default for TrackerBuffers {
    fn default() -> Self {
        Self::new()
    }
}

/// What a home tells the tracker at a frame's start (from its ports).
#[derive(Clone, Copy, Debug)]
pub struct FrameInputs<'t> {
    /// The calibration table in force.
    pub table: Option<CalibTable<'t>>,
    /// The sensor temperature, K, if measured.
    pub temperature_k: Option<Kelvin>,
    /// The home clock now, us.
    pub start_us: u64,
}

/// The tracker application, for up to `N` stars a frame (the board: 32; the host's
/// `process`: 1024, room for any field).
pub struct Tracker<'t, 'b, const N: usize> {
    config: TrackerConfig,
    staged_config: Option<TrackerConfig>,
    geometry: ReadoutGeometry,
    buffers: &'b mut TrackerBuffers,
    table: Option<CalibTable<'t>>,
    /// Length of the last frame's table (0: none); `None` before the first frame.
    table_len: Option<u32>,
    frame: u32,
    started: bool,
    open: bool,
    modes: Modes,
    estimator: DarkScaleEstimator,
    prev_dark_scale: Option<Electrons>,
    /// The frame's temperature when it came from the sensor.
    measured_k: Option<Kelvin>,
    drift: drift::DriftMonitor,
    /// A dark law the home set over the table's ([`Tracker::set_dark_law`]).
    dark_law_override: Option<DarkLaw>,
    last_line: Option<u16>,
    conditions: Option<FrameConditions>,
    temperature_k: Kelvin,
    policy: Option<Policy<'t>>,
    acq: Acquisition<'t, N>,
    trk: Tracking,
    work: FrameWork<N>,
    /// The last frames' hits and areas read, for the radiation rate.
    radiation: RadiationWindow,
}

/// One frame's share of the radiation rate: hits counted, and the pixels and exposure read.
#[derive(Clone, Copy, Debug, Default)]
struct RadiationFrame {
    hits: u16,
    read_px: u32,
    exposure_ms: u32,
}

/// The particle-hit rate over the last [`RADIATION_FRAMES`] frames (a ring).
struct RadiationWindow {
    frames: [RadiationFrame; RADIATION_FRAMES],
    next: usize,
}

impl RadiationWindow {
    const fn new() -> Self {
        Self {
            frames: [RadiationFrame {
                hits: 0,
                read_px: 0,
                exposure_ms: 0,
            }; RADIATION_FRAMES],
            next: 0,
        }
    }

    /// Adds a frame; returns whether the window's rate is above the limit: at least
    /// [`RADIATION_MIN_HITS`], and `hits / (px ms) >= RADIATION_HITS / (area 100 ms)`.
    /// The sums fit a u64: 20 frames of at most 2^32 px times 2^32 ms.
    fn add(&mut self, f: RadiationFrame, active_px: u32) -> bool {
        if let Some(slot) = self.frames.get_mut(self.next) {
            *slot = f;
        }
        self.next = (self.next + 1) % RADIATION_FRAMES;
        let (mut hits, mut px_ms) = (0u64, 0u64);
        for g in &self.frames {
            hits += u64::from(g.hits);
            px_ms = px_ms.saturating_add(u64::from(g.read_px) * u64::from(g.exposure_ms));
        }
        // hits <= 20 * 65,535 and active_px * 100 < 2^39: the product fits.
        hits >= u64::from(RADIATION_MIN_HITS)
            && px_ms > 0
            && u128::from(hits) * u128::from(active_px) * 100
                >= u128::from(RADIATION_HITS) * u128::from(px_ms)
    }
}

/// What a frame's measurements write into: one window's scratch, the star list, the
/// frame's summary with its counters.
struct FrameWork<const N: usize> {
    scratch: Scratch,
    stars: StarList<N>,
    summary: FrameSummary,
    /// New hot and telegraph pixels seen in the tracking windows, and their overlay.
    watch: Watch,
}

/// What a mode's work reaches for one call: the large buffers and the frame's work.
pub(crate) struct Shared<'a, const N: usize> {
    pub(crate) ring: &'a mut Ring,
    pub(crate) capture: &'a mut Capture,
    pub(crate) plans: &'a mut [RawCogPlan; TRACK_WINDOWS],
    pub(crate) scratch: &'a mut Scratch,
    pub(crate) stars: &'a mut StarList<N>,
    pub(crate) summary: &'a mut FrameSummary,
    pub(crate) watch: &'a mut Watch,
}

impl<'a, const N: usize> Shared<'a, N> {
    fn new(buffers: &'a mut TrackerBuffers, work: &'a mut FrameWork<N>) -> Self {
        Self {
            ring: &mut buffers.ring,
            capture: &mut buffers.capture,
            plans: &mut buffers.plans,
            scratch: &mut work.scratch,
            stars: &mut work.stars,
            summary: &mut work.summary,
            watch: &mut work.watch,
        }
    }
}

impl<'t, 'b, const N: usize> Tracker<'t, 'b, N> {
    /// A tracker for lines of `geometry`, configured with `config`, using `buffers`. It
    /// starts in standby and moves to acquisition at its first frame.
    pub fn new(
        config: TrackerConfig,
        geometry: ReadoutGeometry,
        buffers: &'b mut TrackerBuffers,
    ) -> Result<Self, ConfigError> {
        config.validate(N)?;
        if geometry.validate().is_err() || geometry.line_len() > RING_LINE_LEN {
            return Err(ConfigError::Geometry);
        }
        buffers.ring.reset_for(geometry.first_active_col());
        buffers.capture.reset_for(geometry);
        Ok(Self {
            config,
            staged_config: None,
            geometry,
            buffers,
            table: None,
            table_len: None,
            frame: 0,
            started: false,
            open: false,
            modes: Modes::new(),
            estimator: DarkScaleEstimator::new(),
            prev_dark_scale: None,
            measured_k: None,
            drift: drift::DriftMonitor::new(),
            dark_law_override: None,
            last_line: None,
            conditions: None,
            temperature_k: Kelvin::ZERO,
            policy: None,
            acq: Acquisition::new(),
            trk: Tracking::new(),
            radiation: RadiationWindow::new(),
            work: FrameWork {
                scratch: Scratch::new(),
                stars: StarList::new(),
                summary: FrameSummary::empty(0, Mode::Standby, 0),
                watch: Watch::new(crate::calib::refresh::WatchConfig::DEFAULT),
            },
        })
    }

    /// Hot and telegraph pixels found in flight that the table in force does not list yet
    /// (excluded from every tracking window from their confirmation on), for the home to
    /// log or report.
    pub fn new_defects(&self) -> &[Defect] {
        self.work.watch.confirmed()
    }

    /// The star list of the last frame that ended, in the order the telemetry port got it
    /// (the attitude stage's input); it holds until the next frame begins.
    pub fn stars(&self) -> &[StarRecord] {
        self.work.stars.records()
    }

    /// Each star of [`Self::stars`] with the attitude stage's prediction it was measured for
    /// (its catalog identity), `None` for a star the tracker found itself; in the same order.
    pub fn identities(&self) -> impl Iterator<Item = Option<&PredictedStar>> + '_ {
        self.work
            .stars
            .carries()
            .iter()
            .map(|c| c.predicted.as_ref())
    }

    /// Takes the attitude stage's prediction of the next frame's stars (between frames;
    /// replacing any, an empty slice clears it): the next frame tracks one window on each
    /// valid star ([`PredictedStar::is_valid`], the first 32) instead of the
    /// last frame's stars, even where the mode rules would have acquired
    /// ([`ModeReason::Predicted`]). A commanded acquisition or standby drops it. Returns
    /// the stars taken.
    pub fn predict_next(&mut self, stars: &[PredictedStar]) -> usize {
        self.trk.set_prediction(stars)
    }

    /// Asks for one more acquisition frame where the mode rules would hand the next frame
    /// over to tracking after an acquisition frame (between frames; no effect otherwise,
    /// and a command or a prediction of the next frame takes precedence). The attitude
    /// stage asks it when the acquisition gave an attitude but no rate: one image holds no
    /// star's direction of motion (a trail reads the same both ways), so the first
    /// tracking frames on the tracker's own stars would measure moving stars whose motion
    /// is not known yet (`TRAIL_UNKNOWN`), while a second lost-in-space attitude gives the
    /// rate, and the catalog then predicts the next frame's windows with their trails.
    pub fn acquire_again(&mut self) {
        self.modes.acquire_again();
    }

    /// The calibration a window read now gets, as the tracker would calibrate it: the last
    /// frame's table, the last complete dark scale, the configured exposure and the last
    /// frame's temperature (the link's diagnostic windows use it); `None` before a frame
    /// with a table has ended.
    pub fn calibration(&self) -> Option<FrameCalibration<'t>> {
        let conditions = FrameConditions {
            dark_scale_e: self.prev_dark_scale?,
            exposure_ms: self.config.exposure_ms,
            temperature_k: self.temperature_k,
        };
        Some(FrameCalibration::new(self.table?, conditions))
    }

    /// The in-flight defect watch: its candidates and counters.
    pub fn defect_watch(&self) -> &Watch {
        &self.work.watch
    }

    /// Sets a covered-pixel dark law over the table's (section 11) for the dark drift to be
    /// measured against (a law known better than the table's, or one for a table that has
    /// none); `None` goes back to the table's law. A change of the law in force restarts
    /// the running ratio.
    pub fn set_dark_law(&mut self, law: Option<DarkLaw>) {
        self.dark_law_override = law;
        self.apply_dark_law(self.table.and_then(|t| t.dark_law()));
    }

    /// Puts the override, else `table_law`, in force; the running ratio restarts only when
    /// the law changes (a table amended with new defects keeps its ratio).
    fn apply_dark_law(&mut self, table_law: Option<DarkLaw>) {
        let law = self.dark_law_override.or(table_law);
        if law != self.drift.law() {
            self.drift.set_law(law);
        }
    }

    /// The dark law in force.
    pub fn dark_law(&self) -> Option<DarkLaw> {
        self.drift.law()
    }

    /// The running dark ratio now (also in every [`FrameSummary`]).
    pub fn dark_drift(&self) -> DarkDrift {
        self.drift.report()
    }

    /// The readout geometry the tracker was made for.
    pub fn geometry(&self) -> &ReadoutGeometry {
        &self.geometry
    }

    /// The configuration in force.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// The current (or last) frame's mode.
    pub fn mode(&self) -> Mode {
        self.modes.mode()
    }

    /// Checks `config` and stages it for the next frame.
    pub fn set_config(&mut self, config: TrackerConfig) -> Result<(), ConfigError> {
        config.validate(N)?;
        self.staged_config = Some(config);
        Ok(())
    }

    /// Asks for `mode` from the next frame on (see the module's mode rules).
    pub fn command_mode(&mut self, mode: Mode) -> Result<(), CommandError> {
        self.modes.command(mode, self.trk.priors_len() > 0)
    }

    /// What the current frame reads.
    pub fn readout_request(&self) -> ReadoutRequest<'_> {
        match self.modes.mode() {
            Mode::Tracking => ReadoutRequest::Windows(self.trk.rects()),
            Mode::Standby | Mode::Acquisition => ReadoutRequest::FullFrame,
        }
    }

    /// One frame through the ports: begins it, has `source` read what it asks for, takes
    /// every line, ends it. Returns the frame's summary (also sent to the telemetry port),
    /// or the source's error (the frame is ended with what it got, its summary sent).
    pub async fn run_frame<S: LineSource>(
        &mut self,
        source: &mut S,
        ports: &mut Ports<'_, 't>,
    ) -> Result<FrameSummary, S::Error> {
        let inputs = FrameInputs {
            table: ports.tables.active_table(),
            temperature_k: ports.thermometer.sensor_temperature_k(),
            start_us: ports.clock.now_us(),
        };
        let frame = self.begin_frame(inputs, ports.telemetry);
        let read = source.start_frame(frame, &self.readout_request()).await;
        if let Err(e) = read {
            self.end_frame(ports.telemetry);
            return Err(e);
        }
        loop {
            // Known once the frame's first line is in (some sources know it at its start).
            self.set_integration(source.integration());
            match source.next_line().await {
                Ok(Some(l)) => {
                    self.push_line(l.line, l.samples, ports.telemetry);
                }
                Ok(None) => break,
                Err(e) => {
                    self.end_frame(ports.telemetry);
                    return Err(e);
                }
            }
        }
        Ok(self.end_frame(ports.telemetry))
    }

    /// When the current frame's image was integrated, as the line source reports it
    /// ([`LineSource::integration`]; a `None` keeps what it gave before): the trails of its
    /// tracked stars are their motion over it. [`Self::run_frame`] gives it before each
    /// line; a home that pushes lines itself gives it once it knows it. Without it a
    /// trailed star's trail is not known, and the star is flagged
    /// [`StarFlags::TRAIL_UNKNOWN`].
    pub fn set_integration(&mut self, integration: Option<Integration>) {
        self.trk.set_integration(integration);
    }

    /// Starts the next frame (ending an open one first) and returns its number: applies a
    /// staged configuration, takes the table in force, decides the mode and places the
    /// tracking windows. [`Self::readout_request`] then says what to read.
    pub fn begin_frame(
        &mut self,
        inputs: FrameInputs<'t>,
        telemetry: &mut dyn TelemetrySink,
    ) -> u32 {
        if self.open {
            self.end_frame(telemetry);
        }
        let frame = if self.started {
            self.frame.wrapping_add(1)
        } else {
            0
        };
        self.started = true;
        self.frame = frame;
        self.open = true;
        self.trk.next_integration();
        if let Some(c) = self.staged_config.take() {
            self.config = c;
            telemetry.event(&Event::ConfigApplied { frame });
        }

        let table = inputs.table.filter(|t| *t.geometry() == self.geometry);
        let len = table.map_or(0, |t| u32::try_from(t.len_bytes()).unwrap_or(u32::MAX));
        if self.table_len != Some(len) {
            telemetry.event(&Event::TableChanged {
                frame,
                len_bytes: len,
            });
            self.table_len = Some(len);
            // A new table (an in-flight defect commit's among them) may list what the
            // overlay holds.
            if let Some(t) = table {
                self.work.watch.retire_listed(&t);
            }
        }
        // Every frame, not only at a length change: a replacement table of the same length
        // may carry another law (a 16-byte comparison).
        self.apply_dark_law(table.and_then(|t| t.dark_law()));
        self.table = table;

        let (to, change) = self.modes.begin(
            self.trk.priors_len() > 0,
            table.is_some(),
            self.trk.prediction_len() > 0,
        );
        if to != Mode::Tracking {
            self.trk.drop_prediction();
        }
        if let Some((from, reason)) = change {
            telemetry.event(&Event::ModeChange {
                frame,
                from,
                to,
                reason,
            });
        }

        let (temperature_k, source) = match (inputs.temperature_k, table) {
            (Some(t), _) => (t, TemperatureSource::Sensor),
            (None, Some(t)) => (
                t.hot_pixels().reference_temperature_k(),
                TemperatureSource::TableReference,
            ),
            (None, None) => (Kelvin::ZERO, TemperatureSource::None),
        };
        self.temperature_k = temperature_k;
        self.measured_k = inputs.temperature_k;
        self.work.summary = FrameSummary {
            calibrated: table.is_some(),
            temperature_k,
            temperature_source: source,
            ..FrameSummary::empty(frame, to, inputs.start_us)
        };
        self.estimator = DarkScaleEstimator::new();
        self.last_line = None;
        self.conditions = None;
        self.work.stars.clear(usize::from(self.config.max_stars));
        self.policy = table.map(|t| {
            let method = match to {
                Mode::Tracking => self.config.tracking_method,
                _ => self.config.acquisition_method,
            };
            Policy::new(method, &self.config, &t)
        });
        match to {
            Mode::Acquisition => {
                self.work.summary.read_px =
                    u32::from(self.geometry.active_cols) * u32::from(self.geometry.active_rows);
                self.acq.start(&mut self.buffers.ring)
            }
            Mode::Tracking => {
                let placed = self.trk.start(
                    &self.config,
                    &self.geometry,
                    &mut self.buffers.capture,
                    &mut self.work.summary,
                );
                self.work.summary.track_windows = placed;
            }
            Mode::Standby => {}
        }
        frame
    }

    /// Takes raw line `line` of the current frame (`samples`: the whole raw line) and
    /// returns what was made of it. Lines must come in increasing order; a refused line is
    /// counted in the frame summary.
    pub fn push_line(
        &mut self,
        line: u16,
        samples: &[u16],
        telemetry: &mut dyn TelemetrySink,
    ) -> LineOutcome {
        let mut bias_adu = [BiasAdu::ZERO; crate::geometry::MAX_OUTPUTS];
        let (outcome, dark_scale_e) = match self.take_line(line, samples, &mut bias_adu) {
            Some(done) => done,
            None => {
                self.work.summary.lines_refused = self.work.summary.lines_refused.saturating_add(1);
                (LineOutcome::Refused, Electrons::ZERO)
            }
        };
        if line.is_multiple_of(self.config.line_summary_every) {
            telemetry.line(&LineSummary {
                frame: self.frame,
                line,
                bias_adu,
                dark_scale_e,
                outcome,
            });
        }
        outcome
    }

    /// [`Self::push_line`]'s work; `None` when the line is refused.
    fn take_line(
        &mut self,
        line: u16,
        samples: &[u16],
        bias_adu: &mut [BiasAdu; crate::geometry::MAX_OUTPUTS],
    ) -> Option<(LineOutcome, Electrons)> {
        if !self.open
            || samples.len() != self.geometry.line_len()
            || self.last_line.is_some_and(|l| line <= l)
            || line >= self.geometry.lines
        {
            return None;
        }
        let levels = LineLevels::measure(&self.geometry, samples).ok()?;
        *bias_adu = levels.bias_adu;
        self.last_line = Some(line);
        self.work.summary.lines = self.work.summary.lines.saturating_add(1);
        let active = line < self.geometry.active_rows;
        let Some(table) = self.table else {
            let outcome = if active {
                uncalibrated(&self.geometry, samples, &levels)
            } else {
                LineOutcome::Levels
            };
            return Some((outcome, Electrons::ZERO));
        };
        // The covered columns this frame's readout reads (windows read fewer).
        let covered = self.readout_request().covered_cols(&self.geometry);
        self.estimator
            .add_line_cols(&table, samples, &levels, covered)
            .ok()?;
        // The CCD47-20 always has covered columns, so the running estimate exists.
        let dark_scale_e = self
            .prev_dark_scale
            .or_else(|| self.estimator.estimate())
            .unwrap_or(Electrons::ZERO);
        if !active {
            return Some((LineOutcome::Levels, dark_scale_e));
        }
        let conditions = FrameConditions {
            dark_scale_e,
            exposure_ms: self.config.exposure_ms,
            temperature_k: self.temperature_k,
        };
        self.conditions = Some(conditions);
        let cal = FrameCalibration::new(table, conditions);
        let outcome = match (self.modes.mode(), self.policy) {
            (Mode::Acquisition, Some(policy)) => self.acq.line(
                &cal,
                &policy,
                &self.config,
                &self.geometry,
                line,
                samples,
                &levels,
                Shared::new(self.buffers, &mut self.work),
            ),
            (Mode::Tracking, Some(policy)) => self.trk.line(
                &cal,
                &policy,
                &self.config,
                line,
                samples,
                &levels,
                Shared::new(self.buffers, &mut self.work),
            ),
            _ => LineOutcome::Levels,
        };
        Some((outcome, dark_scale_e))
    }

    /// Ends the current frame: serves what is still open, reports the stars and the
    /// summary, decides the next mode. Returns the summary (a no-op returning the last
    /// one when no frame is open).
    pub fn end_frame(&mut self, telemetry: &mut dyn TelemetrySink) -> FrameSummary {
        if !self.open {
            return self.work.summary;
        }
        self.open = false;
        if let (Some(table), Some(conditions), Some(policy)) =
            (self.table, self.conditions, self.policy)
        {
            let cal = FrameCalibration::new(table, conditions);
            match self.modes.mode() {
                Mode::Acquisition => self.acq.finish(
                    &cal,
                    &policy,
                    &self.config,
                    &self.geometry,
                    Shared::new(self.buffers, &mut self.work),
                ),
                Mode::Tracking => self.trk.finish(
                    &cal,
                    &policy,
                    &self.config,
                    Shared::new(self.buffers, &mut self.work),
                ),
                Mode::Standby => {}
            }
        }
        let estimate = self.table.and(self.estimator.estimate());
        self.work.summary.dark_scale_e = estimate;
        if let Some(e) = estimate {
            self.prev_dark_scale = estimate;
            self.drift
                .frame(e, self.measured_k, self.config.exposure_ms);
        }
        self.work.summary.dark_drift = self.drift.report();
        self.work.summary.defects_pending =
            u16::try_from(self.work.watch.confirmed().len()).unwrap_or(u16::MAX);
        self.work.summary.obstructions = self.obstructions();
        let mut centroids = 0u16;
        for s in self.work.stars.records() {
            telemetry.star(self.frame, s);
            if s.is_centroid() {
                centroids = centroids.saturating_add(1);
            }
        }
        self.work.summary.stars =
            u16::try_from(self.work.stars.records().len()).unwrap_or(u16::MAX);
        self.work.summary.centroids = centroids;
        self.work.summary.stars_dropped = self.work.stars.dropped;
        self.trk
            .keep_priors(&self.work.stars, usize::from(self.config.max_tracked));
        self.work.summary.next_mode =
            self.modes
                .end(centroids, &self.config, self.trk.predicted_frame());
        telemetry.frame(&self.work.summary);
        self.work.summary
    }
}

impl<const N: usize> Tracker<'_, '_, N> {
    /// What took stars from the frame now ending (see [`Obstructions`]), each bit measured
    /// in it: the Moon and the Earth from the width of its saturated columns (acquisition:
    /// the largest saturated region over the active rows; tracking: the probe row's widest
    /// run), the Sun from its sky, radiation from the hit rate of the last frames.
    fn obstructions(&mut self) -> Obstructions {
        let s = &self.work.summary;
        let rows = u32::from(self.geometry.active_rows);
        let mut o = Obstructions::empty();
        // The acquisition's region in pixels over the active rows; the probe row's run.
        let (moon, earth) = match (s.mode, s.probe_saturated_cols.map(u32::from)) {
            (Mode::Acquisition, _) => (
                s.saturated_px >= MOON_MIN_COLUMNS * rows,
                s.saturated_px > EARTH_MIN_COLUMNS * rows,
            ),
            (Mode::Tracking, Some(c)) => (c >= MOON_MIN_COLUMNS, c > EARTH_MIN_COLUMNS),
            _ => (false, false),
        };
        if earth {
            o |= Obstructions::EARTH;
        } else if moon {
            o |= Obstructions::MOON;
        }
        if s.sky_e > STRAY_LIGHT_LIMIT_E {
            o |= Obstructions::SUN;
        }
        if s.mode != Mode::Standby {
            let frame = RadiationFrame {
                hits: s.hits,
                read_px: s.read_px,
                exposure_ms: self.config.exposure_ms,
            };
            let active_px = u32::from(self.geometry.active_cols) * rows;
            if self.radiation.add(frame, active_px) {
                o |= Obstructions::RADIATION;
            }
        }
        o
    }
}

/// An active line without a table: the mean of its active samples above their output's
/// bias, ADU.
fn uncalibrated(geometry: &ReadoutGeometry, samples: &[u16], levels: &LineLevels) -> LineOutcome {
    let first = geometry.first_active_col();
    let (mut sum, mut n) = (0i64, 0i64);
    for (col, raw) in samples
        .iter()
        .enumerate()
        .skip(first)
        .take(usize::from(geometry.active_cols))
    {
        let bias = levels.bias(geometry.output_of_col(col));
        // Both in 1/16 ADU: a sample is at most 2^20, the bias at most 2^20 as well.
        sum += (i64::from(*raw) << 4) - i64::from(bias.to_bits());
        n += 1;
    }
    let mean = if n == 0 {
        0.0
    } else {
        sum as f32 / (16.0 * n as f32)
    };
    LineOutcome::Uncalibrated {
        mean_above_bias_adu: mean,
    }
}
