//! Telemetry source data: the housekeeping report, a frame's star list, a frame's attitude,
//! the events and the verification reports, each a fixed big-endian layout written into a
//! slice (and read back by the ground tool with the same field tables). The layouts are
//! tabled in `docs/protocol.md`, generated from [`HK_FIELDS`], [`STAR_FIELDS`] and
//! [`ATTITUDE_FIELDS`].
//!
//! One file a packet: `housekeeping.rs`, `stars.rs`, `attitude.rs`, `events.rs`; the field
//! cursors in `fields.rs`; the ground's decoders apart in `decode.rs`.
//!
//! Cost: a few stores per field; a 32-star list is about 1 KB (6 bytes and
//! [`STAR_BYTES`](super::protocol::STAR_BYTES) a star).

mod attitude;
mod decode;
mod events;
mod fields;
mod housekeeping;
mod stars;

pub use attitude::{
    ATTITUDE_FIELDS, ATTITUDE_FORMAT, ATTITUDE_LEN, AttitudeMissing, AttitudeReport,
    RATE_LIMIT_RAD_S, Validity,
};
pub use decode::decode_stars;
pub use events::{EVENT_DATA_LEN, event, tracker_event};
pub use fields::{Reader, Writer, type_len};
pub use housekeeping::{FrameTotals, HK_FIELDS, HK_LEN, Housekeeping, LinkCounters, status};
pub use stars::{STAR_FIELDS, encode_stars};
