//! The store's one error type: every refused operation and every flash failure, typed.

use super::kind::TableKind;
use embedded_storage::nor_flash::NorFlashErrorKind;

/// A flash operation that failed, as the `embedded-storage` error kinds say.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlashFault {
    /// Offset or length not aligned to the device's unit (a store bug or a bad layout).
    NotAligned,
    /// Outside the device.
    OutOfBounds,
    /// Anything else: a program or erase error, an ECC error on read, a power failure.
    Other,
}

impl From<NorFlashErrorKind> for FlashFault {
    fn from(kind: NorFlashErrorKind) -> Self {
        match kind {
            NorFlashErrorKind::NotAligned => Self::NotAligned,
            NorFlashErrorKind::OutOfBounds => Self::OutOfBounds,
            _ => Self::Other,
        }
    }
}

/// Why a store operation was refused or failed. Nothing is committed by an operation that
/// returns one, and the table in force stays in force.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum StoreError {
    /// The flash device failed (an upload in progress is dropped).
    Flash(FlashFault),
    /// The device's program unit does not divide the 32-byte header, or its erase unit is 0.
    UnsupportedFlash,
    /// A slot is not whole sectors, not inside the device, too small, or overlaps another.
    BadLayout {
        /// The slot's kind.
        kind: TableKind,
        /// Slot 0 or 1.
        slot: u8,
    },
    /// `begin` while an upload is in progress (abort it first).
    UploadInProgress {
        /// The kind being uploaded.
        kind: TableKind,
    },
    /// `chunk`, `commit` or an erase step without an upload in progress.
    NoUpload,
    /// `begin` of an empty table.
    EmptyTable,
    /// `begin` of a table larger than a slot holds.
    TooLong {
        /// The announced length, bytes.
        len_b: u32,
        /// The slot's capacity, bytes.
        capacity_b: u32,
    },
    /// `chunk` or `commit` before the target slot is erased.
    NotErased,
    /// A chunk that does not start where the last one ended.
    OutOfOrder {
        /// The offset expected, bytes.
        expected_b: u32,
        /// The chunk's offset, bytes.
        got_b: u32,
    },
    /// A chunk that ends past the announced length.
    PastEnd {
        /// Where the chunk ends, bytes.
        end_b: u32,
        /// The announced length, bytes.
        total_b: u32,
    },
    /// `commit` before every byte was received.
    Incomplete {
        /// Bytes received.
        received_b: u32,
        /// The announced length, bytes.
        total_b: u32,
    },
    /// The table read back from flash does not have the announced CRC (nothing committed).
    CrcMismatch {
        /// The CRC announced by `begin`.
        expected: u32,
        /// The CRC of the bytes read back.
        computed: u32,
    },
    /// The table has the announced CRC but its own checks refused it (nothing committed).
    Invalid,
    /// A freshly erased sector does not read blank, or a header read back differs.
    VerifyFailed {
        /// Device offset of the unit that differs, bytes.
        offset_b: u32,
    },
    /// No sequence number is left (2^32 - 1 uploads of one kind).
    SequenceExhausted,
    /// No valid table of that kind.
    NoTable,
    /// The caller's buffer is smaller than the table.
    BufferTooSmall {
        /// The table's length, bytes.
        need_b: u32,
    },
}

impl core::fmt::Display for StoreError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Flash(fault) => write!(f, "flash operation failed: {fault:?}"),
            Self::UnsupportedFlash => write!(f, "flash program unit does not fit the store"),
            Self::BadLayout { kind, slot } => write!(f, "bad layout of {kind:?} slot {slot}"),
            Self::UploadInProgress { kind } => write!(f, "an upload of {kind:?} is in progress"),
            Self::NoUpload => write!(f, "no upload in progress"),
            Self::EmptyTable => write!(f, "empty table"),
            Self::TooLong { len_b, capacity_b } => {
                write!(f, "table of {len_b} bytes, a slot holds {capacity_b}")
            }
            Self::NotErased => write!(f, "the target slot is not erased yet"),
            Self::OutOfOrder { expected_b, got_b } => {
                write!(f, "chunk at {got_b}, expected {expected_b}")
            }
            Self::PastEnd { end_b, total_b } => {
                write!(f, "chunk ends at {end_b}, the table has {total_b} bytes")
            }
            Self::Incomplete {
                received_b,
                total_b,
            } => write!(f, "{received_b} of {total_b} bytes received"),
            Self::CrcMismatch { expected, computed } => {
                write!(
                    f,
                    "CRC {computed:#010x} read back, {expected:#010x} announced"
                )
            }
            Self::Invalid => write!(f, "the table's own checks refused it"),
            Self::VerifyFailed { offset_b } => write!(f, "flash verify failed at {offset_b:#x}"),
            Self::SequenceExhausted => write!(f, "no sequence number left"),
            Self::NoTable => write!(f, "no valid table"),
            Self::BufferTooSmall { need_b } => write!(f, "buffer smaller than {need_b} bytes"),
        }
    }
}

impl core::error::Error for StoreError {}
