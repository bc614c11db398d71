//! The covered pixels' dark law (section 11): its bytes at their documented offsets, each
//! field's range with its own error index, the reserved field, the length, `write_table`
//! refusing what the parser refuses, and a table without the section reading no law.

use super::{parse_unit, with_section};
use fixed::types::U8F8;
use startrack_core::table::DARK_LAW_SECTION_LEN;
use startrack_core::table::{CalibTable, DarkLaw, SectionKind, TableError, WriteError};
use startrack_core::units::{ERatePerS, Kelvin};
use startrack_test_support::table_fixtures::*;

const K: SectionKind = SectionKind::DarkLaw;

fn out_of_range(index: u32) -> Result<(), TableError> {
    Err(TableError::OutOfRange { section: K, index })
}

#[test]
fn dark_law_section_values_and_layout() {
    let t = full_spec(SMALL, 0, 0).write();
    let law = CalibTable::parse(&t)
        .expect("parses")
        .dark_law()
        .expect("present");
    assert_eq!(law, dark_law());
    // The documented layout, read back from the section's bytes by hand.
    let raw = RawTable::decompose(&t);
    let d = raw
        .sections
        .iter()
        .find(|s| s.kind == K as u16)
        .expect("section")
        .data
        .clone();
    assert_eq!(d.len(), DARK_LAW_SECTION_LEN);
    assert_eq!(rd32(&d, 0), 0x000C_5876, "rate U16F16");
    assert_eq!(rd32(&d, 4), (253.75 * 65536.0) as u32, "T_ref U16F16");
    assert_eq!(rd16(&d, 8), 0x0680, "doubling U8F8");
    assert_eq!((rd16(&d, 10), rd16(&d, 12)), (0x00C0, 0x0180), "band U8F8");
    assert_eq!(rd16(&d, 14), 0, "reserved");
    // 12.3456 e-/px/s for 2 s, 6.5 K below T_ref: half of 24.69 e-.
    let p = law
        .predicted_e(Kelvin::from_num(247.25), 2000)
        .expect("doubling > 0");
    assert!((p - 12.3456).abs() < 1e-3, "{p}");
    assert_eq!(
        CalibTable::parse(&gains_only(SMALL).write())
            .expect("parses")
            .dark_law(),
        None
    );
}

#[test]
fn dark_law_section_errors() {
    let t = full_spec(SMALL_DUAL, 0, 0).write();
    for len in [DARK_LAW_SECTION_LEN - 1, DARK_LAW_SECTION_LEN + 1, 0] {
        let b = with_section(&t, K, |d| d.resize(len, 0));
        assert_eq!(
            parse_unit(&b),
            Err(TableError::SectionLength(K)),
            "{len} bytes"
        );
    }
    for at in [14usize, 15] {
        let b = with_section(&t, K, |d| d[at] = 1);
        assert_eq!(parse_unit(&b), Err(TableError::Reserved), "byte {at}");
    }
    // Rate 0.
    assert_eq!(
        parse_unit(&with_section(&t, K, |d| wr32(d, 0, 0))),
        out_of_range(0)
    );
    // Reference temperature below 100 K and above 400 K; the ends are in range.
    for (k, want) in [
        (99.99, out_of_range(1)),
        (100.0, Ok(())),
        (400.0, Ok(())),
        (400.01, out_of_range(1)),
    ] {
        let bits = Kelvin::from_num(k).to_bits();
        assert_eq!(
            parse_unit(&with_section(&t, K, |d| wr32(d, 4, bits))),
            want,
            "T_ref {k}"
        );
    }
    // Doubling outside 2..=20 K (zero among them); the ends are in range.
    for (k, want) in [
        (0.0, out_of_range(2)),
        (1.99, out_of_range(2)),
        (2.0, Ok(())),
        (20.0, Ok(())),
        (20.01, out_of_range(2)),
    ] {
        let bits = U8F8::from_num(k).to_bits();
        assert_eq!(
            parse_unit(&with_section(&t, K, |d| wr16(d, 8, bits))),
            want,
            "doubling {k}"
        );
    }
    // Band inverted, or empty.
    let b = with_section(&t, K, |d| {
        wr16(d, 10, 0x0180);
        wr16(d, 12, 0x00C0);
    });
    assert_eq!(parse_unit(&b), out_of_range(3));
    let b = with_section(&t, K, |d| wr16(d, 12, 0x00C0));
    assert_eq!(parse_unit(&b), out_of_range(3));
}

/// A change that takes one field of a law out of its range.
type Spoil = fn(&mut DarkLaw);

#[test]
fn write_table_refuses_bad_dark_laws() {
    let cases: [(Spoil, u32); 4] = [
        (|l| l.rate_e_per_s = ERatePerS::ZERO, 0),
        (|l| l.reference_k = Kelvin::from_num(20), 1),
        (|l| l.doubling_k = U8F8::from_num(40), 2),
        (|l| l.band_low = l.band_high, 3),
    ];
    for (f, index) in cases {
        let mut s = full_spec(SMALL, 0, 0);
        f(s.dark_law.as_mut().expect("present"));
        assert_eq!(
            write_spec(&s.spec()),
            Err(WriteError::Invalid(TableError::OutOfRange {
                section: K,
                index
            })),
            "field {index}"
        );
    }
}
