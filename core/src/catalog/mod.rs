//! The on-board star catalog: every star the tracker can identify (direction, magnitude,
//! colour) and the identification database (star pairs sorted by separation, with a k-vector
//! to find the pairs in an angle interval in O(1)), in one byte string that the firmware
//! reads in place from its own flash slot (zero-copy, no allocation) and the host writes
//! (`startrack catalog build`).
//!
//! Cost: the header and CRC check of every byte on load (the parse also checks every entry's
//! range and order, O(stars + pairs)); after that a star or pair read is a few loads, a pair
//! range is two k-vector loads and a short scan, a cone search is a binary search on `z` and
//! a scan of the stars in its declination band.
//!
//! # Layout (version 1, all integers little-endian)
//!
//! ```text
//! offset size  field
//!  0     4     magic b"STCG"
//!  4     2     version = 1
//!  6     2     reserved, 0
//!  8     4     total length of the catalog in bytes
//! 12     4     star count n_s (1..=65535)
//! 16     4     pair count n_p
//! 20     4     k-vector bins n_k (1..=65536)
//! 24     4     largest pair separation, nrad (the pairs are every pair of pattern stars
//!              closer than this)
//! 28     4     field radius, nrad: the cone that holds the whole field of view
//! 32     4     most stars in any cone of the field radius (an upper bound, for the
//!              false-match probability)
//! 36     4     epoch of the positions, hundredths of a Julian year (202500 = J2025.0)
//! 40     4     CRC-32 of the star section
//! 44     4     CRC-32 of the pair section
//! 48     4     CRC-32 of the k-vector section
//! 52     4     reserved, 0
//! 56     4     CRC-32 (ISO-HDLC) of bytes 0..56
//! 60     4     reserved, 0
//! 64   16*n_s  stars, sorted by z (ascending), each:
//!              x i32, y i32, z i32 (ICRS unit vector, Q1.30: value = bits / 2^30, norm 1
//!              within 2^-20), Hp i16 (millimagnitudes), B-V i16 (millimagnitudes)
//! ...   8*n_p  pairs, sorted by separation (ascending), each:
//!              separation u32 (nrad, below the largest separation), star a u16, star b u16
//!              (indices into the star section, a < b)
//! ...  4*(n_k+1) k-vector: entry k = number of pairs whose separation is below
//!              k * largest separation / n_k (entry 0 = 0, entry n_k = n_p, non-decreasing)
//! ```
//!
//! Any byte that differs from what the builder wrote fails a CRC; a catalog that fails any
//! check is never used ([`CatalogError`] says which check).

mod error;
mod parse;

pub use error::CatalogError;
pub use parse::{Catalog, CatalogStar, Cone, StarPair};

/// The four bytes a catalog starts with.
pub const MAGIC: [u8; 4] = *b"STCG";
/// The catalog format version this crate reads.
pub const VERSION: u16 = 1;
/// Size of the header in bytes.
pub const HEADER_LEN: usize = 64;
/// Size of one star entry in bytes.
pub const STAR_LEN: usize = 16;
/// Size of one pair entry in bytes.
pub const PAIR_LEN: usize = 8;
/// Size of one k-vector entry in bytes.
pub const KVEC_ENTRY_LEN: usize = 4;
/// Most stars a catalog may hold (a pair stores star indices as u16).
pub const MAX_STARS: u32 = 65_535;
/// Most k-vector bins.
pub(crate) const MAX_KVEC_BINS: u32 = 65_536;
/// Scale of the Q1.30 unit-vector components: value = bits / 2^30.
pub const UNIT_SCALE: f64 = 1_073_741_824.0;
/// Tolerance on a stored unit vector's norm: | |v| - 1 | below 2^-20.
pub(crate) const UNIT_NORM_TOLERANCE: f64 = 1.0 / 1_048_576.0;
/// Nanoradians per radian (the unit of stored angles).
pub const NRAD_PER_RAD: f64 = 1e9;

/// The CRC of every section and of the header: CRC-32/ISO-HDLC (the zlib/PNG CRC), as in the
/// calibration table.
pub const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
