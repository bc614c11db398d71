//! The calibration-table contract: what `write_table` writes parses back to the same values,
//! absent sections read as neutral, and every kind of corruption is rejected with its own
//! `TableError`.

#[path = "common/table_fixtures.rs"]
mod table_fixtures;

use fixed::types::U8F8;
use startrack_core::centroid::pixcorr::{PixCorr, PixCorrError};
use startrack_core::geometry::{GeometryError, Output, ReadoutGeometry};
use startrack_core::table::{
    CalibTable, DIR_ENTRY_LEN, HEADER_LEN, HotPixel, HotPolicy, MapSpec, SectionKind, TableError,
    TableSpec, WriteError, write_table,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu, Kelvin};
use table_fixtures::*;

// =============================================================================================
// Round trip.

/// Checks every accessor of `t` against the spec it was written from, over the whole active
/// area and every raw column.
fn assert_matches_spec(t: &CalibTable<'_>, s: &OwnedSpec) {
    let g = s.geometry;
    assert_eq!(*t.geometry(), g);
    assert_eq!(t.saturation_adu(), s.saturation_adu);
    for (o, want) in s.gains.iter().enumerate() {
        assert_eq!(t.gain(Output(o as u8)), *want, "gain of output {o}");
    }
    match &s.column_bias {
        Some(cb) => {
            assert!(t.has_column_bias());
            assert_eq!(cb.len(), g.line_len());
            for (c, want) in cb.iter().enumerate() {
                assert_eq!(t.column_bias(c), *want, "column bias of raw column {c}");
            }
        }
        None => {
            assert!(!t.has_column_bias());
            for c in 0..g.line_len() {
                assert_eq!(t.column_bias(c), ColumnBiasAdu::ZERO);
            }
        }
    }
    match &s.dark {
        Some((l, _)) => {
            let h = t.dark_map().expect("dark map present").header();
            let (tx, ty) = tiles_of(g.active_cols, g.active_rows, *l);
            assert_eq!(
                (h.tile_log2, usize::from(h.tiles_x), usize::from(h.tiles_y)),
                (*l, tx, ty)
            );
        }
        None => assert!(t.dark_map().is_none()),
    }
    match &s.flat {
        Some((l, _)) => {
            let h = t.flat_map().expect("flat map present").header();
            let (tx, ty) = tiles_of(g.active_cols, g.active_rows, *l);
            assert_eq!(
                (h.tile_log2, usize::from(h.tiles_x), usize::from(h.tiles_y)),
                (*l, tx, ty)
            );
        }
        None => assert!(t.flat_map().is_none()),
    }
    for y in 0..g.active_rows {
        for x in 0..g.active_cols {
            let want_d = s
                .dark
                .as_ref()
                .map_or(DarkRel::ONE, |(l, v)| v[tile_index(&g, *l, x, y)]);
            let want_f = s
                .flat
                .as_ref()
                .map_or(FlatInv::ONE, |(l, v)| v[tile_index(&g, *l, x, y)]);
            // Asserting with `if` keeps the 1M-pixel loop fast while still naming the pixel.
            if t.dark_rel(x, y) != want_d {
                panic!("dark_rel({x}, {y}) = {}, wrote {want_d}", t.dark_rel(x, y));
            }
            if t.flat_inv(x, y) != want_f {
                panic!("flat_inv({x}, {y}) = {}, wrote {want_f}", t.flat_inv(x, y));
            }
        }
    }
    let hot = t.hot_pixels();
    assert_eq!(hot.len(), s.hot.len());
    assert_eq!(hot.is_empty(), s.hot.is_empty());
    if !s.hot.is_empty() {
        assert_eq!(hot.reference_temperature_k(), s.hot_ref_k);
    }
    for (i, h) in s.hot.iter().enumerate() {
        assert_eq!(hot.get(i), Some(*h), "hot entry {i}");
        assert_eq!(hot.find(h.x, h.y), Some(*h));
        assert_eq!(hot.lower_bound(h.x, h.y), i);
    }
    assert_eq!(hot.get(s.hot.len()), None);
    let tg = t.telegraph_pixels();
    assert_eq!(tg.len(), s.telegraph.len());
    assert_eq!(tg.is_empty(), s.telegraph.is_empty());
    for (i, &(x, y)) in s.telegraph.iter().enumerate() {
        assert_eq!(tg.get(i), Some((x, y)));
        assert!(tg.contains(x, y), "telegraph ({x}, {y}) not found");
        assert_eq!(tg.lower_bound(x, y), i);
    }
    assert_eq!(tg.get(s.telegraph.len()), None);
    let set = t.pixcorr();
    assert_eq!(set.len(), s.pixcorr.len());
    for (c, want) in set.iter().zip(&s.pixcorr) {
        let mut got = c.header().to_bytes().to_vec();
        got.extend_from_slice(c.knot_bytes());
        assert_eq!(&got, want, "pixel-phase curve");
    }
}

/// Brute-force membership and lower bounds of the defect lists at the given positions.
fn assert_lists_at(t: &CalibTable<'_>, s: &OwnedSpec, positions: impl Iterator<Item = (u16, u16)>) {
    let hot = t.hot_pixels();
    let tg = t.telegraph_pixels();
    for (x, y) in positions {
        let listed = s.hot.iter().find(|h| (h.x, h.y) == (x, y)).copied();
        assert_eq!(hot.find(x, y), listed, "hot find({x}, {y})");
        let lb = s.hot.iter().filter(|h| (h.y, h.x) < (y, x)).count();
        assert_eq!(hot.lower_bound(x, y), lb, "hot lower_bound({x}, {y})");
        assert_eq!(
            tg.contains(x, y),
            s.telegraph.contains(&(x, y)),
            "telegraph contains({x}, {y})"
        );
        let lb = s
            .telegraph
            .iter()
            .filter(|&&(ex, ey)| (ey, ex) < (y, x))
            .count();
        assert_eq!(tg.lower_bound(x, y), lb, "telegraph lower_bound({x}, {y})");
    }
}

/// The written bytes follow the documented layout: header fields at their offsets, every
/// section's bytes equal to an independent encoding, sections inside the table after the
/// directory and not overlapping, all CRCs as documented.
fn assert_layout(bytes: &[u8], s: &OwnedSpec) {
    let g = &s.geometry;
    assert_eq!(&bytes[..4], b"STCT");
    assert_eq!(rd16(bytes, 4), 1);
    assert_eq!(rd32(bytes, 8) as usize, bytes.len());
    let fields = [
        g.overscan_px,
        g.covered_px,
        g.active_cols,
        g.active_rows,
        g.lines,
    ];
    for (i, v) in fields.into_iter().enumerate() {
        assert_eq!(rd16(bytes, 12 + 2 * i), v);
    }
    assert_eq!((bytes[22], bytes[23]), (g.outputs, 0));
    assert_eq!(rd16(bytes, 24), s.saturation_adu);
    assert_eq!(rd16(bytes, 26), 0);
    let n = usize::from(rd16(bytes, 6));
    let dir_end = HEADER_LEN + DIR_ENTRY_LEN * n;
    assert_eq!(
        rd32(bytes, 28),
        crc32_parts(&[&bytes[..28], &bytes[HEADER_LEN..dir_end]])
    );
    let want = RawTable::from_spec(s);
    assert_eq!(n, want.sections.len());
    let mut ranges = Vec::new();
    for ws in &want.sections {
        let kind = SectionKind::from_code(ws.kind).expect("known kind");
        let e = HEADER_LEN + dir_index(bytes, kind) * DIR_ENTRY_LEN;
        assert_eq!(rd16(bytes, e + 2), 0, "directory reserved field");
        let (off, len) = (rd32(bytes, e + 4) as usize, rd32(bytes, e + 8) as usize);
        assert!(
            off >= dir_end && off + len <= bytes.len(),
            "{} out of bounds",
            kind.name()
        );
        assert_eq!(
            &bytes[off..off + len],
            &ws.data[..],
            "{} bytes",
            kind.name()
        );
        assert_eq!(rd32(bytes, e + 12), crc32(&ws.data), "{} CRC", kind.name());
        ranges.push((off, off + len));
    }
    ranges.sort();
    for w in ranges.windows(2) {
        assert!(w[0].1 <= w[1].0, "sections overlap");
    }
}

fn round_trip(s: &OwnedSpec) -> Vec<u8> {
    let bytes = s.write();
    assert_eq!(bytes.len(), s.encoded_len());
    assert_layout(&bytes, s);
    let t = CalibTable::parse(&bytes).unwrap_or_else(|e| panic!("written table rejected: {e}"));
    assert_matches_spec(&t, s);
    bytes
}

#[test]
fn crc_helper_is_crc32_iso_hdlc() {
    // The catalogue check value of CRC-32/ISO-HDLC.
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc32(b""), 0);
    assert_eq!(crc32_parts(&[b"1234", b"56789"]), 0xCBF4_3926);
}

#[test]
fn round_trip_ccd47_20_per_pixel() {
    let s = full_spec(CCD, 0, 0);
    assert_eq!(s.column_bias.as_ref().map(Vec::len), Some(1072));
    assert!(s.hot.iter().any(|h| h.policy == HotPolicy::Correct));
    assert!(s.hot.iter().any(|h| h.policy == HotPolicy::Exclude));
    let bytes = round_trip(&s);
    // 1 MB dark map and 2 MB flat map, as the format's documentation says.
    assert!(bytes.len() > 3 * 1024 * 1024);
    let t = CalibTable::parse(&bytes).expect("parses");
    assert_ne!(t.gain(Output(0)), t.gain(Output(1)));
    let probe = (0..1024u16)
        .step_by(61)
        .flat_map(|y| (0..1024u16).step_by(53).map(move |x| (x, y)));
    let listed = s
        .hot
        .iter()
        .map(|h| (h.x, h.y))
        .chain(s.telegraph.iter().copied());
    let neighbours = listed
        .clone()
        .flat_map(|(x, y)| [(x.wrapping_add(1), y), (x.wrapping_sub(1), y), (x, y + 1)]);
    assert_lists_at(&t, &s, probe.chain(listed).chain(neighbours));
}

#[test]
fn round_trip_ccd47_20_tiled() {
    for (dl, fl) in [(3, 3), (2, 4), (10, 6)] {
        let s = full_spec(CCD, dl, fl);
        let bytes = round_trip(&s);
        let t = CalibTable::parse(&bytes).expect("parses");
        // A tile's value holds over the whole tile: the corners of tile (1, 2) agree.
        let side = 1u16 << dl;
        let (x0, y0) = (side, 2 * side);
        if y0 + side <= 1024 {
            assert_eq!(t.dark_rel(x0, y0), t.dark_rel(x0 + side - 1, y0 + side - 1));
            assert_ne!(
                t.dark_rel(x0, y0),
                t.dark_rel(x0 + side, y0),
                "tiles {dl}: neighbours differ"
            );
        }
    }
}

#[test]
fn round_trip_small_every_tile_size() {
    for g in [SMALL, SMALL_DUAL] {
        for l in 0..=10 {
            let s = full_spec(g, l, 10 - l);
            let bytes = round_trip(&s);
            let t = CalibTable::parse(&bytes).expect("parses");
            let all =
                (0..g.active_rows + 2).flat_map(|y| (0..g.active_cols + 2).map(move |x| (x, y)));
            assert_lists_at(&t, &s, all);
        }
    }
}

#[test]
fn tiles_round_up_at_the_edges() {
    // 16 x 12 in 8 x 8 tiles: 2 x 2 tiles, the bottom row of tiles half outside the area.
    let s = full_spec(SMALL, 3, 3);
    let bytes = s.write();
    let t = CalibTable::parse(&bytes).expect("parses");
    let h = t.dark_map().expect("dark").header();
    assert_eq!((h.tiles_x, h.tiles_y, h.tiles()), (2, 2, 4));
    let (_, d) = s.dark.as_ref().expect("dark");
    assert_eq!(t.dark_rel(15, 11), d[3]);
    assert_eq!(t.dark_rel(8, 0), d[1]);
    assert_eq!(t.dark_rel(7, 8), d[2]);
}

#[test]
fn sections_in_any_order_parse_the_same() {
    let s = full_spec(SMALL_DUAL, 1, 2);
    let mut raw = RawTable::from_spec(&s);
    raw.sections.reverse();
    let bytes = raw.build();
    assert_ne!(bytes, s.write(), "reordering must change the bytes");
    let t = CalibTable::parse(&bytes).expect("reordered table parses");
    assert_matches_spec(&t, &s);
}

#[test]
fn absent_optional_sections_are_neutral() {
    for g in [SMALL, SMALL_DUAL, CCD] {
        let s = gains_only(g);
        let bytes = round_trip(&s);
        assert_eq!(
            bytes.len(),
            HEADER_LEN + DIR_ENTRY_LEN + 4 * usize::from(g.outputs)
        );
        let t = CalibTable::parse(&bytes).expect("parses");
        assert!(t.hot_pixels().is_empty() && t.telegraph_pixels().is_empty());
        assert_eq!(t.hot_pixels().find(0, 0), None);
        assert!(!t.telegraph_pixels().contains(0, 0));
        for (x, y) in [
            (0, 0),
            (g.active_cols - 1, g.active_rows - 1),
            (u16::MAX, u16::MAX),
        ] {
            assert_eq!(t.dark_rel(x, y), DarkRel::ONE);
            assert_eq!(t.flat_inv(x, y), FlatInv::ONE);
        }
        assert_eq!(t.column_bias(g.line_len() - 1), ColumnBiasAdu::ZERO);
    }
}

#[test]
fn each_optional_section_alone() {
    let full = full_spec(SMALL_DUAL, 0, 3);
    let base = gains_only(SMALL_DUAL);
    let variants = [
        OwnedSpec {
            column_bias: full.column_bias.clone(),
            ..base.clone()
        },
        OwnedSpec {
            dark: full.dark.clone(),
            ..base.clone()
        },
        OwnedSpec {
            flat: full.flat.clone(),
            ..base.clone()
        },
        OwnedSpec {
            hot: full.hot.clone(),
            ..base.clone()
        },
        OwnedSpec {
            telegraph: full.telegraph.clone(),
            ..base.clone()
        },
        OwnedSpec {
            pixcorr: full.pixcorr.clone(),
            ..base.clone()
        },
    ];
    for s in &variants {
        let bytes = round_trip(s);
        assert_eq!(usize::from(rd16(&bytes, 6)), 2);
    }
}

#[test]
fn out_of_range_accessors_do_not_panic() {
    let s = full_spec(SMALL_DUAL, 0, 0);
    let bytes = s.write();
    let t = CalibTable::parse(&bytes).expect("parses");
    // An output past the last reads as the last output.
    assert_eq!(t.gain(Output(2)), s.gains[1]);
    assert_eq!(t.gain(Output(u8::MAX)), s.gains[1]);
    // A column past the line, or an absurd one, reads as no bias.
    assert_eq!(t.column_bias(SMALL_DUAL.line_len()), ColumnBiasAdu::ZERO);
    assert_eq!(t.column_bias(usize::MAX), ColumnBiasAdu::ZERO);
    // Far outside the map: neutral values.
    assert_eq!(t.dark_rel(u16::MAX, u16::MAX), DarkRel::ONE);
    assert_eq!(t.flat_inv(u16::MAX, u16::MAX), FlatInv::ONE);
    assert_eq!(t.hot_pixels().get(usize::MAX), None);
    assert_eq!(t.telegraph_pixels().get(usize::MAX), None);
    let hot = t.hot_pixels();
    assert_eq!(hot.lower_bound(u16::MAX, u16::MAX), hot.len());
    assert_eq!(hot.find(u16::MAX, u16::MAX), None);
    assert!(!t.telegraph_pixels().contains(u16::MAX, u16::MAX));
}

#[test]
fn write_into_a_larger_buffer_leaves_the_rest_alone() {
    let s = full_spec(SMALL, 2, 0);
    let spec = s.spec();
    let curves = s.curves();
    let mut buf = vec![0xA5u8; s.encoded_len() + 17];
    let n =
        startrack_core::table::write_table_with_pixcorr(&spec, &curves, &mut buf).expect("writes");
    assert_eq!(n, s.encoded_len());
    assert!(buf[n..].iter().all(|&b| b == 0xA5));
    assert_eq!(&buf[..n], &s.write()[..]);
    // The whole buffer is not a table (the length disagrees), its prefix is.
    assert_eq!(
        parse_unit(&buf),
        Err(TableError::LengthMismatch {
            header: n as u32,
            actual: buf.len() as u32
        })
    );
}

// =============================================================================================
// Corruptions. Each starts from a valid table and reaches exactly one check.

fn small_table() -> Vec<u8> {
    full_spec(SMALL_DUAL, 0, 2).write()
}

fn ccd_gains_only() -> Vec<u8> {
    gains_only(CCD).write()
}

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
    let b = patched(&t, |b| wr16(b, 6, 9));
    assert_eq!(parse_unit(&b), Err(TableError::TooManySections(9)));
    let b = patched(&t, |b| wr16(b, 6, u16::MAX));
    assert!(matches!(
        CalibTable::parse(&b),
        Err(TableError::TooManySections(_))
    ));
    // Nine real directory entries, length consistent.
    let mut raw = RawTable::decompose(&t);
    while raw.sections.len() < 9 {
        raw.sections.push(RawSection::new(
            SectionKind::Gains,
            enc_gains(&gains(&SMALL_DUAL)),
        ));
    }
    assert_eq!(
        parse_unit(&raw.build()),
        Err(TableError::TooManySections(9))
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
    for code in [0u16, 8, 0x0100, u16::MAX] {
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
    let b = patched(&t, |b| wr16(b, e, 9));
    assert_eq!(parse_unit(&b), Err(TableError::UnknownSection(9)));
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

/// `t` with the section of `kind` replaced by `data` (fresh lengths and CRCs).
fn with_section(t: &[u8], kind: SectionKind, f: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut raw = RawTable::decompose(t);
    f(raw.section_mut(kind));
    raw.build()
}

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

fn parse_unit(b: &[u8]) -> Result<(), TableError> {
    CalibTable::parse(b).map(|_| ())
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

// =============================================================================================
// write_table refuses what the parser refuses.

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
        TableError::TooManySections(9),
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

// =============================================================================================
// Layout: every byte under a CRC; tables stored at the start of a larger region.

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

// =============================================================================================
// The pixel-phase correction section.

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
    use startrack_core::centroid::cog::CogPower;
    use startrack_core::centroid::pixcorr::PixCorrBackground;
    use startrack_host::pixcorr::{CurveSpec, build_curve, measured_phase};
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
