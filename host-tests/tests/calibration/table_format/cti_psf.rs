//! The CTI coefficients (section 8) and the field PSF model (section 9): each field's own
//! error, the values read back, the model evaluated against its polynomial in f64, and
//! `write_table` refusing what the parser refuses.

use super::{parse_unit, with_section};
use fixed::types::I16F16;
use startrack_core::table::{CalibTable, SectionKind, TableError, WriteError};
use startrack_test_support::table_fixtures::*;

#[test]
fn cti_section_errors() {
    for g in [SMALL, SMALL_DUAL] {
        let t = full_spec(g, 0, 0).write();
        let k = SectionKind::Cti;
        assert_eq!(
            CalibTable::parse(&t).expect("parses").cti(),
            Some(cti_coeffs(&g))
        );
        // Length: one byte short or long, or the other geometry's output count.
        for f in [
            (|d: &mut Vec<u8>| d.truncate(d.len() - 1)) as fn(&mut Vec<u8>),
            |d| d.push(0),
            |d| d.truncate(11),
            |d| d.extend([0; 8]),
        ] {
            let b = with_section(&t, k, f);
            assert_eq!(parse_unit(&b), Err(TableError::SectionLength(k)));
        }
        let b = with_section(&t, k, |d| wr32(d, 0, 0));
        assert_eq!(
            parse_unit(&b),
            Err(TableError::OutOfRange {
                section: k,
                index: 0
            })
        );
        let b = with_section(&t, k, |d| wr16(d, 10, 1));
        assert_eq!(parse_unit(&b), Err(TableError::Reserved));
        // Every coefficient value is valid: the largest reads back.
        let b = with_section(&t, k, |d| wr32(d, 12, u32::MAX));
        let p = CalibTable::parse(&b).expect("parses");
        assert_eq!(
            p.cti().expect("present").outputs[0].parallel_px.to_bits(),
            u32::MAX
        );
    }
}

/// The model's polynomial in f64 at normalised (u, v), straight from the documented term
/// order `1, u, v, u^2, u v, v^2, u^3, u^2 v, u v^2, v^3`.
fn poly_f64(c: &[f64], degree: u8, u: f64, v: f64) -> f64 {
    let mut k = 0;
    let mut sum = 0.0;
    for total in 0..=i32::from(degree) {
        for j in 0..=total {
            sum += c[k] * u.powi(total - j) * v.powi(j);
            k += 1;
        }
    }
    sum
}

#[test]
fn psf_model_section_values_and_errors() {
    let g = SMALL;
    let t = full_spec(g, 0, 0).write();
    let k = SectionKind::PsfModel;
    let m = CalibTable::parse(&t)
        .expect("parses")
        .psf_model()
        .expect("present");
    assert_eq!(m, psf_model());
    let c: Vec<f64> = m.coeffs.iter().map(|c| c.to_num()).collect();
    for (x, y) in [(0u16, 0u16), (15, 11), (7, 3), (3, 9)] {
        let u = (2.0 * f64::from(x) + 1.0) / f64::from(g.active_cols) - 1.0;
        let v = (2.0 * f64::from(y) + 1.0) / f64::from(g.active_rows) - 1.0;
        let want = poly_f64(&c, 2, u, v);
        let got = f64::from(m.a_px(f32::from(x), f32::from(y), g.active_cols, g.active_rows));
        assert!((got - want).abs() < 1e-5, "a({x}, {y}) = {got}, f64 {want}");
    }
    // Degree past 3: a format error; degree 1 with degree 2's bytes: a length error.
    let b = with_section(&t, k, |d| d[0] = 4);
    assert_eq!(parse_unit(&b), Err(TableError::SectionFormat(k)));
    let b = with_section(&t, k, |d| d[0] = 1);
    assert_eq!(parse_unit(&b), Err(TableError::SectionLength(k)));
    let b = with_section(&t, k, |d| d.truncate(7));
    assert_eq!(parse_unit(&b), Err(TableError::SectionLength(k)));
    for at in [1usize, 6, 7] {
        let b = with_section(&t, k, |d| d[at] = 1);
        assert_eq!(parse_unit(&b), Err(TableError::Reserved), "byte {at}");
    }
    // No stars.
    let b = with_section(&t, k, |d| wr16(d, 4, 0));
    assert_eq!(
        parse_unit(&b),
        Err(TableError::OutOfRange {
            section: k,
            index: 0
        })
    );
    // A u^2 term of -5 px takes the width below 0 at u = -1 and 1: the first failing point
    // of the 5 x 5 check grid in row-major order, (u, v) = (-1, -1), is reported.
    let b = with_section(&t, k, |d| {
        wr32(d, 8 + 4 * 3, I16F16::from_num(-5).to_bits() as u32)
    });
    assert!(matches!(
        parse_unit(&b),
        Err(TableError::OutOfRange { section, index: 0 }) if section == k
    ));
    // A constant of 300 px: too wide.
    let b = with_section(&t, k, |d| {
        for i in 0..6 {
            wr32(d, 8 + 4 * i, 0);
        }
        wr32(d, 8, I16F16::from_num(300).to_bits() as u32);
    });
    assert!(matches!(
        parse_unit(&b),
        Err(TableError::OutOfRange { section, .. }) if section == k
    ));
}

#[test]
fn write_table_refuses_bad_cti_and_psf_models() {
    let mut s = full_spec(SMALL, 0, 0);
    s.cti.as_mut().expect("present").reference_flux_e = 0;
    assert_eq!(
        write_spec(&s.spec()),
        Err(WriteError::Invalid(TableError::OutOfRange {
            section: SectionKind::Cti,
            index: 0
        }))
    );
    let mut s = full_spec(SMALL, 0, 0);
    s.psf_model.as_mut().expect("present").degree = 5;
    assert_eq!(
        write_spec(&s.spec()),
        Err(WriteError::Invalid(TableError::SectionFormat(
            SectionKind::PsfModel
        )))
    );
    let mut s = full_spec(SMALL, 0, 0);
    s.psf_model.as_mut().expect("present").coeffs[0] = I16F16::from_num(-1);
    assert!(matches!(
        write_spec(&s.spec()),
        Err(WriteError::Invalid(TableError::OutOfRange {
            section: SectionKind::PsfModel,
            ..
        }))
    ));
}
