//! The ports: what a home (the board, the host tools, the software-in-the-loop) supplies to
//! the tracker application, as small traits. What the application asks of the sensor each
//! frame is a [`ReadoutRequest`].
//!
//! | port | the board | the host (`process`, `sil`) |
//! |---|---|---|
//! | [`LineSource`] | the CCD sequencer's readout of what the request reads, ADC lines by DMA, and the instants of its frame transfers ([`Integration`]) | a FITS frame, or the simulated CCD47-20 rendering only what the request reads (its exposure after the frame's start) |
//! | [`Clock`] | the MCU timer | frame number x frame period |
//! | [`Thermometer`] | the CCD board's sensor | a fixed value or the FITS keyword |
//! | [`TableStore`] | the flash slot in force | a table file |
//! | [`TelemetrySink`] | the log and the link's telemetry queues (dropped and counted when full) | CSV rows |
//!
//! The line source is async so that the same frame loop ([`super::Tracker::run_frame`])
//! awaits DMA on the board and runs to completion at once on the host. Everything else is
//! called between lines or frames and must not block: a telemetry sink that cannot send a
//! record counts it as lost rather than wait.

use super::record::{Event, FrameSummary, LineSummary, StarRecord};
use crate::readout::ReadoutRequest;
use crate::table::CalibTable;
use crate::units::Kelvin;

/// One raw line as a source delivers it.
#[derive(Clone, Copy, Debug)]
pub struct SourceLine<'a> {
    /// Raw line index within the frame, 0-based, increasing within a frame.
    pub line: u16,
    /// The whole raw line (`geometry.line_len()` samples, ADU); samples the request does not
    /// read may hold anything.
    pub samples: &'a [u16],
}

/// When the image a frame reads was integrated, on the home's clock ([`Clock`], us): from
/// the end of the frame transfer that opened the integration to the start of the one that
/// closed it (on the board the sequencer's frame transfers; a home with a model of the
/// sensor, its model's). The frame cycle tags the frame's attitude at its middle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Integration {
    /// The integration's start, us.
    pub start_us: u64,
    /// Its end, us (not before `start_us`).
    pub end_us: u64,
}

impl Integration {
    /// The middle, us.
    pub const fn mid_us(&self) -> u64 {
        self.start_us + self.end_us.saturating_sub(self.start_us) / 2
    }

    /// The length, us.
    pub const fn duration_us(&self) -> u64 {
        self.end_us.saturating_sub(self.start_us)
    }
}

/// Raw lines in readout order.
#[allow(
    async_fn_in_trait,
    reason = "the tracker and its sources run on one executor; no Send bound is wanted"
)]
pub trait LineSource {
    /// Why a frame could not be read (the frame then ends early; lines already given stay).
    type Error;

    /// Starts reading frame `frame` as `request` says (on the board: the sequencer's
    /// program; in the SIL: what is rendered).
    async fn start_frame(
        &mut self,
        frame: u32,
        request: &ReadoutRequest<'_>,
    ) -> Result<(), Self::Error>;

    /// The frame's next line, or `None` when the frame is over. The line stays valid until
    /// the next call.
    async fn next_line(&mut self) -> Result<Option<SourceLine<'_>>, Self::Error>;

    /// When the image of the frame being read was integrated: known once the frame's first
    /// line is in (a source may know it from the frame's start), asked before each line and
    /// once its lines have ended. The tracker takes its tracked stars' trails over it, the
    /// frame cycle tags the attitude at its middle. `None` when the source does not know (a
    /// recorded frame, a frame that read no line): trailed stars are then flagged
    /// [`super::StarFlags::TRAIL_UNKNOWN`], and the frame cycle takes the configured
    /// exposure before the frame's start.
    fn integration(&self) -> Option<Integration> {
        None
    }
}

/// The home's clock.
pub trait Clock {
    /// Microseconds since an epoch the home defines (monotonic).
    fn now_us(&mut self) -> u64;
}

/// The sensor's temperature.
pub trait Thermometer {
    /// The CCD's temperature now, K; `None` when no reading is available (the table's
    /// hot-pixel reference temperature is then used, and the frame summary says so).
    fn sensor_temperature_k(&mut self) -> Option<Kelvin>;
}

/// The calibration table in force.
pub trait TableStore<'t> {
    /// The checked table to calibrate the next frame with, or `None` (no star processing).
    /// Called at each frame start, so a new table takes effect at a frame boundary.
    fn active_table(&mut self) -> Option<CalibTable<'t>>;
}

/// Where the application's records go. Must not block.
pub trait TelemetrySink {
    /// One line's record (every `line_summary_every`th line).
    fn line(&mut self, _summary: &LineSummary) {}
    /// One star of frame `frame` (called for each reported star, before the frame's summary).
    fn star(&mut self, frame: u32, star: &StarRecord);
    /// The frame's summary, after its stars.
    fn frame(&mut self, summary: &FrameSummary);
    /// An event (mode and table changes).
    fn event(&mut self, event: &Event);
}

/// The ports other than the line source, for [`super::Tracker::run_frame`].
pub struct Ports<'p, 't> {
    /// Time.
    pub clock: &'p mut dyn Clock,
    /// Sensor temperature.
    pub thermometer: &'p mut dyn Thermometer,
    /// The calibration table.
    pub tables: &'p mut dyn TableStore<'t>,
    /// Telemetry.
    pub telemetry: &'p mut dyn TelemetrySink,
}

/// A table store that always gives the same table (the host tools, and the board until
/// tables can be updated in flight).
#[derive(Clone, Copy, Debug)]
pub struct FixedTable<'t>(pub Option<CalibTable<'t>>);

impl<'t> TableStore<'t> for FixedTable<'t> {
    fn active_table(&mut self) -> Option<CalibTable<'t>> {
        self.0
    }
}

/// A thermometer that always reads the same (`None`: no sensor).
#[derive(Clone, Copy, Debug)]
pub struct FixedTemperature(pub Option<Kelvin>);

impl Thermometer for FixedTemperature {
    fn sensor_temperature_k(&mut self) -> Option<Kelvin> {
        self.0
    }
}
