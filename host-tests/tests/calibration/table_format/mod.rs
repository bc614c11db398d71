//! The calibration-table contract: what `write_table` writes parses back to the same values,
//! absent sections read as neutral, and every kind of corruption is rejected with its own
//! `TableError`.
//!
//! - [`round_trip`]: written tables follow the documented layout and parse back;
//! - [`header`]: corruptions of the header and the directory;
//! - [`sections`]: corruptions of the sections' contents;
//! - [`errors`]: `write_table` refuses what the parser refuses; every error's display;
//! - [`layout`]: every byte under a CRC; tables at the start of a larger region;
//! - [`pixcorr`]: the pixel-phase correction section;
//! - [`cti_psf`]: the CTI coefficients and the field PSF model;
//! - [`darklaw`]: the covered pixels' dark law.
//!
//! The fixtures (owned specs, an independent encoder, CRC re-sealing) are shared with
//! `table_fuzz` in `startrack-test-support` (`host-tests/test-support/src/table_fixtures/`).

use startrack_test_support::table_fixtures;

mod cti_psf;
mod darklaw;
mod errors;
mod header;
mod layout;
mod pixcorr;
mod round_trip;
mod sections;

use startrack_core::table::{CalibTable, SectionKind, TableError};
use table_fixtures::*;

fn small_table() -> Vec<u8> {
    full_spec(SMALL_DUAL, 0, 2).write()
}

fn ccd_gains_only() -> Vec<u8> {
    gains_only(CCD).write()
}

fn parse_unit(b: &[u8]) -> Result<(), TableError> {
    CalibTable::parse(b).map(|_| ())
}

/// `t` with the section of `kind` replaced by `data` (fresh lengths and CRCs).
fn with_section(t: &[u8], kind: SectionKind, f: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut raw = RawTable::decompose(t);
    f(raw.section_mut(kind));
    raw.build()
}
