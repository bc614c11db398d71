//! The pixel-phase correction section: its own errors, the curve count `write_table` checks,
//! and a curve from the host builder that round-trips through a table and corrects the
//! measured phase to under 1e-4 px. Cost: one 33-knot curve built on the host.

use super::round_trip::round_trip;
use super::{parse_unit, with_section};
use startrack_core::table::pixcorr::{PixCorr, PixCorrError};
use startrack_core::table::{CalibTable, SectionKind, TableError, WriteError, write_table};
use startrack_test_support::table_fixtures::*;

#[test]
fn pixcorr_section_errors() {
    let t = full_spec(SMALL, 0, 0).write();
    let k = SectionKind::PixCorr;
    let curves = pixcorr_curves();
    // Count 0 and past the maximum; reserved field.
    for count in [0u16, 17] {
        let b = with_section(&t, k, |d| wr16(d, 0, count));
        assert_eq!(
            parse_unit(&b),
            Err(TableError::OutOfRange {
                section: k,
                index: 0
            }),
            "count {count}"
        );
    }
    let b = with_section(&t, k, |d| wr16(d, 2, 1));
    assert_eq!(parse_unit(&b), Err(TableError::Reserved));
    // Shorter than its own header.
    let b = with_section(&t, k, |d| d.truncate(3));
    assert_eq!(parse_unit(&b), Err(TableError::SectionLength(k)));
    // A count above the curves present: the missing curve is reported truncated.
    let b = with_section(&t, k, |d| wr16(d, 0, 3));
    assert_eq!(
        parse_unit(&b),
        Err(TableError::PixCorrCurve {
            index: 2,
            error: PixCorrError::TooShort
        })
    );
    // A byte after the last curve.
    let b = with_section(&t, k, |d| d.push(0));
    assert_eq!(
        parse_unit(&b),
        Err(TableError::PixCorrCurve {
            index: 2,
            error: PixCorrError::TooShort
        })
    );
    // Each field of the second curve, blamed on curve 1 with its own error.
    let second = 4 + curves[0].len();
    let cases: [(usize, u8, PixCorrError); 7] = [
        (0, 0, PixCorrError::Power(0)),
        (1, 2, PixCorrError::BoxSide(2)),
        (2, 3, PixCorrError::Background(3)),
        (3, 200, PixCorrError::Knots(200)),
        (5, 0, PixCorrError::Width),
        (7, 0x90, PixCorrError::PhaseMax),
        (9, 1, PixCorrError::FirstKnot),
    ];
    for (at, v, error) in cases {
        let b = with_section(&t, k, |d| {
            d[second + at] = v;
            if at == 5 {
                d[second + 4] = 0;
            }
        });
        assert_eq!(
            parse_unit(&b),
            Err(TableError::PixCorrCurve { index: 1, error }),
            "byte {at} = {v}"
        );
    }
}

#[test]
fn pixcorr_write_checks_the_curve_count() {
    let s = full_spec(SMALL, 0, 0);
    let one = PixCorr::parse(&s.pixcorr[0]).expect("curve").0;
    let spec = s.spec();
    for (n, ok) in [(16usize, true), (17, false)] {
        let curves = vec![one; n];
        let mut buf = vec![0u8; spec.encoded_len_with_pixcorr(&curves)];
        let r = startrack_core::table::write_table_with_pixcorr(&spec, &curves, &mut buf);
        if ok {
            assert_eq!(r, Ok(buf.len()));
            assert_eq!(CalibTable::parse(&buf).expect("parses").pixcorr().len(), 16);
        } else {
            assert_eq!(
                r,
                Err(WriteError::Invalid(TableError::OutOfRange {
                    section: SectionKind::PixCorr,
                    index: 0
                }))
            );
        }
    }
    // No curves: no section, the same bytes as write_table.
    let mut a = vec![0u8; spec.encoded_len()];
    let mut b = a.clone();
    write_table(&spec, &mut a).expect("writes");
    startrack_core::table::write_table_with_pixcorr(&spec, &[], &mut b).expect("writes");
    assert_eq!(a, b);
}

#[test]
fn pixcorr_curve_from_the_host_builder_round_trips_and_corrects() {
    use startrack_core::table::pixcorr::CogPower;
    use startrack_core::table::pixcorr::PixCorrBackground;
    use startrack_sim::pixcorr::{CurveSpec, build_curve, measured_phase};
    let spec = CurveSpec {
        a_px: 1.5,
        box_side: 3,
        power: CogPower::One,
        background: PixCorrBackground::Given,
        knots: 33,
    };
    let built = build_curve(&spec).expect("builds");
    let s = OwnedSpec {
        pixcorr: vec![built.bytes.clone()],
        ..gains_only(SMALL)
    };
    let bytes = round_trip(&s);
    let t = CalibTable::parse(&bytes).expect("parses");
    let c = t
        .pixcorr()
        .find(CogPower::One, 3, PixCorrBackground::Given, 1.4)
        .expect("found");
    // The stored curve inverts the f64 m(p) to well under a millipixel.
    for i in 0..=20 {
        let p = -0.45 + 0.045 * f64::from(i);
        let m = measured_phase(&spec, p, 0.0);
        let (corr, _) = c.correction(m as f32);
        assert!((m + f64::from(corr) - p).abs() < 1e-4, "phase {p}");
    }
}
