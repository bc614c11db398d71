//! Writing a calibration table into a caller's buffer (no allocation), so that host tools and
//! an in-flight recalibration produce exactly the bytes [`CalibTable::parse`] reads.
//!
//! Cost: one pass over the spec's data to encode it, one CRC pass, and the parse of the
//! result that checks it.

use super::cti::CtiCoeffs;
use super::error::{SectionKind, WriteError};
use super::pixcorr::PixCorr;
use super::psfmodel::{MAX_PSF_DEGREE, PsfModel};
use super::{
    CRC, DIR_ENTRY_LEN, HEADER_LEN, HOT_ENTRY_LEN, HotPixel, HotPolicy, MAGIC, MAP_HEADER_LEN,
    MapHeader, PIXCORR_HEADER_LEN, RefTemperature, TELEGRAPH_ENTRY_LEN, VERSION,
};
use crate::geometry::{MAX_OUTPUTS, ReadoutGeometry};
use crate::table::CalibTable;
use crate::units::{ColumnBiasAdu, DarkRel, FlatInv, GainEPerAdu};

/// A tiled map to write: `tiles` must hold `MapHeader::for_area(..).tiles()` values in
/// row-major tile order.
#[derive(Clone, Copy, Debug)]
pub struct MapSpec<'a, T> {
    /// Tiles are `2^tile_log2` pixels square (0 = per pixel).
    pub tile_log2: u8,
    /// One value per tile.
    pub tiles: &'a [T],
}

/// Everything a table holds, borrowed from the caller.
#[derive(Clone, Copy, Debug)]
pub struct TableSpec<'a> {
    /// Sensor geometry.
    pub geometry: ReadoutGeometry,
    /// Raw samples at or above this are flagged saturated.
    pub saturation_adu: u16,
    /// One gain per output.
    pub gains: &'a [GainEPerAdu],
    /// One offset per raw column, or none.
    pub column_bias: Option<&'a [ColumnBiasAdu]>,
    /// Relative dark map, or none.
    pub dark_rel: Option<MapSpec<'a, DarkRel>>,
    /// Inverse flat map, or none.
    pub flat_inv: Option<MapSpec<'a, FlatInv>>,
    /// Reference temperature of the hot-pixel rates.
    pub hot_ref_k: RefTemperature,
    /// Hot pixels sorted by (y, x); the section is written only when not empty.
    pub hot: &'a [HotPixel],
    /// Telegraph pixels (x, y) sorted by (y, x); written only when not empty.
    pub telegraph: &'a [(u16, u16)],
    /// CTI coefficients (section 8), or none.
    pub cti: Option<CtiCoeffs>,
    /// Field PSF model (section 9), or none.
    pub psf_model: Option<PsfModel>,
    /// The fitted camera model (section 10), or none.
    pub camera_model: Option<crate::attitude::Camera>,
    /// The covered pixels' dark law (section 11), or none.
    pub dark_law: Option<super::DarkLaw>,
}

impl TableSpec<'_> {
    /// Bytes the encoded table takes.
    pub fn encoded_len(&self) -> usize {
        encoded_len(self, &[])
    }

    /// Bytes the encoded table takes with a pixel-phase section of `curves`.
    pub fn encoded_len_with_pixcorr(&self, curves: &[PixCorr<'_>]) -> usize {
        encoded_len(self, curves)
    }
}

/// The sections `spec` and `curves` make, with their lengths, in kind order.
fn sections<'s>(
    spec: &'s TableSpec<'_>,
    curves: &'s [PixCorr<'_>],
) -> impl Iterator<Item = (SectionKind, usize)> + 's {
    let map_len = |tiles: usize, elem: usize| MAP_HEADER_LEN + tiles * elem;
    [
        Some((SectionKind::Gains, 4 * spec.gains.len())),
        spec.column_bias
            .map(|c| (SectionKind::ColumnBias, 2 * c.len())),
        spec.dark_rel
            .map(|m| (SectionKind::DarkRel, map_len(m.tiles.len(), 1))),
        spec.flat_inv
            .map(|m| (SectionKind::FlatInv, map_len(m.tiles.len(), 2))),
        (!spec.hot.is_empty())
            .then_some((SectionKind::HotPixels, 8 + HOT_ENTRY_LEN * spec.hot.len())),
        (!spec.telegraph.is_empty()).then_some((
            SectionKind::Telegraph,
            4 + TELEGRAPH_ENTRY_LEN * spec.telegraph.len(),
        )),
        (!curves.is_empty()).then(|| {
            (
                SectionKind::PixCorr,
                PIXCORR_HEADER_LEN
                    + curves
                        .iter()
                        .map(|c| c.header().encoded_len())
                        .sum::<usize>(),
            )
        }),
        spec.cti.map(|_| {
            (
                SectionKind::Cti,
                CtiCoeffs::encoded_len(usize::from(spec.geometry.outputs).min(MAX_OUTPUTS)),
            )
        }),
        spec.psf_model.map(|m| {
            (
                SectionKind::PsfModel,
                PsfModel::encoded_len(m.degree.min(MAX_PSF_DEGREE)),
            )
        }),
        spec.camera_model
            .map(|_| (SectionKind::CameraModel, super::camera::CAMERA_SECTION_LEN)),
        spec.dark_law
            .map(|_| (SectionKind::DarkLaw, super::darklaw::DARK_LAW_SECTION_LEN)),
    ]
    .into_iter()
    .flatten()
}

fn encoded_len(spec: &TableSpec<'_>, curves: &[PixCorr<'_>]) -> usize {
    let n = sections(spec, curves).count();
    HEADER_LEN + DIR_ENTRY_LEN * n + sections(spec, curves).map(|(_, l)| l).sum::<usize>()
}

/// A bounds-checked little-endian cursor over the output buffer.
struct Out<'b> {
    buf: &'b mut [u8],
    pos: usize,
}

impl Out<'_> {
    fn put(&mut self, bytes: &[u8]) {
        if let Some(dst) = self.buf.get_mut(self.pos..self.pos + bytes.len()) {
            dst.copy_from_slice(bytes);
        }
        self.pos += bytes.len();
    }
}

/// Encodes `spec` into `out` and returns the number of bytes written. The result is parsed
/// back before returning, so a spec that the parser would reject (a zero gain, an unsorted
/// defect list, a map of the wrong size) is reported as [`WriteError::Invalid`] and never
/// produces a table.
pub fn write_table(spec: &TableSpec<'_>, out: &mut [u8]) -> Result<usize, WriteError> {
    write_table_with_pixcorr(spec, &[], out)
}

/// As [`write_table`], with a pixel-phase correction section (kind 7) holding `curves`
/// (none: no section; more than [`super::MAX_PIXCORR_CURVES`]: [`WriteError::Invalid`]).
pub fn write_table_with_pixcorr(
    spec: &TableSpec<'_>,
    curves: &[PixCorr<'_>],
    out: &mut [u8],
) -> Result<usize, WriteError> {
    let len = encoded_len(spec, curves);
    if let Some(cam) = &spec.camera_model {
        super::camera::encode(cam)
            .map_err(|e| WriteError::Invalid(super::TableError::CameraModel(e)))?;
    }
    let buf = out
        .get_mut(..len)
        .ok_or(WriteError::BufferTooSmall { needed: len })?;
    let n = sections(spec, curves).count();
    let dir_end = HEADER_LEN + DIR_ENTRY_LEN * n;

    // Sections first, then the directory that names them, then the header over both.
    let mut o = Out { buf, pos: dir_end };
    let mut entries = [(SectionKind::Gains, 0usize, 0usize); SectionKind::ALL.len()];
    for (slot, (kind, slen)) in entries.iter_mut().zip(sections(spec, curves)) {
        *slot = (kind, o.pos, slen);
        write_section(&mut o, spec, curves, kind);
    }
    for (i, (kind, start, slen)) in entries.iter().take(n).enumerate() {
        let crc = o
            .buf
            .get(*start..start + slen)
            .map_or(0, |s| CRC.checksum(s));
        o.pos = HEADER_LEN + i * DIR_ENTRY_LEN;
        o.put(&(*kind as u16).to_le_bytes());
        o.put(&0u16.to_le_bytes());
        o.put(&(*start as u32).to_le_bytes());
        o.put(&(*slen as u32).to_le_bytes());
        o.put(&crc.to_le_bytes());
    }
    let g = &spec.geometry;
    o.pos = 0;
    o.put(&MAGIC);
    o.put(&VERSION.to_le_bytes());
    o.put(&(n as u16).to_le_bytes());
    o.put(&(len as u32).to_le_bytes());
    for v in [
        g.overscan_px,
        g.covered_px,
        g.active_cols,
        g.active_rows,
        g.lines,
    ] {
        o.put(&v.to_le_bytes());
    }
    o.put(&[g.outputs, 0]);
    o.put(&spec.saturation_adu.to_le_bytes());
    o.put(&0u16.to_le_bytes());
    let mut digest = CRC.digest();
    digest.update(o.buf.get(..28).unwrap_or(&[]));
    digest.update(o.buf.get(HEADER_LEN..dir_end).unwrap_or(&[]));
    o.put(&digest.finalize().to_le_bytes());
    CalibTable::parse(o.buf).map_err(WriteError::Invalid)?;
    Ok(len)
}

fn write_section(o: &mut Out<'_>, spec: &TableSpec<'_>, curves: &[PixCorr<'_>], kind: SectionKind) {
    let g = &spec.geometry;
    match kind {
        SectionKind::Gains => spec
            .gains
            .iter()
            .for_each(|v| o.put(&v.to_bits().to_le_bytes())),
        SectionKind::ColumnBias => spec
            .column_bias
            .unwrap_or(&[])
            .iter()
            .for_each(|v| o.put(&v.to_bits().to_le_bytes())),
        SectionKind::DarkRel => {
            if let Some(m) = spec.dark_rel {
                map_header(o, g, m.tile_log2, 1);
                m.tiles.iter().for_each(|v| o.put(&[v.to_bits()]));
            }
        }
        SectionKind::FlatInv => {
            if let Some(m) = spec.flat_inv {
                map_header(o, g, m.tile_log2, 2);
                m.tiles
                    .iter()
                    .for_each(|v| o.put(&v.to_bits().to_le_bytes()));
            }
        }
        SectionKind::HotPixels => {
            o.put(&spec.hot_ref_k.to_bits().to_le_bytes());
            o.put(&(spec.hot.len() as u32).to_le_bytes());
            for h in spec.hot {
                o.put(&h.x.to_le_bytes());
                o.put(&h.y.to_le_bytes());
                o.put(&h.rate_e_per_s.to_bits().to_le_bytes());
                o.put(&h.doubling_k.to_bits().to_le_bytes());
                o.put(&[matches!(h.policy, HotPolicy::Exclude) as u8, 0]);
            }
        }
        SectionKind::Telegraph => {
            o.put(&(spec.telegraph.len() as u32).to_le_bytes());
            for (x, y) in spec.telegraph {
                o.put(&x.to_le_bytes());
                o.put(&y.to_le_bytes());
            }
        }
        SectionKind::CameraModel => {
            // Encodable: checked before any byte was written.
            if let Some(b) = spec
                .camera_model
                .and_then(|c| super::camera::encode(&c).ok())
            {
                o.put(&b);
            }
        }
        SectionKind::DarkLaw => {
            if let Some(l) = spec.dark_law {
                o.put(&l.encode());
            }
        }
        SectionKind::PixCorr => {
            // A count past u16 is written as u16::MAX: parsing it back rejects the table.
            o.put(
                &u16::try_from(curves.len())
                    .unwrap_or(u16::MAX)
                    .to_le_bytes(),
            );
            o.put(&0u16.to_le_bytes());
            for c in curves {
                o.put(&c.header().to_bytes());
                o.put(c.knot_bytes());
            }
        }
        SectionKind::Cti => {
            if let Some(c) = spec.cti {
                c.write(g.outputs, |b| o.put(b));
            }
        }
        SectionKind::PsfModel => {
            if let Some(m) = spec.psf_model {
                m.write(|b| o.put(b));
            }
        }
    }
}

fn map_header(o: &mut Out<'_>, g: &ReadoutGeometry, tile_log2: u8, format: u8) {
    // A tile size the parser rejects still gets a header; parsing it back reports MapFormat.
    let h = MapHeader::for_area(g.active_cols, g.active_rows, tile_log2.min(15));
    o.put(&[tile_log2, format]);
    o.put(&0u16.to_le_bytes());
    o.put(&h.tiles_x.to_le_bytes());
    o.put(&h.tiles_y.to_le_bytes());
}
