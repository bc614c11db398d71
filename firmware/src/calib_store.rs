//! The calibration table store: finds the table in the `CALIB` flash region, has the core
//! check it, and hands out the checked table or, when there is none or it is bad, nothing.
//!
//! The region is the last 128 KB sector of flash (bank 2, 0x081E_0000), outside the firmware
//! image, so reflashing the firmware keeps the table (unless the whole chip is erased). `memory.x` exports its start and size
//! as the symbols `_calib_start` and `_calib_len`. The table is read in place (zero-copy):
//! the returned [`CalibTable`] borrows the flash for `'static`.
//!
//! A missing or bad table (erased flash reads 0xFF and fails on the magic) never stops the
//! firmware and is never partly used: the typed error is logged and the firmware runs
//! uncalibrated, which every line summary then flags.
//!
//! Not done yet: writing a table into the region from the firmware (the core's
//! `table::write_table` makes one on the host; flash it with
//! `probe-rs download --chip STM32H743ZITx --binary-format bin --base-address 0x081E0000 FILE`).

use crate::lines::GEOMETRY;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{CalibTable, TableError};

unsafe extern "C" {
    /// First byte of the `CALIB` flash region (defined in `memory.x`).
    static _calib_start: u8;
    /// Size of the `CALIB` region in bytes, as the *address* of this absolute symbol.
    static _calib_len: u8;
}

/// Why no table is used.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum StoreError {
    /// The core rejected the bytes (bad magic on erased flash, CRC, ranges, ...).
    Table(TableError),
    /// A valid table, made for another readout geometry than this firmware's.
    GeometryMismatch {
        /// The geometry in the table.
        table: ReadoutGeometry,
        /// The geometry this firmware reads.
        firmware: ReadoutGeometry,
    },
}

/// The whole `CALIB` flash region.
fn region() -> &'static [u8] {
    // Only the symbols' addresses matter. The region is not a Rust object (the u8 declared
    // above is just a name for its first byte), so the slice is built from the plain address,
    // as for any memory-mapped area, not from a pointer to that one-byte static.
    let start = core::ptr::with_exposed_provenance::<u8>((&raw const _calib_start).addr());
    let len = (&raw const _calib_len).addr();
    // SAFETY: `_calib_start` and `_calib_len` come from memory.x and describe the CALIB
    // region of internal flash (0x081E_0000, 128 KB): memory-mapped, always readable,
    // non-null, aligned for u8, smaller than isize::MAX, and outside every Rust object.
    // Nothing in this firmware writes or erases that flash, so the bytes do not change for
    // the life of the program and a shared `'static` slice over them is sound. (A sector
    // left half-programmed by an interrupted write could raise an ECC bus fault on read;
    // flashing tools erase the sector before writing it.)
    unsafe { core::slice::from_raw_parts(start, len) }
}

/// Reads and checks the table; logs the outcome either way.
pub fn load() -> Result<CalibTable<'static>, StoreError> {
    let region = region();
    let result = CalibTable::parse_prefix(region)
        .map_err(StoreError::Table)
        .and_then(|table| {
            if *table.geometry() == GEOMETRY {
                Ok(table)
            } else {
                Err(StoreError::GeometryMismatch {
                    table: *table.geometry(),
                    firmware: GEOMETRY,
                })
            }
        });
    match &result {
        Ok(table) => defmt::info!(
            "calib: table OK at {=usize:#x} ({} bytes in a {} byte region), saturation {} ADU, column bias {}, dark map {}, flat map {}, {} hot, {} telegraph",
            region.as_ptr() as usize,
            table.len_bytes(),
            region.len(),
            table.saturation_adu(),
            table.has_column_bias(),
            table.dark_map().is_some(),
            table.flat_map().is_some(),
            table.hot_pixels().len(),
            table.telegraph_pixels().len()
        ),
        Err(e) => defmt::error!(
            "calib: no usable table at {=usize:#x}: {}; running UNCALIBRATED",
            region.as_ptr() as usize,
            e
        ),
    }
    result
}
