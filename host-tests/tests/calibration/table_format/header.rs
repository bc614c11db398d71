//! Corruptions of the header and the section directory, each starting from a valid table
//! and reaching exactly one check: length, magic, version, CRCs, reserved fields, section
//! count, geometry, unknown or duplicate sections, missing gains, sections out of bounds.
//! Cost: a small table parsed a few hundred times.

use super::{ccd_gains_only, parse_unit, small_table};
use startrack_core::geometry::GeometryError;
use startrack_core::table::{CalibTable, DIR_ENTRY_LEN, HEADER_LEN, SectionKind, TableError};
use startrack_test_support::table_fixtures::*;

#[test]
fn too_short() {
    assert_eq!(
        parse_unit(&[]),
        Err(TableError::TooShort { needed: 32, got: 0 })
    );
    let t = small_table();
    assert_eq!(
        parse_unit(&t[..31]),
        Err(TableError::TooShort {
            needed: 32,
            got: 31
        })
    );
    // Even erased flash shorter than a header is "too short", not "bad magic".
    assert_eq!(
        parse_unit(&[0xFF; 31]),
        Err(TableError::TooShort {
            needed: 32,
            got: 31
        })
    );
}

#[test]
fn bad_magic() {
    let t = small_table();
    for i in 0..4 {
        let mut b = t.clone();
        b[i] ^= 0x20;
        assert_eq!(parse_unit(&b), Err(TableError::BadMagic), "magic byte {i}");
    }
    // Erased flash, of the table's length and of a whole sector.
    assert_eq!(parse_unit(&vec![0xFF; t.len()]), Err(TableError::BadMagic));
    assert_eq!(
        parse_unit(&vec![0xFF; 128 * 1024]),
        Err(TableError::BadMagic)
    );
    assert_eq!(parse_unit(&[0u8; 64]), Err(TableError::BadMagic));
    // Magic bytes in the wrong order.
    let b = patched(&t, |b| b[..4].copy_from_slice(b"TCTS"));
    assert_eq!(parse_unit(&b), Err(TableError::BadMagic));
}

#[test]
fn unsupported_version() {
    let t = small_table();
    for v in [0u16, 2, 0x0100, u16::MAX] {
        let b = patched(&t, |b| wr16(b, 4, v));
        assert_eq!(parse_unit(&b), Err(TableError::UnsupportedVersion(v)));
    }
}

#[test]
fn length_mismatch() {
    let t = small_table();
    let n = t.len() as u32;
    assert_eq!(
        parse_unit(&t[..t.len() - 1]),
        Err(TableError::LengthMismatch {
            header: n,
            actual: n - 1
        })
    );
    let mut longer = t.clone();
    longer.push(0);
    assert_eq!(
        parse_unit(&longer),
        Err(TableError::LengthMismatch {
            header: n,
            actual: n + 1
        })
    );
    // The stated length changed, the bytes not.
    let b = patched(&t, |b| wr32(b, 8, n + 4));
    assert_eq!(
        parse_unit(&b),
        Err(TableError::LengthMismatch {
            header: n + 4,
            actual: n
        })
    );
    // A length that agrees with the bytes but is shorter than header + directory.
    let mut h = t[..HEADER_LEN].to_vec();
    wr32(&mut h, 8, HEADER_LEN as u32);
    reseal_header(&mut h);
    assert!(rd16(&h, 6) > 0);
    assert_eq!(
        parse_unit(&h),
        Err(TableError::LengthMismatch {
            header: 32,
            actual: 32
        })
    );
}

#[test]
fn header_crc() {
    let t = small_table();
    // Any header byte covered by the CRC (after the fields checked before it), any directory
    // byte, and the CRC itself.
    let n = usize::from(rd16(&t, 6));
    let dir_end = HEADER_LEN + DIR_ENTRY_LEN * n;
    for i in (12..28).chain(28..32).chain(HEADER_LEN..dir_end) {
        let mut b = t.clone();
        b[i] ^= 0x01;
        assert_eq!(parse_unit(&b), Err(TableError::HeaderCrc), "byte {i}");
    }
    // A changed section count with the length adjusted still fails the CRC.
    let mut b = t.clone();
    wr16(&mut b, 6, (n - 1) as u16);
    assert_eq!(parse_unit(&b), Err(TableError::HeaderCrc));
}

#[test]
fn reserved_fields() {
    let t = small_table();
    let b = patched(&t, |b| b[23] = 1);
    assert_eq!(parse_unit(&b), Err(TableError::Reserved));
    for v in [1u16, 0x8000] {
        let b = patched(&t, |b| wr16(b, 26, v));
        assert_eq!(parse_unit(&b), Err(TableError::Reserved));
    }
    // A directory entry's reserved field.
    let e = HEADER_LEN + dir_index(&t, SectionKind::FlatInv) * DIR_ENTRY_LEN;
    let b = patched(&t, |b| wr16(b, e + 2, 7));
    assert_eq!(parse_unit(&b), Err(TableError::Reserved));
    // Without resealing, the header CRC catches it first.
    let mut b = t.clone();
    b[23] = 1;
    assert_eq!(parse_unit(&b), Err(TableError::HeaderCrc));
}

#[test]
fn too_many_sections() {
    let t = small_table();
    let b = patched(&t, |b| wr16(b, 6, 17));
    assert_eq!(parse_unit(&b), Err(TableError::TooManySections(17)));
    let b = patched(&t, |b| wr16(b, 6, u16::MAX));
    assert!(matches!(
        CalibTable::parse(&b),
        Err(TableError::TooManySections(_))
    ));
    // Seventeen real directory entries, length consistent.
    let mut raw = RawTable::decompose(&t);
    while raw.sections.len() < 17 {
        raw.sections.push(RawSection::new(
            SectionKind::Gains,
            enc_gains(&gains(&SMALL_DUAL)),
        ));
    }
    assert_eq!(
        parse_unit(&raw.build()),
        Err(TableError::TooManySections(17))
    );
}

#[test]
fn bad_geometry() {
    let t = ccd_gains_only();
    let cases: [(usize, u16, GeometryError); 8] = [
        (22, 3, GeometryError::Outputs),
        (22, 0, GeometryError::Outputs),
        (16, 0, GeometryError::EmptyActiveArea),
        (18, 0, GeometryError::EmptyActiveArea),
        (18, 1034, GeometryError::EmptyActiveArea),
        (12, 0, GeometryError::NoOverScan),
        (16, 8146, GeometryError::TooLarge),
        (16, 1023, GeometryError::OddSplit),
    ];
    for (off, v, want) in cases {
        let b = patched(&t, |b| {
            if off == 22 {
                b[22] = v as u8;
            } else {
                wr16(b, off, v);
            }
        });
        assert_eq!(
            parse_unit(&b),
            Err(TableError::Geometry(want)),
            "field {off} = {v}"
        );
    }
    // The largest line still allowed: 2 * 8 + 2 * 16 + 8144 = 8192 elements.
    let b = patched(&t, |b| wr16(b, 16, 8144));
    assert_eq!(parse_unit(&b), Ok(()));
    let b = patched(&t, |b| wr16(b, 20, 9000));
    assert_eq!(
        parse_unit(&b),
        Err(TableError::Geometry(GeometryError::TooLarge))
    );
}

#[test]
fn unknown_section() {
    let t = small_table();
    for code in [0u16, 0x00FF, 0x0100, u16::MAX] {
        let mut raw = RawTable::decompose(&t);
        raw.sections.push(RawSection {
            kind: code,
            reserved: 0,
            data: vec![1, 2, 3],
        });
        assert_eq!(
            parse_unit(&raw.build()),
            Err(TableError::UnknownSection(code))
        );
    }
    // Re-labelling an existing entry.
    let e = HEADER_LEN + dir_index(&t, SectionKind::Telegraph) * DIR_ENTRY_LEN;
    let b = patched(&t, |b| wr16(b, e, 0x00FF));
    assert_eq!(parse_unit(&b), Err(TableError::UnknownSection(0x00FF)));
}

#[test]
fn duplicate_section() {
    let t = small_table();
    for kind in SectionKind::ALL {
        let mut raw = RawTable::decompose(&t);
        let copy = raw
            .sections
            .iter()
            .find(|s| s.kind == kind as u16)
            .expect("present")
            .clone();
        raw.sections.push(copy);
        assert_eq!(
            parse_unit(&raw.build()),
            Err(TableError::DuplicateSection(kind))
        );
    }
}

#[test]
fn missing_gains() {
    let t = small_table();
    let mut raw = RawTable::decompose(&t);
    raw.remove(SectionKind::Gains);
    assert_eq!(
        parse_unit(&raw.build()),
        Err(TableError::MissingSection(SectionKind::Gains))
    );
    raw.sections.clear();
    let b = raw.build();
    assert_eq!(b.len(), HEADER_LEN);
    assert_eq!(
        parse_unit(&b),
        Err(TableError::MissingSection(SectionKind::Gains))
    );
    // Any one optional section may go.
    for kind in &SectionKind::ALL[1..] {
        let mut raw = RawTable::decompose(&t);
        raw.remove(*kind);
        assert!(
            CalibTable::parse(&raw.build()).is_ok(),
            "without {}",
            kind.name()
        );
    }
}

#[test]
fn section_out_of_bounds() {
    let t = small_table();
    let n = usize::from(rd16(&t, 6));
    let dir_end = HEADER_LEN + DIR_ENTRY_LEN * n;
    let total = t.len() as u32;
    for kind in SectionKind::ALL {
        let e = HEADER_LEN + dir_index(&t, kind) * DIR_ENTRY_LEN;
        let len = rd32(&t, e + 8);
        let err = Err(TableError::SectionOutOfBounds(kind));
        // Offset inside the header or the directory.
        for off in [0u32, 27, 31, dir_end as u32 - 1] {
            let b = patched(&t, |b| wr32(b, e + 4, off));
            assert_eq!(parse_unit(&b), err, "{} at {off}", kind.name());
        }
        // Ending one past the table.
        let b = patched(&t, |b| wr32(b, e + 4, total - len + 1));
        assert_eq!(parse_unit(&b), err, "{} one past the end", kind.name());
        // Starting past the table.
        let b = patched(&t, |b| wr32(b, e + 4, total + 1));
        assert_eq!(parse_unit(&b), err);
        // Length past the end.
        let b = patched(&t, |b| wr32(b, e + 8, total));
        assert_eq!(parse_unit(&b), err);
        // offset + length overflows u32.
        let b = patched(&t, |b| {
            wr32(b, e + 4, u32::MAX - 3);
            wr32(b, e + 8, 0x20);
        });
        assert_eq!(parse_unit(&b), err, "{} overflowing", kind.name());
        let b = patched(&t, |b| {
            wr32(b, e + 4, dir_end as u32);
            wr32(b, e + 8, u32::MAX);
        });
        assert_eq!(parse_unit(&b), err, "{} u32::MAX long", kind.name());
    }
}

#[test]
fn section_crc() {
    let t = small_table();
    for kind in SectionKind::ALL {
        let (off, len) = section_range(&t, kind);
        for i in [off, off + len / 2, off + len - 1] {
            let mut b = t.clone();
            b[i] ^= 0x80;
            assert_eq!(
                parse_unit(&b),
                Err(TableError::SectionCrc(kind)),
                "{} byte {i}",
                kind.name()
            );
        }
        // A wrong stored CRC with the header resealed.
        let e = HEADER_LEN + dir_index(&t, kind) * DIR_ENTRY_LEN;
        let mut b = t.clone();
        wr32(&mut b, e + 12, rd32(&t, e + 12) ^ 1);
        reseal_header(&mut b);
        assert_eq!(parse_unit(&b), Err(TableError::SectionCrc(kind)));
    }
}
