//! The in-flight amendment of a calibration table ([`AmendPlan`]): new hot and telegraph
//! pixels merged into the defect lists of the table in force, streamed out piece by piece
//! from the old table's bytes so that the new table is never held whole. It costs a
//! fixed-size plan and a caller's chunk buffer, no allocation; its size and its reads are
//! told at [`AmendPlan`].

use super::error::SectionKind;
use super::parse::MAX_SECTIONS;
use super::{
    CRC, DIR_ENTRY_LEN, HEADER_LEN, HOT_ENTRY_LEN, MAGIC, RefTemperature, TELEGRAPH_ENTRY_LEN,
    VERSION,
};
use crate::small_sort::sort_by;

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
/// 32 additions per entry). The additions (at most 32 a list) and the sections (at most 16)
/// are sorted by insertion (`small_sort`), at most 496 and 120 comparisons.
#[derive(Clone, Copy, Debug)]
pub struct AmendPlan {
    head: [u8; HEADER_LEN + DIR_ENTRY_LEN * MAX_SECTIONS],
    head_len: usize,
    sections: [AmendSection; MAX_SECTIONS],
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
        let mut head = [0u8; HEADER_LEN + DIR_ENTRY_LEN * MAX_SECTIONS];
        let fixed = head.get_mut(..HEADER_LEN).ok_or(AmendError::BadTable)?;
        if !read(0, fixed) {
            return Err(AmendError::Read);
        }
        let h16 = |b: &[u8], at: usize| super::bytes::u16_at(b, at).ok_or(AmendError::BadTable);
        let h32 = |b: &[u8], at: usize| super::bytes::u32_at(b, at).ok_or(AmendError::BadTable);
        let n_old = usize::from(h16(&head, 6)?);
        if head.get(..4) != Some(&MAGIC[..])
            || h16(&head, 4)? != VERSION
            || n_old > MAX_SECTIONS
            || h32(&head, 8)? != old_len
        {
            return Err(AmendError::BadTable);
        }
        let mut dir = [0u8; DIR_ENTRY_LEN * MAX_SECTIONS];
        let dir_old = dir
            .get_mut(..DIR_ENTRY_LEN * n_old)
            .ok_or(AmendError::BadTable)?;
        if !read(HEADER_LEN as u32, dir_old) {
            return Err(AmendError::Read);
        }
        let mut sections = [AmendSection::default(); MAX_SECTIONS];
        let mut crcs = [0u32; MAX_SECTIONS];
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
                sort_by(p, |&(xa, ya), &(xb, yb)| (ya, xa).cmp(&(yb, xb)));
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
        let mut order = [0usize; MAX_SECTIONS];
        for (i, o) in order.iter_mut().enumerate() {
            *o = i;
        }
        let order = order.get_mut(..n).ok_or(AmendError::BadTable)?;
        let key = |i: usize| {
            let old_off = sections.get(i).map_or(0, |s| s.old_off);
            (i >= n_old, old_off, i)
        };
        sort_by(order, |&i, &j| key(i).cmp(&key(j)));
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
