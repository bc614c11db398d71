//! Shared fixtures for the calibration-table tests: owned table specs, an independent
//! encoder/decoder of the documented layout, and byte patchers that re-seal the header and
//! section CRCs (CRC-32/ISO-HDLC from the `crc` crate) so that the checks behind them are
//! reached.
#![allow(dead_code)]

use startrack_core::centroid::cog::CogPower;
use startrack_core::centroid::pixcorr::{PixCorr, PixCorrBackground};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{
    CalibTable, DIR_ENTRY_LEN, HEADER_LEN, HotPixel, HotPolicy, MAP_HEADER_LEN, MapSpec,
    SectionKind, TableSpec, write_table, write_table_with_pixcorr,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu, Kelvin};

use fixed::types::U8F8;

/// The format's CRC, from the `crc` crate (the same algorithm the core uses, named
/// independently here so the tests do not read the core's own constant).
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Running CRC-32/ISO-HDLC over several slices.
pub fn crc32_parts(parts: &[&[u8]]) -> u32 {
    let mut d = CRC.digest();
    for p in parts {
        d.update(p);
    }
    d.finalize()
}

/// CRC-32/ISO-HDLC of one slice.
pub fn crc32(b: &[u8]) -> u32 {
    crc32_parts(&[b])
}

// ---------------------------------------------------------------------------------------------
// Little-endian field access.

pub fn rd16(b: &[u8], off: usize) -> u16 {
    u16::from_le_bytes([b[off], b[off + 1]])
}

pub fn rd32(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

pub fn wr16(b: &mut [u8], off: usize, v: u16) {
    b[off..off + 2].copy_from_slice(&v.to_le_bytes());
}

pub fn wr32(b: &mut [u8], off: usize, v: u32) {
    b[off..off + 4].copy_from_slice(&v.to_le_bytes());
}

// ---------------------------------------------------------------------------------------------
// Geometries.

/// A small sensor that keeps tests fast: 4 over-scan, 2 covered, 16 x 12 active, 14 lines,
/// one output (line length 28).
pub const SMALL: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 4,
    covered_px: 2,
    active_cols: 16,
    active_rows: 12,
    lines: 14,
    outputs: 1,
};

/// The same small sensor read through two outputs.
pub const SMALL_DUAL: ReadoutGeometry = ReadoutGeometry {
    outputs: 2,
    ..SMALL
};

/// The CCD47-20 read through both outputs.
pub const CCD: ReadoutGeometry = ReadoutGeometry::CCD47_20_DUAL;

// ---------------------------------------------------------------------------------------------
// Owned specs.

/// Everything a `TableSpec` borrows, owned.
#[derive(Clone, Debug)]
pub struct OwnedSpec {
    pub geometry: ReadoutGeometry,
    pub saturation_adu: u16,
    pub gains: Vec<GainEPerAdu>,
    pub column_bias: Option<Vec<ColumnBiasAdu>>,
    pub dark: Option<(u8, Vec<DarkRel>)>,
    pub flat: Option<(u8, Vec<FlatInv>)>,
    pub hot_ref_k: Kelvin,
    pub hot: Vec<HotPixel>,
    pub telegraph: Vec<(u16, u16)>,
    /// Pixel-phase correction curves, each encoded by [`enc_curve`] (none: no section).
    pub pixcorr: Vec<Vec<u8>>,
}

impl OwnedSpec {
    /// The curves, parsed by the core (panics on a malformed fixture).
    pub fn curves(&self) -> Vec<PixCorr<'_>> {
        self.pixcorr
            .iter()
            .map(|b| PixCorr::parse(b).expect("fixture curve").0)
            .collect()
    }

    /// Bytes of the whole table, pixel-phase section included.
    pub fn encoded_len(&self) -> usize {
        self.spec().encoded_len_with_pixcorr(&self.curves())
    }

    pub fn spec(&self) -> TableSpec<'_> {
        TableSpec {
            geometry: self.geometry,
            saturation_adu: self.saturation_adu,
            gains: &self.gains,
            column_bias: self.column_bias.as_deref(),
            dark_rel: self.dark.as_ref().map(|(t, v)| MapSpec {
                tile_log2: *t,
                tiles: v,
            }),
            flat_inv: self.flat.as_ref().map(|(t, v)| MapSpec {
                tile_log2: *t,
                tiles: v,
            }),
            hot_ref_k: self.hot_ref_k,
            hot: &self.hot,
            telegraph: &self.telegraph,
        }
    }

    /// Encodes with `write_table_with_pixcorr`, panicking (in the test) on failure.
    pub fn write(&self) -> Vec<u8> {
        let curves = self.curves();
        let mut buf = vec![0u8; self.encoded_len()];
        let n = write_table_with_pixcorr(&self.spec(), &curves, &mut buf)
            .unwrap_or_else(|e| panic!("write_table failed: {e}"));
        assert_eq!(n, buf.len(), "write_table length differs from encoded_len");
        buf
    }
}

/// Encodes `spec` into a buffer of exactly `encoded_len` bytes.
pub fn write_spec(spec: &TableSpec<'_>) -> Result<Vec<u8>, startrack_core::table::WriteError> {
    let mut buf = vec![0u8; spec.encoded_len()];
    let n = write_table(spec, &mut buf)?;
    assert_eq!(n, buf.len(), "write_table length differs from encoded_len");
    Ok(buf)
}

/// Tiles across and down an area of `cols` x `rows` with tiles of `2^log2` pixels, computed
/// independently of `MapHeader::for_area`.
pub fn tiles_of(cols: u16, rows: u16, log2: u8) -> (usize, usize) {
    let t = 1usize << log2;
    (usize::from(cols).div_ceil(t), usize::from(rows).div_ceil(t))
}

/// Index of the tile holding active pixel (x, y).
pub fn tile_index(g: &ReadoutGeometry, log2: u8, x: u16, y: u16) -> usize {
    let (tx, _) = tiles_of(g.active_cols, g.active_rows, log2);
    (usize::from(y) >> log2) * tx + (usize::from(x) >> log2)
}

/// Distinct, non-trivial dark tiles (every u8 value appears for large maps).
pub fn dark_tiles(g: &ReadoutGeometry, log2: u8) -> Vec<DarkRel> {
    let (tx, ty) = tiles_of(g.active_cols, g.active_rows, log2);
    (0..tx * ty)
        .map(|i| DarkRel::from_bits(((i * 31 + 7) % 256) as u8))
        .collect()
}

/// Non-zero inverse-flat tiles that differ between neighbours.
pub fn flat_tiles(g: &ReadoutGeometry, log2: u8) -> Vec<FlatInv> {
    let (tx, ty) = tiles_of(g.active_cols, g.active_rows, log2);
    (0..tx * ty)
        .map(|i| FlatInv::from_bits(1 + ((i * 7919 + 13) % 65535) as u16))
        .collect()
}

/// Column offsets of both signs over the whole range of I12F4.
pub fn column_bias(g: &ReadoutGeometry) -> Vec<ColumnBiasAdu> {
    (0..g.line_len())
        .map(|c| ColumnBiasAdu::from_bits(((c * 4099 + 5) % 65536) as u16 as i16))
        .collect()
}

/// Distinct gains per output (1.5 and 1.75 e-/ADU plus a low-order bit pattern).
pub fn gains(g: &ReadoutGeometry) -> Vec<GainEPerAdu> {
    (0..g.outputs)
        .map(|o| {
            GainEPerAdu::from_num(1.5 + 0.25 * f64::from(o))
                + GainEPerAdu::from_bits(0x123 + u32::from(o))
        })
        .collect()
}

/// A sorted hot list over the active area: both corners, the middle and a few more, both
/// policies, distinct rates and doubling temperatures.
pub fn hot_pixels(g: &ReadoutGeometry) -> Vec<HotPixel> {
    let (c, r) = (g.active_cols, g.active_rows);
    let mut pos = vec![
        (0, 0),
        (c - 1, 0),
        (c / 2, r / 2),
        (c / 3, r / 2),
        (0, r - 1),
        (c - 1, r - 1),
    ];
    pos.extend((1..r.min(40)).step_by(3).map(|y| ((y * 7) % c, y)));
    pos.sort_by_key(|&(x, y)| (y, x));
    pos.dedup();
    pos.iter()
        .enumerate()
        .map(|(i, &(x, y))| HotPixel {
            x,
            y,
            rate_e_per_s: ERatePerS::from_bits(0x0001_8000 + 0x0101 * i as u32),
            doubling_k: U8F8::from_bits(0x0600 + 3 * i as u16),
            policy: if i % 2 == 0 {
                HotPolicy::Correct
            } else {
                HotPolicy::Exclude
            },
        })
        .collect()
}

/// A sorted telegraph list over the active area, disjoint from `hot_pixels`' positions in
/// general (not required by the format).
pub fn telegraph(g: &ReadoutGeometry) -> Vec<(u16, u16)> {
    let (c, r) = (g.active_cols, g.active_rows);
    let mut pos = vec![(1, 0), (c - 2, r - 1), (c / 2 + 1, r / 2)];
    pos.extend((0..r.min(30)).step_by(5).map(|y| ((y * 3 + 2) % c, y)));
    pos.sort_by_key(|&(x, y)| (y, x));
    pos.dedup();
    pos
}

/// A spec with every section filled.
pub fn full_spec(g: ReadoutGeometry, dark_log2: u8, flat_log2: u8) -> OwnedSpec {
    OwnedSpec {
        geometry: g,
        saturation_adu: 0xFFF0 - u16::from(dark_log2) - 16 * u16::from(flat_log2),
        gains: gains(&g),
        column_bias: Some(column_bias(&g)),
        dark: Some((dark_log2, dark_tiles(&g, dark_log2))),
        flat: Some((flat_log2, flat_tiles(&g, flat_log2))),
        hot_ref_k: Kelvin::from_num(233.25),
        hot: hot_pixels(&g),
        telegraph: telegraph(&g),
        pixcorr: pixcorr_curves(),
    }
}

/// Two small curves (5 and 7 knots), encoded from the documented layout by hand.
pub fn pixcorr_curves() -> Vec<Vec<u8>> {
    vec![
        enc_curve(
            CogPower::One,
            5,
            PixCorrBackground::Given,
            0x0180,
            0x7000,
            &[0, -300, -520, -610, -400],
        ),
        enc_curve(
            CogPower::Two,
            7,
            PixCorrBackground::PerimeterMedian,
            0x0240,
            0x6800,
            &[0, 100, 250, 380, 420, 400, 330],
        ),
    ]
}

/// One curve: the 8-byte header (power, box, background, knot count, a U8F8 bits, m_max
/// U0F16 bits) and its I1F15 knot bits.
pub fn enc_curve(
    power: CogPower,
    box_side: u8,
    bg: PixCorrBackground,
    a_bits: u16,
    m_max_bits: u16,
    knots: &[i16],
) -> Vec<u8> {
    let p = if power == CogPower::One { 1 } else { 2 };
    let mut v = vec![p, box_side, bg as u8, knots.len() as u8];
    v.extend_from_slice(&a_bits.to_le_bytes());
    v.extend_from_slice(&m_max_bits.to_le_bytes());
    v.extend(knots.iter().flat_map(|k| k.to_le_bytes()));
    v
}

/// The pixel-phase section: count, reserved 0, the curves back to back.
pub fn enc_pixcorr(curves: &[Vec<u8>]) -> Vec<u8> {
    let mut v = (curves.len() as u16).to_le_bytes().to_vec();
    v.extend_from_slice(&[0, 0]);
    v.extend(curves.iter().flatten());
    v
}

/// A spec with only the required gains.
pub fn gains_only(g: ReadoutGeometry) -> OwnedSpec {
    OwnedSpec {
        geometry: g,
        saturation_adu: 60_000,
        gains: gains(&g),
        column_bias: None,
        dark: None,
        flat: None,
        hot_ref_k: Kelvin::from_num(240),
        hot: Vec::new(),
        telegraph: Vec::new(),
        pixcorr: Vec::new(),
    }
}

// ---------------------------------------------------------------------------------------------
// Independent encoding of section contents, straight from the documented layout.

pub fn enc_gains(g: &[GainEPerAdu]) -> Vec<u8> {
    g.iter().flat_map(|v| v.to_bits().to_le_bytes()).collect()
}

pub fn enc_column_bias(c: &[ColumnBiasAdu]) -> Vec<u8> {
    c.iter().flat_map(|v| v.to_bits().to_le_bytes()).collect()
}

pub fn enc_map_header(
    tile_log2: u8,
    format: u8,
    reserved: u16,
    tiles_x: u16,
    tiles_y: u16,
) -> Vec<u8> {
    let mut v = vec![tile_log2, format];
    v.extend(reserved.to_le_bytes());
    v.extend(tiles_x.to_le_bytes());
    v.extend(tiles_y.to_le_bytes());
    assert_eq!(v.len(), MAP_HEADER_LEN);
    v
}

pub fn enc_dark(g: &ReadoutGeometry, log2: u8, tiles: &[DarkRel]) -> Vec<u8> {
    let (tx, ty) = tiles_of(g.active_cols, g.active_rows, log2);
    let mut v = enc_map_header(log2, 1, 0, tx as u16, ty as u16);
    v.extend(tiles.iter().map(|t| t.to_bits()));
    v
}

pub fn enc_flat(g: &ReadoutGeometry, log2: u8, tiles: &[FlatInv]) -> Vec<u8> {
    let (tx, ty) = tiles_of(g.active_cols, g.active_rows, log2);
    let mut v = enc_map_header(log2, 2, 0, tx as u16, ty as u16);
    v.extend(tiles.iter().flat_map(|t| t.to_bits().to_le_bytes()));
    v
}

/// One hot entry with explicit policy and reserved bytes.
pub fn enc_hot_entry(h: &HotPixel, policy: u8, reserved: u8) -> Vec<u8> {
    let mut v = Vec::with_capacity(12);
    v.extend(h.x.to_le_bytes());
    v.extend(h.y.to_le_bytes());
    v.extend(h.rate_e_per_s.to_bits().to_le_bytes());
    v.extend(h.doubling_k.to_bits().to_le_bytes());
    v.extend([policy, reserved]);
    v
}

pub fn policy_byte(p: HotPolicy) -> u8 {
    match p {
        HotPolicy::Correct => 0,
        HotPolicy::Exclude => 1,
    }
}

pub fn enc_hot(t_ref: Kelvin, hot: &[HotPixel]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend(t_ref.to_bits().to_le_bytes());
    v.extend((hot.len() as u32).to_le_bytes());
    for h in hot {
        v.extend(enc_hot_entry(h, policy_byte(h.policy), 0));
    }
    v
}

pub fn enc_telegraph(t: &[(u16, u16)]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend((t.len() as u32).to_le_bytes());
    for (x, y) in t {
        v.extend(x.to_le_bytes());
        v.extend(y.to_le_bytes());
    }
    v
}

// ---------------------------------------------------------------------------------------------
// A table as a header plus a list of sections, rebuilt with fresh lengths and CRCs.

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawSection {
    pub kind: u16,
    pub reserved: u16,
    pub data: Vec<u8>,
}

impl RawSection {
    pub fn new(kind: SectionKind, data: Vec<u8>) -> Self {
        Self {
            kind: kind as u16,
            reserved: 0,
            data,
        }
    }
}

#[derive(Clone, Debug)]
pub struct RawTable {
    /// Bytes 0..32 of the header; the section count, total length and CRC are overwritten by
    /// `build`.
    pub header: [u8; HEADER_LEN],
    pub sections: Vec<RawSection>,
}

impl RawTable {
    /// A header for `g` with the given saturation level and no sections.
    pub fn new(g: &ReadoutGeometry, saturation_adu: u16) -> Self {
        let mut h = [0u8; HEADER_LEN];
        h[..4].copy_from_slice(b"STCT");
        wr16(&mut h, 4, 1);
        wr16(&mut h, 12, g.overscan_px);
        wr16(&mut h, 14, g.covered_px);
        wr16(&mut h, 16, g.active_cols);
        wr16(&mut h, 18, g.active_rows);
        wr16(&mut h, 20, g.lines);
        h[22] = g.outputs;
        wr16(&mut h, 24, saturation_adu);
        Self {
            header: h,
            sections: Vec::new(),
        }
    }

    /// The reference encoding of `s`: the documented layout, sections in kind order.
    pub fn from_spec(s: &OwnedSpec) -> Self {
        let g = &s.geometry;
        let mut t = Self::new(g, s.saturation_adu);
        t.sections
            .push(RawSection::new(SectionKind::Gains, enc_gains(&s.gains)));
        if let Some(c) = &s.column_bias {
            t.sections
                .push(RawSection::new(SectionKind::ColumnBias, enc_column_bias(c)));
        }
        if let Some((l, d)) = &s.dark {
            t.sections
                .push(RawSection::new(SectionKind::DarkRel, enc_dark(g, *l, d)));
        }
        if let Some((l, f)) = &s.flat {
            t.sections
                .push(RawSection::new(SectionKind::FlatInv, enc_flat(g, *l, f)));
        }
        if !s.hot.is_empty() {
            t.sections.push(RawSection::new(
                SectionKind::HotPixels,
                enc_hot(s.hot_ref_k, &s.hot),
            ));
        }
        if !s.telegraph.is_empty() {
            t.sections.push(RawSection::new(
                SectionKind::Telegraph,
                enc_telegraph(&s.telegraph),
            ));
        }
        if !s.pixcorr.is_empty() {
            t.sections.push(RawSection::new(
                SectionKind::PixCorr,
                enc_pixcorr(&s.pixcorr),
            ));
        }
        t
    }

    /// Splits a table (whose directory is in bounds) into its header and sections, in
    /// directory order.
    pub fn decompose(bytes: &[u8]) -> Self {
        let mut header = [0u8; HEADER_LEN];
        header.copy_from_slice(&bytes[..HEADER_LEN]);
        let n = usize::from(rd16(bytes, 6));
        let sections = (0..n)
            .map(|i| {
                let e = HEADER_LEN + i * DIR_ENTRY_LEN;
                let off = rd32(bytes, e + 4) as usize;
                let len = rd32(bytes, e + 8) as usize;
                RawSection {
                    kind: rd16(bytes, e),
                    reserved: rd16(bytes, e + 2),
                    data: bytes[off..off + len].to_vec(),
                }
            })
            .collect();
        Self { header, sections }
    }

    pub fn section_mut(&mut self, kind: SectionKind) -> &mut Vec<u8> {
        &mut self
            .sections
            .iter_mut()
            .find(|s| s.kind == kind as u16)
            .unwrap_or_else(|| panic!("no {} section", kind.name()))
            .data
    }

    pub fn remove(&mut self, kind: SectionKind) {
        self.sections.retain(|s| s.kind != kind as u16);
    }

    /// Header, directory, then the sections back to back in list order; fresh section count,
    /// total length, section CRCs and header CRC.
    pub fn build(&self) -> Vec<u8> {
        let n = self.sections.len();
        let dir_end = HEADER_LEN + DIR_ENTRY_LEN * n;
        let total = dir_end + self.sections.iter().map(|s| s.data.len()).sum::<usize>();
        let mut out = vec![0u8; total];
        out[..HEADER_LEN].copy_from_slice(&self.header);
        wr16(&mut out, 6, n as u16);
        wr32(&mut out, 8, total as u32);
        let mut pos = dir_end;
        for (i, s) in self.sections.iter().enumerate() {
            let e = HEADER_LEN + i * DIR_ENTRY_LEN;
            wr16(&mut out, e, s.kind);
            wr16(&mut out, e + 2, s.reserved);
            wr32(&mut out, e + 4, pos as u32);
            wr32(&mut out, e + 8, s.data.len() as u32);
            wr32(&mut out, e + 12, crc32(&s.data));
            out[pos..pos + s.data.len()].copy_from_slice(&s.data);
            pos += s.data.len();
        }
        reseal_header(&mut out);
        out
    }
}

// ---------------------------------------------------------------------------------------------
// Re-sealing patched bytes.

/// Directory index of the section of `kind`.
pub fn dir_index(bytes: &[u8], kind: SectionKind) -> usize {
    let n = usize::from(rd16(bytes, 6));
    (0..n)
        .find(|i| rd16(bytes, HEADER_LEN + i * DIR_ENTRY_LEN) == kind as u16)
        .unwrap_or_else(|| panic!("no {} section", kind.name()))
}

/// (offset, length) of the section of `kind`.
pub fn section_range(bytes: &[u8], kind: SectionKind) -> (usize, usize) {
    let e = HEADER_LEN + dir_index(bytes, kind) * DIR_ENTRY_LEN;
    (rd32(bytes, e + 4) as usize, rd32(bytes, e + 8) as usize)
}

/// Recomputes the header CRC over bytes 0..28 and the directory, as far as both are present
/// (the section count is clamped to the bytes available). Does nothing for fewer than 32 bytes.
pub fn reseal_header(b: &mut [u8]) {
    if b.len() < HEADER_LEN {
        return;
    }
    let n = usize::from(rd16(b, 6));
    let dir_end = (HEADER_LEN + DIR_ENTRY_LEN * n).min(b.len());
    let crc = crc32_parts(&[&b[..28], &b[HEADER_LEN..dir_end]]);
    wr32(b, 28, crc);
}

/// Recomputes the CRC of directory entry `i` if the entry and its section are in bounds.
pub fn reseal_section(b: &mut [u8], i: usize) {
    let e = HEADER_LEN + i * DIR_ENTRY_LEN;
    if e + DIR_ENTRY_LEN > b.len() {
        return;
    }
    let off = rd32(b, e + 4) as usize;
    let len = rd32(b, e + 8) as usize;
    if let Some(end) = off.checked_add(len).filter(|&end| end <= b.len()) {
        let crc = crc32(&b[off..end]);
        wr32(b, e + 12, crc);
    }
}

/// Re-seals every in-bounds section, then the header (whose CRC covers the section CRCs).
pub fn reseal_all(b: &mut [u8]) {
    if b.len() < HEADER_LEN {
        return;
    }
    let n = usize::from(rd16(b, 6)).min(16);
    for i in 0..n {
        reseal_section(b, i);
    }
    reseal_header(b);
}

/// Copies `bytes`, applies `patch`, re-seals everything and parses.
pub fn patched(bytes: &[u8], patch: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut b = bytes.to_vec();
    patch(&mut b);
    reseal_all(&mut b);
    b
}

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
    visited
}
