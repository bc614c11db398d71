//! Why a star catalog was rejected.

/// Why a catalog is not used. A catalog that fails any check is never partly used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CatalogError {
    /// Fewer bytes than the header needs.
    TooShort {
        /// Bytes given.
        got: u32,
    },
    /// The first four bytes are not `STCG` (erased flash reads as 0xFF).
    BadMagic,
    /// A version this firmware does not read.
    UnsupportedVersion(u16),
    /// The header's total length disagrees with the bytes given or with its own counts.
    LengthMismatch {
        /// Length the header states.
        header: u32,
        /// Bytes given.
        actual: u32,
    },
    /// The header fails its CRC.
    HeaderCrc,
    /// A reserved field is not zero.
    Reserved,
    /// A count or angle in the header is outside its range (no star, too many stars or bins,
    /// a zero separation or field radius).
    HeaderRange,
    /// The star section fails its CRC.
    StarCrc,
    /// The pair section fails its CRC.
    PairCrc,
    /// The k-vector section fails its CRC.
    KVectorCrc,
    /// Star `index` is not a unit vector, or is out of `z` order.
    Star {
        /// The star's index.
        index: u32,
    },
    /// Pair `index` names a star past the end, names a star twice or out of order, or is out
    /// of separation order or past the largest separation.
    Pair {
        /// The pair's index.
        index: u32,
    },
    /// K-vector entry `index` disagrees with the pairs.
    KVector {
        /// The entry's index.
        index: u32,
    },
}

impl core::fmt::Display for CatalogError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooShort { got } => write!(f, "star catalog too short: {got} bytes"),
            Self::BadMagic => f.write_str("not a star catalog (bad magic)"),
            Self::UnsupportedVersion(v) => write!(f, "star catalog version {v} not supported"),
            Self::LengthMismatch { header, actual } => write!(
                f,
                "star catalog length: header says {header}, have {actual} bytes"
            ),
            Self::HeaderCrc => f.write_str("star catalog header CRC mismatch"),
            Self::Reserved => f.write_str("star catalog: reserved field not zero"),
            Self::HeaderRange => f.write_str("star catalog: header count or angle out of range"),
            Self::StarCrc => f.write_str("star catalog: star section CRC mismatch"),
            Self::PairCrc => f.write_str("star catalog: pair section CRC mismatch"),
            Self::KVectorCrc => f.write_str("star catalog: k-vector CRC mismatch"),
            Self::Star { index } => write!(f, "star catalog: star {index} invalid"),
            Self::Pair { index } => write!(f, "star catalog: pair {index} invalid"),
            Self::KVector { index } => write!(f, "star catalog: k-vector entry {index} invalid"),
        }
    }
}

impl core::error::Error for CatalogError {}
