//! Layout: every byte of a table is under a CRC (gaps and overlaps between sections are
//! rejected), map look-ups outside the active area are neutral, and a table stored at the
//! start of a larger region (the flash sector) parses with `parse_prefix`. Cost: a small
//! table parsed a few times.

use super::{parse_unit, small_table};
use startrack_core::table::{CalibTable, DIR_ENTRY_LEN, HEADER_LEN, SectionKind, TableError};
use startrack_core::units::{DarkRel, FlatInv};
use startrack_test_support::table_fixtures::*;

#[test]
fn gaps_and_overlaps_between_sections_are_rejected() {
    let t = small_table();
    // A gap at the end: one extra byte that no section (and so no CRC) covers.
    let mut b = t.clone();
    b.push(0);
    let total = b.len() as u32;
    wr32(&mut b, 8, total);
    reseal_all(&mut b);
    assert!(matches!(parse_unit(&b), Err(TableError::SectionLayout(_))));
    // A gap in the middle: move the last section one byte later.
    let n = usize::from(rd16(&t, 6));
    let last = (0..n)
        .max_by_key(|i| rd32(&t, HEADER_LEN + i * DIR_ENTRY_LEN + 4))
        .unwrap();
    let e = HEADER_LEN + last * DIR_ENTRY_LEN;
    let (off, len) = (rd32(&t, e + 4) as usize, rd32(&t, e + 8) as usize);
    let mut b = t[..off].to_vec();
    b.push(0);
    b.extend_from_slice(&t[off..off + len]);
    let total = b.len() as u32;
    wr32(&mut b, 8, total);
    wr32(&mut b, e + 4, off as u32 + 1);
    reseal_all(&mut b);
    let kind = SectionKind::from_code(rd16(&t, e)).unwrap();
    assert_eq!(parse_unit(&b), Err(TableError::SectionLayout(kind)));
    // An overlap: the last section also claims the byte before it.
    let mut b = t.clone();
    wr32(&mut b, e + 4, off as u32 - 1);
    wr32(&mut b, e + 8, len as u32 + 1);
    reseal_all(&mut b);
    assert_eq!(parse_unit(&b), Err(TableError::SectionLayout(kind)));
}

#[test]
fn map_lookups_outside_the_active_area_are_neutral() {
    // Per pixel and tiled: a pixel just past the right or bottom edge must not read the next
    // row's value.
    for log2 in [0u8, 3] {
        let s = full_spec(SMALL, log2, log2);
        let bytes = s.write();
        let t = CalibTable::parse(&bytes).unwrap();
        let (w, h) = (SMALL.active_cols, SMALL.active_rows);
        for (x, y) in [(w, 0), (w, 1), (0, h), (w + 7, 3), (w - 1, h)] {
            assert_eq!(t.dark_rel(x, y), DarkRel::ONE, "tile 2^{log2} ({x},{y})");
            assert_eq!(t.flat_inv(x, y), FlatInv::ONE, "tile 2^{log2} ({x},{y})");
        }
    }
}

#[test]
fn a_table_at_the_start_of_a_larger_region() {
    let t = small_table();
    let mut region = t.clone();
    region.resize(t.len() + 4096, 0xFF);
    let parsed = CalibTable::parse_prefix(&region).expect("prefix parses");
    assert_eq!(parsed.len_bytes(), t.len());
    // Erased flash, a stated length past the region, a region too short for the header.
    assert_eq!(
        CalibTable::parse_prefix(&[0xFF; 4096]).err(),
        Some(TableError::BadMagic)
    );
    assert_eq!(
        CalibTable::parse_prefix(&region[..t.len() - 1]).err(),
        Some(TableError::LengthMismatch {
            header: t.len() as u32,
            actual: t.len() as u32 - 1
        })
    );
    assert!(matches!(
        CalibTable::parse_prefix(&t[..10]),
        Err(TableError::TooShort { .. })
    ));
    // A corrupt table inside the region is still rejected.
    let mut bad = region.clone();
    bad[t.len() - 1] ^= 1;
    assert!(CalibTable::parse_prefix(&bad).is_err());
}
