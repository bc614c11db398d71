//! The housekeeping report `TM[3,25]`: the link's and the tracker's counters, the last
//! frame's state and the table in force ([`Housekeeping`]), its field table
//! ([`HK_FIELDS`], from which `docs/protocol.md` is generated) and its encoder. A few stores
//! a field.

use super::super::command::mode_number;
use super::super::upload::TableInfo;
use super::fields::{Writer, type_len};
use crate::tracker::{Mode, TemperatureSource};

/// The link's own counters, since start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkCounters {
    /// Bytes received.
    pub rx_bytes: u32,
    /// Frames decoded into a packet.
    pub packets: u32,
    /// Frames that were not valid COBS or overran the receive buffer.
    pub framing_errors: u32,
    /// Packets whose CRC-16 was wrong.
    pub crc_errors: u32,
    /// Telecommands executed (`TM[1,1]` sent or queued).
    pub accepted: u32,
    /// Telecommands rejected, for any reason (`TM[1,2]`).
    pub rejected: u32,
    /// Telemetry packets queued.
    pub tm_queued: u32,
    /// Telemetry packets dropped because their queue was full (a slow link).
    pub tm_dropped: u32,
    /// Stars not sent because a frame had more than a star list holds.
    pub stars_not_sent: u32,
}

/// The tracker's loss counters summed over every frame since start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameTotals {
    /// Frames ended.
    pub frames: u32,
    /// Lines refused.
    pub lines_refused: u32,
    /// Acquisition candidates lost by the detector's full list.
    pub candidates_dropped: u32,
    /// Acquisition windows that could not wait for their rows.
    pub windows_dropped: u32,
    /// Acquisition windows whose rows had left the line ring.
    pub ring_lost: u32,
    /// Windows that could not be calibrated.
    pub calib_failed: u32,
    /// Tracking windows that could not be placed.
    pub track_refused: u32,
    /// Tracking windows without a star.
    pub track_lost: u32,
    /// Stars not reported because the star list was full.
    pub stars_dropped: u32,
    /// Windows counted as particle hits.
    pub hits: u32,
    /// Detections and windows masked on a bright object.
    pub masked: u32,
}

/// The housekeeping report `TM[3,25]` (structure id 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Housekeeping {
    /// The last frame's mode.
    pub mode: Mode,
    /// The mode the rules give the next frame.
    pub next_mode: Mode,
    /// The last frame had a calibration table.
    pub calibrated: bool,
    /// Where the temperature came from.
    pub temperature_source: TemperatureSource,
    /// Sensor temperature used, K (U16F16 bits in telemetry).
    pub temperature_k_bits: u32,
    /// The last frame's number.
    pub frame: u32,
    /// The last frame's reported stars.
    pub stars: u16,
    /// The last frame's usable centroids.
    pub centroids: u16,
    /// Loss counters since start.
    pub totals: FrameTotals,
    /// Link counters since start.
    pub link: LinkCounters,
    /// The calibration table in force.
    pub table: Option<TableInfo>,
    /// Time since start, us.
    pub uptime_us: u64,
    /// The set-up steps that failed at this boot (`safe::SetupFaults` bits 0-15; 0: none).
    pub setup_faults: u16,
    /// The running dark ratio, covered pixels measured / the dark law's prediction (U8F8
    /// bits; 0: not measured).
    pub dark_ratio_u8f8: u16,
    /// [`status`] bits.
    pub status: u8,
    /// Pixels confirmed in flight that the table in force does not list yet.
    pub defects_pending: u16,
    /// The last frame's windows counted as particle hits (the radiation monitor).
    pub hits: u16,
    /// The last frame's detections and windows masked on a bright object.
    pub masked: u16,
    /// The last frame's [`crate::tracker::Obstructions`] bits.
    pub obstructions: u8,
}

/// Bits of housekeeping's `status` field.
pub mod status {
    /// The running dark ratio is outside the dark law's band.
    pub const DARK_DRIFT: u8 = 1;
}

/// Every housekeeping field in order: name, type, meaning.
pub const HK_FIELDS: [(&str, &str, &str); 42] = [
    ("sid", "u16", "structure id, 1"),
    (
        "mode",
        "u8",
        "last frame's mode (0 standby, 1 acquisition, 2 tracking)",
    ),
    ("next_mode", "u8", "the next frame's mode by the rules"),
    ("calibrated", "u8", "1: a calibration table was in force"),
    (
        "temperature_source",
        "u8",
        "0 sensor, 1 table reference, 2 none",
    ),
    (
        "temperature_k",
        "u32",
        "sensor temperature, K x 65536 (U16F16)",
    ),
    ("frame", "u32", "last frame's number"),
    ("stars", "u16", "last frame's reported stars"),
    ("centroids", "u16", "last frame's usable centroids"),
    ("frames", "u32", "frames since start"),
    ("lines_refused", "u32", "lines refused since start"),
    (
        "candidates_dropped",
        "u32",
        "acquisition candidates lost, since start",
    ),
    (
        "windows_dropped",
        "u32",
        "acquisition windows dropped, since start",
    ),
    (
        "ring_lost",
        "u32",
        "windows whose rows left the ring, since start",
    ),
    ("calib_failed", "u32", "windows not calibrated, since start"),
    (
        "track_refused",
        "u32",
        "tracking windows not placed, since start",
    ),
    (
        "track_lost",
        "u32",
        "tracking windows without a star, since start",
    ),
    (
        "stars_dropped",
        "u32",
        "stars over the star list, since start",
    ),
    ("rx_bytes", "u32", "link bytes received"),
    ("packets", "u32", "frames decoded into a packet"),
    ("framing_errors", "u32", "frames not COBS or too long"),
    ("crc_errors", "u32", "packets with a wrong CRC-16"),
    ("accepted", "u32", "telecommands executed"),
    ("rejected", "u32", "telecommands rejected"),
    ("tm_queued", "u32", "telemetry packets queued"),
    (
        "tm_dropped",
        "u32",
        "telemetry packets dropped (queue full)",
    ),
    ("stars_not_sent", "u32", "stars over a star-list packet"),
    ("table_kind", "u8", "kind of the table in force"),
    ("table_present", "u8", "1: a table is in force"),
    ("table_len", "u32", "its length, bytes"),
    ("table_crc32", "u32", "its CRC-32"),
    ("table_sequence", "u32", "its store sequence number"),
    ("uptime_us", "u64", "time since start, us"),
    (
        "setup_faults",
        "u16",
        "set-up steps that failed at this boot (SetupFaults bits, docs/storage.md); 0: none",
    ),
    (
        "dark_ratio",
        "u16",
        "running dark ratio, covered pixels / dark law, x 256 (U8F8); 0: not measured",
    ),
    (
        "status",
        "u8",
        "bit 0 DARK_DRIFT: dark ratio outside its band",
    ),
    (
        "defects_pending",
        "u16",
        "pixels confirmed in flight, not yet in the table",
    ),
    (
        "hits",
        "u16",
        "last frame's windows counted as particle hits (the radiation monitor; the sharpest flagged `POOR_FIT`)",
    ),
    (
        "masked",
        "u16",
        "last frame's detections and windows masked on a bright object (saturated)",
    ),
    (
        "obstructions",
        "u8",
        "what took stars from the last frame: bit 0 MOON, 1 EARTH, 2 SUN (stray light), 3 RADIATION",
    ),
    (
        "hits_total",
        "u32",
        "windows counted as particle hits, since start",
    ),
    (
        "masked_total",
        "u32",
        "detections and windows masked, since start",
    ),
];

/// Length of the housekeeping source data, bytes.
#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time: a bad index fails the build, never the program"
)]
pub const HK_LEN: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < HK_FIELDS.len() {
        n += type_len(HK_FIELDS[i].1);
        i += 1;
    }
    n
};

const fn source_number(s: TemperatureSource) -> u8 {
    match s {
        TemperatureSource::Sensor => 0,
        TemperatureSource::TableReference => 1,
        TemperatureSource::None => 2,
    }
}

impl Housekeeping {
    /// Writes the report; `None` if `out` is shorter than [`HK_LEN`].
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        let t = &self.totals;
        let l = &self.link;
        let table = self.table.unwrap_or(TableInfo {
            kind: 0,
            len_bytes: 0,
            crc32: 0,
            sequence: 0,
        });
        let mut w = Writer::new(out);
        w.u16(1)
            .u8(mode_number(self.mode))
            .u8(mode_number(self.next_mode))
            .u8(u8::from(self.calibrated))
            .u8(source_number(self.temperature_source))
            .u32(self.temperature_k_bits)
            .u32(self.frame)
            .u16(self.stars)
            .u16(self.centroids);
        for v in [
            t.frames,
            t.lines_refused,
            t.candidates_dropped,
            t.windows_dropped,
            t.ring_lost,
            t.calib_failed,
            t.track_refused,
            t.track_lost,
            t.stars_dropped,
            l.rx_bytes,
            l.packets,
            l.framing_errors,
            l.crc_errors,
            l.accepted,
            l.rejected,
            l.tm_queued,
            l.tm_dropped,
            l.stars_not_sent,
        ] {
            w.u32(v);
        }
        w.u8(table.kind)
            .u8(u8::from(self.table.is_some()))
            .u32(table.len_bytes)
            .u32(table.crc32)
            .u32(table.sequence)
            .u64(self.uptime_us)
            .u16(self.setup_faults)
            .u16(self.dark_ratio_u8f8)
            .u8(self.status)
            .u16(self.defects_pending)
            .u16(self.hits)
            .u16(self.masked)
            .u8(self.obstructions)
            .u32(t.hits)
            .u32(t.masked);
        w.finish()
    }
}
