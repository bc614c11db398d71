//! The calibration table: every map and list the calibration needs, in one byte string that
//! the firmware reads in place from flash (zero-copy, no allocation) and host tools write.
//!
//! # Layout (version 1, all integers little-endian)
//!
//! ```text
//! offset size  field
//!  0     4     magic  b"STCT"
//!  4     2     version = 1
//!  6     2     section count n (at most 16)
//!  8     4     total length of the table in bytes (header + directory + sections)
//! 12     2     geometry.overscan_px
//! 14     2     geometry.covered_px
//! 16     2     geometry.active_cols
//! 18     2     geometry.active_rows
//! 20     2     geometry.lines
//! 22     1     geometry.outputs (1 or 2)
//! 23     1     reserved, 0
//! 24     2     saturation level, ADU: a raw sample at or above it is flagged saturated
//! 26     2     reserved, 0
//! 28     4     header CRC-32 (ISO-HDLC) of bytes 0..28 followed by the directory
//! 32   16*n    directory, one entry per section:
//!              kind u16, reserved u16, offset u32, length u32, CRC-32 of the section u32
//! ...          sections, back to back from the end of the directory to the end of the table
//!              (in any order, no gap, no overlap: every byte is under exactly one CRC)
//! ```
//!
//! # Sections
//! | kind | name | contents | format |
//! |---|---|---|---|
//! | 1 | gains | one per output | u32, [`GainEPerAdu`](crate::units::GainEPerAdu) U4F28 e-/ADU, not 0 |
//! | 2 | column bias | one per raw column (`line_len`) | i16, [`ColumnBiasAdu`](crate::units::ColumnBiasAdu) I12F4 ADU |
//! | 3 | relative dark | [map header](MapHeader) + u8 per tile | [`DarkRel`](crate::units::DarkRel) U2F6, covered mean = 1 |
//! | 4 | inverse flat | map header + u16 per tile | [`FlatInv`](crate::units::FlatInv) U2F14, not 0 |
//! | 5 | hot pixels | u32 reference temperature U16F16 K, u32 count, entries | see [`HotPixel`] |
//! | 6 | telegraph pixels | u32 count, entries x u16, y u16 | active coordinates |
//! | 7 | pixel-phase correction | u16 count (1..=16), u16 reserved 0, curves back to back | see [`pixcorr`] |
//! | 8 | CTI coefficients | reference flux, exponent, per output parallel and serial shift per transfer | see [`CtiCoeffs`] |
//! | 9 | field PSF model | degree, scatter, star count, polynomial coefficients of `a(x, y)` | see [`PsfModel`] |
//! | 10 | camera model | 36 bytes, below | see [`camera`] |
//! | 11 | dark law | 16 bytes: covered dark rate at `T_ref`, `T_ref`, doubling, band | see [`DarkLaw`] |
//!
//! Gains are required; every other section is optional and its absence means "no
//! correction": column bias 0, relative dark 1 (the covered columns' dark subtracted
//! uniformly), flat 1, no hot or telegraph pixels, an uncorrected centre of gravity, no CTI
//! correction, no field PSF model, no dark law (the tracker's dark drift is not measured
//! unless the home sets a law).
//!
//! A pixel-phase correction curve (section 7) is an 8-byte header (power, box side,
//! background, knot count, PSF width `a` U8F8 px, largest measured phase U0F16 px) and its
//! knots (i16, I1F15 px); each curve is checked like any entry, and a bad one is reported as
//! [`TableError::PixCorrCurve`] with its index. The host builds them
//! (`startrack_sim::pixcorr`); the firmware picks one with [`CalibTable::pixcorr`] and
//! [`pixcorr::PixCorrSet::find`].
//!
//! A map covers the active area in square tiles of `2^tile_log2` pixels (0 = one value per
//! pixel, the full map; larger tiles are the reduced form that fits internal flash: the
//! CCD47-20's full relative dark map is 1 MB, in 4x4 tiles 64 KB). Map header (8 bytes):
//! `tile_log2 u8` (0..=10), `element format u8` (1 = U2F6 u8, 2 = U2F14 u16),
//! `reserved u16`, `tiles_x u16`, `tiles_y u16` (= active size divided by the tile, rounded up).
//!
//! The camera model (section 10, optional; absent means the caller's nominal camera) is
//! [`camera::CAMERA_SECTION_LEN`] bytes of fixed-point values, laid out in [`camera`]; the
//! parser checks that its distortion is invertible over the active area for every colour
//! in [`camera::COLOUR_RANGE_BV_MAG`] and reports [`TableError::CameraModel`] otherwise.
//!
//! Hot-pixel entries (12 bytes): `x u16, y u16` (active coordinates), `dark rate u32`
//! (U16F16 e-/s at the reference temperature), `doubling u16` (U8F8 K: the rate doubles
//! every this many kelvin, the pixel's own law), `policy u8` (0 correct, 1 exclude),
//! `reserved u8`. Hot and telegraph entries are sorted by (y, x) with no repeats.

mod amend;
mod bytes;
pub mod camera;
pub(crate) mod cti;
pub(crate) mod darklaw;
mod error;
mod parse;
pub mod pixcorr;
pub(crate) mod psfmodel;
mod write;

pub use amend::{AmendError, AmendPlan, MAX_AMEND_PIXELS, TableReader};
pub use cti::{CtiCoeffs, CtiOutput};
pub use darklaw::{DARK_LAW_SECTION_LEN, DarkLaw};
pub use error::{SectionKind, TableError, WriteError};
pub use parse::{CalibTable, DefectList, HotList, MapView};
pub use psfmodel::{MAX_PSF_DEGREE, MAX_PSF_TERMS, PsfModel, psf_terms};
pub use write::{MapSpec, TableSpec, write_table, write_table_with_pixcorr};

use crate::units::{ERatePerS, Kelvin};
use fixed::types::U8F8;

/// The four bytes a table starts with.
pub const MAGIC: [u8; 4] = *b"STCT";
/// The table format version this crate reads and writes.
pub const VERSION: u16 = 1;
/// Size of the fixed header in bytes.
pub const HEADER_LEN: usize = 32;
/// Size of one directory entry in bytes.
pub const DIR_ENTRY_LEN: usize = 16;
/// Size of a map section's header in bytes.
pub const MAP_HEADER_LEN: usize = 8;
/// Size of one hot-pixel entry in bytes.
pub const HOT_ENTRY_LEN: usize = 12;
/// Size of one telegraph-pixel entry in bytes.
pub const TELEGRAPH_ENTRY_LEN: usize = 4;
/// Most curves a pixel-phase correction section may hold.
pub const MAX_PIXCORR_CURVES: u16 = 16;
/// Size of the pixel-phase correction section's own header (count, reserved).
pub const PIXCORR_HEADER_LEN: usize = 4;
/// Largest map tile: 2^10 = 1024 pixels.
pub const MAX_TILE_LOG2: u8 = 10;

/// The CRC every section and the header carry: CRC-32/ISO-HDLC (the zlib/PNG CRC), so that
/// any tool can check a table.
pub(crate) const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// What the calibration does with a hot pixel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HotPolicy {
    /// Subtract the pixel's own dark signal, from its rate and temperature law.
    Correct,
    /// Do not use the pixel; a star window that holds it is flagged.
    Exclude,
}

/// A pixel with abnormally high dark current and its own temperature law.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HotPixel {
    /// Active column.
    pub x: u16,
    /// Active row.
    pub y: u16,
    /// Dark rate at the table's reference temperature, e-/s.
    pub rate_e_per_s: ERatePerS,
    /// The rate doubles every `doubling_k` kelvin (U8F8, > 0).
    pub doubling_k: U8F8,
    /// Correct or exclude.
    pub policy: HotPolicy,
}

/// The reference temperature of the hot-pixel rates.
pub type RefTemperature = Kelvin;

/// A map's tiling, shared by the relative dark and inverse flat maps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MapHeader {
    /// Tiles are `2^tile_log2` pixels square.
    pub tile_log2: u8,
    /// Tiles across the active area.
    pub tiles_x: u16,
    /// Tiles down the active area.
    pub tiles_y: u16,
}

impl MapHeader {
    /// The tiling of an active area of `cols` x `rows` with tiles of `2^tile_log2` pixels.
    pub const fn for_area(cols: u16, rows: u16, tile_log2: u8) -> Self {
        let tile_log2 = if tile_log2 > 16 { 16 } else { tile_log2 };
        let t = 1u32 << tile_log2;
        Self {
            tile_log2,
            tiles_x: ((cols as u32 + t - 1) >> tile_log2) as u16,
            tiles_y: ((rows as u32 + t - 1) >> tile_log2) as u16,
        }
    }

    /// Number of tiles.
    pub const fn tiles(&self) -> usize {
        self.tiles_x as usize * self.tiles_y as usize
    }
}
