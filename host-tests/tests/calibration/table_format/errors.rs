//! `write_table` refuses what the parser would refuse (with the same error) and a buffer
//! too small; every error of both displays as one non-empty line. Cost: small specs only.

use fixed::types::U8F8;
use startrack_core::geometry::{GeometryError, ReadoutGeometry};
use startrack_core::table::pixcorr::PixCorrError;
use startrack_core::table::{
    CalibTable, DIR_ENTRY_LEN, HEADER_LEN, MapSpec, SectionKind, TableError, TableSpec, WriteError,
    write_table,
};
use startrack_core::units::{DarkRel, FlatInv, GainEPerAdu, Kelvin};
use startrack_test_support::table_fixtures::*;

#[test]
fn write_table_refuses_invalid_specs() {
    let inv = |e| Err(WriteError::Invalid(e));
    let base = full_spec(SMALL_DUAL, 0, 1);

    let mut s = base.clone();
    s.gains[0] = GainEPerAdu::ZERO;
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::OutOfRange {
            section: SectionKind::Gains,
            index: 0
        })
    );

    let mut s = base.clone();
    s.gains.pop();
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::SectionLength(SectionKind::Gains))
    );

    let mut s = base.clone();
    s.hot.swap(1, 2);
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::OutOfRange {
            section: SectionKind::HotPixels,
            index: 2
        })
    );

    let mut s = base.clone();
    let dup = s.hot[3];
    s.hot.insert(3, dup);
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::OutOfRange {
            section: SectionKind::HotPixels,
            index: 4
        })
    );

    let mut s = base.clone();
    s.hot[0].doubling_k = U8F8::ZERO;
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::OutOfRange {
            section: SectionKind::HotPixels,
            index: 0
        })
    );

    let mut s = base.clone();
    s.telegraph.push((0, SMALL_DUAL.active_rows));
    let last = s.telegraph.len() as u32 - 1;
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::OutOfRange {
            section: SectionKind::Telegraph,
            index: last
        })
    );

    let mut s = base.clone();
    s.column_bias.as_mut().expect("bias").pop();
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::SectionLength(SectionKind::ColumnBias))
    );

    let mut s = base.clone();
    s.dark.as_mut().expect("dark").1.pop();
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::SectionLength(SectionKind::DarkRel))
    );

    let mut s = base.clone();
    s.flat.as_mut().expect("flat").1[5] = FlatInv::ZERO;
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::OutOfRange {
            section: SectionKind::FlatInv,
            index: 5
        })
    );

    let mut s = base.clone();
    s.geometry.outputs = 3;
    s.gains.push(GainEPerAdu::ONE);
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::Geometry(GeometryError::Outputs))
    );

    let s = OwnedSpec {
        geometry: ReadoutGeometry {
            active_cols: 15,
            ..SMALL_DUAL
        },
        ..gains_only(SMALL_DUAL)
    };
    assert_eq!(
        write_spec(&s.spec()),
        inv(TableError::Geometry(GeometryError::OddSplit))
    );
}

#[test]
fn write_table_buffer_too_small() {
    let s = full_spec(SMALL, 1, 0);
    let spec = s.spec();
    let needed = spec.encoded_len();
    for len in [0, 31, needed - 1] {
        let mut buf = vec![0u8; len];
        assert_eq!(
            write_table(&spec, &mut buf),
            Err(WriteError::BufferTooSmall { needed }),
            "buffer {len}"
        );
    }
    // The check is on the size, before the contents: an invalid spec in a short buffer.
    let mut bad = s.clone();
    bad.gains[0] = GainEPerAdu::ZERO;
    let mut buf = [0u8; 8];
    assert_eq!(
        write_table(&bad.spec(), &mut buf),
        Err(WriteError::BufferTooSmall { needed })
    );
    // TableSpec borrowed straight, without the fixture.
    let gains = [GainEPerAdu::ONE];
    let spec = TableSpec {
        geometry: SMALL,
        saturation_adu: 1,
        gains: &gains,
        column_bias: None,
        dark_rel: Some(MapSpec {
            tile_log2: 10,
            tiles: &[DarkRel::ONE],
        }),
        flat_inv: None,
        hot_ref_k: Kelvin::ZERO,
        hot: &[],
        telegraph: &[],
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    };
    assert_eq!(
        spec.encoded_len(),
        HEADER_LEN + 2 * DIR_ENTRY_LEN + 4 + 8 + 1
    );
    let mut buf = vec![0u8; spec.encoded_len()];
    assert_eq!(write_table(&spec, &mut buf), Ok(buf.len()));
}

// =============================================================================================
// Display.

#[test]
fn every_error_displays_as_one_non_empty_line() {
    let mut errors: Vec<TableError> = vec![
        TableError::TooShort { needed: 32, got: 3 },
        TableError::BadMagic,
        TableError::UnsupportedVersion(7),
        TableError::LengthMismatch {
            header: 100,
            actual: 99,
        },
        TableError::HeaderCrc,
        TableError::Reserved,
        TableError::TooManySections(17),
        TableError::UnknownSection(42),
        TableError::PixCorrCurve {
            index: 3,
            error: PixCorrError::Knots(200),
        },
    ];
    for g in [
        GeometryError::Outputs,
        GeometryError::EmptyActiveArea,
        GeometryError::NoOverScan,
        GeometryError::TooLarge,
        GeometryError::OddSplit,
    ] {
        errors.push(TableError::Geometry(g));
    }
    for k in SectionKind::ALL {
        errors.extend([
            TableError::DuplicateSection(k),
            TableError::MissingSection(k),
            TableError::SectionOutOfBounds(k),
            TableError::SectionCrc(k),
            TableError::SectionLayout(k),
            TableError::SectionLength(k),
            TableError::MapFormat(k),
            TableError::SectionFormat(k),
            TableError::OutOfRange {
                section: k,
                index: 17,
            },
        ]);
    }
    let mut texts: Vec<String> = Vec::new();
    for e in &errors {
        let s = e.to_string();
        assert!(!s.trim().is_empty(), "{e:?} displays empty");
        assert!(
            !s.contains('\n') && !s.contains('\r'),
            "{e:?} displays on several lines: {s:?}"
        );
        if let TableError::OutOfRange { section, .. }
        | TableError::SectionCrc(section)
        | TableError::DuplicateSection(section) = e
        {
            assert!(
                s.contains(section.name()),
                "{s:?} does not name the section"
            );
        }
        let w = WriteError::Invalid(*e).to_string();
        assert!(
            !w.is_empty() && !w.contains('\n') && w.contains(&s),
            "{w:?}"
        );
        texts.push(s);
    }
    // Distinct errors read differently.
    let mut unique = texts.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), texts.len(), "two errors share a message");
    let w = WriteError::BufferTooSmall { needed: 1234 }.to_string();
    assert!(w.contains("1234") && !w.contains('\n'));
    // Errors produced by the parser display the same way.
    let e = CalibTable::parse(&[0u8; 10]).expect_err("too short");
    assert!(!e.to_string().is_empty() && !e.to_string().contains('\n'));
}
