//! An independent encoder of the documented layout: each section's bytes built field by
//! field, and [`RawTable`], a table as a header plus a list of sections rebuilt with fresh
//! lengths and CRCs (the reference encoding of a spec, and the starting point of the
//! corruptions). Cost: one pass over the sections' values.

use super::bytes::{crc32, rd16, rd32, reseal_header, wr16, wr32};
use super::specs::{OwnedSpec, tiles_of};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{
    CtiCoeffs, DIR_ENTRY_LEN, HEADER_LEN, HotPixel, HotPolicy, MAP_HEADER_LEN, PsfModel,
    SectionKind,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, FlatInv, GainEPerAdu, Kelvin};

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

/// The pixel-phase section: count, reserved 0, the curves back to back.
pub fn enc_pixcorr(curves: &[Vec<u8>]) -> Vec<u8> {
    let mut v = (curves.len() as u16).to_le_bytes().to_vec();
    v.extend_from_slice(&[0, 0]);
    v.extend(curves.iter().flatten());
    v
}

/// The CTI section: reference flux u32, flux offset u32, exponent u16, reserved u16, then
/// per output of the geometry the parallel and serial shifts (u32 each).
pub fn enc_cti(outputs: u8, c: &CtiCoeffs) -> Vec<u8> {
    let mut v = c.reference_flux_e.to_le_bytes().to_vec();
    v.extend(c.flux_offset_e.to_le_bytes());
    v.extend(c.alpha.to_bits().to_le_bytes());
    v.extend([0, 0]);
    for o in &c.outputs[..usize::from(outputs)] {
        v.extend(o.parallel_px.to_bits().to_le_bytes());
        v.extend(o.serial_px.to_bits().to_le_bytes());
    }
    v
}

/// The dark-law section from its documented layout: rate U16F16, T_ref U16F16, doubling
/// U8F8, band low and high U8F8, reserved u16.
pub fn enc_dark_law(l: &startrack_core::table::DarkLaw) -> Vec<u8> {
    let mut v = l.rate_e_per_s.to_bits().to_le_bytes().to_vec();
    v.extend(l.reference_k.to_bits().to_le_bytes());
    v.extend(l.doubling_k.to_bits().to_le_bytes());
    v.extend(l.band_low.to_bits().to_le_bytes());
    v.extend(l.band_high.to_bits().to_le_bytes());
    v.extend([0, 0]);
    v
}

/// The PSF model section: degree u8, reserved u8, scatter u16, stars u16, reserved u16, then
/// (d + 1)(d + 2) / 2 coefficients (i32 each).
pub fn enc_psf_model(m: &PsfModel) -> Vec<u8> {
    let mut v = vec![m.degree, 0];
    v.extend(m.scatter_px.to_bits().to_le_bytes());
    v.extend(m.stars.to_le_bytes());
    v.extend([0, 0]);
    let d = usize::from(m.degree);
    for c in &m.coeffs[..(d + 1) * (d + 2) / 2] {
        v.extend(c.to_bits().to_le_bytes());
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
        if let Some(c) = &s.cti {
            t.sections
                .push(RawSection::new(SectionKind::Cti, enc_cti(g.outputs, c)));
        }
        if let Some(m) = &s.psf_model {
            t.sections
                .push(RawSection::new(SectionKind::PsfModel, enc_psf_model(m)));
        }
        if let Some(c) = &s.camera_model {
            t.sections.push(RawSection::new(
                SectionKind::CameraModel,
                startrack_core::table::camera::encode(c)
                    .expect("fixture camera encodes")
                    .to_vec(),
            ));
        }
        if let Some(l) = &s.dark_law {
            t.sections
                .push(RawSection::new(SectionKind::DarkLaw, enc_dark_law(l)));
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
