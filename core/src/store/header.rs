//! The slot header: one 32-byte program unit at the start of a slot, written last, that says
//! which table the slot holds, how new it is, and the CRC of its bytes.
//!
//! ```text
//! offset size  field (little-endian)
//!  0     4     magic b"STSH"
//!  4     1     header version = 1
//!  5     1     table kind (1 calibration, 2 catalog)
//!  6     2     reserved, 0
//!  8     4     sequence number (1, 2, ...: the higher, the newer)
//! 12     4     table length, bytes (1 ..= slot capacity)
//! 16     4     CRC-32/ISO-HDLC of the table's bytes
//! 20     8     reserved, 0
//! 28     4     CRC-32/ISO-HDLC of bytes 0..28
//! ```

use super::kind::TableKind;

/// Size of the header, bytes: one STM32H7 program unit.
pub const HEADER_LEN: usize = 32;
/// The four bytes a slot header starts with.
pub const SLOT_MAGIC: [u8; 4] = *b"STSH";
/// The header version this crate writes and reads.
pub const SLOT_VERSION: u8 = 1;

/// CRC-32/ISO-HDLC, the calibration table's own CRC, for the header and the table bytes.
pub(crate) const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// A decoded slot header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SlotHeader {
    /// The table's kind.
    pub kind: TableKind,
    /// Upload sequence number: the valid slot with the higher one is in force.
    pub sequence: u32,
    /// Table length, bytes.
    pub len_b: u32,
    /// CRC-32/ISO-HDLC of the table's bytes (the table id the link reports with `sequence`).
    pub crc32: u32,
}

/// Why a header unit is not a header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HeaderError {
    /// Every byte 0xFF: the unit is erased (nothing was ever committed there).
    Erased,
    /// Wrong magic or version.
    Magic,
    /// The header CRC does not match.
    Crc,
    /// Unknown kind, or a kind other than the slot's.
    Kind,
    /// Length 0 or larger than the slot.
    Length,
}

impl SlotHeader {
    /// The 32 bytes of the header.
    pub fn encode(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        let fields: [(usize, &[u8]); 6] = [
            (0, &SLOT_MAGIC),
            (4, &[SLOT_VERSION, self.kind.code()]),
            (8, &self.sequence.to_le_bytes()),
            (12, &self.len_b.to_le_bytes()),
            (16, &self.crc32.to_le_bytes()),
            (28, &[]),
        ];
        for (at, bytes) in fields {
            if let Some(dst) = b.get_mut(at..at + bytes.len()) {
                dst.copy_from_slice(bytes);
            }
        }
        let crc = CRC.checksum(b.get(..28).unwrap_or(&[]));
        if let Some(dst) = b.get_mut(28..32) {
            dst.copy_from_slice(&crc.to_le_bytes());
        }
        b
    }

    /// Decodes a header unit of a `kind` slot holding at most `capacity_b` table bytes.
    pub fn decode(
        b: &[u8; HEADER_LEN],
        kind: TableKind,
        capacity_b: u32,
    ) -> Result<Self, HeaderError> {
        if b.iter().all(|&x| x == 0xFF) {
            return Err(HeaderError::Erased);
        }
        let word = |at: usize| {
            let mut w = [0u8; 4];
            if let Some(src) = b.get(at..at + 4) {
                w.copy_from_slice(src);
            }
            u32::from_le_bytes(w)
        };
        if b.get(0..4) != Some(&SLOT_MAGIC[..]) || b.get(4) != Some(&SLOT_VERSION) {
            return Err(HeaderError::Magic);
        }
        if CRC.checksum(b.get(..28).unwrap_or(&[])) != word(28) {
            return Err(HeaderError::Crc);
        }
        let code = b.get(5).copied().unwrap_or(0);
        if TableKind::from_code(code) != Some(kind) {
            return Err(HeaderError::Kind);
        }
        let len_b = word(12);
        if len_b == 0 || len_b > capacity_b {
            return Err(HeaderError::Length);
        }
        Ok(Self {
            kind,
            sequence: word(8),
            len_b,
            crc32: word(16),
        })
    }
}
