//! Tables in flash that survive power cuts: two slots per table kind, a new table written to
//! the slot not in force and put in force by one last 32-byte header write.
//!
//! What it is for: the tracker gets new calibration tables during the mission (new hot
//! pixels, a new flat) over its link, and a power cut at any moment of an update must leave
//! it with the old table or the new one, never a corrupt one and never none while one was
//! valid. What it costs: two slots per kind (on the STM32H743, 4 x 256 KB of bank 2 for the
//! calibration and catalog kinds, [`H743_BANK2`]), a mount that reads every valid table once
//! for its CRC, and per upload one erase of the target slot (1-2 s per 128 KB sector on the
//! chip) plus one program of each 32-byte unit. No allocation; the largest buffer is a
//! 256-byte stack block.
//!
//! # The rules it is built for (STM32H7 internal flash)
//! - Erase is per 128 KB sector and sets every byte to 0xFF.
//! - Programming is per 32-byte unit (a flash word with its own ECC), once between erases.
//! - A unit whose program or erase was cut by a power loss may read as an ECC error (a bus
//!   fault on the chip).
//!
//! The store runs over the `embedded-storage` [`NorFlash`](embedded_storage::nor_flash::NorFlash)
//! trait, which embassy-stm32 implements for the H7 flash and the host's mock implements with
//! those rules enforced and power cuts injected.
//!
//! # Format and the power-cut argument
//! A slot is a [header](SlotHeader) unit at its start, then the table's bytes. An upload:
//! 1. [`FlashStore::begin`]: the target is the slot *not* in force; nothing is written.
//! 2. [`FlashStore::erase_step`] once per sector of the target slot (header sector first),
//!    each checked blank. The slot in force is never erased.
//! 3. [`FlashStore::chunk`]s, in order: each completed 32-byte unit is programmed once.
//! 4. [`FlashStore::commit`]: the last unit (padded with 0xFF) is programmed, the table
//!    read back and its CRC compared with the announced one, then the header (sequence
//!    number = the highest seen + 1, length, CRC, its own CRC) written last, and read back.
//!    [`FlashStore::commit_checked`] also runs the table's own checks (a calibration table's
//!    parse and geometry) before the header.
//!
//! At mount a slot is valid when its header unit reads, decodes (magic, version, kind,
//! length, header CRC) and the table's bytes have the header's CRC; the valid slot with the
//! higher sequence number is in force. A cut before the header write leaves the target with
//! an erased, unreadable or invalid header: the old table stays in force. A cut during the
//! header write leaves it torn (unreadable, or failing its CRC): the old table stays. Once the
//! header is written, the new table is valid and newer. The table in force is never written
//! or erased, so it stays valid through every step.
//!
//! Mount reads only the header unit of each slot and, behind a valid header, table units that
//! were all programmed and read back before that header was written. The only unit it may
//! read torn is therefore a header (or any unit of a sector whose erase was cut): the store
//! treats a failed read as "slot unusable", and the firmware's read must turn the chip's ECC
//! fault into such an error rather than a crash (see `docs/storage.md`).
//!
//! # Where the erase runs
//! Erasing is a separate step so that it never runs in the frame loop: the home runs
//! [`FlashStore::erase_step`] (blocking) where a stall is harmless, or erases the range
//! [`FlashStore::pending_erase`] names with its own (async) driver and then calls
//! [`FlashStore::confirm_erased`]. Chunks and commit program a few units each (tens of
//! microseconds per unit on the chip).

mod error;
mod header;
mod kind;
mod layout;
mod slots;

pub use error::{FlashFault, StoreError};
pub use header::{HEADER_LEN, HeaderError, SLOT_MAGIC, SLOT_VERSION, SlotHeader};
pub use kind::TableKind;
pub use layout::{
    H743_BANK_B, H743_BANK2, H743_BANK2_ADDRESS, H743_PROGRAM_UNIT_B, H743_SECTOR_B, Layout, Slot,
};
pub use slots::{
    ActiveTable, CommitInfo, EraseProgress, FlashStore, MountError, SlotState, UploadStatus,
};
