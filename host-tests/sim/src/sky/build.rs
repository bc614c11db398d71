//! Building the on-board catalog (`startrack_core::catalog`) from the star list.
//!
//! Stars: every listed star down to [`BuildSpec::mag_limit`], sorted by `z` for the cone
//! search. Pattern stars (those in the pair database): brightest first, a star is kept when
//! fewer than [`BuildSpec::pattern_per_cap`] kept stars lie within
//! [`BuildSpec::pattern_cap_rad`] of it, so the pattern stars cover the sky evenly and are
//! locally the brightest (the ones the tracker measures first). Pairs: every two pattern
//! stars closer than [`BuildSpec::max_separation_rad`], sorted by separation, with a
//! k-vector of [`BuildSpec::kvector_bins`] bins.

use super::SkyStar;
use startrack_core::catalog::{
    CRC, HEADER_LEN, MAGIC, MAX_STARS, NRAD_PER_RAD, UNIT_SCALE, VERSION,
};

/// What goes into a catalog.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildSpec {
    /// Faintest star kept, Hp.
    pub mag_limit: f64,
    /// Pattern-star selection cap radius, rad.
    pub pattern_cap_rad: f64,
    /// Most pattern stars per cap.
    pub pattern_per_cap: usize,
    /// Pairs closer than this, rad.
    pub max_separation_rad: f64,
    /// Radius of the cone holding the field of view, rad.
    pub field_radius_rad: f64,
    /// K-vector bins.
    pub kvector_bins: u32,
    /// Epoch of the positions, hundredths of a Julian year.
    pub epoch_centi_jy: u32,
}

impl BuildSpec {
    /// The 15 degree square field of the tracker (field cone radius: half the diagonal).
    pub fn fov_15deg() -> Self {
        Self {
            mag_limit: 6.5,
            pattern_cap_rad: 4.0f64.to_radians(),
            pattern_per_cap: 3,
            max_separation_rad: 12.0f64.to_radians(),
            field_radius_rad: (7.5f64.to_radians().tan() * 2f64.sqrt()).atan(),
            kvector_bins: 8192,
            epoch_centi_jy: super::LIST_EPOCH_CENTI_JY,
        }
    }
}

/// What a build made.
#[derive(Clone, Debug, PartialEq)]
pub struct Built {
    /// The catalog bytes.
    pub bytes: Vec<u8>,
    /// Stars.
    pub stars: usize,
    /// Pattern stars.
    pub pattern_stars: usize,
    /// Pairs.
    pub pairs: usize,
    /// Most stars in any field cone.
    pub max_field_stars: u32,
    /// Hipparcos number of each catalog star, in catalog order.
    pub hip: Vec<u32>,
}

/// Why a catalog could not be built.
#[derive(Clone, Debug, PartialEq)]
pub struct BuildError(pub String);

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "cannot build the catalog: {}", self.0)
    }
}

impl std::error::Error for BuildError {}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Stars within `radius` of each of `centres`, counted with a z-sorted sweep.
fn max_in_cones(dirs_by_z: &[[f64; 3]], centres: &[[f64; 3]], radius: f64) -> u32 {
    let zs: Vec<f64> = dirs_by_z.iter().map(|d| d[2]).collect();
    let chord = 2.0 * (radius / 2.0).sin();
    let cos_r = radius.cos();
    centres
        .iter()
        .map(|c| {
            let lo = zs.partition_point(|z| *z < c[2] - chord);
            let hi = zs.partition_point(|z| *z <= c[2] + chord);
            dirs_by_z[lo..hi]
                .iter()
                .filter(|d| dot(**d, *c) >= cos_r)
                .count() as u32
        })
        .max()
        .unwrap_or(0)
}

/// Builds the catalog bytes.
pub fn build(list: &[SkyStar], spec: &BuildSpec) -> Result<Built, BuildError> {
    let mut stars: Vec<&SkyStar> = list.iter().filter(|s| s.hp_mag <= spec.mag_limit).collect();
    if stars.is_empty() || stars.len() > MAX_STARS as usize {
        return Err(BuildError(format!("{} stars (1..=65535)", stars.len())));
    }
    let quant = |d: [f64; 3]| d.map(|c| (c * UNIT_SCALE).round() as i32);
    stars.sort_by_key(|s| (quant(s.dir())[2], s.hip));
    let dirs: Vec<[f64; 3]> = stars
        .iter()
        .map(|s| quant(s.dir()).map(|c| f64::from(c) / UNIT_SCALE))
        .collect();

    // Pattern stars: brightest first, at most `pattern_per_cap` in any cap around a kept one.
    let mut by_mag: Vec<usize> = (0..stars.len()).collect();
    by_mag.sort_by(|&a, &b| stars[a].hp_mag.total_cmp(&stars[b].hp_mag));
    let cos_cap = spec.pattern_cap_rad.cos();
    let mut pattern: Vec<usize> = Vec::new();
    for &i in &by_mag {
        let near = pattern
            .iter()
            .filter(|&&p| dot(dirs[p], dirs[i]) >= cos_cap)
            .count();
        if near < spec.pattern_per_cap {
            pattern.push(i);
        }
    }
    pattern.sort_unstable();

    // Pairs among pattern stars.
    let max_nrad = (spec.max_separation_rad * NRAD_PER_RAD).round() as u32;
    let mut pairs: Vec<(u32, u16, u16)> = Vec::new();
    for (x, &a) in pattern.iter().enumerate() {
        for &b in &pattern[x + 1..] {
            let (da, db) = (dirs[a], dirs[b]);
            let cr = [
                da[1] * db[2] - da[2] * db[1],
                da[2] * db[0] - da[0] * db[2],
                da[0] * db[1] - da[1] * db[0],
            ];
            let sep = dot(cr, cr).sqrt().atan2(dot(da, db));
            let nrad = (sep * NRAD_PER_RAD).round();
            if nrad < f64::from(max_nrad) {
                pairs.push((nrad as u32, a as u16, b as u16));
            }
        }
    }
    pairs.sort_unstable();
    let bins = spec.kvector_bins;
    let mut kvec = Vec::with_capacity(bins as usize + 1);
    let mut below = 0usize;
    for k in 0..=bins {
        let edge = (u64::from(k) * u64::from(max_nrad)).div_ceil(u64::from(bins));
        while below < pairs.len() && u64::from(pairs[below].0) < edge {
            below += 1;
        }
        kvec.push(below as u32);
    }

    // Upper bound on the stars in any field cone: cones of radius R + d around a Fibonacci
    // lattice whose every point of the sky is within d of a lattice point.
    let n_lattice = 10_000usize;
    let spacing = (4.0 * std::f64::consts::PI / n_lattice as f64).sqrt();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let lattice: Vec<[f64; 3]> = (0..n_lattice)
        .map(|i| {
            let z = 1.0 - (2 * i + 1) as f64 / n_lattice as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            [r * t.cos(), r * t.sin(), z]
        })
        .collect();
    let max_field_stars = max_in_cones(&dirs, &lattice, spec.field_radius_rad + spacing);

    let mut star_bytes = Vec::with_capacity(stars.len() * 16);
    for s in &stars {
        for c in quant(s.dir()) {
            star_bytes.extend_from_slice(&c.to_le_bytes());
        }
        let mmag = |m: f64| ((m * 1000.0).round().clamp(-32768.0, 32767.0) as i16).to_le_bytes();
        star_bytes.extend_from_slice(&mmag(s.hp_mag));
        star_bytes.extend_from_slice(&mmag(s.bv_mag));
    }
    let mut pair_bytes = Vec::with_capacity(pairs.len() * 8);
    for (sep, a, b) in &pairs {
        pair_bytes.extend_from_slice(&sep.to_le_bytes());
        pair_bytes.extend_from_slice(&a.to_le_bytes());
        pair_bytes.extend_from_slice(&b.to_le_bytes());
    }
    let kvec_bytes: Vec<u8> = kvec.iter().flat_map(|k| k.to_le_bytes()).collect();
    let total = HEADER_LEN + star_bytes.len() + pair_bytes.len() + kvec_bytes.len();
    let mut head = Vec::with_capacity(HEADER_LEN);
    head.extend_from_slice(&MAGIC);
    head.extend_from_slice(&VERSION.to_le_bytes());
    head.extend_from_slice(&0u16.to_le_bytes());
    for v in [
        total as u32,
        stars.len() as u32,
        pairs.len() as u32,
        bins,
        max_nrad,
        (spec.field_radius_rad * NRAD_PER_RAD).round() as u32,
        max_field_stars,
        spec.epoch_centi_jy,
        CRC.checksum(&star_bytes),
        CRC.checksum(&pair_bytes),
        CRC.checksum(&kvec_bytes),
        0,
    ] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    let crc = CRC.checksum(&head);
    head.extend_from_slice(&crc.to_le_bytes());
    head.extend_from_slice(&0u32.to_le_bytes());
    let mut bytes = head;
    bytes.extend_from_slice(&star_bytes);
    bytes.extend_from_slice(&pair_bytes);
    bytes.extend_from_slice(&kvec_bytes);
    Ok(Built {
        bytes,
        stars: stars.len(),
        pattern_stars: pattern.len(),
        pairs: pairs.len(),
        max_field_stars,
        hip: stars.iter().map(|s| s.hip).collect(),
    })
}

/// The repo's star list built with [`BuildSpec::fov_15deg`] (what the tests and `solve`
/// use when no catalog file is given).
pub fn default_catalog() -> Result<Built, BuildError> {
    let list =
        super::read_list(&super::default_list_path()).map_err(|e| BuildError(e.to_string()))?;
    build(&list, &BuildSpec::fov_15deg())
}
