//! Writing a calibration table into a caller's buffer (no allocation), so that host tools and
//! an in-flight recalibration produce exactly the bytes [`CalibTable::parse`] reads.

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

/// Most pixels one amendment adds to each defect list (the tracker's overlay holds 32).
pub const MAX_AMEND_PIXELS: usize = 32;

/// Why a table could not be amended with new defect pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AmendError {
    /// Every pixel given is listed already (or none was given).
    NothingToAdd,
    /// The table's bytes could not be read.
    Read,
    /// The table in force is not a table this crate reads (magic, version, lengths).
    BadTable,
    /// The directory has no room for a new hot or telegraph section (16 sections).
    DirectoryFull,
    /// The amended table would be longer than 4 GiB.
    TooLong,
}

impl AmendError {
    /// A stable code for telemetry.
    pub const fn code(self) -> u16 {
        match self {
            Self::NothingToAdd => 1,
            Self::Read => 2,
            Self::BadTable => 3,
            Self::DirectoryFull => 4,
            Self::TooLong => 5,
        }
    }
}

/// One section of an amended table.
#[derive(Clone, Copy, Debug, Default)]
struct AmendSection {
    kind: u16,
    /// Where it was in the old table, and how long (0, 0: new).
    old_off: u32,
    old_len: u32,
    new_off: u32,
    new_len: u32,
    /// Which defect list it takes additions from: 0 none, 1 hot, 2 telegraph.
    list: u8,
}

/// Pixels added to one defect list, sorted by (y, x), with their index in the merged list.
#[derive(Clone, Copy, Debug)]
struct Additions {
    px: [(u16, u16); MAX_AMEND_PIXELS],
    merged_at: [u32; MAX_AMEND_PIXELS],
    n: usize,
    /// Entries the old list had.
    old_count: u32,
}

impl Additions {
    const EMPTY: Self = Self {
        px: [(0, 0); MAX_AMEND_PIXELS],
        merged_at: [0; MAX_AMEND_PIXELS],
        n: 0,
        old_count: 0,
    };

    fn pixels(&self) -> &[(u16, u16)] {
        self.px.get(..self.n).unwrap_or(&[])
    }
}

/// The plan of a calibration table amended with new hot and telegraph pixels: the table in
/// force, read through a caller's reader, with pixels merged into its hot-pixel (section 5)
/// and telegraph (section 6) lists; every other byte copied. Streamed, never held whole: the
/// new table is produced piece by piece with [`Self::emit`] (into a flash slot's upload
/// chunks), so amending a 200 KB table costs a 1,184-byte plan (on a 64-bit host) and a
/// chunk buffer.
///
/// What it is for: the in-flight defect watch confirms pixels; this puts them in the table
/// so that they survive a reset and the overlay can forget them. The new hot entries are
/// excluded (policy 1) with rate 0 and doubling 1 K (an excluded pixel's law is not used);
/// a new hot section takes `hot_ref_k` as its reference temperature.
///
/// Cost: [`Self::new`] reads the header and directory and binary-searches the old lists for
/// each pixel (a few dozen 4-byte reads) and streams the two changed sections and the whole
/// table once for their CRCs (what [`Self::emit`] costs for the whole table); [`Self::emit`]
/// copies old bytes through the reader and encodes merged entries (a pass over the at most
/// 32 additions per entry).
#[derive(Clone, Copy, Debug)]
pub struct AmendPlan {
    head: [u8; HEADER_LEN + DIR_ENTRY_LEN * super::parse::MAX_SECTIONS],
    head_len: usize,
    sections: [AmendSection; super::parse::MAX_SECTIONS],
    n_sections: usize,
    hot: Additions,
    tel: Additions,
    hot_ref_k: RefTemperature,
    len: u32,
    crc32: u32,
}

/// Reads `out.len()` bytes of the table in force at byte `offset`; `false` when it cannot.
pub type TableReader<'r> = dyn FnMut(u32, &mut [u8]) -> bool + 'r;

fn rd_u32(read: &mut TableReader<'_>, at: u32) -> Result<u32, AmendError> {
    let mut b = [0u8; 4];
    if !read(at, &mut b) {
        return Err(AmendError::Read);
    }
    Ok(u32::from_le_bytes(b))
}

/// (y, x) of the old list's entry `i` (entries of `entry_len` bytes from `first`).
fn rd_pos(
    read: &mut TableReader<'_>,
    first: u32,
    entry_len: u32,
    i: u32,
) -> Result<(u16, u16), AmendError> {
    let v = rd_u32(read, first + entry_len * i)?;
    Ok(((v >> 16) as u16, (v & 0xFFFF) as u16))
}

impl AmendPlan {
    /// Plans the table of `old_len` bytes that `read` reads, with `hot` and `telegraph`
    /// pixels (active x, y; at most [`MAX_AMEND_PIXELS`] each, more are ignored) added to
    /// its lists. Pixels listed already (in either list, or twice) are skipped.
    pub fn new(
        read: &mut TableReader<'_>,
        old_len: u32,
        hot: &[(u16, u16)],
        telegraph: &[(u16, u16)],
        hot_ref_k: RefTemperature,
    ) -> Result<Self, AmendError> {
        let mut head = [0u8; HEADER_LEN + DIR_ENTRY_LEN * super::parse::MAX_SECTIONS];
        let fixed = head.get_mut(..HEADER_LEN).ok_or(AmendError::BadTable)?;
        if !read(0, fixed) {
            return Err(AmendError::Read);
        }
        let h16 = |b: &[u8], at: usize| super::parse::u16_at(b, at).ok_or(AmendError::BadTable);
        let h32 = |b: &[u8], at: usize| super::parse::u32_at(b, at).ok_or(AmendError::BadTable);
        let n_old = usize::from(h16(&head, 6)?);
        if head.get(..4) != Some(&MAGIC[..])
            || h16(&head, 4)? != VERSION
            || n_old > super::parse::MAX_SECTIONS
            || h32(&head, 8)? != old_len
        {
            return Err(AmendError::BadTable);
        }
        let mut dir = [0u8; DIR_ENTRY_LEN * super::parse::MAX_SECTIONS];
        let dir_old = dir
            .get_mut(..DIR_ENTRY_LEN * n_old)
            .ok_or(AmendError::BadTable)?;
        if !read(HEADER_LEN as u32, dir_old) {
            return Err(AmendError::Read);
        }
        let mut sections = [AmendSection::default(); super::parse::MAX_SECTIONS];
        let mut crcs = [0u32; super::parse::MAX_SECTIONS];
        for (i, (s, c)) in sections
            .iter_mut()
            .zip(crcs.iter_mut())
            .enumerate()
            .take(n_old)
        {
            let e = i * DIR_ENTRY_LEN;
            *s = AmendSection {
                kind: h16(&dir, e)?,
                old_off: h32(&dir, e + 4)?,
                old_len: h32(&dir, e + 8)?,
                ..AmendSection::default()
            };
            *c = h32(&dir, e + 12)?;
            if s.old_off
                .checked_add(s.old_len)
                .is_none_or(|end| end > old_len)
            {
                return Err(AmendError::BadTable);
            }
        }
        // The old lists: where their entries start, how many.
        let find = |kind: SectionKind| {
            sections
                .iter()
                .take(n_old)
                .position(|s| s.kind == kind as u16)
        };
        let (hot_at, tel_at) = (find(SectionKind::HotPixels), find(SectionKind::Telegraph));
        let mut lists = [(Additions::EMPTY, 0u32), (Additions::EMPTY, 0u32)];
        let mut table_hot_ref = hot_ref_k;
        // (where, the list header's length: hot 8 with its temperature, telegraph 4)
        for (li, (at, hdr)) in [(hot_at, 8u32), (tel_at, 4u32)].into_iter().enumerate() {
            let Some((adds, first)) = lists.get_mut(li) else {
                continue;
            };
            if let Some(s) = at.and_then(|i| sections.get(i)) {
                adds.old_count = rd_u32(read, s.old_off + hdr - 4)?;
                *first = s.old_off + hdr;
                if li == 0 {
                    table_hot_ref = RefTemperature::from_bits(rd_u32(read, s.old_off)?);
                }
            }
        }
        // Sorted, deduplicated additions not already in either list.
        let [(mut hot_adds, hot_first), (mut tel_adds, tel_first)] = lists;
        let listed = [
            (hot_first, HOT_ENTRY_LEN as u32, hot_adds.old_count),
            (tel_first, TELEGRAPH_ENTRY_LEN as u32, tel_adds.old_count),
        ];
        for (adds, pixels) in [(&mut hot_adds, hot), (&mut tel_adds, telegraph)] {
            for &(x, y) in pixels.iter().take(MAX_AMEND_PIXELS) {
                let mut found = false;
                for (first, entry_len, count) in listed {
                    if count > 0 {
                        let i = lower_bound(read, first, entry_len, count, (y, x))?;
                        found |= i < count && rd_pos(read, first, entry_len, i)? == (y, x);
                    }
                }
                if found || adds.pixels().contains(&(x, y)) {
                    continue;
                }
                if let Some(slot) = adds.px.get_mut(adds.n) {
                    *slot = (x, y);
                    adds.n += 1;
                }
            }
            let n = adds.n;
            if let Some(p) = adds.px.get_mut(..n) {
                p.sort_unstable_by_key(|&(x, y)| (y, x));
            }
        }
        if hot_adds.n == 0 && tel_adds.n == 0 {
            return Err(AmendError::NothingToAdd);
        }
        for (adds, first, entry_len) in [
            (&mut hot_adds, hot_first, HOT_ENTRY_LEN as u32),
            (&mut tel_adds, tel_first, TELEGRAPH_ENTRY_LEN as u32),
        ] {
            let (count, n) = (adds.old_count, adds.n);
            for j in 0..n {
                let (x, y) = adds.px.get(j).copied().unwrap_or_default();
                let below = if count == 0 {
                    0
                } else {
                    lower_bound(read, first, entry_len, count, (y, x))?
                };
                if let Some(m) = adds.merged_at.get_mut(j) {
                    *m = below + j as u32;
                }
            }
        }
        // New sections: a list that had none gets one at the end.
        let mut n = n_old;
        for (at, adds, kind, list) in [
            (hot_at, &hot_adds, SectionKind::HotPixels, 1u8),
            (tel_at, &tel_adds, SectionKind::Telegraph, 2u8),
        ] {
            match at.and_then(|i| sections.get_mut(i)) {
                Some(s) => s.list = list,
                None if adds.n > 0 => {
                    let s = sections.get_mut(n).ok_or(AmendError::DirectoryFull)?;
                    *s = AmendSection {
                        kind: kind as u16,
                        list,
                        ..AmendSection::default()
                    };
                    n += 1;
                }
                None => {}
            }
        }
        // Lengths and offsets: old sections in their old order (back to back), new last.
        let mut order = [0usize; super::parse::MAX_SECTIONS];
        for (i, o) in order.iter_mut().enumerate() {
            *o = i;
        }
        let order = order.get_mut(..n).ok_or(AmendError::BadTable)?;
        order.sort_unstable_by_key(|&i| {
            let old_off = sections.get(i).map_or(0, |s| s.old_off);
            (i >= n_old, old_off, i)
        });
        let head_len = HEADER_LEN + DIR_ENTRY_LEN * n;
        let mut pos = head_len as u64;
        for &i in order.iter() {
            let Some(s) = sections.get_mut(i) else {
                continue;
            };
            let grow = |adds: &Additions, entry_len: usize, hdr: u32| {
                let base = if s.old_len == 0 { hdr } else { s.old_len };
                u64::from(base) + (adds.n * entry_len) as u64
            };
            let new_len = match s.list {
                1 => grow(&hot_adds, HOT_ENTRY_LEN, 8),
                2 => grow(&tel_adds, TELEGRAPH_ENTRY_LEN, 4),
                _ => u64::from(s.old_len),
            };
            s.new_off = u32::try_from(pos).map_err(|_| AmendError::TooLong)?;
            s.new_len = u32::try_from(new_len).map_err(|_| AmendError::TooLong)?;
            pos += new_len;
        }
        let len = u32::try_from(pos).map_err(|_| AmendError::TooLong)?;
        let mut plan = Self {
            head,
            head_len,
            sections,
            n_sections: n,
            hot: hot_adds,
            tel: tel_adds,
            hot_ref_k: table_hot_ref,
            len,
            crc32: 0,
        };
        // Section CRCs (changed lists streamed), the directory, the header and its CRC.
        for i in 0..n {
            let Some(s) = plan.sections.get(i).copied() else {
                continue;
            };
            let crc = if s.list == 0 {
                crcs.get(i).copied().unwrap_or(0)
            } else {
                let mut digest = CRC.digest();
                plan.stream(read, s.new_off, s.new_len, &mut |b| digest.update(b))?;
                digest.finalize()
            };
            let e = HEADER_LEN + i * DIR_ENTRY_LEN;
            // kind u16 and reserved u16 0 as one little-endian u32, offset, length, CRC.
            for (k, v) in [u32::from(s.kind), s.new_off, s.new_len, crc]
                .iter()
                .enumerate()
            {
                put(&mut plan.head, e + 4 * k, &v.to_le_bytes());
            }
        }
        let n16 = u16::try_from(n).map_err(|_| AmendError::DirectoryFull)?;
        put(&mut plan.head, 6, &n16.to_le_bytes());
        put(&mut plan.head, 8, &len.to_le_bytes());
        let mut digest = CRC.digest();
        digest.update(plan.head.get(..28).unwrap_or(&[]));
        digest.update(plan.head.get(HEADER_LEN..head_len).unwrap_or(&[]));
        let head_crc = digest.finalize();
        put(&mut plan.head, 28, &head_crc.to_le_bytes());
        let mut digest = CRC.digest();
        plan.stream(read, 0, len, &mut |b| digest.update(b))?;
        plan.crc32 = digest.finalize();
        Ok(plan)
    }

    /// The amended table's length, bytes.
    pub fn len_bytes(&self) -> u32 {
        self.len
    }

    /// The amended table's CRC-32/ISO-HDLC (the store's upload CRC).
    pub fn crc32(&self) -> u32 {
        self.crc32
    }

    /// The pixels (x, y) added to the hot list, sorted by (y, x).
    pub fn added_hot(&self) -> &[(u16, u16)] {
        self.hot.pixels()
    }

    /// The pixels (x, y) added to the telegraph list, sorted by (y, x).
    pub fn added_telegraph(&self) -> &[(u16, u16)] {
        self.tel.pixels()
    }

    /// Writes the amended table's bytes from `offset` into `out` (as many as fit before its
    /// end); returns how many. The table in force must be the one planned from.
    pub fn emit(
        &self,
        read: &mut TableReader<'_>,
        offset: u32,
        out: &mut [u8],
    ) -> Result<usize, AmendError> {
        let want = u32::try_from(out.len()).unwrap_or(u32::MAX);
        let n = want.min(self.len.saturating_sub(offset));
        let mut at = 0usize;
        self.stream(read, offset, n, &mut |b| {
            if let Some(d) = out.get_mut(at..at + b.len()) {
                d.copy_from_slice(b);
            }
            at += b.len();
        })?;
        Ok(at)
    }

    /// Calls `sink` with the amended table's bytes `offset..offset + len`, in order, in
    /// pieces of at most 64 bytes.
    fn stream(
        &self,
        read: &mut TableReader<'_>,
        offset: u32,
        len: u32,
        sink: &mut dyn FnMut(&[u8]),
    ) -> Result<(), AmendError> {
        let end = offset.saturating_add(len).min(self.len);
        let mut pos = offset;
        let mut buf = [0u8; 64];
        while pos < end {
            let n = self.piece(read, pos, end, &mut buf)?;
            if n == 0 {
                return Err(AmendError::BadTable);
            }
            sink(buf.get(..n).unwrap_or(&[]));
            pos += n as u32;
        }
        Ok(())
    }

    /// The bytes from `pos` (before `end`) up to the end of the piece holding it (header
    /// and directory, a copied run, one list entry), at most `buf.len()`.
    fn piece(
        &self,
        read: &mut TableReader<'_>,
        pos: u32,
        end: u32,
        buf: &mut [u8; 64],
    ) -> Result<usize, AmendError> {
        let room = (end - pos).min(64) as usize;
        if (pos as usize) < self.head_len {
            let src = self
                .head
                .get(pos as usize..self.head_len)
                .ok_or(AmendError::BadTable)?;
            let n = src.len().min(room);
            buf.get_mut(..n)
                .ok_or(AmendError::BadTable)?
                .copy_from_slice(src.get(..n).ok_or(AmendError::BadTable)?);
            return Ok(n);
        }
        let s = self
            .sections
            .iter()
            .take(self.n_sections)
            .find(|s| pos >= s.new_off && pos - s.new_off < s.new_len)
            .ok_or(AmendError::BadTable)?;
        let rel = pos - s.new_off;
        let left = (s.new_len - rel) as usize;
        let (adds, entry_len, hdr) = match s.list {
            1 => (&self.hot, HOT_ENTRY_LEN as u32, 8u32),
            2 => (&self.tel, TELEGRAPH_ENTRY_LEN as u32, 4u32),
            _ => {
                let n = left.min(room);
                let dst = buf.get_mut(..n).ok_or(AmendError::BadTable)?;
                if !read(s.old_off + rel, dst) {
                    return Err(AmendError::Read);
                }
                return Ok(n);
            }
        };
        // A list section: its header (reference temperature, count), then merged entries.
        let mut one = [0u8; HOT_ENTRY_LEN];
        let total = adds.old_count + adds.n as u32;
        let (piece, start): (&[u8], u32) = if rel < hdr {
            if s.list == 1 {
                put(&mut one, 0, &self.hot_ref_k.to_bits().to_le_bytes());
                put(&mut one, 4, &total.to_le_bytes());
            } else {
                put(&mut one, 0, &total.to_le_bytes());
            }
            (one.get(..hdr as usize).unwrap_or(&[]), 0)
        } else {
            let i = (rel - hdr) / entry_len;
            let start = hdr + i * entry_len;
            match adds.merged_at.iter().take(adds.n).position(|&m| m == i) {
                Some(j) => {
                    let (x, y) = adds.px.get(j).copied().unwrap_or_default();
                    put(&mut one, 0, &x.to_le_bytes());
                    put(&mut one, 2, &y.to_le_bytes());
                    if s.list == 1 {
                        // Rate 0, doubling 1 K (U8F8 0x0100), excluded, reserved 0.
                        put(&mut one, 8, &[0x00, 0x01, 1, 0]);
                    }
                }
                None => {
                    let before = adds
                        .merged_at
                        .iter()
                        .take(adds.n)
                        .filter(|&&m| m < i)
                        .count();
                    let k = i - before as u32;
                    let dst = one
                        .get_mut(..entry_len as usize)
                        .ok_or(AmendError::BadTable)?;
                    if k >= adds.old_count || !read(s.old_off + hdr + k * entry_len, dst) {
                        return Err(AmendError::Read);
                    }
                }
            }
            (one.get(..entry_len as usize).unwrap_or(&[]), start)
        };
        let skip = (rel - start) as usize;
        let src = piece.get(skip..).ok_or(AmendError::BadTable)?;
        let n = src.len().min(room);
        buf.get_mut(..n)
            .ok_or(AmendError::BadTable)?
            .copy_from_slice(src.get(..n).ok_or(AmendError::BadTable)?);
        Ok(n)
    }
}

/// Copies `b` into `dst` at `at` (nothing if it does not fit).
fn put(dst: &mut [u8], at: usize, b: &[u8]) {
    if let Some(d) = dst.get_mut(at..at + b.len()) {
        d.copy_from_slice(b);
    }
}

/// The first of `count` sorted entries at `first` whose (y, x) is not below `key`.
fn lower_bound(
    read: &mut TableReader<'_>,
    first: u32,
    entry_len: u32,
    count: u32,
    key: (u16, u16),
) -> Result<u32, AmendError> {
    let (mut lo, mut hi) = (0u32, count);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if rd_pos(read, first, entry_len, mid)? < key {
            lo = mid + 1;
        } else {
            hi = mid;
        }
    }
    Ok(lo)
}
