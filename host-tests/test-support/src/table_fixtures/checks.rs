//! What the parser promises, checked: the error of a table that must not parse, the bytes
//! covered by a CRC, and [`exercise`], every accessor over the active area and beyond with
//! the invariants of a parsed table. Cost: [`exercise`] visits at most 259 x 259 pixels.

use super::bytes::{rd16, rd32};
use fixed::types::U8F8;
use startrack_core::table::{CalibTable, DIR_ENTRY_LEN, HEADER_LEN};
use startrack_core::units::{FlatInv, GainEPerAdu};

/// Parses and returns only the error (panics in the test if the table parses).
pub fn parse_err(bytes: &[u8]) -> startrack_core::table::TableError {
    match CalibTable::parse(bytes) {
        Ok(_) => panic!("table of {} bytes unexpectedly parsed", bytes.len()),
        Err(e) => e,
    }
}

/// Bytes of the table covered by a check: the header CRC (bytes 0..28 and the directory), the
/// CRC field itself, and every section's bytes. `true` where covered.
pub fn crc_coverage(bytes: &[u8]) -> Vec<bool> {
    let mut cov = vec![false; bytes.len()];
    let n = usize::from(rd16(bytes, 6));
    let dir_end = HEADER_LEN + DIR_ENTRY_LEN * n;
    cov[..dir_end].iter_mut().for_each(|c| *c = true);
    for i in 0..n {
        let e = HEADER_LEN + i * DIR_ENTRY_LEN;
        let off = rd32(bytes, e + 4) as usize;
        let len = rd32(bytes, e + 8) as usize;
        cov[off..off + len].iter_mut().for_each(|c| *c = true);
    }
    cov
}

/// Calls every accessor over the active area (capped to 256 x 256 pixels for large corrupted
/// geometries) and a margin beyond it, and checks the invariants the parser promises. Returns
/// the number of pixels visited.
pub fn exercise(t: &CalibTable<'_>) -> usize {
    let g = *t.geometry();
    assert_eq!(g.validate(), Ok(()), "parsed geometry must be valid");
    for o in 0..=3u8 {
        assert_ne!(
            t.gain(startrack_core::geometry::Output(o)),
            GainEPerAdu::ZERO
        );
    }
    for c in 0..g.line_len() + 4 {
        let _ = t.column_bias(c);
    }
    let _ = t.column_bias(usize::MAX);
    let cols = g.active_cols.min(256);
    let rows = g.active_rows.min(256);
    let mut visited = 0;
    for y in 0..rows.saturating_add(3) {
        for x in 0..cols.saturating_add(3) {
            let _ = t.dark_rel(x, y);
            let f = t.flat_inv(x, y);
            if x < g.active_cols && y < g.active_rows {
                assert_ne!(f, FlatInv::ZERO, "zero inverse flat at ({x}, {y})");
            }
            let _ = t.hot_pixels().find(x, y);
            let _ = t.hot_pixels().lower_bound(x, y);
            let _ = t.telegraph_pixels().contains(x, y);
            visited += 1;
        }
    }
    for (x, y) in [(u16::MAX, u16::MAX), (u16::MAX, 0), (0, u16::MAX)] {
        let _ = t.dark_rel(x, y);
        let _ = t.flat_inv(x, y);
        let _ = t.hot_pixels().find(x, y);
        let _ = t.telegraph_pixels().contains(x, y);
    }
    let hot = t.hot_pixels();
    let mut prev = None;
    for i in 0..hot.len() {
        let h = hot.get(i).expect("listed hot pixel must decode");
        assert!(h.x < g.active_cols && h.y < g.active_rows);
        assert_ne!(h.doubling_k, U8F8::ZERO);
        assert!(prev < Some((h.y, h.x)), "hot list not strictly sorted");
        prev = Some((h.y, h.x));
        assert_eq!(hot.find(h.x, h.y), Some(h));
    }
    assert_eq!(hot.get(hot.len()), None);
    let tg = t.telegraph_pixels();
    let mut prev = None;
    for i in 0..tg.len() {
        let (x, y) = tg.get(i).expect("listed telegraph pixel must decode");
        assert!(x < g.active_cols && y < g.active_rows);
        assert!(prev < Some((y, x)), "telegraph list not strictly sorted");
        prev = Some((y, x));
        assert!(tg.contains(x, y));
    }
    assert_eq!(tg.get(tg.len()), None);
    // Every curve reads, and its correction is finite across and beyond a pixel.
    let set = t.pixcorr();
    assert_eq!(set.iter().count(), set.len());
    for c in set.iter() {
        let h = c.header();
        assert!(h.knots >= 5 && h.box_side % 2 == 1);
        assert_eq!(
            set.find(h.power, h.box_side, h.background, h.a_px.to_num())
                .map(|f| f.header().a_px),
            Some(h.a_px)
        );
        for i in -12..=12 {
            let (v, s) = c.correction(0.1 * i as f32);
            assert!(v.is_finite() && s.is_finite());
        }
    }
    // The CTI correction is finite (and bounded by a pixel per transfer) everywhere, for
    // any flux; the PSF model is positive and finite over the field.
    if let Some(cti) = startrack_core::calib::cti::CtiCorrection::from_table(t, 0.7) {
        for (x, y) in [
            (0.0, 0.0),
            (f32::from(g.active_cols), f32::from(g.active_rows)),
        ] {
            for f in [f32::NAN, -1.0, 0.0, 1e-9, 1.0, 1e4, 1e12, f32::INFINITY] {
                let (dx, dy) = cti.shift_px(f, x, y);
                assert!(dx.is_finite() && dy.is_finite(), "CTI shift at {f} e-");
            }
        }
    }
    if let Some(l) = t.dark_law() {
        assert_eq!(l.out_of_range_field(), None, "dark law out of range: {l:?}");
        let p = l.predicted_e(startrack_core::units::Kelvin::from_num(253), 1000);
        assert!(
            p.is_some_and(|p| p.is_finite() && p > 0.0),
            "dark law predicts {p:?}"
        );
    }
    if let Some(m) = t.psf_model() {
        for (x, y) in [
            (0.0, 0.0),
            (f32::from(g.active_cols - 1), f32::from(g.active_rows - 1)),
        ] {
            let a = m.a_px(x, y, g.active_cols, g.active_rows);
            assert!(a > 0.0 && a < 256.0, "PSF model a = {a} at ({x}, {y})");
        }
    }
    visited
}
