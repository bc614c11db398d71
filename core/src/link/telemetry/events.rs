//! The event reports `TM[5,1]` (information) and `TM[5,2]` (anomaly): the event numbers
//! ([`event`]), their fixed data length, and a tracker event's number and data
//! ([`tracker_event`]). A few stores an event.

use super::super::command::mode_number;
use super::fields::Writer;
use crate::tracker::{Event, ModeReason};

/// Event numbers of `TM[5,1]` and `TM[5,2]`.
pub mod event {
    /// Mode change: frame u32, from u8, to u8, reason u8.
    pub const MODE_CHANGE: u16 = 1;
    /// Table in force changed: frame u32, length u32.
    pub const TABLE_CHANGED: u16 = 2;
    /// Configuration applied: frame u32.
    pub const CONFIG_APPLIED: u16 = 3;
    /// A telecommand was rejected (anomaly): request id u32, reason u16, parameter u32.
    pub const COMMAND_REJECTED: u16 = 4;
    /// A table upload was committed: kind u8, length u32, CRC-32 u32, sequence u32.
    pub const TABLE_ACCEPTED: u16 = 5;
    /// A table upload was refused at commit (anomaly): kind u8, refusal u16.
    pub const TABLE_REFUSED: u16 = 6;
    /// The in-flight defects were committed into a new table: hot pixels added u16,
    /// telegraph pixels added u16, length u32, CRC-32 u32, sequence u32.
    pub const DEFECTS_COMMITTED: u16 = 7;
}

/// Bytes of event data after the event number (zero-padded).
pub const EVENT_DATA_LEN: usize = 16;

const fn reason_number(r: ModeReason) -> u8 {
    match r {
        ModeReason::Start => 0,
        ModeReason::Command => 1,
        ModeReason::Acquired => 2,
        ModeReason::TooFewStars => 3,
        ModeReason::Reacquire => 4,
        ModeReason::NoTable => 5,
        ModeReason::TableAvailable => 6,
        ModeReason::Predicted => 7,
    }
}

/// A tracker event's number and data.
pub fn tracker_event(e: &Event) -> (u16, [u8; EVENT_DATA_LEN]) {
    let mut d = [0u8; EVENT_DATA_LEN];
    let mut w = Writer::new(&mut d);
    let id = match *e {
        Event::ModeChange {
            frame,
            from,
            to,
            reason,
        } => {
            w.u32(frame)
                .u8(mode_number(from))
                .u8(mode_number(to))
                .u8(reason_number(reason));
            event::MODE_CHANGE
        }
        Event::TableChanged { frame, len_bytes } => {
            w.u32(frame).u32(len_bytes);
            event::TABLE_CHANGED
        }
        Event::ConfigApplied { frame } => {
            w.u32(frame);
            event::CONFIG_APPLIED
        }
    };
    (id, d)
}
