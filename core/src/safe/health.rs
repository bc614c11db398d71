//! Housekeeping: the tracker's state in one struct the link reports (mode, faults, counters
//! kept across resets and since boot, the table in force, temperature, uptime). The home
//! updates it from the frame summaries and the store; it allocates nothing and costs a few
//! additions per frame.

use super::fault::{FaultRecord, SetupFaults};
use super::temperature::ThermoSource;
use crate::store::ActiveTable;
use crate::tracker::{FrameSummary, Mode};
use crate::units::Kelvin;

/// Which table is in force: the link reports it as (sequence, CRC).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TableId {
    /// The store's sequence number of the upload that put it in force.
    pub sequence: u32,
    /// CRC-32/ISO-HDLC of its bytes.
    pub crc32: u32,
    /// Its length, bytes.
    pub len_b: u32,
}

impl From<ActiveTable> for TableId {
    fn from(a: ActiveTable) -> Self {
        Self {
            sequence: a.header.sequence,
            crc32: a.header.crc32,
            len_b: a.header.len_b,
        }
    }
}

/// The housekeeping record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Health {
    /// The last frame's mode (standby until a frame ran).
    pub mode: Mode,
    /// This boot's set-up faults (empty: all set up).
    pub setup_faults: SetupFaults,
    /// The counters kept across resets.
    pub record: FaultRecord,
    /// Frames run since boot.
    pub frames: u32,
    /// Frames since boot that ran without a calibration table.
    pub frames_uncalibrated: u32,
    /// Lines refused since boot (summed from the frame summaries).
    pub lines_refused: u32,
    /// Stars lost since boot: candidates and windows dropped, ring-lost, calibration failed,
    /// stars not reported (summed from the frame summaries).
    pub stars_lost: u32,
    /// Windows lost in tracking since boot.
    pub track_lost: u32,
    /// The calibration table in force.
    pub calibration: Option<TableId>,
    /// The catalog in force.
    pub catalog: Option<TableId>,
    /// The last frame's sensor temperature, K (`None`: no reading).
    pub temperature_k: Option<Kelvin>,
    /// Where it came from.
    pub temperature_source: ThermoSource,
    /// Time since boot, ms.
    pub uptime_ms: u64,
}

impl Health {
    /// Housekeeping at boot, with the record as loaded and this boot's set-up faults.
    pub const fn new(record: FaultRecord, setup_faults: SetupFaults) -> Self {
        Self {
            mode: Mode::Standby,
            setup_faults,
            record,
            frames: 0,
            frames_uncalibrated: 0,
            lines_refused: 0,
            stars_lost: 0,
            track_lost: 0,
            calibration: None,
            catalog: None,
            temperature_k: None,
            temperature_source: ThermoSource::None,
            uptime_ms: 0,
        }
    }

    /// Counts a frame's summary.
    pub fn on_frame(&mut self, s: &FrameSummary) {
        self.mode = s.mode;
        self.frames = self.frames.saturating_add(1);
        if !s.calibrated {
            self.frames_uncalibrated = self.frames_uncalibrated.saturating_add(1);
        }
        self.lines_refused = self
            .lines_refused
            .saturating_add(u32::from(s.lines_refused));
        let lost = s
            .candidates_dropped
            .saturating_add(u32::from(s.windows_dropped))
            .saturating_add(u32::from(s.ring_lost))
            .saturating_add(u32::from(s.calib_failed))
            .saturating_add(u32::from(s.stars_dropped));
        self.stars_lost = self.stars_lost.saturating_add(lost);
        self.track_lost = self.track_lost.saturating_add(u32::from(s.track_lost));
    }

    /// Notes the thermometer's last reading and source.
    pub(crate) fn on_temperature(&mut self, k: Option<Kelvin>, source: ThermoSource) {
        self.temperature_k = k;
        self.temperature_source = source;
    }
}
