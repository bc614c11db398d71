//! The tracker task: the core's tracker application ([`startrack_core::tracker`]) bound to
//! the board's ports and run frame after frame, the same on every board. Everything from a
//! raw line to a reported star happens in the core; this file only says where lines, time,
//! temperature, the table and the telemetry come from.
//!
//! | port | bound to |
//! |---|---|
//! | lines | [`ChannelLines`]: the request to the board's line path ([`crate::lines::REQUESTS`]; on the STM32H743 the sequencer), its line buffers back ([`crate::lines::FILLED`]), each with the frame's integration from the line path's frame transfers |
//! | clock | embassy-time's `Instant` (the board's time driver) |
//! | sync pulse | the board's capture of the PPS line ([`crate::pps`]; on the STM32H743 TIM5), taken between frames before the link |
//! | temperature | the board's `Thermometer` (on the STM32H743 the CCD board's TMP117, else the MCU's) |
//! | table | the calibration table in force in the board's table store, copied to RAM at start-up ([`crate::flash_store`]), or none; uploads through the link, and the in-flight defect commit (`TC[133,7]`, moved on by `LinkService::poll` between frames), go to the flash store ([`crate::flash_store::with_link_tables`]) and are used from the next start |
//! | telemetry | the defmt log ([`crate::telemetry`]) |
//!
//! The frame and what follows it (the link's housekeeping, the attitude stage with the
//! catalog in flash, [`crate::catalog`], and the table's camera model or the nominal 15
//! degree camera, its report on the link, housekeeping) are the core's frame cycle
//! ([`startrack_core::cycle`]); this task logs the attitude, marks the watchdog's progress
//! ([`crate::watchdog`]) and publishes the cycle's housekeeping ([`crate::safe_state::HEALTH`]).
//!
//! Each frame's [`ReadoutRequest`] (full frame, or the tracking windows) and the configured
//! exposure go to the board's line path (on the STM32H743 the CCD sequencer, which compiles
//! and plays that frame next); only the lines its plan digitises come back. After each frame
//! the board sees its outcome too (`board::after_frame`).

use crate::board::Thermometer;
use crate::lines::{FILLED, FREE, FrameRequest, GEOMETRY, LineBuf, REQUESTS, RawLine};
use crate::telemetry::DefmtTelemetry;
use crate::{board, safe_state, watchdog};
use core::convert::Infallible;
use startrack_core::attitude::Camera;
use startrack_core::catalog::Catalog;
use startrack_core::cycle::{CyclePorts, FrameCycle};
use startrack_core::link::TableUpload;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::readout::ReadoutRequest;
use startrack_core::safe::SetupFaults;
use startrack_core::solver::{Solver, SolverConfig};
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    Clock, FixedTable, Integration, LineSource, SourceLine, Tracker, TrackerBuffers, TrackerConfig,
};

/// Stars a frame the board keeps (candidates, windows, reported stars).
pub const MAX_STARS: usize = 32;

/// The exposure at start-up, ms: the flight configuration's (39 ms: a 30-window tracking
/// frame integrates for it and cycles in 49.4 ms; a full frame, read in 0.6 s, integrates
/// for its readout, docs/sequencer.md); a command sets another.
const EXPOSURE_MS: u32 = TrackerConfig::FLIGHT.exposure_ms;

/// How long a line may take beyond the exposure before the frame is ended without it (a
/// full frame's readout is 0.55 s at 1 MHz).
const LINE_TIMEOUT_US: u64 = 1_000_000;

/// The camera the attitude stage assumes without a fitted one in the table: the CCD47-20's
/// 1024 x 1024 active area behind a 15 degree field, principal point at the centre, no
/// distortion (focal length 512 / tan(7.5 degrees) px).
fn nominal_camera() -> Camera {
    Camera::pinhole(3889.0261057152775, [511.5, 511.5])
}

/// Centroid 1-sigma the identification's tolerances assume, px.
const IDENT_SIGMA_PX: f64 = 0.2;

/// The board's lines as the tracker's line source. `start_frame` sends the request
/// (windows copied) and the exposure to the board's line path ([`REQUESTS`]), which reads
/// that frame; `next_line` then hands over the lines read for that frame
/// (tagged with its number), in order, up to the one marked last. Lines of older frames
/// are given back unread; a line of a later frame ends this one. The buffer handed out last
/// goes back to the readout at the next call.
pub struct ChannelLines {
    /// The buffer lent by the last `next_line`.
    lent: Option<&'static mut LineBuf>,
    /// A line of a later frame, received while looking for the end of this one.
    held: Option<RawLine>,
    /// The tracker's frame being delivered.
    frame: u32,
    /// The frame's last line was delivered.
    ended: bool,
    /// The frame reads no line (no window): `next_line` waits this long (the exposure, while
    /// the frame is clocked) and ends it, us.
    no_lines_us: Option<u64>,
    /// The exposure sent with each request, us.
    exposure_us: u32,
    /// When the frame's image was integrated, from its lines (the line path's frame
    /// transfers).
    integration: Option<Integration>,
}

impl ChannelLines {
    /// A source that asks for frames with an exposure of `exposure_ms`.
    pub const fn new(exposure_ms: u32) -> Self {
        Self {
            lent: None,
            held: None,
            frame: 0,
            ended: true,
            no_lines_us: None,
            exposure_us: exposure_ms.saturating_mul(1000),
            integration: None,
        }
    }

    /// The exposure of the frames requested from now on.
    pub fn set_exposure_ms(&mut self, exposure_ms: u32) {
        self.exposure_us = exposure_ms.saturating_mul(1000);
    }

    /// Gives the lent buffer back to the readout.
    fn release(&mut self) {
        if let Some(buf) = self.lent.take() {
            give_back(buf);
        }
    }
}

/// Returns a line buffer to the readout.
fn give_back(buf: &'static mut LineBuf) {
    if FREE.try_send(buf).is_err() {
        // Cannot happen: FREE holds as many entries as there are buffers.
        defmt::error!("lines: free-buffer channel full, a line buffer is lost");
    }
}

impl LineSource for ChannelLines {
    type Error = Infallible;

    async fn start_frame(
        &mut self,
        frame: u32,
        request: &ReadoutRequest<'_>,
    ) -> Result<(), Infallible> {
        self.release();
        self.frame = frame;
        self.ended = false;
        self.integration = None;
        // No window: nothing to read (the frame is still clocked, for its exposure).
        self.no_lines_us = matches!(request, ReadoutRequest::Windows(w) if w.is_empty())
            .then_some(u64::from(self.exposure_us));
        REQUESTS.signal(FrameRequest::new(frame, request, self.exposure_us));
        Ok(())
    }

    async fn next_line(&mut self) -> Result<Option<SourceLine<'_>>, Infallible> {
        self.release();
        let timeout =
            embassy_time::Duration::from_micros(u64::from(self.exposure_us) + LINE_TIMEOUT_US);
        if let Some(us) = self.no_lines_us.take() {
            embassy_time::Timer::after_micros(us).await;
            self.ended = true;
        }
        loop {
            if self.ended {
                return Ok(None);
            }
            let raw = match self.held.take() {
                Some(raw) => raw,
                None => match embassy_time::with_timeout(timeout, FILLED.receive()).await {
                    Ok(raw) => raw,
                    Err(_) => {
                        defmt::warn!("lines: frame {} ended, no line in time", self.frame);
                        self.ended = true;
                        return Ok(None);
                    }
                },
            };
            // Wrapping distance of the line's frame from this one.
            let ahead = raw.frame.wrapping_sub(self.frame) as i32;
            if ahead < 0 {
                give_back(raw.samples);
                continue;
            }
            if ahead > 0 {
                // A line of a later frame: this frame lost its last lines.
                self.held = Some(raw);
                self.ended = true;
                return Ok(None);
            }
            self.ended = raw.last;
            self.integration = raw.integration.or(self.integration);
            let line = raw.line;
            let samples: &LineBuf = self.lent.insert(raw.samples);
            return Ok(Some(SourceLine {
                line,
                samples: &samples[..],
            }));
        }
    }

    fn integration(&self) -> Option<Integration> {
        self.integration
    }
}

/// embassy-time as the tracker's clock.
struct BoardClock;

impl Clock for BoardClock {
    fn now_us(&mut self) -> u64 {
        embassy_time::Instant::now().as_micros()
    }
}

/// The tracker task: the core's frame cycle ([`FrameCycle`]) with the flight configuration
/// and this board's exposure, frame after frame; between frames the link is served and the
/// in-flight defect commit moved on, inside the flash store's round
/// ([`crate::flash_store::with_link_tables`]). A configuration the core refuses (which the
/// constants here cannot produce) is logged, the safe standby is entered
/// ([`safe_state::enter_standby`]) and the task ends. (Ending rather than idling keeps the
/// refused tracker out of the task's state: an await in that branch would hold it there
/// beside the running one.)
#[embassy_executor::task]
pub async fn tracker_task(
    table: Option<CalibTable<'static>>,
    catalog: Option<Catalog<'static>>,
    buffers: &'static mut TrackerBuffers,
    mut thermometer: Thermometer,
) {
    let config = TrackerConfig {
        exposure_ms: EXPOSURE_MS,
        max_stars: MAX_STARS as u16,
        ..TrackerConfig::FLIGHT
    };
    let tracker = match Tracker::<MAX_STARS>::new(config, GEOMETRY, buffers) {
        Ok(t) => t,
        Err(e) => {
            defmt::error!("tracker: configuration refused: {}", e);
            safe_state::enter_standby(SetupFaults::TRACKER_CONFIG);
            return;
        }
    };
    let Some(link) = crate::link::SERVICE
        .try_uninit()
        .map(|slot| slot.write(startrack_core::link::LinkService::new()))
    else {
        defmt::error!("link service already taken");
        return;
    };
    // The table's fitted camera model (distortion, lateral colour), else the nominal one.
    let camera = table
        .as_ref()
        .and_then(|t| t.camera_model())
        .unwrap_or_else(nominal_camera);
    let solver = catalog.map(|c| Solver::new(c, SolverConfig::for_camera(camera, IDENT_SIGMA_PX)));
    // Housekeeping starts from what set-up recorded (the fault record, the set-up faults that
    // did not stop the tracker, the tables in force): main has finished set-up before this
    // task first runs.
    let mut cycle = FrameCycle::new(tracker, link, solver, safe_state::health());
    let mut source = ChannelLines::new(EXPOSURE_MS);
    let mut clock = BoardClock;
    let mut store = crate::flash_store::HeldTables::new();
    let mut tables = FixedTable(table);
    let mut log = DefmtTelemetry;
    let mut pulses = crate::pps::BoardPulses;
    loop {
        // The pulses first: a time-set command served next is for a later pulse.
        cycle.sync(&mut pulses);
        crate::flash_store::with_link_tables(&mut store, |uploads| {
            crate::link::serve(&mut cycle, uploads);
        });
        if cycle.reset_requested() {
            // Let the transmit task send the acceptance, then reset.
            embassy_time::Timer::after_millis(50).await;
            crate::board::system_reset(startrack_core::safe::ResetCause::Software);
        }
        source.set_exposure_ms(cycle.tracker().config().exposure_ms);
        let mut ports = CyclePorts {
            clock: &mut clock,
            thermometer: &mut thermometer,
            tables: &mut tables,
            table_in_force: store.active(TABLE_KIND_CALIBRATION),
            telemetry: &mut log,
        };
        let Ok(outcome) = cycle.run_frame(&mut source, &mut ports).await;
        match outcome.attitude {
            Some(Ok(fix)) => defmt::info!(
                "frame {}: attitude {} ({} of {} stars), q = [{}, {}, {}, {}]",
                outcome.summary.frame,
                fix.mode,
                fix.matched,
                fix.used,
                fix.attitude.q.0[0],
                fix.attitude.q.0[1],
                fix.attitude.q.0[2],
                fix.attitude.q.0[3]
            ),
            Some(Err(e)) => defmt::info!("frame {}: no attitude ({})", outcome.summary.frame, e),
            None => {}
        }
        board::after_frame(&outcome, cycle.tracker().stars(), source.integration());
        watchdog::progress();
        safe_state::set_health(cycle.health());
    }
}
