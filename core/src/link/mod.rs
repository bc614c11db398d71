//! The command and telemetry link: how the spacecraft's on-board computer commands and reads
//! the tracker over a serial line (RS-422 in flight; TCP on 127.0.0.1 in the
//! software-in-the-loop).
//!
//! ```text
//! UART bytes -> framing (COBS, 0x00-delimited)  -> CCSDS Space Packet, PUS-C TC, CRC-16
//!            -> command (typed, or a Rejection) -> the tracker / the table store
//! tracker records, events, answers -> PUS-C TM (APID, service, subtype, uptime, CRC-16)
//!            -> COBS frame -> urgent or bulk queue -> UART as it can take them
//! ```
//!
//! One job a module: [`protocol`] (every number, and the table `docs/protocol.md` is made
//! from), [`framing`], `command` (reading a command: [`Command`], its [`Rejection`]s),
//! [`telemetry`] (the reports' layouts), `upload` (the table-store port, [`TableUpload`]),
//! `flash_upload` (that port over the flash table store, [`FlashTables`]), `service`
//! (the state that ties them together, [`LinkService`], and the tracker's telemetry port).
//!
//! Packets are read and written with the `spacepackets` crate (no std, no alloc): the
//! standard's header fields and CRC are not hand-coded here.
//!
//! Memory: [`LinkService`] holds the two telemetry queues, a receive frame, three packet
//! buffers and the in-flight defect commit's plan, all fixed; its size is in
//! `docs/protocol.md` and bounded by the host test `link_decoder`. Cost: see [`LinkService`].

pub(crate) mod command;
pub(crate) mod flash_upload;
pub mod framing;
pub mod protocol;
pub(crate) mod service;
pub mod telemetry;
pub(crate) mod upload;

pub use command::{Command, Rejection, Velocity, WindowKind, WindowRequest, mode_number};
pub use flash_upload::{FlashTables, active_info, read_active_at, refusal_of};
pub use service::{LinkService, NoWindows, Targets, TrackerControl, WindowReader};
pub use upload::{TableInfo, TableUpload, UploadRefusal};
