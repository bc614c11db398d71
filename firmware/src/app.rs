//! The tracker task: the core's tracker application ([`startrack_core::tracker`]) bound to
//! the board's ports and run frame after frame. Everything from a raw line to a reported
//! star happens in the core; this file only says where lines, time, temperature, the table
//! and the telemetry come from on this board.
//!
//! | port | on this board |
//! |---|---|
//! | lines | [`ChannelLines`]: the readout task's DMA'd line buffers ([`crate::lines`]) |
//! | clock | embassy-time's `Instant` |
//! | temperature | [`BoardThermometer`]: the CCD board's sensor (not wired yet), else the MCU's ([`crate::mcu_temp`]) |
//! | table | the calibration table in force in flash bank 2, copied to RAM at start-up ([`crate::flash_store`]), or none; uploads through the link go to the flash store ([`crate::flash_store::with_link_tables`]) and are used from the next start |
//! | telemetry | the defmt log ([`crate::telemetry`]) |
//!
//! After every frame the task marks the watchdog's progress ([`crate::watchdog`]) and adds
//! the frame to housekeeping ([`crate::safe_state::HEALTH`]).
//!
//! The readout free-runs without a sequencer, so the tracker's [`ReadoutRequest`] is not
//! sent anywhere yet: every line is read whole, which serves any request. The exposure is
//! taken as one frame period of the timer-paced readout.

use crate::lines::{FILLED, FREE, GEOMETRY, LineBuf, RawLine};
use crate::mcu_temp::{McuThermometer, NoBoardSensor};
use crate::readout::LINE_PERIOD;
use crate::telemetry::DefmtTelemetry;
use crate::{safe_state, watchdog};
use core::convert::Infallible;
use startrack_core::safe::{FallbackThermometer, SetupFaults};
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    Clock, FixedTable, LineSource, Ports, ReadoutRequest, SourceLine, Tracker, TrackerBuffers,
    TrackerConfig,
};

/// The board's sensor temperature: the CCD board's sensor, else the MCU's.
pub type BoardThermometer = FallbackThermometer<NoBoardSensor, McuThermometer>;

/// Stars a frame the board keeps (candidates, windows, reported stars).
pub const MAX_STARS: usize = 32;

/// Exposure assumed for the hot-pixel law: one frame period of the timer-paced readout.
const EXPOSURE_MS: u32 = (GEOMETRY.lines as u64 * LINE_PERIOD.as_millis()) as u32;

/// The line buffers of the readout task as the tracker's line source. A frame is the run
/// of lines the readout numbered with one frame number; the buffer handed out last goes
/// back to the readout at the next call.
pub struct ChannelLines {
    /// The buffer lent by the last `next_line`.
    lent: Option<&'static mut LineBuf>,
    /// A line of the next frame, received while looking for the end of this one.
    held: Option<RawLine>,
    /// The readout frame being delivered (`None` until its first line).
    frame: Option<u32>,
    /// The frame's last line was delivered.
    ended: bool,
}

impl ChannelLines {
    /// A source that takes the readout's lines from the next one on.
    pub const fn new() -> Self {
        Self {
            lent: None,
            held: None,
            frame: None,
            ended: false,
        }
    }

    /// Gives the lent buffer back to the readout.
    fn release(&mut self) {
        if let Some(buf) = self.lent.take()
            && FREE.try_send(buf).is_err()
        {
            // Cannot happen: FREE holds as many entries as there are buffers.
            defmt::error!("lines: free-buffer channel full, a line buffer is lost");
        }
    }
}

impl LineSource for ChannelLines {
    type Error = Infallible;

    async fn start_frame(
        &mut self,
        _frame: u32,
        _request: &ReadoutRequest<'_>,
    ) -> Result<(), Infallible> {
        self.release();
        self.frame = None;
        self.ended = false;
        Ok(())
    }

    async fn next_line(&mut self) -> Result<Option<SourceLine<'_>>, Infallible> {
        self.release();
        if self.ended {
            return Ok(None);
        }
        let raw = match self.held.take() {
            Some(raw) => raw,
            None => FILLED.receive().await,
        };
        match self.frame {
            Some(f) if f != raw.frame => {
                // A line of the next frame: this frame lost its last lines.
                self.held = Some(raw);
                self.ended = true;
                return Ok(None);
            }
            Some(_) => {}
            None => self.frame = Some(raw.frame),
        }
        self.ended = raw.line + 1 >= GEOMETRY.lines;
        let line = raw.line;
        let samples: &LineBuf = self.lent.insert(raw.samples);
        Ok(Some(SourceLine {
            line,
            samples: &samples[..],
        }))
    }
}

/// embassy-time as the tracker's clock.
struct BoardClock;

impl Clock for BoardClock {
    fn now_us(&mut self) -> u64 {
        embassy_time::Instant::now().as_micros()
    }
}

/// The tracker task: the flight configuration with this board's exposure, frame after
/// frame. A configuration the core refuses (which the constants here cannot produce) is
/// logged, the safe standby is entered ([`safe_state::enter_standby`]) and the task ends.
/// (Ending rather than idling keeps the refused tracker out of the task's state: an await in
/// that branch would hold it there beside the running one.)
#[embassy_executor::task]
pub async fn tracker_task(
    table: Option<CalibTable<'static>>,
    buffers: &'static mut TrackerBuffers,
    mut thermometer: BoardThermometer,
) {
    let config = TrackerConfig {
        exposure_ms: EXPOSURE_MS,
        max_stars: MAX_STARS as u16,
        ..TrackerConfig::FLIGHT
    };
    let mut tracker = match Tracker::<MAX_STARS>::new(config, GEOMETRY, buffers) {
        Ok(t) => t,
        Err(e) => {
            defmt::error!("tracker: configuration refused: {}", e);
            safe_state::enter_standby(SetupFaults::TRACKER_CONFIG);
            return;
        }
    };
    let mut source = ChannelLines::new();
    let mut clock = BoardClock;
    let mut store = crate::flash_store::HeldTables::new();
    let mut tables = FixedTable(table);
    let mut log = DefmtTelemetry;
    let Some(link) = crate::link::SERVICE
        .try_uninit()
        .map(|slot| slot.write(startrack_core::link::LinkService::new()))
    else {
        defmt::error!("link service already taken");
        return;
    };
    loop {
        crate::flash_store::with_link_tables(&mut store, |tables| {
            crate::link::serve(link, &mut tracker, tables);
        });
        if link.reset_requested() {
            // Let the transmit task send the acceptance, then reset.
            embassy_time::Timer::after_millis(50).await;
            cortex_m::peripheral::SCB::sys_reset();
        }
        let mut telemetry = crate::link::Tee {
            log: &mut log,
            link: &mut *link,
        };
        let mut ports = Ports {
            clock: &mut clock,
            thermometer: &mut thermometer,
            tables: &mut tables,
            telemetry: &mut telemetry,
        };
        let Ok(summary) = tracker.run_frame(&mut source, &mut ports).await;
        link.end_of_frame(&store);
        watchdog::progress();
        let (k, source_used) = (thermometer.last_k(), thermometer.source());
        safe_state::update_health(|h| {
            h.on_frame(&summary);
            h.on_temperature(k, source_used);
        });
    }
}
