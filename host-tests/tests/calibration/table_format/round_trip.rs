//! Round trip: what `write_table` writes follows the documented layout byte for byte and
//! parses back to the same values, over the whole active area and every raw column, for the
//! CCD47-20 and a small sensor, per pixel and tiled; absent sections read as neutral.
//! Cost: the CCD47-20 cases walk its 1024 x 1024 active area a few times.

use super::parse_unit;
use startrack_core::geometry::Output;
use startrack_core::table::{
    CalibTable, DIR_ENTRY_LEN, HEADER_LEN, HotPolicy, SectionKind, TableError,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, FlatInv};
use startrack_test_support::table_fixtures::*;

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
    assert_eq!(t.cti(), s.cti, "CTI coefficients");
    assert_eq!(t.psf_model(), s.psf_model, "field PSF model");
    assert_eq!(t.dark_law(), s.dark_law, "dark law");
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

pub(super) fn round_trip(s: &OwnedSpec) -> Vec<u8> {
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
        OwnedSpec {
            cti: full.cti,
            ..base.clone()
        },
        OwnedSpec {
            psf_model: full.psf_model,
            ..base.clone()
        },
        OwnedSpec {
            dark_law: full.dark_law,
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
