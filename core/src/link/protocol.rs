//! The protocol's numbers, defined once: the APID map, every message's service and subtype,
//! the telemetry packets' fixed parts. The decoder, the encoders, the ground tool and
//! `docs/protocol.md` (generated from [`MESSAGES`] and checked by the host test
//! `link_protocol_doc`) all read them from here.
//!
//! Packets are CCSDS Space Packets (version 0, unsegmented) with an ECSS PUS-C secondary
//! header and the CRC-16/CCITT-FALSE packet error control field. A telecommand's secondary
//! header is 5 bytes (PUS version 2, ack flags, service, subtype, source id); a telemetry
//! packet's is 7 bytes plus an [`TIMESTAMP_LEN`]-byte time field: the tracker's uptime, us,
//! big-endian `u64`. Every multi-byte field of the application data is big-endian.

/// The tracker's telecommands, their verification reports and its events.
pub const APID_CONTROL: u16 = 0x100;
/// Housekeeping reports.
pub const APID_HOUSEKEEPING: u16 = 0x101;
/// Per-frame star lists.
pub const APID_STARS: u16 = 0x102;
/// Diagnostic windows and table reports.
pub const APID_DIAGNOSTICS: u16 = 0x103;
/// APID of the attitude reports.
pub const APID_ATTITUDE: u16 = 0x104;
/// Every APID the tracker sends or takes, with its name.
pub const APIDS: [(u16, &str); 5] = [
    (APID_CONTROL, "control"),
    (APID_HOUSEKEEPING, "housekeeping"),
    (APID_STARS, "stars"),
    (APID_DIAGNOSTICS, "diagnostics"),
    (APID_ATTITUDE, "attitude"),
];

/// Length of the telemetry time field, bytes (the uptime in us, big-endian `u64`).
pub const TIMESTAMP_LEN: usize = 8;
/// Longest telecommand packet taken, bytes (header, secondary header, data, CRC).
pub const MAX_TC_LEN: usize = 1100;
/// Most data bytes in one table-upload chunk.
pub const MAX_CHUNK_BYTES: usize = 1024;
/// Longest telemetry packet sent, bytes.
pub const MAX_TM_LEN: usize = 1100;
/// Most stars in one star-list packet (the board's capacity; more are counted as not sent).
pub const MAX_LINK_STARS: usize = 32;
/// Bytes of one star in a star list.
pub const STAR_BYTES: usize = 33;
/// The star list's format, its fourth byte: 2 has quality (`flags`) and provenance apart
/// (format 1 had no format byte and carried provenance in `flags` bits 18-19).
pub const STAR_LIST_FORMAT: u8 = 2;
/// Largest speed the velocity command takes, m/s (0.001 c: the first-order aberration's
/// neglected term is then 0.2").
pub const MAX_SPEED_M_S: f64 = 300_000.0;
/// Side of the largest diagnostic window, px.
pub const MAX_WINDOW_PX: u16 = 64;
/// Table kind of the calibration table (the only kind so far).
pub const TABLE_KIND_CALIBRATION: u8 = 1;

/// A service type and subtype.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MessageType {
    /// PUS service type.
    pub service: u8,
    /// PUS message subtype.
    pub subtype: u8,
}

const fn mt(service: u8, subtype: u8) -> MessageType {
    MessageType { service, subtype }
}

/// `TM[1,1]`: the telecommand was accepted and executed.
pub const TM_ACCEPTED: MessageType = mt(1, 1);
/// `TM[1,2]`: the telecommand was rejected, with a [`super::Rejection`] code.
pub const TM_REJECTED: MessageType = mt(1, 2);
/// `TC[3,27]`: send one housekeeping report now.
pub const TC_HOUSEKEEPING: MessageType = mt(3, 27);
/// `TC[3,31]`: housekeeping report period, frames (0: only on request).
pub const TC_HOUSEKEEPING_PERIOD: MessageType = mt(3, 31);
/// `TM[3,25]`: a housekeeping report.
pub const TM_HOUSEKEEPING: MessageType = mt(3, 25);
/// `TM[5,1]`: an informative event.
pub const TM_EVENT_INFO: MessageType = mt(5, 1);
/// `TM[5,2]`: an anomaly event (a rejected command, a refused table).
pub const TM_EVENT_ANOMALY: MessageType = mt(5, 2);
/// `TC[17,1]`: are you alive.
pub const TC_PING: MessageType = mt(17, 1);
/// `TM[17,2]`: alive.
pub const TM_PONG: MessageType = mt(17, 2);
/// `TC[130,1]`: set the mode from the next frame on.
pub const TC_SET_MODE: MessageType = mt(130, 1);
/// `TC[130,2]`: set configuration parameters from the next frame on.
pub const TC_SET_PARAMS: MessageType = mt(130, 2);
/// `TC[130,3]`: reset the tracker.
pub const TC_RESET: MessageType = mt(130, 3);
/// `TC[131,1]`: send the star list of the next N frames.
pub const TC_STARS: MessageType = mt(131, 1);
/// `TM[131,2]`: one frame's star list.
pub const TM_STARS: MessageType = mt(131, 2);
/// `TC[132,1]`: read a raw or calibrated window of the next frame.
pub const TC_WINDOW: MessageType = mt(132, 1);
/// `TM[132,2]`: one row of a window.
pub const TM_WINDOW_ROW: MessageType = mt(132, 2);
/// `TC[133,1]`: begin a table upload.
pub const TC_TABLE_BEGIN: MessageType = mt(133, 1);
/// `TC[133,2]`: one chunk of the table.
pub const TC_TABLE_CHUNK: MessageType = mt(133, 2);
/// `TC[133,3]`: commit the uploaded table.
pub const TC_TABLE_COMMIT: MessageType = mt(133, 3);
/// `TC[133,4]`: abort the upload.
pub const TC_TABLE_ABORT: MessageType = mt(133, 4);
/// `TC[133,5]`: report the table in force.
pub const TC_TABLE_REPORT: MessageType = mt(133, 5);
/// `TC[133,7]`: write the pixels the in-flight watch confirmed into a new calibration table
/// (the table in force with them added to its defect lists) through the upload path.
pub const TC_TABLE_COMMIT_DEFECTS: MessageType = mt(133, 7);
/// `TM[133,6]`: the table in force.
pub const TM_TABLE_REPORT: MessageType = mt(133, 6);
/// `TC[9,128]`: the spacecraft time of the next sync pulse (CUC with its P-field). Service 9
/// is PUS time management; it defines no command to set an on-board clock, so the subtype is
/// one of the mission-specific range (128 and up).
pub const TC_TIME_SET: MessageType = mt(9, 128);
/// `TC[134,1]`: the spacecraft's velocity (ICRF, barycentric) at a spacecraft time, for the
/// attitude stage's stellar aberration.
pub const TC_VELOCITY: MessageType = mt(134, 1);
/// A frame's attitude (every frame the attitude stage runs).
pub const TM_ATTITUDE: MessageType = mt(134, 2);

/// Which way a message goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// Ground to tracker.
    Telecommand,
    /// Tracker to ground.
    Telemetry,
}

/// One message of the protocol, as `docs/protocol.md` lists it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MessageDef {
    /// Short name (the ground tool's and the docs').
    pub name: &'static str,
    /// Telecommand or telemetry.
    pub direction: Direction,
    /// APID.
    pub apid: u16,
    /// Service and subtype.
    pub kind: MessageType,
    /// The application data (telecommand) or source data (telemetry), big-endian.
    pub data: &'static str,
}

const fn tc(name: &'static str, kind: MessageType, data: &'static str) -> MessageDef {
    MessageDef {
        name,
        direction: Direction::Telecommand,
        apid: APID_CONTROL,
        kind,
        data,
    }
}

const fn tm(name: &'static str, apid: u16, kind: MessageType, data: &'static str) -> MessageDef {
    MessageDef {
        name,
        direction: Direction::Telemetry,
        apid,
        kind,
        data,
    }
}

/// Every message, telecommands first.
pub const MESSAGES: [MessageDef; 26] = [
    tc("ping", TC_PING, "none"),
    tc("housekeeping", TC_HOUSEKEEPING, "none"),
    tc(
        "housekeeping-period",
        TC_HOUSEKEEPING_PERIOD,
        "frames u16 (0: on request only)",
    ),
    tc(
        "set-mode",
        TC_SET_MODE,
        "mode u8 (0 standby, 1 acquisition, 2 tracking)",
    ),
    tc(
        "set-params",
        TC_SET_PARAMS,
        "1 to 8 x (parameter u8, value u32)",
    ),
    tc("reset", TC_RESET, "none"),
    tc(
        "stars",
        TC_STARS,
        "frames u16 (0: stop, 65535: every frame)",
    ),
    tc(
        "window",
        TC_WINDOW,
        "x0 u16, y0 u16, side_px u16, kind u8 (0 raw ADU, 1 calibrated e- x 64)",
    ),
    tc(
        "table-begin",
        TC_TABLE_BEGIN,
        "kind u8, total_len u32, crc32 u32",
    ),
    tc(
        "table-chunk",
        TC_TABLE_CHUNK,
        "offset u32, 1 to 1024 data bytes",
    ),
    tc("table-commit", TC_TABLE_COMMIT, "none"),
    tc("table-abort", TC_TABLE_ABORT, "none"),
    tc("table-report", TC_TABLE_REPORT, "kind u8"),
    tc("table-commit-defects", TC_TABLE_COMMIT_DEFECTS, "none"),
    tc(
        "time-set",
        TC_TIME_SET,
        "P-field u8 (0x1E), coarse u32 s, fine u16 2^-16 s: the spacecraft time (CUC) of the next sync pulse",
    ),
    tc(
        "velocity",
        TC_VELOCITY,
        "vx, vy, vz f32 m/s (ICRF, barycentric; at most 300 km/s), coarse u32 s, fine u16: the CUC time it holds at",
    ),
    tm(
        "accepted",
        APID_CONTROL,
        TM_ACCEPTED,
        "request id: packet id u16, sequence control u16",
    ),
    tm(
        "rejected",
        APID_CONTROL,
        TM_REJECTED,
        "request id u32, reason u16, parameter u32",
    ),
    tm(
        "event",
        APID_CONTROL,
        TM_EVENT_INFO,
        "event u16, 16 bytes of event data",
    ),
    tm(
        "anomaly",
        APID_CONTROL,
        TM_EVENT_ANOMALY,
        "event u16, 16 bytes of event data",
    ),
    tm("pong", APID_CONTROL, TM_PONG, "none"),
    tm(
        "housekeeping",
        APID_HOUSEKEEPING,
        TM_HOUSEKEEPING,
        "the housekeeping fields",
    ),
    tm(
        "stars",
        APID_STARS,
        TM_STARS,
        "frame u32, mode u8, format u8 (2), count u8, count x star (33 bytes)",
    ),
    tm(
        "window-row",
        APID_DIAGNOSTICS,
        TM_WINDOW_ROW,
        "x0 u16, y0 u16, side u16, row u16, kind u8, side x i32",
    ),
    tm(
        "table-report",
        APID_DIAGNOSTICS,
        TM_TABLE_REPORT,
        "kind u8, present u8, len u32, crc32 u32, sequence u32",
    ),
    tm(
        "attitude",
        APID_ATTITUDE,
        TM_ATTITUDE,
        "the attitude report's fields, format 2 (128 bytes)",
    ),
];

/// The message definition of a telecommand of type `kind`, if there is one.
pub fn telecommand(kind: MessageType) -> Option<&'static MessageDef> {
    MESSAGES
        .iter()
        .find(|m| m.direction == Direction::Telecommand && m.kind == kind)
}

/// A configuration parameter that [`TC_SET_PARAMS`] sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParamDef {
    /// Its number in the telecommand.
    pub id: u8,
    /// The [`crate::tracker::TrackerConfig`] field.
    pub name: &'static str,
    /// How the `u32` value is read.
    pub encoding: &'static str,
}

/// Every parameter of [`TC_SET_PARAMS`].
pub const PARAMS: [ParamDef; 7] = [
    ParamDef {
        id: 1,
        name: "exposure_ms",
        encoding: "u32, ms",
    },
    ParamDef {
        id: 2,
        name: "detect.pixel_sigmas",
        encoding: "f32 bits",
    },
    ParamDef {
        id: 3,
        name: "detect.peak_sigmas",
        encoding: "f32 bits",
    },
    ParamDef {
        id: 4,
        name: "detect.min_snr",
        encoding: "f32 bits",
    },
    ParamDef {
        id: 5,
        name: "min_track_stars",
        encoding: "u32 (at most 65535)",
    },
    ParamDef {
        id: 6,
        name: "reacquire_every",
        encoding: "u32, frames",
    },
    ParamDef {
        id: 7,
        name: "max_stars",
        encoding: "u32 (at most 65535)",
    },
];
