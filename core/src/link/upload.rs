//! The table-upload port: what the link calls to store a table sent in chunks. The board
//! binds it to the flash table store (two slots per kind: the new table goes to the inactive
//! one), the host to memory (`startrack_host::link_home::MemoryTables`).
//!
//! An upload is `begin` (kind, whole length, CRC-32), `chunk`s in order (each at the offset
//! the previous ones reached), then `commit` or `abort`. A refusal leaves the table in force
//! untouched; a refused chunk leaves the upload where it was, so the ground may resend from
//! [`UploadRefusal::OutOfOrder`]'s `expected` offset.
//!
//! Cost: each call does what the store does with the bytes it is given; nothing here waits.

/// A table kept by the store.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TableInfo {
    /// Table kind ([`super::protocol::TABLE_KIND_CALIBRATION`]).
    pub kind: u8,
    /// Length, bytes.
    pub len_bytes: u32,
    /// CRC-32/ISO-HDLC (the zlib CRC) of the whole table.
    pub crc32: u32,
    /// Store sequence number: higher is newer (a store with one slot may keep 0).
    pub sequence: u32,
}

/// Why the store refused an upload step. Stable codes: [`Self::code`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum UploadRefusal {
    /// A chunk, commit or abort with no upload begun.
    NotStarted,
    /// An upload is already under way (abort it first), or the store is busy (an erase).
    Busy,
    /// The table kind is not one the store keeps.
    UnknownKind,
    /// The table is longer than a slot, or a chunk runs past the announced length.
    TooLong,
    /// A chunk's offset is not where the upload stands.
    OutOfOrder {
        /// Where the next chunk must start, bytes.
        expected: u32,
    },
    /// Commit before every byte was received.
    Incomplete,
    /// The received bytes' CRC-32 differs from the announced one.
    CrcMismatch,
    /// The table is complete and its CRC right, but it is not a usable table (its own
    /// checks, or another sensor's geometry).
    Invalid,
    /// The storage failed (erase or write error); the table in force is kept.
    Storage,
}

impl UploadRefusal {
    /// The refusal's code in telemetry (the `parameter` of a rejection's upper 16 bits).
    pub const fn code(self) -> u16 {
        match self {
            Self::NotStarted => 1,
            Self::Busy => 2,
            Self::UnknownKind => 3,
            Self::TooLong => 4,
            Self::OutOfOrder { .. } => 5,
            Self::Incomplete => 6,
            Self::CrcMismatch => 7,
            Self::Invalid => 8,
            Self::Storage => 9,
        }
    }

    /// The name the ground tool prints.
    pub const fn name(self) -> &'static str {
        match self {
            Self::NotStarted => "no upload begun",
            Self::Busy => "store busy or an upload under way",
            Self::UnknownKind => "unknown table kind",
            Self::TooLong => "table too long",
            Self::OutOfOrder { .. } => "chunk out of order",
            Self::Incomplete => "upload incomplete",
            Self::CrcMismatch => "CRC-32 mismatch",
            Self::Invalid => "not a usable table",
            Self::Storage => "storage failure",
        }
    }
}

impl core::fmt::Display for UploadRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::OutOfOrder { expected } => {
                write!(f, "{} (expected offset {expected})", self.name())
            }
            _ => f.write_str(self.name()),
        }
    }
}

impl core::error::Error for UploadRefusal {}

/// The store a table upload writes to.
pub trait TableUpload {
    /// Starts an upload of a `kind` table of `total_len` bytes whose CRC-32 is `crc32`.
    fn begin(&mut self, kind: u8, total_len: u32, crc32: u32) -> Result<(), UploadRefusal>;
    /// Takes `data` at byte `offset` of the table (the bytes received so far).
    fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), UploadRefusal>;
    /// Checks the whole table (length, CRC-32, the table's own checks) and makes it the one
    /// in force. When this returns `Ok`, the table survives a reset and is used from the
    /// next frame on; on `Err` the table in force is unchanged and the upload is over.
    fn commit(&mut self) -> Result<TableInfo, UploadRefusal>;
    /// Drops the upload under way, if any (the table in force is unchanged).
    fn abort(&mut self);
    /// The table of `kind` in force.
    fn active(&self, kind: u8) -> Option<TableInfo>;
    /// Reads `out.len()` bytes of the table of `kind` in force from byte `offset` (the
    /// in-flight defect commit builds its new table from them); `false` when it cannot (no
    /// table, past its end, a read error, or a store that does not read back: the default).
    fn read_active(&mut self, kind: u8, offset: u32, out: &mut [u8]) -> bool {
        let _ = (kind, offset, out);
        false
    }
}
