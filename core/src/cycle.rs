//! The frame cycle: one frame of the tracker application and everything a home runs around
//! it, written once for the board, `startrack process`, the SIL and the served SIL.
//!
//! ```text
//! between frames   link bytes in (commands act on the tracker here, never mid-frame),
//!                  the link's work (diagnostic window rows, the in-flight defect commit),
//!                  telemetry out as the home's link can take it
//! run_frame        the tracker's frame (its records to the link and to the home's own sink)
//!                  -> the link's periodic housekeeping
//!                  -> the attitude stage on the frame's star list, its report on the link,
//!                     tagged at mid-exposure in spacecraft time (the cycle's clock, set by
//!                     the link's time-set command and the home's sync pulses), with the
//!                     angular rate of the last attitudes ([`crate::attitude::RateFilter`]);
//!                     with the link's velocity command (within [`VELOCITY_MAX_AGE_S`] of
//!                     the frame's spacecraft time) the attitude is of the ICRF, stellar
//!                     aberration removed, else of the apparent sky and flagged so
//!                  -> an acquisition frame's attitude with no rate yet: one more
//!                     acquisition frame ([`Tracker::acquire_again`]), whose attitude
//!                     gives the rate
//!                  -> the next frame's windows: with a rate and an attitude no older than
//!                     [`PREDICT_MAX_AGE_US`] at the next frame's mid-exposure, the catalog's
//!                     stars there ([`Solver::predict`]), handed to the tracker
//!                     ([`Tracker::predict_next`]); the attitude stage then takes each star's
//!                     identity from its window ([`Solver::update_with_identities`])
//!                  -> housekeeping (Health): the frame's counters, the temperature and its
//!                     source, the uptime
//! ```
//!
//! The next frame's mid-exposure is this frame's plus the interval between this frame's
//! and the last one's (the frame cycle's own mid-exposure times; none before two frames, so
//! the first frames track on their own stars). No prediction (no rate yet, the attitude
//! lost for longer than [`PREDICT_MAX_AGE_US`], fewer than [`MIN_PREDICTED`] stars on the
//! sensor) leaves the tracker to its own rules: windows on its last stars, a full frame when
//! it loses them or every `reacquire_every` frames.
//!
//! A home binds its hardware to the ports ([`CyclePorts`], the line source, the link's
//! table store and window reader, the sync pulse) and calls [`FrameCycle::run_frame`] once a
//! frame, with [`FrameCycle::receive`], [`FrameCycle::poll`], [`FrameCycle::sync`] and
//! [`FrameCycle::transmit`] between frames as its link allows; it decides nothing about a
//! frame itself.
//!
//! Mid-exposure, the instant a report is tagged with, is the middle of the frame's
//! integration as its line source saw it ([`crate::tracker::Integration`]): on the board
//! from the end of the frame transfer that opened the previous frame's program to the start
//! of the one that opens this frame's (the CCD is frame-transfer: the image a frame reads
//! was integrated under the previous program, for its exposure or its readout, whichever
//! was longer, docs/sequencer.md). A source that does not know gives none, and the tag is
//! then the frame's start less half the previous frame's configured exposure, held at the
//! counter's 0 where it would fall before it.
//!
//! Cost: the tracker's frame ([`crate::tracker`]), the link's star list and report encoding
//! ([`crate::link`]), the attitude stage when a catalog is given ([`crate::solver`]), the
//! catalog prediction of the next frame's windows ([`crate::predict`]), and a few additions
//! for housekeeping. Memory: the tracker (owned), a borrowed
//! [`LinkService`], the solver (a catalog reference and a prior).

use crate::link::telemetry::Housekeeping;
use crate::link::{LinkService, TableInfo, TableUpload, Targets, WindowReader};
use crate::predict::{PredictConfig, PredictedStars};
use crate::safe::{Health, ThermoSource};
use crate::solver::{Fix, SolveError, Solver};
use crate::time::{SpacecraftClock, SyncPulse};
use crate::tracker::{
    Clock, Event, FrameSummary, LineSource, LineSummary, Mode, Ports, StarRecord, TableStore,
    TelemetrySink, Thermometer, Tracker,
};
use crate::units::Kelvin;

/// A thermometer that says which sensor gave its last reading, for housekeeping.
pub trait SourcedThermometer: Thermometer {
    /// The sensor of the last reading ([`ThermoSource::None`] when it gave none).
    fn source(&self) -> ThermoSource;
}

impl SourcedThermometer for crate::tracker::FixedTemperature {
    fn source(&self) -> ThermoSource {
        match self.0 {
            Some(_) => ThermoSource::External,
            None => ThermoSource::None,
        }
    }
}

impl<E: Thermometer, M: Thermometer> SourcedThermometer for crate::safe::FallbackThermometer<E, M> {
    fn source(&self) -> ThermoSource {
        crate::safe::FallbackThermometer::source(self)
    }
}

/// What a home provides to a frame besides its lines.
pub struct CyclePorts<'p, 't> {
    /// Time.
    pub clock: &'p mut dyn Clock,
    /// Sensor temperature.
    pub thermometer: &'p mut dyn SourcedThermometer,
    /// The calibration table the frame uses.
    pub tables: &'p mut dyn TableStore<'t>,
    /// The calibration table the link's store holds in force, as housekeeping reports it
    /// (the store changes only between frames).
    pub table_in_force: Option<TableInfo>,
    /// The home's own sink for the tracker's records (a log, a recorder), besides the link.
    pub telemetry: &'p mut dyn TelemetrySink,
}

/// What a frame gave: the tracker's summary and the attitude stage's result (`None`
/// without a catalog).
#[derive(Clone, Copy, Debug)]
pub struct FrameOutcome {
    /// The tracker's summary of the frame.
    pub summary: FrameSummary,
    /// The frame's attitude, or why it has none.
    pub attitude: Option<Result<Fix, SolveError>>,
    /// The attitude report sent on the link (`None` without a catalog).
    pub report: Option<crate::link::telemetry::AttitudeReport>,
}

/// The tracker application with its link, its attitude stage and its housekeeping, for up
/// to `N` stars a frame.
pub struct FrameCycle<'t, 'b, 'c, 'l, const N: usize> {
    tracker: Tracker<'t, 'b, N>,
    link: &'l mut LinkService,
    solver: Option<Solver<'c>>,
    health: Health,
    clock: SpacecraftClock,
    rate: crate::attitude::RateFilter,
    velocity: Option<crate::link::Velocity>,
    /// The exposure the last frame's program integrated for, us (`None` before the first).
    last_exposure_us: Option<u64>,
    /// The last frame's mid-exposure, us (`None` before the first).
    last_mid_us: Option<u64>,
    /// The last rate the filter gave (`None` once its window restarts).
    last_rate: Option<crate::attitude::Rate>,
    /// Whether the attitude stage predicts the next frame's windows.
    predicting: bool,
    /// Stars the tracker took from the last prediction, for its next frame.
    predicted: usize,
}

/// The attitude stage predicts the next frame's windows from an attitude at most this old
/// at the next frame's mid-exposure, us: a fix that stops coming (stars lost, a bad frame)
/// is propagated by the rate for this long before the tracker is left to its own rules.
pub const PREDICT_MAX_AGE_US: u64 = 500_000;

/// Fewest stars a prediction must hold to be handed to the tracker (identification's
/// fewest).
pub const MIN_PREDICTED: usize = crate::ident::MIN_MATCHES;

/// A velocity is applied to frames within this of its time, s: a low orbit's velocity turns
/// by 4 degrees a minute, 0.4" of aberration at 7.7 km/s.
pub const VELOCITY_MAX_AGE_S: f64 = 60.0;

/// The platform's largest angular acceleration a cycle assumes until it is told
/// ([`FrameCycle::set_max_acceleration`]), rad/s^2: 1 deg/s^2.
pub const DEFAULT_MAX_ACCEL_RAD_S2: f64 = 0.017_453_292_519_943_295;

/// The home's sink and the link, each given every record.
struct Both<'a> {
    home: &'a mut dyn TelemetrySink,
    link: &'a mut LinkService,
}

impl TelemetrySink for Both<'_> {
    fn line(&mut self, summary: &LineSummary) {
        self.home.line(summary);
        self.link.line(summary);
    }

    fn star(&mut self, frame: u32, star: &StarRecord) {
        self.home.star(frame, star);
        self.link.star(frame, star);
    }

    fn frame(&mut self, summary: &FrameSummary) {
        self.home.frame(summary);
        self.link.frame(summary);
    }

    fn event(&mut self, event: &Event) {
        self.home.event(event);
        self.link.event(event);
    }
}

impl<'t, 'b, 'c, 'l, const N: usize> FrameCycle<'t, 'b, 'c, 'l, N> {
    /// The cycle of `tracker`, serving `link`, with the attitude stage `solver` (none: no
    /// attitude), starting from the housekeeping `health` (its boot fields: the fault record,
    /// the set-up faults, the tables in force).
    pub fn new(
        tracker: Tracker<'t, 'b, N>,
        link: &'l mut LinkService,
        solver: Option<Solver<'c>>,
        health: Health,
    ) -> Self {
        link.set_setup_faults(health.setup_faults.bits());
        Self {
            tracker,
            link,
            solver,
            health,
            clock: SpacecraftClock::new(),
            rate: crate::attitude::RateFilter::new(DEFAULT_MAX_ACCEL_RAD_S2),
            velocity: None,
            last_exposure_us: None,
            last_mid_us: None,
            last_rate: None,
            predicting: true,
            predicted: 0,
        }
    }

    /// Whether the attitude stage predicts the next frame's windows from the catalog (on by
    /// default; off, tracking places its windows on its own last stars and reacquires every
    /// `reacquire_every` frames). Takes effect from the next frame.
    pub fn set_predicting(&mut self, on: bool) {
        self.predicting = on;
        if !on {
            self.tracker.predict_next(&[]);
        }
    }

    /// The platform's largest angular acceleration, rad/s^2 (from the spacecraft's
    /// specification): until the rate filter has the 4 attitudes that measure the
    /// acceleration, each attitude's covariance carries what this much acceleration could
    /// shift a star's mean position over the exposure by, and the rate's what it could make
    /// the rate lag by ([`crate::attitude::RateFilter`]). Forgets the rate filter's window.
    pub fn set_max_acceleration(&mut self, max_accel_rad_s2: f64) {
        self.rate = crate::attitude::RateFilter::new(max_accel_rad_s2);
        self.last_rate = None;
    }

    /// Stars the attitude stage predicted for the next frame (0: none, the tracker follows
    /// its own rules).
    pub fn predicted(&self) -> usize {
        self.predicted
    }

    /// The spacecraft clock model the reports are tagged by.
    pub fn spacecraft_clock(&self) -> &SpacecraftClock {
        &self.clock
    }

    /// Takes the sync pulses `pulses` has seen since the last call (between frames, as
    /// often as the home likes: each pulse carries its own counter value). A home calls it
    /// before [`Self::receive`], so that a time-set command applies to a pulse after it.
    pub fn sync(&mut self, pulses: &mut dyn SyncPulse) {
        self.clock.poll(pulses);
    }

    /// The tracker application.
    pub fn tracker(&self) -> &Tracker<'t, 'b, N> {
        &self.tracker
    }

    /// The tracker application, for a home's direct commands (its set-up, the host tools'
    /// mode sequence).
    pub fn tracker_mut(&mut self) -> &mut Tracker<'t, 'b, N> {
        &mut self.tracker
    }

    /// The link service.
    pub fn link(&self) -> &LinkService {
        self.link
    }

    /// The link's housekeeping report now, with `table_in_force` the calibration table the
    /// link's store holds in force.
    pub fn housekeeping(&self, table_in_force: Option<TableInfo>) -> Housekeeping {
        self.link.housekeeping(table_in_force)
    }

    /// Housekeeping as of the last frame.
    pub fn health(&self) -> &Health {
        &self.health
    }

    /// The attitude stage (none without a catalog).
    pub fn solver(&self) -> Option<&Solver<'c>> {
        self.solver.as_ref()
    }

    /// Sets the time the link stamps telemetry with (the home's clock, us).
    pub fn set_link_time(&mut self, now_us: u64) {
        self.link.set_time(now_us);
    }

    /// Takes bytes the link received, executing every telecommand they complete on the
    /// tracker, `tables` and `windows`; a time-set command goes to the spacecraft clock, for
    /// the next pulse [`Self::sync`] takes.
    pub fn receive(
        &mut self,
        bytes: &[u8],
        tables: &mut dyn TableUpload,
        windows: &mut dyn WindowReader,
    ) {
        let mut targets = Targets {
            tracker: &mut self.tracker,
            tables,
            windows,
        };
        self.link.receive(bytes, &mut targets);
        if let Some(t) = self.link.take_time_set() {
            self.clock.command_set(t);
        }
        if let Some(v) = self.link.take_velocity() {
            self.velocity = Some(v);
        }
    }

    /// The link's work between frames: diagnostic window rows as its queue has room, the
    /// in-flight defect commit's next step.
    pub fn poll(&mut self, tables: &mut dyn TableUpload, windows: &mut dyn WindowReader) {
        let mut targets = Targets {
            tracker: &mut self.tracker,
            tables,
            windows,
        };
        self.link.poll(&mut targets);
    }

    /// Copies queued telemetry into `out` (urgent first); returns the bytes written.
    pub fn transmit(&mut self, out: &mut [u8]) -> usize {
        self.link.transmit(out)
    }

    /// A reset was commanded and acknowledged: the home resets once the queues are sent.
    pub fn reset_requested(&self) -> bool {
        self.link.reset_requested()
    }

    /// Runs one frame from `source` and everything after it: the link's housekeeping, the
    /// attitude stage (its report on the link), the frame's housekeeping. A source error ends
    /// the frame early, as [`Tracker::run_frame`] does, and skips the rest.
    pub async fn run_frame<S: LineSource>(
        &mut self,
        source: &mut S,
        ports: &mut CyclePorts<'_, 't>,
    ) -> Result<FrameOutcome, S::Error> {
        let mut noted = Noted {
            inner: &mut *ports.thermometer,
            last_k: None,
        };
        let mut telemetry = Both {
            home: &mut *ports.telemetry,
            link: &mut *self.link,
        };
        let mut tracker_ports = Ports {
            clock: &mut *ports.clock,
            thermometer: &mut noted,
            tables: &mut *ports.tables,
            telemetry: &mut telemetry,
        };
        let summary = self.tracker.run_frame(source, &mut tracker_ports).await?;
        let (last_k, source_used) = (noted.last_k, noted.source());
        self.link.end_of_frame(ports.table_in_force);
        let exposure_us = u64::from(self.tracker.config().exposure_ms) * 1000;
        let integrated_us = self.last_exposure_us.unwrap_or(exposure_us);
        self.last_exposure_us = Some(exposure_us);
        let integration = source.integration();
        let mid_us = integration.map_or_else(
            || summary.start_us.saturating_sub(integrated_us / 2),
            |i| i.mid_us(),
        );
        let integration_s = integration.map_or(integrated_us, |i| i.duration_us()) as f64 * 1e-6;
        let mut report = None;
        let attitude = self.solver.as_mut().map(|solver| {
            let time = self.clock.time_of(mid_us);
            // The velocity, when the frame's spacecraft time is known and near its time.
            let velocity = match (time, self.velocity) {
                (Ok(t), Some(v))
                    if libm::fabs(t.cuc.to_seconds() - v.at.to_seconds()) <= VELOCITY_MAX_AGE_S =>
                {
                    Some(v.v_m_s)
                }
                _ => None,
            };
            let (result, aberration_applied) = solver.update_with_identities(
                self.tracker.stars(),
                self.tracker.identities(),
                mid_us,
                velocity,
            );
            // Under an acceleration the stars' centroids are past their mid-exposure
            // positions: the attitude is turned back to its middle by the acceleration the
            // rate filter measured up to the last frame (none yet: the platform's bound in
            // the covariance), how far depending on the trails' length against the PSF,
            // from the last rate across the boresight. The filter is given the attitude at
            // mid-exposure, so that its samples are the motion's own.
            let accel = self.rate.acceleration();
            let trail_px = self.last_rate.map_or(0.0, |r| {
                libm::hypot(r.w_rad_s[0], r.w_rad_s[1])
                    * integration_s
                    * solver.camera().focal_length_px
            });
            let psf_px = f64::from(self.tracker.config().psf_sigma_px());
            let width_px = libm::sqrt(psf_px * psf_px + 1.0 / 12.0);
            let k = crate::centroid::trail_fit::accel_offset_fraction(trail_px, width_px);
            let result = result.map(|mut fix| {
                fix.attitude = accel.mid_exposure(
                    &fix.attitude,
                    integration_s,
                    k,
                    crate::centroid::trail_fit::ACCEL_OFFSET_SIGMA,
                );
                fix
            });
            // The rate of the attitudes so far, this frame's the newest (none without it).
            let rate = result
                .as_ref()
                .ok()
                .and_then(|f| self.rate.push(f.time_us, &f.attitude));
            if result.is_ok() {
                self.last_rate = rate;
                // An acquisition's attitude without a rate: acquire once more for the rate
                // rather than track stars whose motion is not known.
                if rate.is_none() && self.predicting && summary.mode == Mode::Acquisition {
                    self.tracker.acquire_again();
                }
            }
            let mut r = crate::link::telemetry::AttitudeReport::of(
                summary.frame,
                &result,
                mid_us,
                time,
                rate,
                aberration_applied,
            );
            r.flags |= crate::link::telemetry::Validity::of_obstructions(summary.obstructions);
            let latency = ports.clock.now_us().saturating_sub(mid_us);
            r.latency_us = u32::try_from(latency).unwrap_or(u32::MAX);
            self.link.send_attitude(&r);
            report = Some(r);
            result
        });
        self.predict_next(mid_us);
        self.last_mid_us = Some(mid_us);
        self.health.on_frame(&summary);
        self.health.on_temperature(last_k, source_used);
        self.health.uptime_ms = ports.clock.now_us() / 1000;
        Ok(FrameOutcome {
            summary,
            attitude,
            report,
        })
    }
}

impl<const N: usize> FrameCycle<'_, '_, '_, '_, N> {
    /// Hands the tracker the catalog's stars at the next frame's mid-exposure, this frame's
    /// `mid_us` plus the last interval, or clears its prediction when there is none.
    fn predict_next(&mut self, mid_us: u64) {
        let mut out = PredictedStars::new();
        let interval_us = self
            .last_mid_us
            .and_then(|last| mid_us.checked_sub(last))
            .filter(|&d| d > 0);
        if let (true, Some(solver), Some(rate), Some(interval_us)) = (
            self.predicting,
            self.solver.as_ref(),
            self.last_rate.as_ref(),
            interval_us,
        ) {
            let next_mid_us = mid_us.saturating_add(interval_us);
            let fresh = solver
                .prior()
                .is_some_and(|(_, t)| next_mid_us.saturating_sub(t) <= PREDICT_MAX_AGE_US);
            let g = self.tracker.geometry();
            let active = [g.active_cols, g.active_rows];
            let exposure_s = f64::from(self.tracker.config().exposure_ms) * 1e-3;
            let cfg = PredictConfig::flight(self.tracker.config().window_px);
            let predicted = fresh
                && solver
                    .predict(
                        rate,
                        self.rate.acceleration().alpha_rad_s2,
                        next_mid_us,
                        exposure_s,
                        interval_us as f64 * 1e-6,
                        active,
                        &cfg,
                        &mut out,
                    )
                    .is_ok();
            if !predicted || out.len() < MIN_PREDICTED {
                out.clear();
            }
        }
        self.predicted = self.tracker.predict_next(&out);
    }
}

/// The home's thermometer, its last reading kept for housekeeping.
struct Noted<'a> {
    inner: &'a mut dyn SourcedThermometer,
    last_k: Option<Kelvin>,
}

impl Noted<'_> {
    fn source(&self) -> ThermoSource {
        match self.last_k {
            Some(_) => self.inner.source(),
            None => ThermoSource::None,
        }
    }
}

impl Thermometer for Noted<'_> {
    fn sensor_temperature_k(&mut self) -> Option<Kelvin> {
        self.last_k = self.inner.sensor_temperature_k();
        self.last_k
    }
}
