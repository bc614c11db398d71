//! Reading and checking a calibration table in place.

use super::bytes::{u16_at, u32_at};
use super::cti::{CtiCoeffs, CtiFormatError};
use super::error::{SectionKind, TableError};
use super::pixcorr::PixCorrSet;
use super::psfmodel::{PsfFormatError, PsfModel};
use super::{
    CRC, DIR_ENTRY_LEN, HEADER_LEN, HOT_ENTRY_LEN, HotPixel, HotPolicy, MAGIC, MAP_HEADER_LEN,
    MAX_PIXCORR_CURVES, MAX_TILE_LOG2, MapHeader, PIXCORR_HEADER_LEN, RefTemperature,
    TELEGRAPH_ENTRY_LEN, VERSION,
};
use crate::geometry::{MAX_OUTPUTS, Output, ReadoutGeometry};
use crate::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu};
use fixed::types::U8F8;

/// Most sections a table may list.
pub const MAX_SECTIONS: usize = 16;

/// A checked table, borrowing the bytes it was read from. All accessors are total: the
/// checks in [`CalibTable::parse`] guarantee that every index they compute is in range, and
/// they still return a neutral value rather than panic if called out of range.
#[derive(Clone, Copy, Debug)]
pub struct CalibTable<'a> {
    len: usize,
    geometry: ReadoutGeometry,
    saturation_adu: u16,
    gains: [GainEPerAdu; MAX_OUTPUTS],
    column_bias: Option<&'a [u8]>,
    dark: Option<MapView<'a>>,
    flat: Option<MapView<'a>>,
    hot: HotList<'a>,
    telegraph: DefectList<'a>,
    pixcorr: PixCorrSet<'a>,
    cti: Option<CtiCoeffs>,
    psf_model: Option<PsfModel>,
    camera_model: Option<&'a [u8]>,
    dark_law: Option<super::DarkLaw>,
}

/// A tiled map over the active area, read in place.
#[derive(Clone, Copy, Debug)]
pub struct MapView<'a> {
    header: MapHeader,
    active_cols: u16,
    active_rows: u16,
    elem_bytes: usize,
    data: &'a [u8],
}

impl<'a> MapView<'a> {
    /// The map's tiling.
    pub fn header(&self) -> MapHeader {
        self.header
    }

    fn tile_index(&self, x: u16, y: u16) -> usize {
        let tx = usize::from(x >> self.header.tile_log2);
        let ty = usize::from(y >> self.header.tile_log2);
        ty * usize::from(self.header.tiles_x) + tx
    }

    /// The raw element bits at active pixel (x, y), or `None` outside the active area (a
    /// pixel past the right edge must not read the next row's tile).
    fn bits(&self, x: u16, y: u16) -> Option<u32> {
        if x >= self.active_cols || y >= self.active_rows {
            return None;
        }
        let i = self.tile_index(x, y).checked_mul(self.elem_bytes)?;
        match self.elem_bytes {
            1 => self.data.get(i).map(|b| u32::from(*b)),
            _ => u16_at(self.data, i).map(u32::from),
        }
    }

    /// The element bits of tile `i` in row-major tile order (the raw pre-filter reads a tile
    /// row's tiles by index: `detect::prefilter`).
    pub(crate) fn tile_bits(&self, i: usize) -> Option<u32> {
        match self.elem_bytes {
            1 => self.data.get(i).map(|b| u32::from(*b)),
            _ => u16_at(self.data, i.checked_mul(2)?).map(u32::from),
        }
    }
}

/// The hot-pixel list, sorted by (y, x), read in place.
#[derive(Clone, Copy, Debug, Default)]
pub struct HotList<'a> {
    t_ref_k: RefTemperature,
    entries: &'a [u8],
}

impl<'a> HotList<'a> {
    /// Number of hot pixels.
    pub fn len(&self) -> usize {
        self.entries.len() / HOT_ENTRY_LEN
    }

    /// True when the list is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The temperature at which the listed rates hold.
    pub fn reference_temperature_k(&self) -> RefTemperature {
        self.t_ref_k
    }

    /// Entry `i`, or `None` past the end or if the policy byte is unknown (the parser rejects
    /// such tables, so this happens only for an index out of range).
    pub fn get(&self, i: usize) -> Option<HotPixel> {
        let e = self.entries.get(i.checked_mul(HOT_ENTRY_LEN)?..)?;
        let policy = match *e.get(10)? {
            0 => HotPolicy::Correct,
            1 => HotPolicy::Exclude,
            _ => return None,
        };
        Some(HotPixel {
            x: u16_at(e, 0)?,
            y: u16_at(e, 2)?,
            rate_e_per_s: ERatePerS::from_bits(u32_at(e, 4)?),
            doubling_k: U8F8::from_bits(u16_at(e, 8)?),
            policy,
        })
    }

    /// Index of the first entry at or after (y, x) in (y, x) order.
    pub fn lower_bound(&self, x: u16, y: u16) -> usize {
        lower_bound(self.len(), (y, x), |i| self.get(i).map(|h| (h.y, h.x)))
    }

    /// The hot pixel at (x, y), if listed.
    pub fn find(&self, x: u16, y: u16) -> Option<HotPixel> {
        self.get(self.lower_bound(x, y))
            .filter(|h| h.x == x && h.y == y)
    }
}

/// A sorted list of active-area pixel positions (the telegraph pixels), read in place.
#[derive(Clone, Copy, Debug, Default)]
pub struct DefectList<'a> {
    entries: &'a [u8],
}

impl<'a> DefectList<'a> {
    /// Number of pixels listed.
    pub fn len(&self) -> usize {
        self.entries.len() / TELEGRAPH_ENTRY_LEN
    }

    /// True when the list is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entry `i` as (x, y).
    pub fn get(&self, i: usize) -> Option<(u16, u16)> {
        let off = i.checked_mul(TELEGRAPH_ENTRY_LEN)?;
        Some((u16_at(self.entries, off)?, u16_at(self.entries, off + 2)?))
    }

    /// Index of the first entry at or after (y, x) in (y, x) order.
    pub fn lower_bound(&self, x: u16, y: u16) -> usize {
        lower_bound(self.len(), (y, x), |i| self.get(i).map(|(ex, ey)| (ey, ex)))
    }

    /// True when (x, y) is listed.
    pub fn contains(&self, x: u16, y: u16) -> bool {
        self.get(self.lower_bound(x, y)) == Some((x, y))
    }
}

/// First index in `0..len` whose key is not less than `key`; `key_at` is sorted.
fn lower_bound(len: usize, key: (u16, u16), key_at: impl Fn(usize) -> Option<(u16, u16)>) -> usize {
    let (mut lo, mut hi) = (0usize, len);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        match key_at(mid) {
            Some(k) if k < key => lo = mid + 1,
            _ => hi = mid,
        }
    }
    lo
}

struct Section<'a> {
    kind: SectionKind,
    offset: usize,
    bytes: &'a [u8],
}

impl<'a> CalibTable<'a> {
    /// Checks `bytes` completely (magic, version, lengths, every CRC, every entry's range)
    /// and returns a view of it, or the first problem found.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, TableError> {
        let got = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
        let too_short = |needed: usize| TableError::TooShort {
            needed: u32::try_from(needed).unwrap_or(u32::MAX),
            got,
        };
        let head = bytes.get(..HEADER_LEN).ok_or(too_short(HEADER_LEN))?;
        if head.get(..4) != Some(&MAGIC[..]) {
            return Err(TableError::BadMagic);
        }
        let rd16 = |off| u16_at(head, off).ok_or(too_short(HEADER_LEN));
        let version = rd16(4)?;
        if version != VERSION {
            return Err(TableError::UnsupportedVersion(version));
        }
        let n_sections = rd16(6)?;
        let total = u32_at(head, 8).ok_or(too_short(HEADER_LEN))?;
        if usize::from(n_sections) > MAX_SECTIONS {
            return Err(TableError::TooManySections(n_sections));
        }
        let dir_end = HEADER_LEN + DIR_ENTRY_LEN * usize::from(n_sections);
        if total != got || (total as usize) < dir_end {
            return Err(TableError::LengthMismatch {
                header: total,
                actual: got,
            });
        }
        let dir = bytes.get(HEADER_LEN..dir_end).ok_or(too_short(dir_end))?;
        let mut digest = CRC.digest();
        digest.update(head.get(..28).ok_or(too_short(HEADER_LEN))?);
        digest.update(dir);
        if digest.finalize() != u32_at(head, 28).ok_or(too_short(HEADER_LEN))? {
            return Err(TableError::HeaderCrc);
        }
        if head.get(23) != Some(&0) || rd16(26)? != 0 {
            return Err(TableError::Reserved);
        }
        let outputs = *head.get(22).ok_or(too_short(HEADER_LEN))?;
        let geometry = ReadoutGeometry {
            overscan_px: rd16(12)?,
            covered_px: rd16(14)?,
            active_cols: rd16(16)?,
            active_rows: rd16(18)?,
            lines: rd16(20)?,
            outputs,
        };
        geometry.validate().map_err(TableError::Geometry)?;
        let saturation_adu = rd16(24)?;

        let mut found: [Option<&'a [u8]>; 9] = [None; 9];
        let mut camera_model: Option<&'a [u8]> = None;
        let mut dark_law: Option<&'a [u8]> = None;
        // (offset, length, kind) of each section, to prove they cover the table exactly.
        let mut extents = [(0usize, 0usize, SectionKind::Gains); MAX_SECTIONS];
        for i in 0..usize::from(n_sections) {
            let s = section(bytes, dir, i, dir_end)?;
            if let Some(e) = extents.get_mut(i) {
                *e = (s.offset, s.bytes.len(), s.kind);
            }
            if s.kind == SectionKind::CameraModel {
                if camera_model.replace(s.bytes).is_some() {
                    return Err(TableError::DuplicateSection(s.kind));
                }
                continue;
            }
            if s.kind == SectionKind::DarkLaw {
                if dark_law.replace(s.bytes).is_some() {
                    return Err(TableError::DuplicateSection(s.kind));
                }
                continue;
            }
            let slot = found
                .get_mut(s.kind as usize - 1)
                .ok_or(TableError::UnknownSection(s.kind as u16))?;
            if slot.is_some() {
                return Err(TableError::DuplicateSection(s.kind));
            }
            *slot = Some(s.bytes);
        }
        let [
            gains,
            column_bias,
            dark,
            flat,
            hot,
            telegraph,
            pixcorr,
            cti,
            psf_model,
        ] = found;
        if gains.is_none() {
            return Err(TableError::MissingSection(SectionKind::Gains));
        }
        // Sections follow the directory back to back with no gap or overlap, so that every
        // byte of the table is under the header CRC or exactly one section CRC.
        let extents = extents
            .get_mut(..usize::from(n_sections))
            .unwrap_or(&mut []);
        extents.sort_unstable_by_key(|e| e.0);
        let mut next = dir_end;
        for (off, len, kind) in extents.iter() {
            if *off != next {
                return Err(TableError::SectionLayout(*kind));
            }
            next = off + len;
        }
        if next != bytes.len() {
            let last = extents.last().map_or(SectionKind::Gains, |e| e.2);
            return Err(TableError::SectionLayout(last));
        }

        let gains = parse_gains(
            gains.ok_or(TableError::MissingSection(SectionKind::Gains))?,
            &geometry,
        )?;
        if column_bias.is_some_and(|cb| cb.len() != 2 * geometry.line_len()) {
            return Err(TableError::SectionLength(SectionKind::ColumnBias));
        }
        let dark = dark
            .map(|d| parse_map(d, SectionKind::DarkRel, &geometry))
            .transpose()?;
        let flat = flat
            .map(|d| parse_map(d, SectionKind::FlatInv, &geometry))
            .transpose()?;
        let hot = hot
            .map(|h| parse_hot(h, &geometry))
            .transpose()?
            .unwrap_or_default();
        let telegraph = telegraph
            .map(|t| parse_telegraph(t, &geometry))
            .transpose()?
            .unwrap_or_default();
        let pixcorr = pixcorr.map(parse_pixcorr).transpose()?.unwrap_or_default();
        let cti = cti.map(|b| parse_cti(b, &geometry)).transpose()?;
        let psf_model = psf_model.map(parse_psf_model).transpose()?;
        if let Some(c) = camera_model {
            super::camera::parse(c, geometry.active_cols, geometry.active_rows)?;
        }
        let dark_law = dark_law.map(super::darklaw::parse).transpose()?;

        Ok(Self {
            len: bytes.len(),
            geometry,
            saturation_adu,
            gains,
            column_bias,
            dark,
            flat,
            hot,
            telegraph,
            pixcorr,
            cti,
            psf_model,
            camera_model,
            dark_law,
        })
    }

    /// Checks a table stored at the start of a larger region (a flash sector): the length
    /// comes from the table's own header, and the bytes after it are ignored. Errors as
    /// [`Self::parse`]; a stated length past the region is a [`TableError::LengthMismatch`].
    pub fn parse_prefix(region: &'a [u8]) -> Result<Self, TableError> {
        if region.get(..4).is_some_and(|m| m != &MAGIC[..]) {
            return Err(TableError::BadMagic);
        }
        let got = u32::try_from(region.len()).unwrap_or(u32::MAX);
        let stated = u32_at(region, 8).ok_or(TableError::TooShort {
            needed: HEADER_LEN as u32,
            got,
        })?;
        let bytes = region
            .get(..stated as usize)
            .ok_or(TableError::LengthMismatch {
                header: stated,
                actual: got,
            })?;
        Self::parse(bytes)
    }

    /// The table's size in bytes.
    pub fn len_bytes(&self) -> usize {
        self.len
    }

    /// The sensor geometry the table was made for.
    pub fn geometry(&self) -> &ReadoutGeometry {
        &self.geometry
    }

    /// Raw samples at or above this level are flagged saturated.
    pub fn saturation_adu(&self) -> u16 {
        self.saturation_adu
    }

    /// The gain of `output`, e-/ADU (the last output's for an out-of-range index).
    pub fn gain(&self, output: Output) -> GainEPerAdu {
        let i = usize::from(output.0).min(usize::from(self.geometry.outputs) - 1);
        self.gains.get(i).copied().unwrap_or(GainEPerAdu::ONE)
    }

    /// Bias offset of raw column `col` from the line's over-scan level, ADU (0 when the table
    /// has no column-bias section or `col` is past the line).
    pub fn column_bias(&self, col: usize) -> ColumnBiasAdu {
        self.column_bias
            .and_then(|b| u16_at(b, col.checked_mul(2)?))
            .map_or(ColumnBiasAdu::ZERO, |v| ColumnBiasAdu::from_bits(v as i16))
    }

    /// Relative dark of active pixel (x, y) (1 when the table has no dark map).
    pub fn dark_rel(&self, x: u16, y: u16) -> DarkRel {
        self.dark
            .and_then(|m| m.bits(x, y))
            .map_or(DarkRel::ONE, |b| DarkRel::from_bits(b as u8))
    }

    /// Inverse flat of active pixel (x, y) (1 when the table has no flat map).
    pub fn flat_inv(&self, x: u16, y: u16) -> FlatInv {
        self.flat
            .and_then(|m| m.bits(x, y))
            .map_or(FlatInv::ONE, |b| FlatInv::from_bits(b as u16))
    }

    /// The relative dark map, if present.
    pub fn dark_map(&self) -> Option<MapView<'a>> {
        self.dark
    }

    /// The inverse flat map, if present.
    pub fn flat_map(&self) -> Option<MapView<'a>> {
        self.flat
    }

    /// True when the table has a column-bias section.
    pub fn has_column_bias(&self) -> bool {
        self.column_bias.is_some()
    }

    /// The hot-pixel list (empty when absent).
    pub fn hot_pixels(&self) -> HotList<'a> {
        self.hot
    }

    /// The telegraph-pixel list (empty when absent).
    pub fn telegraph_pixels(&self) -> DefectList<'a> {
        self.telegraph
    }

    /// The pixel-phase correction curves of the centre of gravity (empty when absent).
    pub fn pixcorr(&self) -> PixCorrSet<'a> {
        self.pixcorr
    }

    /// The CTI coefficients (section 8), if present.
    pub fn cti(&self) -> Option<CtiCoeffs> {
        self.cti
    }

    /// The field PSF model (section 9), if present.
    pub fn psf_model(&self) -> Option<PsfModel> {
        self.psf_model
    }

    /// The fitted camera model (section 10), or `None` when the table has none (the caller
    /// uses its nominal camera). Decoded from the table's bytes at each call (nine loads).
    pub fn camera_model(&self) -> Option<crate::attitude::Camera> {
        self.camera_model
            .and_then(|b| super::camera::decode(b).ok())
    }

    /// The covered pixels' dark law (section 11), if present: the tracker measures its dark
    /// drift against it.
    pub fn dark_law(&self) -> Option<super::DarkLaw> {
        self.dark_law
    }
}

fn section<'a>(
    bytes: &'a [u8],
    dir: &[u8],
    i: usize,
    dir_end: usize,
) -> Result<Section<'a>, TableError> {
    let e = i * DIR_ENTRY_LEN;
    let bad = TableError::TooShort {
        needed: dir_end as u32,
        got: bytes.len() as u32,
    };
    let code = u16_at(dir, e).ok_or(bad)?;
    let kind = SectionKind::from_code(code).ok_or(TableError::UnknownSection(code))?;
    if u16_at(dir, e + 2).ok_or(bad)? != 0 {
        return Err(TableError::Reserved);
    }
    let off = u32_at(dir, e + 4).ok_or(bad)? as usize;
    let len = u32_at(dir, e + 8).ok_or(bad)? as usize;
    let crc = u32_at(dir, e + 12).ok_or(bad)?;
    let end = off
        .checked_add(len)
        .ok_or(TableError::SectionOutOfBounds(kind))?;
    if off < dir_end {
        return Err(TableError::SectionOutOfBounds(kind));
    }
    let s = bytes
        .get(off..end)
        .ok_or(TableError::SectionOutOfBounds(kind))?;
    if CRC.checksum(s) != crc {
        return Err(TableError::SectionCrc(kind));
    }
    Ok(Section {
        kind,
        offset: off,
        bytes: s,
    })
}

fn parse_gains(b: &[u8], g: &ReadoutGeometry) -> Result<[GainEPerAdu; MAX_OUTPUTS], TableError> {
    let k = SectionKind::Gains;
    if b.len() != 4 * usize::from(g.outputs) {
        return Err(TableError::SectionLength(k));
    }
    let mut gains = [GainEPerAdu::ONE; MAX_OUTPUTS];
    for (i, slot) in gains.iter_mut().enumerate().take(usize::from(g.outputs)) {
        let bits = u32_at(b, 4 * i).ok_or(TableError::SectionLength(k))?;
        if bits == 0 {
            return Err(TableError::OutOfRange {
                section: k,
                index: i as u32,
            });
        }
        *slot = GainEPerAdu::from_bits(bits);
    }
    Ok(gains)
}

fn parse_map<'a>(
    b: &'a [u8],
    k: SectionKind,
    g: &ReadoutGeometry,
) -> Result<MapView<'a>, TableError> {
    let tile_log2 = *b.first().ok_or(TableError::SectionLength(k))?;
    let format = *b.get(1).ok_or(TableError::SectionLength(k))?;
    let (want_format, elem_bytes) = match k {
        SectionKind::DarkRel => (1u8, 1usize),
        _ => (2u8, 2usize),
    };
    if tile_log2 > MAX_TILE_LOG2 || format != want_format || u16_at(b, 2) != Some(0) {
        return Err(TableError::MapFormat(k));
    }
    let want = MapHeader::for_area(g.active_cols, g.active_rows, tile_log2);
    if u16_at(b, 4) != Some(want.tiles_x) || u16_at(b, 6) != Some(want.tiles_y) {
        return Err(TableError::MapFormat(k));
    }
    let data = b
        .get(MAP_HEADER_LEN..)
        .ok_or(TableError::SectionLength(k))?;
    if data.len() != want.tiles() * elem_bytes {
        return Err(TableError::SectionLength(k));
    }
    let view = MapView {
        header: want,
        active_cols: g.active_cols,
        active_rows: g.active_rows,
        elem_bytes,
        data,
    };
    if k == SectionKind::FlatInv {
        // A zero inverse flat would silently erase a pixel's signal.
        if let Some(i) = (0..want.tiles()).find(|&i| view.tile_bits(i) == Some(0)) {
            return Err(TableError::OutOfRange {
                section: k,
                index: i as u32,
            });
        }
    }
    Ok(view)
}

fn parse_hot<'a>(b: &'a [u8], g: &ReadoutGeometry) -> Result<HotList<'a>, TableError> {
    let k = SectionKind::HotPixels;
    let t_ref = u32_at(b, 0).ok_or(TableError::SectionLength(k))?;
    let count = u32_at(b, 4).ok_or(TableError::SectionLength(k))? as usize;
    let entries = b.get(8..).ok_or(TableError::SectionLength(k))?;
    if Some(entries.len()) != count.checked_mul(HOT_ENTRY_LEN) {
        return Err(TableError::SectionLength(k));
    }
    let list = HotList {
        t_ref_k: RefTemperature::from_bits(t_ref),
        entries,
    };
    let mut prev: Option<(u16, u16)> = None;
    for i in 0..count {
        let bad = TableError::OutOfRange {
            section: k,
            index: i as u32,
        };
        let h = list.get(i).ok_or(bad)?;
        let reserved = entries.get(i * HOT_ENTRY_LEN + 11).copied();
        if h.x >= g.active_cols
            || h.y >= g.active_rows
            || h.doubling_k == U8F8::ZERO
            || reserved != Some(0)
            || prev.is_some_and(|p| p >= (h.y, h.x))
        {
            return Err(bad);
        }
        prev = Some((h.y, h.x));
    }
    Ok(list)
}

fn parse_telegraph<'a>(b: &'a [u8], g: &ReadoutGeometry) -> Result<DefectList<'a>, TableError> {
    let k = SectionKind::Telegraph;
    let count = u32_at(b, 0).ok_or(TableError::SectionLength(k))? as usize;
    let entries = b.get(4..).ok_or(TableError::SectionLength(k))?;
    if Some(entries.len()) != count.checked_mul(TELEGRAPH_ENTRY_LEN) {
        return Err(TableError::SectionLength(k));
    }
    let list = DefectList { entries };
    let mut prev: Option<(u16, u16)> = None;
    for i in 0..count {
        let bad = TableError::OutOfRange {
            section: k,
            index: i as u32,
        };
        let (x, y) = list.get(i).ok_or(bad)?;
        if x >= g.active_cols || y >= g.active_rows || prev.is_some_and(|p| p >= (y, x)) {
            return Err(bad);
        }
        prev = Some((y, x));
    }
    Ok(list)
}

fn parse_pixcorr(b: &[u8]) -> Result<PixCorrSet<'_>, TableError> {
    let k = SectionKind::PixCorr;
    let count = u16_at(b, 0).ok_or(TableError::SectionLength(k))?;
    if u16_at(b, 2).ok_or(TableError::SectionLength(k))? != 0 {
        return Err(TableError::Reserved);
    }
    if count == 0 || count > MAX_PIXCORR_CURVES {
        return Err(TableError::OutOfRange {
            section: k,
            index: 0,
        });
    }
    let curves = b
        .get(PIXCORR_HEADER_LEN..)
        .ok_or(TableError::SectionLength(k))?;
    PixCorrSet::parse(usize::from(count), curves).map_err(|(i, error)| TableError::PixCorrCurve {
        index: i as u32,
        error,
    })
}

fn parse_cti(b: &[u8], g: &ReadoutGeometry) -> Result<CtiCoeffs, TableError> {
    let k = SectionKind::Cti;
    CtiCoeffs::parse(b, g.outputs).map_err(|e| match e {
        CtiFormatError::Length => TableError::SectionLength(k),
        CtiFormatError::Reserved => TableError::Reserved,
        CtiFormatError::Range => TableError::OutOfRange {
            section: k,
            index: 0,
        },
    })
}

fn parse_psf_model(b: &[u8]) -> Result<PsfModel, TableError> {
    let k = SectionKind::PsfModel;
    PsfModel::parse(b).map_err(|e| match e {
        PsfFormatError::Degree => TableError::SectionFormat(k),
        PsfFormatError::Length => TableError::SectionLength(k),
        PsfFormatError::Reserved => TableError::Reserved,
        PsfFormatError::Range(index) => TableError::OutOfRange { section: k, index },
    })
}
