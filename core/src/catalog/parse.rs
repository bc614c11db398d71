//! Reading and checking a star catalog in place, and the queries identification makes.

use super::{
    CRC, CatalogError, HEADER_LEN, KVEC_ENTRY_LEN, MAGIC, MAX_KVEC_BINS, MAX_STARS, NRAD_PER_RAD,
    PAIR_LEN, STAR_LEN, UNIT_NORM_TOLERANCE, UNIT_SCALE, VERSION,
};

fn u16_at(b: &[u8], off: usize) -> Option<u16> {
    let s = b.get(off..off.checked_add(2)?)?;
    Some(u16::from_le_bytes([*s.first()?, *s.get(1)?]))
}

fn u32_at(b: &[u8], off: usize) -> Option<u32> {
    let s = b.get(off..off.checked_add(4)?)?;
    let mut a = [0u8; 4];
    a.copy_from_slice(s);
    Some(u32::from_le_bytes(a))
}

/// One catalog star.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CatalogStar {
    /// ICRS unit vector at the catalog's epoch.
    pub dir: [f64; 3],
    /// Hipparcos Hp magnitude, millimagnitudes.
    pub hp_mmag: i16,
    /// B-V colour index, millimagnitudes.
    pub bv_mmag: i16,
}

/// One pair of pattern stars.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StarPair {
    /// Angular separation, nrad.
    pub separation_nrad: u32,
    /// The first star's index (the smaller).
    pub a: u16,
    /// The second star's index.
    pub b: u16,
}

/// A checked catalog, borrowing the bytes it was read from. Every accessor is total: it
/// returns `None` (or an empty range) out of range rather than panic.
#[derive(Clone, Copy, Debug)]
pub struct Catalog<'a> {
    stars: &'a [u8],
    pairs: &'a [u8],
    kvec: &'a [u8],
    n_stars: u32,
    n_pairs: u32,
    bins: u32,
    max_sep_nrad: u32,
    field_radius_nrad: u32,
    max_field_stars: u32,
    epoch_cjy: u32,
}

impl<'a> Catalog<'a> {
    /// Checks `bytes` completely (magic, version, lengths, every CRC, every entry's range and
    /// order) and returns a view of it, or the first problem found.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, CatalogError> {
        let got = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
        let head = bytes
            .get(..HEADER_LEN)
            .ok_or(CatalogError::TooShort { got })?;
        if head.get(..4) != Some(&MAGIC[..]) {
            return Err(CatalogError::BadMagic);
        }
        let short = CatalogError::TooShort { got };
        let rd = |off| u32_at(head, off).ok_or(short);
        let version = u16_at(head, 4).ok_or(short)?;
        if version != VERSION {
            return Err(CatalogError::UnsupportedVersion(version));
        }
        let total = rd(8)?;
        if total != got {
            return Err(CatalogError::LengthMismatch {
                header: total,
                actual: got,
            });
        }
        if CRC.checksum(head.get(..56).ok_or(short)?) != rd(56)? {
            return Err(CatalogError::HeaderCrc);
        }
        if u16_at(head, 6) != Some(0) || rd(52)? != 0 || rd(60)? != 0 {
            return Err(CatalogError::Reserved);
        }
        let (n_stars, n_pairs, bins) = (rd(12)?, rd(16)?, rd(20)?);
        let (max_sep_nrad, field_radius_nrad) = (rd(24)?, rd(28)?);
        if n_stars == 0
            || n_stars > MAX_STARS
            || bins == 0
            || bins > MAX_KVEC_BINS
            || max_sep_nrad == 0
            || field_radius_nrad == 0
        {
            return Err(CatalogError::HeaderRange);
        }
        let star_len = (n_stars as usize).checked_mul(STAR_LEN);
        let pair_len = (n_pairs as usize).checked_mul(PAIR_LEN);
        let kvec_len = (bins as usize + 1).checked_mul(KVEC_ENTRY_LEN);
        let expected = star_len
            .zip(pair_len)
            .zip(kvec_len)
            .and_then(|((s, p), k)| HEADER_LEN.checked_add(s)?.checked_add(p)?.checked_add(k));
        let (Some(star_len), Some(pair_len), Some(expected)) = (star_len, pair_len, expected)
        else {
            return Err(CatalogError::HeaderRange);
        };
        if expected != bytes.len() {
            return Err(CatalogError::LengthMismatch {
                header: u32::try_from(expected).unwrap_or(u32::MAX),
                actual: got,
            });
        }
        let stars = bytes.get(HEADER_LEN..HEADER_LEN + star_len).ok_or(short)?;
        let pairs = bytes
            .get(HEADER_LEN + star_len..HEADER_LEN + star_len + pair_len)
            .ok_or(short)?;
        let kvec = bytes.get(HEADER_LEN + star_len + pair_len..).ok_or(short)?;
        if CRC.checksum(stars) != rd(40)? {
            return Err(CatalogError::StarCrc);
        }
        if CRC.checksum(pairs) != rd(44)? {
            return Err(CatalogError::PairCrc);
        }
        if CRC.checksum(kvec) != rd(48)? {
            return Err(CatalogError::KVectorCrc);
        }
        let cat = Self {
            stars,
            pairs,
            kvec,
            n_stars,
            n_pairs,
            bins,
            max_sep_nrad,
            field_radius_nrad,
            max_field_stars: rd(32)?,
            epoch_cjy: rd(36)?,
        };
        cat.check_entries()?;
        Ok(cat)
    }

    fn check_entries(&self) -> Result<(), CatalogError> {
        let mut last_z = i32::MIN;
        for i in 0..self.n_stars {
            let bad = CatalogError::Star { index: i };
            let raw = self.raw_dir(i as usize).ok_or(bad)?;
            let n2: f64 = raw
                .iter()
                .map(|c| f64::from(*c) * f64::from(*c))
                .sum::<f64>()
                / (UNIT_SCALE * UNIT_SCALE);
            if (libm::sqrt(n2) - 1.0).abs() > UNIT_NORM_TOLERANCE || raw[2] < last_z {
                return Err(bad);
            }
            last_z = raw[2];
        }
        let mut last_sep = 0u32;
        for i in 0..self.n_pairs {
            let bad = CatalogError::Pair { index: i };
            let p = self.pair(i as usize).ok_or(bad)?;
            if p.a >= p.b
                || u32::from(p.b) >= self.n_stars
                || p.separation_nrad < last_sep
                || p.separation_nrad >= self.max_sep_nrad
            {
                return Err(bad);
            }
            last_sep = p.separation_nrad;
        }
        // Entry k must count the pairs below k * max / bins exactly: check it against the
        // sorted pairs with one merge pass.
        let mut below = 0u32;
        for k in 0..=self.bins {
            let bad = CatalogError::KVector { index: k };
            let edge = self.bin_edge_nrad(k);
            while below < self.n_pairs
                && u64::from(self.pair(below as usize).ok_or(bad)?.separation_nrad) < edge
            {
                below += 1;
            }
            if self.kvec_at(k) != Some(below) {
                return Err(bad);
            }
        }
        Ok(())
    }

    /// Lower edge of k-vector bin `k`, nrad (as u64: exact, no rounding surprises).
    fn bin_edge_nrad(&self, k: u32) -> u64 {
        (u64::from(k) * u64::from(self.max_sep_nrad)).div_ceil(u64::from(self.bins))
    }

    fn kvec_at(&self, k: u32) -> Option<u32> {
        u32_at(self.kvec, (k as usize).checked_mul(KVEC_ENTRY_LEN)?)
    }

    fn raw_dir(&self, i: usize) -> Option<[i32; 3]> {
        let off = i.checked_mul(STAR_LEN)?;
        let c = |k: usize| u32_at(self.stars, off + 4 * k).map(|v| v as i32);
        Some([c(0)?, c(1)?, c(2)?])
    }

    /// Number of stars.
    pub fn star_count(&self) -> usize {
        self.n_stars as usize
    }

    /// Number of pattern-star pairs.
    pub fn pair_count(&self) -> usize {
        self.n_pairs as usize
    }

    /// Pairs are every pair of pattern stars closer than this, rad.
    pub fn max_separation_rad(&self) -> f64 {
        f64::from(self.max_sep_nrad) / NRAD_PER_RAD
    }

    /// Radius of the cone that holds the whole field of view, rad.
    pub fn field_radius_rad(&self) -> f64 {
        f64::from(self.field_radius_nrad) / NRAD_PER_RAD
    }

    /// Most stars in any cone of [`Self::field_radius_rad`] (an upper bound).
    pub fn max_field_stars(&self) -> u32 {
        self.max_field_stars
    }

    /// Epoch of the positions, hundredths of a Julian year.
    pub fn epoch_centi_jy(&self) -> u32 {
        self.epoch_cjy
    }

    /// Star `i`'s unit vector, without the magnitude and colour.
    pub fn dir(&self, i: usize) -> Option<[f64; 3]> {
        let r = self.raw_dir(i)?;
        Some(r.map(|c| f64::from(c) / UNIT_SCALE))
    }

    /// Star `i`.
    pub fn star(&self, i: usize) -> Option<CatalogStar> {
        let off = i.checked_mul(STAR_LEN)?;
        Some(CatalogStar {
            dir: self.dir(i)?,
            hp_mmag: u16_at(self.stars, off + 12)? as i16,
            bv_mmag: u16_at(self.stars, off + 14)? as i16,
        })
    }

    /// Pair `i` (pairs are sorted by separation).
    pub fn pair(&self, i: usize) -> Option<StarPair> {
        let off = i.checked_mul(PAIR_LEN)?;
        Some(StarPair {
            separation_nrad: u32_at(self.pairs, off)?,
            a: u16_at(self.pairs, off + 4)?,
            b: u16_at(self.pairs, off + 6)?,
        })
    }

    /// Indices of the pairs whose separation lies in `[lo_rad, hi_rad]`: two k-vector loads
    /// give the bins' pair range, then the ends are trimmed by a scan of the two edge bins.
    pub fn pairs_between(&self, lo_rad: f64, hi_rad: f64) -> core::ops::Range<usize> {
        let to_nrad = |r: f64| {
            let v = r * NRAD_PER_RAD;
            if v.is_nan() || v <= 0.0 {
                0u32
            } else if v >= f64::from(self.max_sep_nrad) {
                self.max_sep_nrad
            } else {
                v as u32
            }
        };
        let (lo, hi) = (to_nrad(lo_rad), to_nrad(hi_rad));
        if lo > hi || lo >= self.max_sep_nrad {
            return 0..0;
        }
        let bin_of = |v: u32| -> u32 {
            let b = u64::from(v) * u64::from(self.bins) / u64::from(self.max_sep_nrad);
            (b as u32).min(self.bins - 1)
        };
        let mut start = self.kvec_at(bin_of(lo)).unwrap_or(0) as usize;
        let mut end = self.kvec_at(bin_of(hi) + 1).unwrap_or(self.n_pairs) as usize;
        let sep = |i: usize| self.pair(i).map_or(u32::MAX, |p| p.separation_nrad);
        while start < end && sep(start) < lo {
            start += 1;
        }
        while end > start && sep(end - 1) > hi {
            end -= 1;
        }
        start..end
    }

    /// The stars within `radius_rad` of the unit vector `dir`: a binary search for the start
    /// of the band `|z - dir.z| <= chord` and a scan of it.
    pub fn cone(&self, dir: [f64; 3], radius_rad: f64) -> Cone<'a> {
        let radius = radius_rad.clamp(0.0, core::f64::consts::PI);
        let chord = 2.0 * libm::sin(radius / 2.0);
        let z_lo = ((dir[2] - chord).max(-2.0) * UNIT_SCALE) as i64;
        let z_hi = ((dir[2] + chord).min(2.0) * UNIT_SCALE) as i64;
        let (mut lo, mut hi) = (0usize, self.n_stars as usize);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            match self.raw_dir(mid) {
                Some(r) if i64::from(r[2]) < z_lo => lo = mid + 1,
                _ => hi = mid,
            }
        }
        Cone {
            cat: *self,
            next: lo,
            z_hi,
            dir,
            cos_radius: libm::cos(radius),
        }
    }
}

/// Iterator over the stars of a cone: yields (index, unit vector).
#[derive(Clone, Debug)]
pub struct Cone<'a> {
    cat: Catalog<'a>,
    next: usize,
    z_hi: i64,
    dir: [f64; 3],
    cos_radius: f64,
}

impl Iterator for Cone<'_> {
    type Item = (usize, [f64; 3]);

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let i = self.next;
            let raw = self.cat.raw_dir(i)?;
            if i64::from(raw[2]) > self.z_hi {
                return None;
            }
            self.next += 1;
            let v = raw.map(|c| f64::from(c) / UNIT_SCALE);
            let d = v[0] * self.dir[0] + v[1] * self.dir[1] + v[2] * self.dir[2];
            if d >= self.cos_radius {
                return Some((i, v));
            }
        }
    }
}
