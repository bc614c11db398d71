//! Fuzz-style properties of the calibration-table parser: no input makes it panic, every
//! single-bit corruption of a written table is rejected, and whatever passes the structural
//! checks is safe to read everywhere.

use startrack_test_support::table_fixtures;

use fixed::types::{I16F16, U0F16, U0F32, U8F8};
use proptest::prelude::*;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::PixCorrBackground;
use startrack_core::table::{
    CalibTable, CtiCoeffs, CtiOutput, DIR_ENTRY_LEN, HEADER_LEN, HotPixel, HotPolicy, PsfModel,
    SectionKind, TableError,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu, Kelvin};
use table_fixtures::*;

/// Small tables with every section, per pixel and tiled, one and two outputs.
fn small_tables() -> Vec<Vec<u8>> {
    vec![
        full_spec(SMALL, 0, 0).write(),
        full_spec(SMALL_DUAL, 3, 1).write(),
        full_spec(SMALL_DUAL, 10, 0).write(),
    ]
}

/// Parses and, when the bytes are accepted, reads everything.
fn parse_and_read(b: &[u8]) -> Result<(), TableError> {
    CalibTable::parse(b).map(|t| {
        exercise(&t);
    })
}

#[test]
fn every_byte_of_a_written_table_is_under_a_crc() {
    for t in small_tables()
        .into_iter()
        .chain([full_spec(CCD, 3, 3).write(), gains_only(SMALL).write()])
    {
        let cov = crc_coverage(&t);
        let uncovered: Vec<usize> = (0..t.len()).filter(|&i| !cov[i]).collect();
        assert!(
            uncovered.is_empty(),
            "bytes not covered by any CRC: {uncovered:?}"
        );
    }
}

#[test]
fn every_single_bit_flip_of_a_small_table_is_rejected() {
    // Exhaustive over every bit of the small tables (a few thousand parses).
    for t in small_tables() {
        assert!(CalibTable::parse(&t).is_ok());
        for i in 0..t.len() {
            for bit in 0..8 {
                let mut b = t.clone();
                b[i] ^= 1 << bit;
                assert!(
                    CalibTable::parse(&b).is_err(),
                    "flip of bit {bit} of byte {i} accepted"
                );
            }
        }
    }
}

/// A spec of a random small geometry with random contents that the parser accepts.
fn arb_spec() -> impl Strategy<Value = OwnedSpec> {
    let geom = (1u16..6, 0u16..4, 1u16..24, 1u16..20, 0u16..4, 1u8..=2).prop_map(
        |(os, cov, c, r, extra, o)| ReadoutGeometry {
            overscan_px: os,
            covered_px: cov,
            active_cols: if o == 2 { c * 2 } else { c },
            active_rows: r,
            lines: r + extra,
            outputs: o,
        },
    );
    (geom, any::<u64>(), 0u8..=10, 0u8..=10, any::<[bool; 8]>()).prop_map(
        |(g, seed, dl, fl, present)| {
            // A small deterministic generator keeps the strategy simple and the values varied.
            let mut s = seed | 1;
            let mut next = move || {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                s
            };
            let (dtx, dty) = tiles_of(g.active_cols, g.active_rows, dl);
            let (ftx, fty) = tiles_of(g.active_cols, g.active_rows, fl);
            let mut hot: Vec<HotPixel> = (0..next() % 12)
                .map(|_| HotPixel {
                    x: (next() % u64::from(g.active_cols)) as u16,
                    y: (next() % u64::from(g.active_rows)) as u16,
                    rate_e_per_s: ERatePerS::from_bits(next() as u32),
                    doubling_k: U8F8::from_bits(1 + (next() % 0xFFFF) as u16),
                    policy: if next() % 2 == 0 {
                        HotPolicy::Correct
                    } else {
                        HotPolicy::Exclude
                    },
                })
                .collect();
            hot.sort_by_key(|h| (h.y, h.x));
            hot.dedup_by_key(|h| (h.y, h.x));
            let mut tg: Vec<(u16, u16)> = (0..next() % 12)
                .map(|_| {
                    (
                        (next() % u64::from(g.active_cols)) as u16,
                        (next() % u64::from(g.active_rows)) as u16,
                    )
                })
                .collect();
            tg.sort_by_key(|&(x, y)| (y, x));
            tg.dedup();
            // 1..=16 curves with random valid fields and knots.
            let curves: Vec<Vec<u8>> = (0..1 + next() % 16)
                .map(|_| {
                    let n = 5 + (next() % 125) as usize;
                    let mut knots: Vec<i16> = (0..n).map(|_| next() as i16).collect();
                    knots[0] = 0;
                    enc_curve(
                        if next() % 2 == 0 {
                            CogPower::One
                        } else {
                            CogPower::Two
                        },
                        3 + 2 * (next() % 15) as u8,
                        [
                            PixCorrBackground::Given,
                            PixCorrBackground::PerimeterMean,
                            PixCorrBackground::PerimeterMedian,
                        ][(next() % 3) as usize],
                        1 + (next() % 0xFFFF) as u16,
                        1 + (next() % 0x8000) as u16,
                        &knots,
                    )
                })
                .collect();
            OwnedSpec {
                geometry: g,
                saturation_adu: next() as u16,
                gains: (0..g.outputs)
                    .map(|_| GainEPerAdu::from_bits(1 + (next() as u32 >> 1)))
                    .collect(),
                column_bias: present[0].then(|| {
                    (0..g.line_len())
                        .map(|_| ColumnBiasAdu::from_bits(next() as i16))
                        .collect()
                }),
                dark: present[1].then(|| {
                    (
                        dl,
                        (0..dtx * dty)
                            .map(|_| DarkRel::from_bits(next() as u8))
                            .collect(),
                    )
                }),
                flat: present[2].then(|| {
                    (
                        fl,
                        (0..ftx * fty)
                            .map(|_| FlatInv::from_bits(1 + (next() % 0xFFFF) as u16))
                            .collect(),
                    )
                }),
                hot_ref_k: Kelvin::from_bits(next() as u32),
                hot: if present[3] { hot } else { Vec::new() },
                telegraph: if present[4] { tg } else { Vec::new() },
                pixcorr: if present[5] { curves } else { Vec::new() },
                cti: present[6].then(|| {
                    let mut outputs = [CtiOutput::default(); 2];
                    for o in outputs.iter_mut().take(usize::from(g.outputs)) {
                        *o = CtiOutput {
                            parallel_px: U0F32::from_bits(next() as u32),
                            serial_px: U0F32::from_bits(next() as u32),
                        };
                    }
                    CtiCoeffs {
                        reference_flux_e: 1 + (next() as u32 >> 1),
                        flux_offset_e: next() as u32,
                        alpha: U0F16::from_bits(next() as u16),
                        outputs,
                    }
                }),
                // A constant-width model of random degree whose higher terms are small enough
                // to keep the width positive over the field.
                psf_model: present[7].then(|| {
                    let degree = (next() % 4) as u8;
                    let mut coeffs = [I16F16::ZERO; 10];
                    coeffs[0] = I16F16::from_num(0.5 + (next() % 1000) as f64 / 100.0);
                    let terms = (usize::from(degree) + 1) * (usize::from(degree) + 2) / 2;
                    for c in coeffs.iter_mut().take(terms).skip(1) {
                        *c = I16F16::from_num(((next() % 200) as f64 - 100.0) / 2500.0);
                    }
                    PsfModel {
                        degree,
                        scatter_px: U8F8::from_bits(next() as u16),
                        stars: 1 + (next() % 0xFFFF) as u16,
                        coeffs,
                    }
                }),
                camera_model: None,
                dark_law: None,
            }
        },
    )
}

/// Checks the parsed table against its spec on every pixel and every list position.
fn check_round_trip(s: &OwnedSpec) -> Result<(), TestCaseError> {
    let bytes = s.write();
    let t = CalibTable::parse(&bytes).map_err(|e| TestCaseError::fail(format!("rejected: {e}")))?;
    prop_assert_eq!(t.cti(), s.cti);
    prop_assert_eq!(t.psf_model(), s.psf_model);
    prop_assert_eq!(t.pixcorr().len(), s.pixcorr.len());
    for (c, want) in t.pixcorr().iter().zip(&s.pixcorr) {
        let mut got = c.header().to_bytes().to_vec();
        got.extend_from_slice(c.knot_bytes());
        prop_assert_eq!(&got, want);
    }
    let g = s.geometry;
    prop_assert_eq!(*t.geometry(), g);
    prop_assert_eq!(t.saturation_adu(), s.saturation_adu);
    for (o, want) in s.gains.iter().enumerate() {
        prop_assert_eq!(t.gain(startrack_core::geometry::Output(o as u8)), *want);
    }
    for c in 0..g.line_len() {
        let want = s.column_bias.as_ref().map_or(ColumnBiasAdu::ZERO, |v| v[c]);
        prop_assert_eq!(t.column_bias(c), want);
    }
    for y in 0..g.active_rows {
        for x in 0..g.active_cols {
            let d = s
                .dark
                .as_ref()
                .map_or(DarkRel::ONE, |(l, v)| v[tile_index(&g, *l, x, y)]);
            let f = s
                .flat
                .as_ref()
                .map_or(FlatInv::ONE, |(l, v)| v[tile_index(&g, *l, x, y)]);
            prop_assert_eq!(t.dark_rel(x, y), d);
            prop_assert_eq!(t.flat_inv(x, y), f);
            let h = s.hot.iter().find(|h| (h.x, h.y) == (x, y)).copied();
            prop_assert_eq!(t.hot_pixels().find(x, y), h);
            let lb = s.hot.iter().filter(|h| (h.y, h.x) < (y, x)).count();
            prop_assert_eq!(t.hot_pixels().lower_bound(x, y), lb);
            prop_assert_eq!(
                t.telegraph_pixels().contains(x, y),
                s.telegraph.contains(&(x, y))
            );
        }
    }
    prop_assert_eq!(t.hot_pixels().len(), s.hot.len());
    prop_assert_eq!(t.telegraph_pixels().len(), s.telegraph.len());
    exercise(&t);
    Ok(())
}

/// One mutation of a table's bytes.
#[derive(Clone, Debug)]
enum Mutation {
    /// XOR a byte with a non-zero mask.
    Xor(usize, u8),
    /// Overwrite a little-endian u16 (lands on the header, directory and section fields).
    Put16(usize, u16),
    /// Overwrite a little-endian u32.
    Put32(usize, u32),
    /// Overwrite a u16 with a small value (0, 1, a count) where boundaries matter.
    Small16(usize, u8),
}

fn arb_mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 1u8..).prop_map(|(i, m)| Mutation::Xor(i, m)),
        (any::<usize>(), any::<u16>()).prop_map(|(i, v)| Mutation::Put16(i, v)),
        (any::<usize>(), any::<u32>()).prop_map(|(i, v)| Mutation::Put32(i, v)),
        (any::<usize>(), 0u8..20).prop_map(|(i, v)| Mutation::Small16(i, v)),
    ]
}

fn apply(b: &mut [u8], m: &Mutation) {
    let n = b.len();
    match *m {
        Mutation::Xor(i, x) => b[i % n] ^= x,
        Mutation::Put16(i, v) => {
            let i = i % (n - 1);
            wr16(b, i, v);
        }
        Mutation::Put32(i, v) => {
            let i = i % (n - 3);
            wr32(b, i, v);
        }
        Mutation::Small16(i, v) => {
            let i = i % (n - 1);
            wr16(b, i, u16::from(v));
        }
    }
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(512)))]

    /// (a) Arbitrary bytes never panic the parser (or the accessors, if they parse).
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..4096)) {
        let r = parse_and_read(&bytes);
        if bytes.len() < HEADER_LEN {
            prop_assert_eq!(r, Err(TableError::TooShort { needed: 32, got: bytes.len() as u32 }));
        }
    }

    /// (b) Arbitrary bytes behind a valid magic and version never panic, and are never
    /// blamed on the magic or the version.
    #[test]
    fn arbitrary_bytes_behind_a_valid_prefix_never_panic(
        tail in proptest::collection::vec(any::<u8>(), 0..4096),
        n_sections in 0u16..10,
        fix_len in any::<bool>(),
        seal in any::<bool>(),
    ) {
        let mut b = b"STCT\x01\x00".to_vec();
        b.extend(&tail);
        if b.len() >= HEADER_LEN {
            // Optionally make the count, the length and the header CRC plausible so that
            // the directory is walked.
            if fix_len {
                wr16(&mut b, 6, n_sections);
                let len = b.len() as u32;
                wr32(&mut b, 8, len);
            }
            if seal {
                reseal_all(&mut b);
            }
        }
        let r = parse_and_read(&b);
        prop_assert!(!matches!(r, Err(TableError::BadMagic | TableError::UnsupportedVersion(_))));
    }

    /// (c) Flipping any one bit of a written table makes it fail to parse.
    #[test]
    fn one_bit_flip_is_rejected(which in 0usize..4, pos in any::<usize>(), bit in 0u8..8) {
        let t = match which {
            0 => full_spec(SMALL, 0, 0).write(),
            1 => full_spec(SMALL_DUAL, 3, 2).write(),
            2 => full_spec(SMALL, 10, 4).write(),
            _ => gains_only(SMALL_DUAL).write(),
        };
        let i = pos % t.len();
        let mut b = t.clone();
        b[i] ^= 1 << bit;
        prop_assert!(CalibTable::parse(&b).is_err(), "bit {} of byte {} of {} accepted", bit, i, t.len());
    }

    /// (d) Random corruption with every CRC re-sealed, so the structural checks are what
    /// stands between the bytes and the accessors: never a panic, and whatever parses reads
    /// safely over the whole active area.
    #[test]
    fn resealed_corruption_never_panics(
        which in 0usize..3,
        muts in proptest::collection::vec(arb_mutation(), 1..6),
    ) {
        let mut b = small_tables().swap_remove(which);
        for m in &muts {
            apply(&mut b, m);
        }
        reseal_all(&mut b);
        let _ = parse_and_read(&b);
    }

    /// (d') The same, restricted to the header and directory, where every byte is structure.
    #[test]
    fn resealed_header_corruption_never_panics(
        which in 0usize..3,
        muts in proptest::collection::vec(arb_mutation(), 1..4),
    ) {
        let mut b = small_tables().swap_remove(which);
        let dir_end = HEADER_LEN + DIR_ENTRY_LEN * usize::from(rd16(&b, 6));
        let mut head = b[..dir_end].to_vec();
        for m in &muts {
            apply(&mut head, m);
        }
        // Keep the magic and version (the first checks) so the rest is reached.
        head[..6].copy_from_slice(b"STCT\x01\x00");
        b[..dir_end].copy_from_slice(&head);
        reseal_all(&mut b);
        let _ = parse_and_read(&b);
    }

    /// (e) Any valid spec round-trips: every accessor returns what was written.
    #[test]
    fn random_specs_round_trip(s in arb_spec()) {
        check_round_trip(&s)?;
    }
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(64)))]

    /// (c) on the full-size CCD47-20 table (tiled maps keep it at ~52 KB).
    #[test]
    fn one_bit_flip_of_the_ccd_table_is_rejected(pos in any::<usize>(), bit in 0u8..8) {
        let t = ccd_table();
        let i = pos % t.len();
        let mut b = t.to_vec();
        b[i] ^= 1 << bit;
        prop_assert!(CalibTable::parse(&b).is_err(), "bit {} of byte {} accepted", bit, i);
    }
}

fn ccd_table() -> &'static [u8] {
    static T: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    T.get_or_init(|| full_spec(ReadoutGeometry::CCD47_20_DUAL, 3, 3).write())
}

#[test]
fn resealed_section_corruption_of_each_kind_is_caught_or_harmless() {
    // Walk every byte of every section, set it to a few values, reseal: the parser must
    // either reject it with an error about that section or accept a table that reads safely.
    let (mut accepted, mut rejected) = (0usize, 0usize);
    for t in small_tables() {
        for kind in SectionKind::ALL {
            let (off, len) = section_range(&t, kind);
            for i in off..off + len {
                for v in [0x00u8, 0x01, 0x80, 0xFF] {
                    let b = patched(&t, |b| b[i] = v);
                    match CalibTable::parse(&b) {
                        Ok(p) => {
                            exercise(&p);
                            accepted += 1;
                        }
                        Err(TableError::PixCorrCurve { .. } | TableError::Reserved)
                            if kind == SectionKind::PixCorr =>
                        {
                            rejected += 1;
                        }
                        Err(TableError::Reserved)
                            if matches!(
                                kind,
                                SectionKind::Cti | SectionKind::PsfModel | SectionKind::DarkLaw
                            ) =>
                        {
                            rejected += 1;
                        }
                        Err(TableError::CameraModel(_) | TableError::Reserved)
                            if kind == SectionKind::CameraModel =>
                        {
                            rejected += 1;
                        }
                        Err(
                            TableError::SectionLength(k)
                            | TableError::MapFormat(k)
                            | TableError::SectionFormat(k)
                            | TableError::OutOfRange { section: k, .. },
                        ) => {
                            assert_eq!(
                                k,
                                kind,
                                "byte {i} of {} blamed on {}",
                                kind.name(),
                                k.name()
                            );
                            rejected += 1;
                        }
                        Err(e) => panic!("byte {i} of {}: unexpected {e:?}", kind.name()),
                    }
                }
            }
        }
    }
    // Both outcomes occur (dark values are all valid; a zero gain is not).
    assert!(
        accepted > 0 && rejected > 0,
        "accepted {accepted}, rejected {rejected}"
    );
}
