//! Corruptions inside the sections, each re-sealed so that the content check is the one
//! that fails: section lengths, map formats, out-of-range gains, flat tiles, hot and
//! telegraph pixels. Cost: a small table rebuilt and parsed per case.

use super::{parse_unit, small_table, with_section};
use fixed::types::U8F8;
use startrack_core::table::{CalibTable, HotPixel, HotPolicy, SectionKind, TableError, WriteError};
use startrack_core::units::{DarkRel, ERatePerS, FlatInv, GainEPerAdu};
use startrack_test_support::table_fixtures::*;

#[test]
fn section_length() {
    let t = small_table();
    let sl = |k| Err(TableError::SectionLength(k));
    // Gains: one output's worth on a two-output geometry, three outputs, an odd length, none.
    let one = enc_gains(&[GainEPerAdu::ONE]);
    let three = enc_gains(&[GainEPerAdu::ONE; 3]);
    for g in [one, three, vec![0x01; 7], Vec::new()] {
        let b = with_section(&t, SectionKind::Gains, |d| *d = g);
        assert_eq!(parse_unit(&b), sl(SectionKind::Gains));
    }
    // Column bias: one column short, one extra, one byte extra, empty.
    for f in [
        (|d: &mut Vec<u8>| d.truncate(d.len() - 2)) as fn(&mut Vec<u8>),
        |d| d.extend([0, 0]),
        |d| d.push(0),
        |d| d.clear(),
    ] {
        let b = with_section(&t, SectionKind::ColumnBias, f);
        assert_eq!(parse_unit(&b), sl(SectionKind::ColumnBias));
    }
    // Maps: one element short, one element extra, header only, nothing at all.
    for (kind, elem) in [(SectionKind::DarkRel, 1), (SectionKind::FlatInv, 2)] {
        let b = with_section(&t, kind, |d| d.truncate(d.len() - elem));
        assert_eq!(parse_unit(&b), sl(kind));
        let b = with_section(&t, kind, |d| d.extend(vec![0x40; elem]));
        assert_eq!(parse_unit(&b), sl(kind));
        let b = with_section(&t, kind, |d| d.truncate(8));
        assert_eq!(parse_unit(&b), sl(kind));
        let b = with_section(&t, kind, |d| d.clear());
        assert_eq!(parse_unit(&b), sl(kind));
    }
    // Hot pixels: the count disagrees with the bytes either way, a stray byte, no count.
    let k = SectionKind::HotPixels;
    let b = with_section(&t, k, |d| {
        let v = rd32(d, 4);
        wr32(d, 4, v + 1)
    });
    assert_eq!(parse_unit(&b), sl(k));
    let b = with_section(&t, k, |d| {
        let v = rd32(d, 4);
        wr32(d, 4, v - 1)
    });
    assert_eq!(parse_unit(&b), sl(k));
    let b = with_section(&t, k, |d| wr32(d, 4, u32::MAX));
    assert_eq!(parse_unit(&b), sl(k));
    let b = with_section(&t, k, |d| d.push(0));
    assert_eq!(parse_unit(&b), sl(k));
    let b = with_section(&t, k, |d| d.truncate(6));
    assert_eq!(parse_unit(&b), sl(k));
    // Telegraph pixels likewise.
    let k = SectionKind::Telegraph;
    let b = with_section(&t, k, |d| {
        let v = rd32(d, 0);
        wr32(d, 0, v + 1)
    });
    assert_eq!(parse_unit(&b), sl(k));
    let b = with_section(&t, k, |d| d.truncate(d.len() - 1));
    assert_eq!(parse_unit(&b), sl(k));
    let b = with_section(&t, k, |d| d.truncate(3));
    assert_eq!(parse_unit(&b), sl(k));
    // Empty lists with a zero count are fine.
    let b = with_section(&t, k, |d| *d = 0u32.to_le_bytes().to_vec());
    assert!(
        CalibTable::parse(&b)
            .expect("empty telegraph list")
            .telegraph_pixels()
            .is_empty()
    );
}

#[test]
fn map_format() {
    let t = small_table();
    for kind in [SectionKind::DarkRel, SectionKind::FlatInv] {
        let mf = Err(TableError::MapFormat(kind));
        for l in [11u8, 16, 255] {
            let b = with_section(&t, kind, |d| d[0] = l);
            assert_eq!(parse_unit(&b), mf, "tile_log2 {l}");
        }
        let wrong_formats: &[u8] = if kind == SectionKind::DarkRel {
            &[0, 2, 3]
        } else {
            &[0, 1, 3]
        };
        for &f in wrong_formats {
            let b = with_section(&t, kind, |d| d[1] = f);
            assert_eq!(parse_unit(&b), mf, "{} format {f}", kind.name());
        }
        let b = with_section(&t, kind, |d| wr16(d, 2, 1));
        assert_eq!(parse_unit(&b), mf, "map reserved");
        for off in [4, 6] {
            for delta in [1i32, -1] {
                let b = with_section(&t, kind, |d| {
                    let v = i32::from(rd16(d, off)) + delta;
                    wr16(d, off, v as u16)
                });
                assert_eq!(parse_unit(&b), mf, "tile count at {off} {delta:+}");
            }
        }
        // A different tile size with the old tile counts and data.
        let b = with_section(&t, kind, |d| d[0] += 1);
        assert_eq!(parse_unit(&b), mf);
    }
}

#[test]
fn write_table_writes_a_rejected_tile_size_as_map_format() {
    let mut s = full_spec(SMALL, 0, 0);
    s.dark = Some((11, vec![DarkRel::ONE]));
    assert_eq!(
        write_spec(&s.spec()),
        Err(WriteError::Invalid(TableError::MapFormat(
            SectionKind::DarkRel
        )))
    );
    let mut s = full_spec(SMALL, 0, 0);
    s.flat = Some((200, vec![FlatInv::ONE]));
    assert_eq!(
        write_spec(&s.spec()),
        Err(WriteError::Invalid(TableError::MapFormat(
            SectionKind::FlatInv
        )))
    );
}

fn oor(section: SectionKind, index: u32) -> Result<(), TableError> {
    Err(TableError::OutOfRange { section, index })
}

#[test]
fn out_of_range_gains_and_flat() {
    let t = small_table();
    for i in 0..2 {
        let b = with_section(&t, SectionKind::Gains, |d| wr32(d, 4 * i, 0));
        assert_eq!(parse_unit(&b), oor(SectionKind::Gains, i as u32));
    }
    // The first zero inverse-flat tile is reported, by its index.
    let s = full_spec(SMALL_DUAL, 0, 0);
    let t = s.write();
    let b = with_section(&t, SectionKind::FlatInv, |d| {
        wr16(d, 8 + 2 * 150, 0);
        wr16(d, 8 + 2 * 37, 0);
    });
    assert_eq!(parse_unit(&b), oor(SectionKind::FlatInv, 37));
    let last = 16 * 12 - 1;
    let b = with_section(&t, SectionKind::FlatInv, |d| wr16(d, 8 + 2 * last, 0));
    assert_eq!(parse_unit(&b), oor(SectionKind::FlatInv, last as u32));
    // A zero dark is fine (U2F6, 0..4): no range check on it.
    let b = with_section(&t, SectionKind::DarkRel, |d| d[8 + 5] = 0);
    let p = CalibTable::parse(&b).expect("zero dark is valid");
    assert_eq!(p.dark_rel(5, 0), DarkRel::ZERO);
}

/// The small table with its hot list replaced by `entries` (raw 12-byte entries).
fn with_hot(t: &[u8], entries: &[Vec<u8>]) -> Vec<u8> {
    with_section(t, SectionKind::HotPixels, |d| {
        d.truncate(4);
        d.extend((entries.len() as u32).to_le_bytes());
        entries.iter().for_each(|e| d.extend(e));
    })
}

fn hp(x: u16, y: u16) -> HotPixel {
    HotPixel {
        x,
        y,
        rate_e_per_s: ERatePerS::from_num(12.5),
        doubling_k: U8F8::from_num(6.5),
        policy: HotPolicy::Exclude,
    }
}

fn entry(x: u16, y: u16) -> Vec<u8> {
    enc_hot_entry(&hp(x, y), 1, 0)
}

#[test]
fn out_of_range_hot_pixels() {
    let t = small_table();
    let (c, r) = (SMALL_DUAL.active_cols, SMALL_DUAL.active_rows);
    let k = SectionKind::HotPixels;
    // Sanity: the replacement itself parses.
    let ok = with_hot(
        &t,
        &[entry(0, 0), entry(5, 0), entry(1, 1), entry(c - 1, r - 1)],
    );
    assert_eq!(CalibTable::parse(&ok).expect("valid").hot_pixels().len(), 4);
    let cases: Vec<(Vec<Vec<u8>>, u32)> = vec![
        (vec![entry(0, 0), entry(c, 0)], 1),
        (vec![entry(u16::MAX, 0)], 0),
        (vec![entry(0, 0), entry(1, 0), entry(0, r)], 2),
        (vec![entry(3, 2), entry(2, 2)], 1),
        (vec![entry(0, 3), entry(5, 2)], 1),
        (vec![entry(0, 0), entry(4, 4), entry(4, 4)], 2),
        (vec![entry(0, 0), enc_hot_entry(&hp(1, 0), 2, 0)], 1),
        (vec![enc_hot_entry(&hp(1, 0), 0xFF, 0)], 0),
        (
            vec![
                entry(0, 0),
                entry(1, 0),
                enc_hot_entry(
                    &HotPixel {
                        doubling_k: U8F8::ZERO,
                        ..hp(2, 0)
                    },
                    0,
                    0,
                ),
            ],
            2,
        ),
        (vec![enc_hot_entry(&hp(1, 0), 0, 1)], 0),
    ];
    for (entries, index) in cases {
        assert_eq!(
            parse_unit(&with_hot(&t, &entries)),
            oor(k, index),
            "{entries:?}"
        );
    }
}

#[test]
fn out_of_range_telegraph_pixels() {
    let t = small_table();
    let (c, r) = (SMALL_DUAL.active_cols, SMALL_DUAL.active_rows);
    let k = SectionKind::Telegraph;
    let cases: [(&[(u16, u16)], u32); 6] = [
        (&[(0, 0), (c, 1)], 1),
        (&[(0, r)], 0),
        (&[(0, 0), (1, 0), (2, u16::MAX)], 2),
        (&[(2, 1), (1, 1)], 1),
        (&[(0, 5), (15, 4)], 1),
        (&[(3, 3), (3, 3)], 1),
    ];
    for (list, index) in cases {
        let b = with_section(&t, k, |d| *d = enc_telegraph(list));
        assert_eq!(parse_unit(&b), oor(k, index), "{list:?}");
    }
}
