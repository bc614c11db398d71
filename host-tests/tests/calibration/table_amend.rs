//! A table amended with in-flight defects (`table::AmendPlan`): streamed in any chunking it
//! is byte for byte the table `write_table` makes of the merged lists, its CRC is the
//! upload's, pixels already listed are skipped, a table without defect lists gets them.

use fixed::types::U8F8;
use proptest::prelude::*;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{
    AmendError, AmendPlan, CalibTable, HotPixel, HotPolicy, TableSpec, write_table,
};
use startrack_core::units::{ERatePerS, GainEPerAdu, Kelvin};

const GEOMETRY: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 8,
    covered_px: 16,
    active_cols: 128,
    active_rows: 128,
    lines: 130,
    outputs: 2,
};

fn hot(x: u16, y: u16, rate: f64) -> HotPixel {
    HotPixel {
        x,
        y,
        rate_e_per_s: ERatePerS::from_num(rate),
        doubling_k: U8F8::from_num(7),
        policy: HotPolicy::Correct,
    }
}

/// A new hot entry as the amendment writes it.
fn excluded(x: u16, y: u16) -> HotPixel {
    HotPixel {
        x,
        y,
        rate_e_per_s: ERatePerS::ZERO,
        doubling_k: U8F8::from_num(1),
        policy: HotPolicy::Exclude,
    }
}

fn table(hot: &[HotPixel], telegraph: &[(u16, u16)]) -> Vec<u8> {
    table_with_law(hot, telegraph, None)
}

fn table_with_law(
    hot: &[HotPixel],
    telegraph: &[(u16, u16)],
    dark_law: Option<startrack_core::table::DarkLaw>,
) -> Vec<u8> {
    let gains = [GainEPerAdu::from_num(2.0); 2];
    let bias = vec![startrack_core::units::ColumnBiasAdu::from_num(0.5); GEOMETRY.line_len()];
    let spec = TableSpec {
        geometry: GEOMETRY,
        saturation_adu: 60_000,
        gains: &gains,
        column_bias: Some(&bias),
        dark_rel: None,
        flat_inv: None,
        hot_ref_k: Kelvin::from_num(293),
        hot,
        telegraph,
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law,
    };
    let mut out = vec![0u8; spec.encoded_len()];
    let n = write_table(&spec, &mut out).unwrap();
    out.truncate(n);
    out
}

fn plan(old: &[u8], hot: &[(u16, u16)], tel: &[(u16, u16)]) -> Result<AmendPlan, AmendError> {
    let mut read = |at: u32, out: &mut [u8]| {
        old.get(at as usize..at as usize + out.len())
            .map(|b| out.copy_from_slice(b))
            .is_some()
    };
    AmendPlan::new(&mut read, old.len() as u32, hot, tel, Kelvin::from_num(250))
}

/// The amended table, emitted in chunks of `chunk` bytes.
fn emit(old: &[u8], p: &AmendPlan, chunk: usize) -> Vec<u8> {
    let mut read = |at: u32, out: &mut [u8]| {
        old.get(at as usize..at as usize + out.len())
            .map(|b| out.copy_from_slice(b))
            .is_some()
    };
    let mut new = Vec::new();
    let mut buf = vec![0u8; chunk];
    while (new.len() as u32) < p.len_bytes() {
        let n = p.emit(&mut read, new.len() as u32, &mut buf).unwrap();
        assert!(n > 0);
        new.extend_from_slice(&buf[..n]);
    }
    assert_eq!(p.emit(&mut read, new.len() as u32, &mut buf), Ok(0));
    new
}

fn crc(b: &[u8]) -> u32 {
    crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(b)
}

#[test]
fn new_pixels_merge_into_both_lists_as_write_table_would() {
    let old_hot = [hot(10, 3, 50.0), hot(5, 5, 100.0), hot(0, 90, 7.0)];
    let old_tel = [(7, 7), (100, 8)];
    let old = table(&old_hot, &old_tel);
    // (10, 3) is listed hot, (7, 7) telegraph: skipped; (1, 1) given twice.
    let p = plan(
        &old,
        &[(100, 100), (10, 3), (1, 1), (1, 1), (127, 5)],
        &[(7, 7), (2, 2), (64, 64)],
    )
    .unwrap();
    assert_eq!(p.added_hot(), &[(1, 1), (127, 5), (100, 100)]);
    assert_eq!(p.added_telegraph(), &[(2, 2), (64, 64)]);
    let mut want_hot = old_hot.to_vec();
    want_hot.extend([excluded(100, 100), excluded(1, 1), excluded(127, 5)]);
    want_hot.sort_by_key(|h| (h.y, h.x));
    let mut want_tel = vec![(7, 7), (100, 8), (2, 2), (64, 64)];
    want_tel.sort_by_key(|&(x, y)| (y, x));
    let want = table(&want_hot, &want_tel);
    for chunk in [1, 7, 64, 100, 1024, 100_000] {
        let new = emit(&old, &p, chunk);
        assert_eq!(new, want, "chunk {chunk}");
    }
    assert_eq!(p.len_bytes() as usize, want.len());
    assert_eq!(p.crc32(), crc(&want));
}

/// An in-flight defect commit keeps the table's dark law (section 11), whether the lists it
/// grows come before it or are appended after it.
#[test]
fn an_amended_table_keeps_its_dark_law() {
    let law = startrack_core::table::DarkLaw {
        rate_e_per_s: ERatePerS::from_num(19.75),
        reference_k: Kelvin::from_num(293),
        doubling_k: U8F8::from_num(6.5),
        band_low: U8F8::from_num(0.8),
        band_high: U8F8::from_num(1.25),
    };
    for (old_hot, old_tel) in [(vec![hot(5, 5, 100.0)], vec![(7, 7)]), (vec![], vec![])] {
        let old = table_with_law(&old_hot, &old_tel, Some(law));
        let p = plan(&old, &[(3, 4)], &[(9, 9)]).unwrap();
        let new = emit(&old, &p, 64);
        let t = CalibTable::parse(&new).unwrap();
        assert_eq!(t.dark_law(), Some(law));
        assert_eq!(t.hot_pixels().len(), old_hot.len() + 1);
    }
}

#[test]
fn a_table_without_defect_lists_gets_both() {
    let old = table(&[], &[]);
    let p = plan(&old, &[(3, 4)], &[(9, 9), (8, 1)]).unwrap();
    let new = emit(&old, &p, 256);
    assert_eq!(p.crc32(), crc(&new));
    let t = CalibTable::parse(&new).unwrap();
    assert_eq!(t.hot_pixels().len(), 1);
    assert_eq!(t.hot_pixels().get(0), Some(excluded(3, 4)));
    // The new hot section takes the given reference temperature.
    assert_eq!(
        t.hot_pixels().reference_temperature_k(),
        Kelvin::from_num(250)
    );
    assert!(t.telegraph_pixels().contains(8, 1) && t.telegraph_pixels().contains(9, 9));
    assert_eq!(t.telegraph_pixels().len(), 2);
    // Every other section is the old one.
    let o = CalibTable::parse(&old).unwrap();
    for c in 0..GEOMETRY.line_len() {
        assert_eq!(t.column_bias(c), o.column_bias(c));
    }
}

#[test]
fn nothing_new_is_refused() {
    let old = table(&[hot(5, 5, 100.0)], &[(7, 7)]);
    assert_eq!(
        plan(&old, &[(5, 5), (7, 7)], &[(5, 5)]).unwrap_err(),
        AmendError::NothingToAdd
    );
    assert_eq!(plan(&old, &[], &[]).unwrap_err(), AmendError::NothingToAdd);
    // A reader that fails, or a table that is not one.
    let mut fail = |_: u32, _: &mut [u8]| false;
    assert_eq!(
        AmendPlan::new(&mut fail, old.len() as u32, &[(1, 1)], &[], Kelvin::ZERO).unwrap_err(),
        AmendError::Read
    );
    let mut bad = old.clone();
    bad[0] = b'X';
    assert_eq!(
        plan(&bad, &[(1, 1)], &[]).unwrap_err(),
        AmendError::BadTable
    );
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(64)))]
    /// Any lists and any additions: the amended table parses, lists the union, and matches
    /// `write_table`'s bytes when the old table had both lists.
    #[test]
    fn any_lists_and_additions_merge(
        old_hot in proptest::collection::btree_set((0u16..128, 0u16..128), 1..40),
        old_tel in proptest::collection::btree_set((0u16..128, 0u16..128), 1..20),
        add_hot in proptest::collection::vec((0u16..128, 0u16..128), 0..32),
        add_tel in proptest::collection::vec((0u16..128, 0u16..128), 0..32),
        chunk in 1usize..700,
    ) {
        let mut hp: Vec<HotPixel> = old_hot.iter().map(|&(y, x)| hot(x, y, 10.0)).collect();
        hp.sort_by_key(|h| (h.y, h.x));
        let mut tp: Vec<(u16, u16)> = old_tel.iter().map(|&(y, x)| (x, y)).collect();
        tp.sort_by_key(|&(x, y)| (y, x));
        let old = table(&hp, &tp);
        let listed = |p: &(u16, u16)| hp.iter().any(|h| (h.x, h.y) == *p) || tp.contains(p);
        let mut want_hot = hp.clone();
        for p in &add_hot {
            if !listed(p) && !want_hot.iter().any(|h| (h.x, h.y) == *p) {
                want_hot.push(excluded(p.0, p.1));
            }
        }
        want_hot.sort_by_key(|h| (h.y, h.x));
        let mut want_tel = tp.clone();
        for p in &add_tel {
            if !listed(p) && !want_tel.contains(p) {
                want_tel.push(*p);
            }
        }
        want_tel.sort_by_key(|&(x, y)| (y, x));
        match plan(&old, &add_hot, &add_tel) {
            Err(AmendError::NothingToAdd) => {
                prop_assert_eq!(want_hot.len(), hp.len());
                prop_assert_eq!(want_tel.len(), tp.len());
            }
            Err(e) => prop_assert!(false, "{e:?}"),
            Ok(p) => {
                let new = emit(&old, &p, chunk);
                prop_assert_eq!(&new, &table(&want_hot, &want_tel));
                prop_assert_eq!(p.crc32(), crc(&new));
            }
        }
    }
}
