//! The on-board star catalog where the programmer put it (the board's `CATALOG_ADDRESS`: on
//! the STM32H743 bank 1's last five sectors, `CATALOG` in its memory map, 0x0806_0000,
//! 640 KB; on `mps2-an500` where the PIL loads it), read in place and checked completely by the
//! core's parser (magic, version, lengths, every CRC and entry) once at start-up.
//!
//! The catalog (584,404 bytes for a 15 degree field, docs/attitude.md) does not fit the table
//! store's 256 KB catalog slots in bank 2, so it is not uploaded over the link: a person with
//! a board writes it with probe-rs (docs/hardware.md). An erased or corrupt region is a typed
//! error, the `NO_CATALOG` set-up fault, and a tracker without attitude.
//!
//! Cost: one pass of CRC-32 over the catalog at start-up (about 0.6 M bytes).

use crate::board::{CATALOG_ADDRESS, CATALOG_REGION_B};
use startrack_core::catalog::{Catalog, CatalogError};

/// The catalog in its flash region, or why there is none.
pub fn load() -> Result<Catalog<'static>, CatalogError> {
    let start = core::ptr::with_exposed_provenance::<u8>(CATALOG_ADDRESS);
    // SAFETY: the region is the board's catalog region, memory-mapped and readable; the
    // firmware never erases or programs it (the table store writes only its own flash), and
    // the linker keeps code and data out of it (the board's memory map), so the bytes stay as
    // they are for the program's life.
    let region: &'static [u8] = unsafe { core::slice::from_raw_parts(start, CATALOG_REGION_B) };
    // The header's total length (bytes 8..12) says how much of the region is the catalog;
    // anything longer than the region (an erased region reads 0xFFFF_FFFF) is refused by the
    // parser as a length mismatch against the whole region.
    let total = region
        .get(8..12)
        .and_then(|b| <[u8; 4]>::try_from(b).ok())
        .map_or(0, u32::from_le_bytes) as usize;
    let bytes = region.get(..total).unwrap_or(region);
    Catalog::parse(bytes)
}
