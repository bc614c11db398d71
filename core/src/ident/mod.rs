//! Star identification: which catalog star each measured star is, lost in space (no prior)
//! or tracking (from a prior attitude several degrees off), with a bounded false-match
//! probability, with the focal length up to [`IdentConfig::max_scale_error`] off (the scale
//! is fitted and reported). No allocation: the work lives on the stack (lost in space about
//! 31 KB, 16 KB of it the pairs of one separation window, `IK_CAPACITY`; tracking about
//! 12 KB: the high-water marks `cargo m7-bench` prints).
//!
//! # Lost in space: triangles from the pair database, then statistical verification
//! Measured triangles of the brightest [`IdentConfig::pattern_stars`] stars are tried in the
//! pyramid order (Mortari et al. 2004: indices spread so a false or missing star spoils few
//! triangles). The focal length may be off by up to [`IdentConfig::max_scale_error`]
//! (thermal or calibration error), so a measured separation `d` is `s D` of the catalog
//! one, `s` unknown within `1 +- max_scale_error`: what is matched is the triangle's shape.
//! A triangle is labelled `i` opposite its longest side, `(i, j)` its middle side and
//! `(i, k)` its shortest. The k-vector gives the catalog pairs `(a, b)` whose separation
//! `D_ab` puts `d_ij` within [`IdentConfig::pair_tolerance_rad`] at some scale of the range;
//! that pair fixes the scale to `tol / D_ab`, and at it the pairs near `d_ik` holding `a`
//! (sorted by star once per triangle) give `c`, which must sit at `d_jk` from `b` (from the
//! catalog directions: no third search) with the same handedness; finally the three sides
//! must fit one scale (their sums' ratio) within the tolerance each. Each such catalog
//! triangle is a hypothesis: its 3-star attitude and scale are checked against every
//! measured star.
//!
//! Why this rather than 4-star geometric hashing: the pair database (8 bytes a pair, k-vector
//! 4 bytes a bin) is the smallest database that finds a pattern in O(1) per pair, fits
//! internal flash for a 15 degree field, and leaves the decision to the verification below,
//! which counts every star in the field rather than four.
//!
//! # Verification and the false-match bound
//! A hypothesis attitude maps each measured star (its tangent-plane coordinates divided by
//! the hypothesis's scale) to the sky; it matches when a catalog star lies within
//! [`IdentConfig::match_radius_rad`]. In rounds (at most `MAX_REFITS`, until the matches
//! stop changing) the attitude and the scale are refit from the matches (Gauss-Newton on
//! four parameters from the q-method's start), every star matched again, refit, and a match
//! whose residual exceeds `TIGHT_SIGMAS` of its own sigma dropped (an attitude pulled by a
//! false star or a wrong neighbour loses it here). A catalog star goes to the measured star
//! nearest it, and two measured stars within twice the match radius of each other are
//! matched only to two catalog stars (a false star beside a true one would take its catalog
//! star and pull the fit). When the fit is loose (few or clustered stars: some star's
//! predicted position 3-sigma above a quarter of the match radius), every star is matched
//! again within the radius widened by 3 of its sigmas predicted from the fit's covariance,
//! and the rounds run again from there. The solution's attitude covariance is
//! the marginal one of that fit (the scale's uncertainty included), and its scale is
//! reported with its sigma ([`FocalScale`]); a fitted scale outside the searched range is
//! no solution.
//! The false-match bound (its model in `ident/bound.rs`): under a wrong hypothesis each
//! non-basis star's gate holds a catalog star with probability `p` (the field's catalog
//! stars times the gate's area over the field's), the chance that `c` or more match is a
//! Poisson binomial tail `T`, counted twice (at the match radius; and in gates of
//! [`GATE_SIGMAS`] of each star's leave-one-out error with the photometry agreeing, ranked
//! then by how close the counted stars fall), each held to half the level, and the level
//! `alpha` spent along the search, `s_j` of it on the `j`-th hypothesis, the shares summing
//! to at most 1 over [`IdentConfig::max_hypotheses`]. A catalog triangle whose three stars'
//! brightness disagrees (a star off the triangle's zero point by more than
//! [`IdentConfig::photometric_tolerance_mag`]) is no hypothesis and is not counted: the
//! test reads the triangle only, never the stars the bound counts. A solution is accepted
//! only when `2 T / s_j` is at most [`IdentConfig::max_false_probability`]; that bound is
//! reported.
//!
//! # Tracking
//! The prior attitude maps each pattern star to the sky; its candidates are the catalog
//! stars within the prior error plus the pair tolerance (a rotation by `theta` moves any
//! direction by at most `theta`), at most `MAX_CANDIDATES` each. The directions are first
//! rescaled by the prior's focal-length scale, and the sides may differ from the catalog's
//! by [`IdentConfig::track_scale_error`] of their length (the drift since the prior).
//! Triangles are formed from candidates only and verified as above.
//!
//! # Known identities
//! When the stars were measured where the catalog predicted them (the tracker's windows from
//! the last attitude, [`crate::predict`]), [`confirm`] takes their identities and only
//! verifies them: the joint fit, the worst star beyond `TIGHT_SIGMAS` dropped until none is,
//! the leverage test and the false-match bound, as a hypothesis's verification.
//!
//! Cost: a lost-in-space triangle costs a counting sort of `2 P_ik` entries and one bucket
//! lookup per orientation of the `P_ij` pairs (`P` the pairs in a tolerance window over the
//! scale range, a few thousand), a hypothesis a quick check of a few cone searches and, for
//! the few that pass it, a 3-star q-method, `n` cone searches and rounds of the joint fit; a
//! tracking triangle a few dozen angle checks. On the Cortex-M7 (`cargo m7-bench`, 15 degree
//! fields) lost in space takes about 3.3 M instructions a field (median) and 15.7 M at the
//! 99th percentile, tracking 0.67 M.

use crate::attitude::{self, Attitude, Observation, Quat, angle_between, cross, dot};
use crate::catalog::Catalog;

mod bound;

pub use bound::{GATE_SIGMAS, bound_with_field_stars, level_share};

/// Most measured stars looked at (the brightest; the rest are ignored).
pub const MAX_STARS: usize = 32;
/// Most pattern stars (triangle vertices).
pub(crate) const MAX_PATTERN: usize = 16;
/// Most catalog candidates kept per pattern star in tracking.
pub(crate) const MAX_CANDIDATES: usize = 16;
/// A final match's residual is at most this many of its sigmas (a 2-D Gaussian passes
/// 5 sigma with probability 1 - 4e-6).
pub(crate) const TIGHT_SIGMAS: f64 = 5.0;
/// The matching is widened by the fit's covariance only when some star's 3-sigma predicted
/// position exceeds this fraction of the match radius (below it, the widened matching finds
/// what the rounds found).
pub(crate) const WIDEN_FROM: f64 = 0.25;
/// Most match-and-refit rounds of a hypothesis (they stop when the matches stop changing).
pub(crate) const MAX_REFITS: usize = 6;
/// Fewest matched stars in a solution (three for the triangle and one more).
pub(crate) const MIN_MATCHES: usize = 4;

/// Identification settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IdentConfig {
    /// A measured and a catalog separation agree when within this, rad.
    pub pair_tolerance_rad: f64,
    /// A measured star matches a catalog star within this, rad.
    pub match_radius_rad: f64,
    /// Largest accepted false-match probability bound.
    pub max_false_probability: f64,
    /// Brightest measured stars used as triangle vertices (at most `MAX_PATTERN`, 16).
    pub pattern_stars: usize,
    /// Most hypotheses verified in one identification (the false-match level is spent over
    /// them).
    pub max_hypotheses: u32,
    /// Largest focal-length error lost in space searches: the camera model's focal length
    /// is within `1 +- max_scale_error` times the true one (0 to 0.05).
    pub max_scale_error: f64,
    /// Largest change of the focal length from the prior's in tracking, as a fraction of it
    /// (0 to 0.05): the drift between two solved frames.
    pub track_scale_error: f64,
    /// A star's catalog Hp agrees with its instrumental magnitude plus the hypothesis's zero
    /// point within this, mag (0.1 to 5): the noise, the camera band's colour terms against
    /// Hp and the zero point's error together.
    pub photometric_tolerance_mag: f64,
}

impl IdentConfig {
    /// Settings for a camera with focal length `focal_length_px` and centroid 1-sigma
    /// `sigma_px`: pair tolerance 6 sigma of a separation (two stars' errors) plus 1 px of
    /// catalog and model error, match radius 5 sigma plus 1 px, 10^-9 false-match bound;
    /// lost in space tolerates a focal length off by up to 2 %, tracking a drift of 0.5 %
    /// from the prior's scale; a star's brightness agrees with its catalog Hp within 1 mag
    /// (3 sigma of 0.1 mag of noise, colour terms up to 0.2 mag a magnitude of B-V against
    /// Hp, and the zero point's error from three stars).
    pub fn for_camera(focal_length_px: f64, sigma_px: f64) -> Self {
        let sep_sigma_px = sigma_px * core::f64::consts::SQRT_2;
        Self {
            pair_tolerance_rad: (6.0 * sep_sigma_px + 1.0) / focal_length_px,
            match_radius_rad: (5.0 * sigma_px + 1.0) / focal_length_px,
            max_false_probability: 1e-9,
            pattern_stars: 12,
            max_hypotheses: 5000,
            max_scale_error: 0.02,
            track_scale_error: 0.005,
            photometric_tolerance_mag: 1.0,
        }
    }
}

/// One measured star: its camera-frame unit vector and 1-sigma angular error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measured {
    /// Camera-frame unit vector.
    pub dir: [f64; 3],
    /// 1-sigma angular error across the line of sight, rad.
    pub sigma_rad: f64,
    /// Instrumental magnitude, `-2.5 log10` of the measured flux in any fixed unit (the zero
    /// point is found per hypothesis), `None` when not measured or saturated: the star is
    /// then counted by its position only.
    pub inst_mag: Option<f32>,
}

impl Measured {
    /// The instrumental magnitude of a flux in any fixed unit (`None` unless finite and
    /// positive).
    pub fn inst_mag_of(flux: f64) -> Option<f32> {
        (flux.is_finite() && flux > 0.0).then(|| (-2.5 * libm::log10(flux)) as f32)
    }
}

/// A measured star and the catalog star it is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Match {
    /// Index in the measured list.
    pub star: u8,
    /// Index in the catalog.
    pub catalog: u16,
}

/// An identification and the attitude from all its stars.
#[derive(Clone, Debug, PartialEq)]
pub struct Solution {
    /// Attitude and covariance from every matched star.
    pub attitude: Attitude,
    /// The matched stars, in measured order.
    pub matches: heapless::Vec<Match, MAX_STARS>,
    /// Upper bound on the probability that this solution is a false match.
    pub false_probability: f64,
    /// Hypotheses verified.
    pub hypotheses: u32,
    /// The focal-length scale fitted with the attitude: the focal length that images the
    /// matched stars is the camera model's times `scale.value` (measured separations are
    /// `scale.value` times the true ones).
    pub scale: FocalScale,
}

/// A focal-length scale estimated from identified stars, with its 1-sigma.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FocalScale {
    /// True focal length over the camera model's (1 when the model is right).
    pub value: f64,
    /// 1-sigma of `value` (from the fit's covariance; the attitude's covariance is the
    /// marginal one with the scale fitted).
    pub sigma: f64,
}

/// Why no identification was made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum IdentError {
    /// Fewer than `MIN_MATCHES` (4) measured stars.
    TooFewStars,
    /// A measured star is not a finite unit vector with a positive sigma, or the settings
    /// are out of range.
    BadInput,
    /// No hypothesis passed verification (`hypotheses` were tried).
    NoMatch {
        /// Hypotheses verified.
        hypotheses: u32,
    },
}

impl core::fmt::Display for IdentError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooFewStars => write!(f, "identification needs {MIN_MATCHES} stars or more"),
            Self::BadInput => f.write_str("identification: bad star or setting"),
            Self::NoMatch { hypotheses } => {
                write!(f, "no identification ({hypotheses} hypotheses verified)")
            }
        }
    }
}

impl core::error::Error for IdentError {}

/// Buckets of the `d_ik` scratch (by star index modulo this; 2 KB of offsets and 2 KB of
/// cursors), about one entry each.
pub(crate) const IK_BUCKETS: usize = 1024;

/// Entries of the (star, partner) scratch of one triangle's `d_ik` pairs (16 KB: the
/// shortest side's window over the whole scale range up to about 6.5 degrees).
pub(crate) const IK_CAPACITY: usize = 4096;

/// The pyramid order of triangles over `n` stars (Mortari): (i, i+dj, i+dj+dk).
struct Triangles {
    n: usize,
    dj: usize,
    dk: usize,
    i: usize,
}

impl Triangles {
    fn new(n: usize) -> Self {
        Self {
            n,
            dj: 1,
            dk: 1,
            i: 0,
        }
    }
}

impl Iterator for Triangles {
    type Item = (usize, usize, usize);

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if self.dj + 1 >= self.n {
                return None;
            }
            if self.dk + self.dj >= self.n {
                self.dj += 1;
                self.dk = 1;
                self.i = 0;
                continue;
            }
            if self.i + self.dj + self.dk >= self.n {
                self.dk += 1;
                self.i = 0;
                continue;
            }
            let t = (self.i, self.i + self.dj, self.i + self.dj + self.dk);
            self.i += 1;
            return Some(t);
        }
    }
}

fn check_input(stars: &[Measured], cfg: &IdentConfig) -> Result<usize, IdentError> {
    let n = stars.len().min(MAX_STARS);
    let unit = |v: [f64; 3]| v.iter().all(|c| c.is_finite()) && (dot(v, v) - 1.0).abs() < 1e-9;
    let stars_ok = stars
        .iter()
        .take(n)
        .all(|s| unit(s.dir) && s.sigma_rad > 0.0 && s.sigma_rad.is_finite());
    let cfg_ok = cfg.pair_tolerance_rad > 0.0
        && cfg.match_radius_rad > 0.0
        && cfg.match_radius_rad < 0.1
        && cfg.max_false_probability.is_finite()
        && (3..=MAX_PATTERN).contains(&cfg.pattern_stars)
        && (0.0..=0.05).contains(&cfg.max_scale_error)
        && (0.0..=0.05).contains(&cfg.track_scale_error)
        && (0.1..=5.0).contains(&cfg.photometric_tolerance_mag);
    if !stars_ok || !cfg_ok {
        return Err(IdentError::BadInput);
    }
    if n < MIN_MATCHES {
        return Err(IdentError::TooFewStars);
    }
    Ok(n)
}

fn dir_of(stars: &[Measured], i: usize) -> [f64; 3] {
    stars.get(i).map_or([0.0, 0.0, 1.0], |s| s.dir)
}

/// The sign of the triple product `a . (b x c)`, or 0 when the three are too near a great
/// circle for the sign to be trusted.
fn handedness(a: [f64; 3], b: [f64; 3], c: [f64; 3], min_abs: f64) -> i8 {
    let t = dot(a, cross(b, c));
    if t > min_abs {
        1
    } else if t < -min_abs {
        -1
    } else {
        0
    }
}

/// Identifies `stars` (brightest first) with no prior, the focal length anywhere within
/// `1 +- cfg.max_scale_error` of the camera model's.
///
/// Each triangle is relabelled so that `i` is the vertex opposite its longest side, `(i, j)`
/// its middle side and `(i, k)` its shortest: the pairs near `d_ij` (searched over the
/// whole scale range) fix the scale to `tol / D_ab`, so the partners `c` of `a` near `d_ik`
/// and the longest side `b c` are checked at that scale, and the longest side, read from
/// the catalog directions, may be longer than the pair database's largest separation.
pub fn lost_in_space(
    cat: &Catalog<'_>,
    stars: &[Measured],
    cfg: &IdentConfig,
) -> Result<Solution, IdentError> {
    let n = check_input(stars, cfg)?;
    let crowd = crowding(stars, n, cfg.match_radius_rad);
    let np = n.min(cfg.pattern_stars);
    let tol = cfg.pair_tolerance_rad;
    // The model's focal length within 1 +- ds of the true one: s = f_true / f_model.
    let ds = cfg.max_scale_error;
    let (s_lo, s_hi) = (1.0 / (1.0 + ds), 1.0 / (1.0 - ds));
    let max_sep = cat.max_separation_rad();
    let mut scratch = [(0u16, 0u16); IK_CAPACITY];
    let bucket = |star: u16| usize::from(star) % IK_BUCKETS;
    let mut hyps = 0u32;
    for tri in Triangles::new(np) {
        let (i, j, k) = relabel(stars, tri);
        let (vi, vj, vk) = (dir_of(stars, i), dir_of(stars, j), dir_of(stars, k));
        let (dij, dik, djk) = (
            angle_between(vi, vj),
            angle_between(vi, vk),
            angle_between(vj, vk),
        );
        if dij / s_lo + tol >= max_sep || dik < 4.0 * tol {
            continue;
        }
        let hand = handedness(vi, vj, vk, tol * dij.min(dik));
        // The pairs near d_ik as (star, partner) both ways, grouped by a bucket of the star
        // (a counting sort: two passes over the pairs), so the partners `c` of a vertex `a`
        // are the few entries of its bucket. A triangle whose range is too long for the
        // scratch (a shortest side beyond about 6.5 degrees) is left to the others.
        let ik_range = cat.pairs_between(dik / s_hi - tol, dik / s_lo + tol);
        if 2 * ik_range.len() > IK_CAPACITY {
            continue;
        }
        let mut start = [0u16; IK_BUCKETS + 1];
        for pk in ik_range.clone() {
            let Some(p) = cat.pair(pk) else { continue };
            for x in [p.a, p.b] {
                if let Some(c) = start.get_mut(bucket(x) + 1) {
                    *c += 1;
                }
            }
        }
        for b in 0..IK_BUCKETS {
            let prev = start.get(b).copied().unwrap_or(0);
            if let Some(c) = start.get_mut(b + 1) {
                *c += prev;
            }
        }
        let mut next = [0u16; IK_BUCKETS];
        next.copy_from_slice(start.get(..IK_BUCKETS).unwrap_or(&[0; IK_BUCKETS]));
        for pk in ik_range.clone() {
            let Some(p) = cat.pair(pk) else { continue };
            for (x, y) in [(p.a, p.b), (p.b, p.a)] {
                let Some(at) = next.get_mut(bucket(x)) else {
                    continue;
                };
                if let Some(slot) = scratch.get_mut(usize::from(*at)) {
                    *slot = (x, y);
                }
                *at += 1;
            }
        }
        let len = usize::from(start.get(IK_BUCKETS).copied().unwrap_or(0));
        let by_star = scratch.get(..len).unwrap_or(&[]);
        for pi in cat.pairs_between(dij / s_hi - tol, dij / s_lo + tol) {
            let Some(pij) = cat.pair(pi) else { continue };
            // The scales this pair allows: |d_ij - s D_ab| <= tol, within the searched range.
            let d_ab = f64::from(pij.separation_nrad) / crate::catalog::NRAD_PER_RAD;
            if d_ab <= 0.0 {
                continue;
            }
            let (lo_s, hi_s) = (
                ((dij - tol) / d_ab).max(s_lo),
                ((dij + tol) / d_ab).min(s_hi),
            );
            if lo_s > hi_s || lo_s <= 0.0 {
                continue;
            }
            // As squared chords |r_a - r_c|^2 (monotonic in the angle; no arc cosine in the
            // inner loop).
            let ac = (chord2((dik - tol) / hi_s), chord2((dik + tol) / lo_s));
            let bc = (chord2((djk - tol) / hi_s), chord2((djk + tol) / lo_s));
            for (a, b) in [(pij.a, pij.b), (pij.b, pij.a)] {
                let (lo, hi) = (
                    usize::from(start.get(bucket(a)).copied().unwrap_or(0)),
                    usize::from(start.get(bucket(a) + 1).copied().unwrap_or(0)),
                );
                if lo == hi {
                    continue;
                }
                let (Some(ra), Some(rb)) = (cat.dir(a.into()), cat.dir(b.into())) else {
                    continue;
                };
                let partners = by_star.get(lo..hi).unwrap_or(&[]).iter();
                for c in partners.filter(|e| e.0 == a).map(|e| e.1) {
                    let Some(rc) = cat.dir(c.into()) else {
                        continue;
                    };
                    if c == b {
                        continue;
                    }
                    let (c_ac, c_bc) = (dist2(ra, rc), dist2(rb, rc));
                    if c_ac < ac.0 || c_ac > ac.1 || c_bc < bc.0 || c_bc > bc.1 {
                        continue;
                    }
                    let (d_ac, d_bc) = (angle_between(ra, rc), angle_between(rb, rc));
                    if hand != 0 && handedness(ra, rb, rc, 0.0) != hand {
                        continue;
                    }
                    // One scale for the three sides (their sum's ratio), each side within
                    // the tolerance at it: the triangle's shape matches.
                    let s = (dij + dik + djk) / (d_ab + d_ac + d_bc);
                    if (dij - s * d_ab).abs() > tol
                        || (dik - s * d_ac).abs() > tol
                        || (djk - s * d_bc).abs() > tol
                    {
                        continue;
                    }
                    // A triangle whose brightness disagrees is no hypothesis: it is not
                    // counted, so the level is spent on the triangles that can be the
                    // field's (the test reads the triangle only: bound.rs).
                    let basis = [(i, a), (j, b), (k, c)];
                    if !bound::triangle_agrees(cat, stars, &basis, cfg.photometric_tolerance_mag) {
                        continue;
                    }
                    hyps += 1;
                    if let Some(sol) =
                        hypothesis(cat, stars, n, &crowd, basis, s, (s_lo, s_hi), cfg, hyps)
                    {
                        return Ok(sol);
                    }
                    if hyps >= cfg.max_hypotheses {
                        return Err(IdentError::NoMatch { hypotheses: hyps });
                    }
                }
            }
        }
    }
    Err(IdentError::NoMatch { hypotheses: hyps })
}

/// The squared chord `4 sin^2(d / 2)` of an angle `d` (negative angles give 0), from its
/// series `d^2 (1 - d^2 / 12)`: below 1e-7 of it relative for `d` up to 0.4 rad.
fn chord2(d: f64) -> f64 {
    let d = d.max(0.0);
    d * d * (1.0 - d * d / 12.0 + d * d * d * d / 360.0)
}

/// `|a - b|^2`.
fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    dot(d, d)
}

/// The triangle `tri` relabelled `(i, j, k)`: `i` opposite the longest side, `(i, j)` the
/// middle side, `(i, k)` the shortest.
fn relabel(stars: &[Measured], tri: (usize, usize, usize)) -> (usize, usize, usize) {
    let v = [tri.0, tri.1, tri.2];
    let d = |a: usize, b: usize| angle_between(dir_of(stars, a), dir_of(stars, b));
    // opposite[x]: the side not touching vertex x; `order` sorts the vertices by it,
    // longest first. The side (i, j) is the one opposite k, so k is opposite the middle
    // side and j opposite the shortest.
    let opposite = [d(tri.1, tri.2), d(tri.0, tri.2), d(tri.0, tri.1)];
    // Three compare-exchanges, each moving only a strictly longer side forward (stable).
    let longer = |x: usize, y: usize| {
        let dx = opposite.get(x).copied().unwrap_or(0.0);
        let dy = opposite.get(y).copied().unwrap_or(0.0);
        dy.total_cmp(&dx) == core::cmp::Ordering::Greater
    };
    let (mut first, mut second, mut third) = (0usize, 1usize, 2usize);
    if longer(first, second) {
        core::mem::swap(&mut first, &mut second);
    }
    if longer(second, third) {
        core::mem::swap(&mut second, &mut third);
    }
    if longer(first, second) {
        core::mem::swap(&mut first, &mut second);
    }
    let at = |x: usize| v.get(x).copied().unwrap_or(0);
    (at(first), at(third), at(second))
}

/// `stars` with their tangent-plane coordinates `(x/z, y/z)` divided by `scale` (the
/// directions a camera model with the focal length times `scale` gives), the first `n`.
fn rescaled(stars: &[Measured], n: usize, scale: f64) -> heapless::Vec<Measured, MAX_STARS> {
    let k = 1.0 / scale;
    stars
        .iter()
        .take(n.min(MAX_STARS))
        .map(|s| Measured {
            dir: rescale_dir(s.dir, k),
            sigma_rad: s.sigma_rad * k,
            inst_mag: s.inst_mag,
        })
        .collect()
}

/// The unit vector `dir` with its tangent-plane coordinates multiplied by `k` (unchanged
/// when it is not in front of the camera).
pub(crate) fn rescale_dir(dir: [f64; 3], k: f64) -> [f64; 3] {
    let [x, y, z] = dir;
    if z <= 1e-6 {
        return dir;
    }
    let (u, v) = (x / z * k, y / z * k);
    let r = 1.0 / libm::sqrt(u * u + v * v + 1.0);
    [u * r, v * r, r]
}

/// Identifies `stars` (brightest first) near the `prior` attitude, which may be off by up to
/// `prior_error_rad` (any axis), the focal length within `cfg.track_scale_error` of the
/// camera model's.
pub fn track(
    cat: &Catalog<'_>,
    stars: &[Measured],
    prior: Quat,
    prior_error_rad: f64,
    cfg: &IdentConfig,
) -> Result<Solution, IdentError> {
    track_scaled(cat, stars, prior, 1.0, prior_error_rad, cfg)
}

/// [`track`] from a prior that also holds a focal-length scale (a [`FocalScale::value`] of
/// an earlier solution): the scale may have drifted from it by `cfg.track_scale_error`.
pub fn track_scaled(
    cat: &Catalog<'_>,
    stars: &[Measured],
    prior: Quat,
    prior_scale: f64,
    prior_error_rad: f64,
    cfg: &IdentConfig,
) -> Result<Solution, IdentError> {
    let n = check_input(stars, cfg)?;
    let crowd = crowding(stars, n, cfg.match_radius_rad);
    if !(0.0..0.2).contains(&prior_error_rad) || !(0.9..=1.1).contains(&prior_scale) {
        return Err(IdentError::BadInput);
    }
    let prior = prior.normalized().ok_or(IdentError::BadInput)?;
    let scaled = rescaled(stars, n, prior_scale);
    let np = n.min(cfg.pattern_stars);
    let ds = cfg.track_scale_error;
    let tol = cfg.pair_tolerance_rad;
    let side_tol = |d: f64| tol + ds * d;
    let mut cands: [heapless::Vec<u16, MAX_CANDIDATES>; MAX_PATTERN] =
        core::array::from_fn(|_| heapless::Vec::new());
    for (i, c) in cands.iter_mut().enumerate().take(np) {
        let v = dir_of(&scaled, i);
        let sky = prior.rotate_inv(v);
        // A scale error moves a star by at most `ds` times its angle from the boresight.
        let off_axis = libm::acos(v[2].clamp(-1.0, 1.0));
        for (idx, _) in cat.cone(sky, prior_error_rad + tol + ds * off_axis) {
            // Past the capacity, the farther candidates are dropped: the triangle is
            // then found from other stars or not at all, never wrongly.
            let _ = c.push(u16::try_from(idx).unwrap_or(u16::MAX));
        }
    }
    let cand = |i: usize| cands.get(i).map_or(&[][..], |c| c.as_slice());
    let mut hyps = 0u32;
    let range = (prior_scale / (1.0 + ds), prior_scale / (1.0 - ds));
    for (i, j, k) in Triangles::new(np) {
        let (vi, vj, vk) = (dir_of(&scaled, i), dir_of(&scaled, j), dir_of(&scaled, k));
        let (dij, dik, djk) = (
            angle_between(vi, vj),
            angle_between(vi, vk),
            angle_between(vj, vk),
        );
        if dij.min(dik).min(djk) < 4.0 * tol {
            continue;
        }
        let hand = handedness(vi, vj, vk, tol * dij.min(dik));
        for &a in cand(i) {
            let Some(ra) = cat.dir(a.into()) else {
                continue;
            };
            for &b in cand(j) {
                let Some(rb) = cat.dir(b.into()) else {
                    continue;
                };
                if b == a || (angle_between(ra, rb) - dij).abs() > side_tol(dij) {
                    continue;
                }
                for &c in cand(k) {
                    let Some(rc) = cat.dir(c.into()) else {
                        continue;
                    };
                    if c == a
                        || c == b
                        || (angle_between(ra, rc) - dik).abs() > side_tol(dik)
                        || (angle_between(rb, rc) - djk).abs() > side_tol(djk)
                        || (hand != 0 && handedness(ra, rb, rc, 0.0) != hand)
                    {
                        continue;
                    }
                    hyps += 1;
                    let basis = [(i, a), (j, b), (k, c)];
                    let d_cat =
                        angle_between(ra, rb) + angle_between(ra, rc) + angle_between(rb, rc);
                    let s = prior_scale * (dij + dik + djk) / d_cat;
                    if let Some(sol) = hypothesis(cat, stars, n, &crowd, basis, s, range, cfg, hyps)
                    {
                        return Ok(sol);
                    }
                    if hyps >= cfg.max_hypotheses {
                        return Err(IdentError::NoMatch { hypotheses: hyps });
                    }
                }
            }
        }
    }
    Err(IdentError::NoMatch { hypotheses: hyps })
}

/// Most stars [`confirm`] drops as inconsistent before it gives up (a frame with more than
/// this many stars off their identities is searched instead).
pub(crate) const CONFIRM_MAX_DROPPED: usize = 8;

/// Identification from identities known beforehand: `stars` (brightest first) are the
/// catalog stars `ids` (one per star, in order: the tracker's stars measured in the windows
/// the catalog predicted), the attitude near `prior` with focal-length scale near
/// `prior_scale`. Nothing is searched; the identities are verified: the attitude and the
/// scale are fitted to them as in verification (Gauss-Newton from `prior`), the star whose
/// studentised residual (its residual over its own sigma and `sqrt(1 - h)`, `h` the share
/// of its position the fit follows) is largest beyond `TIGHT_SIGMAS` (5) is dropped and the
/// fit repeated until every residual is within (a false star or a hot pixel measured in a
/// predicted window cannot stay in the attitude), at most `CONFIRM_MAX_DROPPED` (8) times;
/// the fit must not follow one star alone (leverage, as in verification), its scale must
/// be within `cfg.track_scale_error` of `prior_scale`, and the wide count's false-match bound
/// (module documentation) held to the flat `alpha / H_max`, for `n` stars of which the kept
/// ones matched, must pass. Any
/// failure is an error (the caller then searches: [`track_scaled`], [`lost_in_space`]).
/// Cost: a joint fit of the stars (three Gauss-Newton steps, ~100 flops a star) per round.
#[inline(never)]
pub fn confirm(
    cat: &Catalog<'_>,
    stars: &[Measured],
    ids: &[u16],
    prior: Quat,
    prior_scale: f64,
    cfg: &IdentConfig,
) -> Result<Solution, IdentError> {
    let n = check_input(stars, cfg)?.min(ids.len());
    if n < MIN_MATCHES {
        return Err(IdentError::TooFewStars);
    }
    if !(0.9..=1.1).contains(&prior_scale) {
        return Err(IdentError::BadInput);
    }
    let prior = prior.normalized().ok_or(IdentError::BadInput)?;
    let no_match = IdentError::NoMatch { hypotheses: 1 };
    let mut matches: heapless::Vec<Match, MAX_STARS> = heapless::Vec::new();
    for (m, &catalog) in ids.iter().enumerate().take(n) {
        let (Ok(star), Some(_)) = (u8::try_from(m), cat.dir(usize::from(catalog))) else {
            continue;
        };
        // The same catalog star twice is no identity: both are left out.
        if ids.iter().take(n).filter(|&&c| c == catalog).count() > 1 {
            continue;
        }
        let _ = matches.push(Match { star, catalog });
    }
    let (mut q, mut s) = (prior, prior_scale);
    let mut dropped = 0;
    let joint = loop {
        if matches.len() < MIN_MATCHES {
            return Err(no_match);
        }
        let joint = fit(cat, stars, &matches, s, Some(q)).ok_or(no_match)?;
        (q, s) = (joint.attitude.q, joint.scale.value);
        let scaled = rescaled(stars, n, s);
        // The largest residual in its own sigmas, studentised: a residual's variance is the
        // star's own less what the fit follows of it (its leverage `h`), so a star the fit
        // follows (a heavy one: a hot pixel's spike measured with a tiny sigma) shows its
        // disagreement rather than hiding it in the others' residuals.
        let worst = matches
            .iter()
            .enumerate()
            .filter_map(|(k, m)| {
                let st = scaled.get(usize::from(m.star))?;
                let r = cat.dir(usize::from(m.catalog))?;
                let p = predicted_sigma(st.dir, &joint.cov, s);
                let h = (0.5 * p * p / (st.sigma_rad * st.sigma_rad)).min(1.0 - 1e-6);
                let z = angle_between(q.rotate(r), st.dir) / st.sigma_rad;
                Some((k, z / libm::sqrt(1.0 - h)))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match worst {
            // A NaN residual is no agreement either.
            Some((k, z)) if z.is_nan() || z > TIGHT_SIGMAS => {
                if dropped == CONFIRM_MAX_DROPPED {
                    return Err(no_match);
                }
                matches.remove(k);
                dropped += 1;
            }
            _ => break joint,
        }
    };
    if high_leverage(stars, n, &matches, &joint) {
        return Err(no_match);
    }
    let ds = cfg.track_scale_error;
    let margin = 3.0 * joint.scale.sigma;
    if joint.scale.value < prior_scale / (1.0 + ds) - margin
        || joint.scale.value > prior_scale / (1.0 - ds) + margin
    {
        return Err(no_match);
    }
    let false_probability = bound::given_identities_bound(cat, cfg, n, matches.len(), q);
    if false_probability > cfg.max_false_probability {
        return Err(no_match);
    }
    Ok(Solution {
        attitude: joint.attitude,
        matches,
        false_probability,
        hypotheses: 1,
        scale: joint.scale,
    })
}

/// Verifies the triangle `basis` (measured index, catalog index) with `scale` its
/// focal-length scale: the solution when its false-match bound passes and its fitted scale
/// lies in `range` (widened by 3 of its sigmas).
#[allow(clippy::too_many_arguments)]
fn hypothesis(
    cat: &Catalog<'_>,
    stars: &[Measured],
    n: usize,
    crowd: &Crowd,
    basis: [(usize, u16); 3],
    scale: f64,
    range: (f64, f64),
    cfg: &IdentConfig,
    hyps: u32,
) -> Option<Solution> {
    if !precheck(
        cat,
        stars,
        n,
        scale,
        basis,
        PRECHECK_RADII * cfg.match_radius_rad,
    ) {
        return None;
    }
    let scaled = rescaled(stars, n, scale);
    let mut obs = [Observation {
        camera: [0.0, 0.0, 1.0],
        icrs: [0.0, 0.0, 1.0],
        sigma_rad: 1.0,
    }; 3];
    for (o, &(m, c)) in obs.iter_mut().zip(basis.iter()) {
        o.camera = dir_of(&scaled, m);
        o.icrs = cat.dir(c.into())?;
    }
    let first = attitude::solve(&obs).ok()?;
    let (matches, _) = match_all(cat, &scaled, n, crowd, first.q, cfg.match_radius_rad, None);
    if matches.len() < MIN_MATCHES {
        return None;
    }
    // Rounds of: refit attitude and scale from the matches, match every star again, refit,
    // and keep only the stars within TIGHT_SIGMAS of their own sigma of that fit (an
    // attitude pulled by a false star or a wrong neighbour loses them here); until the
    // matches stop changing. A triangle's attitude and scale can be off enough that the
    // stars far from it fall outside the match radius, or on a neighbour, until a round
    // brings them in. The largest set seen is kept.
    let (mut matches, s, _) = rounds(cat, stars, n, crowd, matches, scale, first.q, cfg)?;
    let mut joint = fit(cat, stars, &matches, s, None)?;
    // A fit from few or clustered stars can be loose enough (its roll, mostly) that the
    // other stars of the field are predicted beyond the match radius: they are matched
    // again within the radius widened by 3 of their predicted sigmas, and the rounds run
    // again from there. What is kept still passes the rounds' TIGHT_SIGMAS test.
    let scaled = rescaled(stars, n, s);
    let loose = |st: &Measured| {
        3.0 * predicted_sigma(st.dir, &joint.cov, s) > WIDEN_FROM * cfg.match_radius_rad
    };
    let was_loose = scaled.iter().any(loose);
    if matches.len() < n && was_loose {
        let spread = Some((&joint.cov, s));
        let (wide, _) = match_all(
            cat,
            &scaled,
            n,
            crowd,
            joint.attitude.q,
            cfg.match_radius_rad,
            spread,
        );
        if wide.len() > matches.len()
            && let Some((grown, s2, _)) =
                rounds(cat, stars, n, crowd, wide, s, joint.attitude.q, cfg)
            && grown.len() > matches.len()
            && let Some(j) = fit(cat, stars, &grown, s2, None)
        {
            (matches, joint) = (grown, j);
        }
    }
    // A star the fit follows almost wholly (one far from a cluster, which carries the roll
    // and the scale: two parameters for its two coordinates) is checked by no other star:
    // a false star there passes the rounds with a small residual and a wrong attitude.
    // Such a hypothesis is no solution (another triangle, or no attitude). Only a loose
    // fit can have one: a tight fit's stars are all below a quarter of LEVERAGE_MAX.
    if was_loose && high_leverage(stars, n, &matches, &joint) {
        return None;
    }
    // The field's density at the basis's own attitude: it depends on the triangle only,
    // not on the stars the bound counts.
    let false_probability = bound::false_match_bound(
        cat,
        cfg,
        &bound::Verified {
            stars,
            n,
            basis,
            matches: &matches,
            joint: &joint,
            triangle_q: first.q,
            j: hyps,
        },
    );
    if false_probability > cfg.max_false_probability {
        return None;
    }
    let margin = 3.0 * joint.scale.sigma;
    if joint.scale.value < range.0 - margin || joint.scale.value > range.1 + margin {
        return None;
    }
    Some(Solution {
        attitude: joint.attitude,
        matches,
        false_probability,
        hypotheses: hyps,
        scale: joint.scale,
    })
}

/// The match-and-refit rounds of [`hypothesis`] from `matches` at scale `scale` and attitude
/// `q`: the largest consistent set seen, with the scale and attitude of the last round.
#[allow(clippy::too_many_arguments)]
fn rounds(
    cat: &Catalog<'_>,
    stars: &[Measured],
    n: usize,
    crowd: &Crowd,
    mut matches: heapless::Vec<Match, MAX_STARS>,
    scale: f64,
    q: Quat,
    cfg: &IdentConfig,
) -> Option<(heapless::Vec<Match, MAX_STARS>, f64, Quat)> {
    let mut best: heapless::Vec<Match, MAX_STARS> = heapless::Vec::new();
    let (mut s, mut q) = (scale, q);
    for _ in 0..MAX_REFITS {
        let refit = fit(cat, stars, &matches, s, Some(q))?;
        let scaled = rescaled(stars, n, refit.scale.value);
        let (all, _) = match_all(
            cat,
            &scaled,
            n,
            crowd,
            refit.attitude.q,
            cfg.match_radius_rad,
            None,
        );
        let refit = fit(cat, stars, &all, refit.scale.value, Some(refit.attitude.q))?;
        q = refit.attitude.q;
        s = refit.scale.value;
        let scaled = rescaled(stars, n, s);
        let next = keep_consistent(cat, &scaled, &all, refit.attitude.q);
        let same = next == matches;
        matches = next;
        if matches.len() > best.len() {
            best = matches.clone();
        }
        if same || matches.len() < MIN_MATCHES {
            break;
        }
    }
    (best.len() >= MIN_MATCHES).then_some((best, s, q))
}

/// Non-basis stars the quick check of a hypothesis looks at (the brightest).
const PRECHECK_STARS: usize = 4;
/// The quick check's radius in match radii (the triangle's own attitude and scale, before
/// any refit, can put a star a match radius or more off).
const PRECHECK_RADII: f64 = 2.0;

/// The quick check of a hypothesis before its verification: under the TRIAD attitude of
/// two of its stars (about 100 flops), at least one of the [`PRECHECK_STARS`] brightest
/// other stars falls within `radius` of a catalog star. A wrong triangle fails it almost
/// always, for a few cone searches instead of a q-method and a cone search per star; a
/// right one fails only when all of those stars are false or missing (its other
/// triangles are tried then). It only rejects: what it passes is verified in full.
fn precheck(
    cat: &Catalog<'_>,
    stars: &[Measured],
    n: usize,
    scale: f64,
    basis: [(usize, u16); 3],
    radius: f64,
) -> bool {
    let at = |m: usize| rescale_dir(dir_of(stars, m), 1.0 / scale);
    let [(i, a), (j, b), _] = basis;
    let (Some(ra), Some(rb)) = (cat.dir(a.into()), cat.dir(b.into())) else {
        return false;
    };
    let (bi, bj) = (at(i), at(j));
    let frame = |x: [f64; 3], y: [f64; 3]| -> Option<[[f64; 3]; 3]> {
        let c = cross(x, y);
        let nc = libm::sqrt(dot(c, c));
        if nc <= 1e-12 {
            return None;
        }
        let t2 = c.map(|v| v / nc);
        Some([x, t2, cross(x, t2)])
    };
    let (Some(fb), Some(fr)) = (frame(bi, bj), frame(ra, rb)) else {
        return false;
    };
    let mut looked = 0;
    for m in 0..n.min(stars.len()) {
        if basis.iter().any(|&(x, _)| x == m) {
            continue;
        }
        if looked == PRECHECK_STARS {
            break;
        }
        looked += 1;
        // The star in the basis's own frame, then that frame's axes on the sky.
        let v = at(m);
        let c = fb.map(|t| dot(t, v));
        let mut sky = [0.0f64; 3];
        for (axis, coef) in fr.iter().zip(c) {
            for (out, v) in sky.iter_mut().zip(axis) {
                *out += coef * v;
            }
        }
        if cat.cone(sky, radius).next().is_some() {
            return true;
        }
    }
    looked == 0
}

/// For each measured star, the others within twice the match radius of it (bit `m` for
/// star `m`): either of two such stars could be the image of a catalog star between them.
pub(crate) type Crowd = [u32; MAX_STARS];

/// The [`Crowd`] of the first `n` stars (`n (n - 1) / 2` dot products, once per
/// identification).
fn crowding(stars: &[Measured], n: usize, match_radius_rad: f64) -> Crowd {
    let mut crowd = [0u32; MAX_STARS];
    let near = libm::cos(2.0 * match_radius_rad);
    for (a, sa) in stars.iter().enumerate().take(n.min(MAX_STARS)) {
        for (b, sb) in stars.iter().enumerate().take(n.min(MAX_STARS)).skip(a + 1) {
            if dot(sa.dir, sb.dir) > near {
                if let Some(x) = crowd.get_mut(a) {
                    *x |= 1 << b;
                }
                if let Some(x) = crowd.get_mut(b) {
                    *x |= 1 << a;
                }
            }
        }
    }
    crowd
}

/// Every measured star matched to its nearest catalog star within `radius` under `q`; a
/// catalog star is matched once, to the measured star nearest it. A star with another
/// measured star within twice the match radius ([`Crowd`]) is matched only when each of
/// them has a catalog star of its own: a false star (or an uncatalogued companion) next to
/// a true star would otherwise take its catalog star and pull the fit off it, far enough
/// that the true star no longer falls in the radius. With `spread` (the covariance of a fit
/// of the rotation and the scale, and the scale), a star's radius is widened by 3 of its
/// position sigmas predicted from it.
#[allow(clippy::too_many_arguments)]
fn match_all(
    cat: &Catalog<'_>,
    stars: &[Measured],
    n: usize,
    crowd: &Crowd,
    q: Quat,
    radius: f64,
    spread: Option<(&[[f64; 4]; 4], f64)>,
) -> (heapless::Vec<Match, MAX_STARS>, usize) {
    // Each star's nearest catalog star and its cosine.
    let mut nearest = [None::<(u16, f64)>; MAX_STARS];
    for (s, slot) in stars.iter().zip(nearest.iter_mut()).take(n) {
        let r = match spread {
            Some((cov, scale)) => radius + 3.0 * predicted_sigma(s.dir, cov, scale),
            None => radius,
        };
        let sky = q.rotate_inv(s.dir);
        let mut best: Option<(usize, f64)> = None;
        for (idx, v) in cat.cone(sky, r) {
            let d = dot(sky, v);
            if best.is_none_or(|(_, bd)| d > bd) {
                best = Some((idx, d));
            }
        }
        *slot = best.and_then(|(idx, d)| Some((u16::try_from(idx).ok()?, d)));
    }
    let mut out: heapless::Vec<Match, MAX_STARS> = heapless::Vec::new();
    for (m, &this) in nearest.iter().enumerate().take(n) {
        let Some((catalog, d)) = this else { continue };
        let Ok(star) = u8::try_from(m) else { continue };
        let mut others = crowd.get(m).copied().unwrap_or(0);
        let mut alone = true;
        while others != 0 {
            let o = others.trailing_zeros() as usize;
            others &= others - 1;
            let theirs = nearest.get(o).copied().flatten();
            alone &= theirs.is_some_and(|(c, _)| c != catalog);
        }
        // The nearest measured star takes a catalog star claimed by several.
        let taken = nearest
            .iter()
            .take(n)
            .any(|x| x.is_some_and(|(c, od)| c == catalog && od > d));
        if alone && !taken {
            let _ = out.push(Match { star, catalog });
        }
    }
    let len = out.len();
    (out, len)
}

/// A matched star whose leverage in the fit exceeds this is followed by the fit rather than
/// checked against it (leverage: the star's predicted position variance per axis over its
/// own variance; the leverages of a fit sum to its 4 parameters over `2 m` coordinates,
/// 0.5 a star at the 4-star minimum).
pub(crate) const LEVERAGE_MAX: f64 = 0.9;

/// Whether some matched star has a leverage above [`LEVERAGE_MAX`] in `joint`, the fit of
/// `matches`.
fn high_leverage(stars: &[Measured], n: usize, matches: &[Match], joint: &Joint) -> bool {
    let s = joint.scale.value;
    let scaled = rescaled(stars, n, s);
    matches.iter().any(|m| {
        scaled.get(usize::from(m.star)).is_some_and(|st| {
            let p = predicted_sigma(st.dir, &joint.cov, s);
            0.5 * p * p > LEVERAGE_MAX * st.sigma_rad * st.sigma_rad
        })
    })
}

/// The 1-sigma of a star's position (rad, tangent plane, the root of the trace of its 2 x 2
/// covariance) at direction `dir` predicted from the covariance `cov` of a fit's rotation and
/// scale at scale `scale`.
pub(crate) fn predicted_sigma(dir: [f64; 3], cov: &[[f64; 4]; 4], scale: f64) -> f64 {
    let Some((ju, jw, _)) = jacobian(dir, scale) else {
        return 0.0;
    };
    let mut var = 0.0;
    for (a, row) in cov.iter().enumerate() {
        for (b, c) in row.iter().enumerate() {
            let (ua, wa) = (
                ju.get(a).copied().unwrap_or(0.0),
                jw.get(a).copied().unwrap_or(0.0),
            );
            let (ub, wb) = (
                ju.get(b).copied().unwrap_or(0.0),
                jw.get(b).copied().unwrap_or(0.0),
            );
            var += (ua * ub + wa * wb) * c;
        }
    }
    libm::sqrt(var.max(0.0))
}

/// The derivatives of the tangent-plane coordinates `s (v_x, v_y) / v_z` of the camera-frame
/// direction `v` by a small rotation `e` (camera frame, `v' = v + e x v`) and by the scale
/// `s`, with `(v_x, v_y) / v_z`; `None` behind or at the edge of the tangent plane.
fn jacobian(v: [f64; 3], s: f64) -> Option<([f64; 4], [f64; 4], [f64; 2])> {
    let [vx, vy, vz] = v;
    if vz <= 1e-6 {
        return None;
    }
    let (u, w) = (vx / vz, vy / vz);
    // d v / d e: the rows of the x, y and z components, by e_x, e_y, e_z.
    let (dx, dy, dz) = ([0.0, vz, -vy], [-vz, 0.0, vx], [vy, -vx, 0.0]);
    let mut ju = [0.0f64; 4];
    let mut jw = [0.0f64; 4];
    for c in 0..3 {
        let (x, y, z) = (
            dx.get(c).copied().unwrap_or(0.0),
            dy.get(c).copied().unwrap_or(0.0),
            dz.get(c).copied().unwrap_or(0.0),
        );
        if let (Some(a), Some(b)) = (ju.get_mut(c), jw.get_mut(c)) {
            *a = s * (x - u * z) / vz;
            *b = s * (y - w * z) / vz;
        }
    }
    ju[3] = u;
    jw[3] = w;
    Some((ju, jw, [u, w]))
}

/// A match stays when its residual under `q` is within [`TIGHT_SIGMAS`] of its sigma.
fn keep_consistent(
    cat: &Catalog<'_>,
    stars: &[Measured],
    matches: &[Match],
    q: Quat,
) -> heapless::Vec<Match, MAX_STARS> {
    matches
        .iter()
        .filter(|m| {
            let (Some(s), Some(r)) = (stars.get(usize::from(m.star)), cat.dir(m.catalog.into()))
            else {
                return false;
            };
            angle_between(q.rotate(r), s.dir) <= TIGHT_SIGMAS * s.sigma_rad
        })
        .copied()
        .collect()
}

/// An attitude fitted with the focal-length scale.
struct Joint {
    attitude: Attitude,
    scale: FocalScale,
    /// Covariance of the small rotation (rad, camera frame) and the scale.
    cov: [[f64; 4]; 4],
}

/// Gauss-Newton steps of the joint fit (it starts from the q-method at the given scale or
/// from a given attitude near the solution; the model is nearly linear there).
const JOINT_STEPS: usize = 2;

/// The attitude and focal-length scale that best fit the matched stars: from `start` (or
/// the q-method on the directions at `scale` when there is none), Gauss-Newton on the four parameters (a small rotation
/// `e`, camera frame, and the scale `s`) of the model `t_i = s P(q r_i)`, `P(v) = (v_x,
/// v_y) / v_z` the tangent-plane coordinates, against each star's measured `P(b_i)`, weight
/// `(z_i^1.5 / sigma_i)^2` (a star's angular sigma is its tangent-plane sigma times
/// `z^1.5`). The covariance is the inverse normal matrix: the attitude's block is its
/// marginal covariance with the scale fitted.
fn fit(
    cat: &Catalog<'_>,
    stars: &[Measured],
    matches: &[Match],
    scale: f64,
    start: Option<Quat>,
) -> Option<Joint> {
    let start = match start {
        Some(q) => q,
        None => {
            let scaled = rescaled(stars, MAX_STARS, scale);
            let mut obs = [Observation {
                camera: [0.0, 0.0, 1.0],
                icrs: [0.0, 0.0, 1.0],
                sigma_rad: 1.0,
            }; MAX_STARS];
            for (o, m) in obs.iter_mut().zip(matches) {
                let s = scaled.get(usize::from(m.star))?;
                o.camera = s.dir;
                o.sigma_rad = s.sigma_rad;
                o.icrs = cat.dir(m.catalog.into())?;
            }
            attitude::solve(obs.get(..matches.len())?).ok()?.q
        }
    };
    if matches.len() < 3 {
        return None;
    }
    let (mut q, mut s) = (start, scale);
    let mut cov = [[0.0f64; 4]; 4];
    for step in 0..=JOINT_STEPS {
        let mut normal = [[0.0f64; 4]; 4];
        let mut rhs = [0.0f64; 4];
        for m in matches {
            let meas = stars.get(usize::from(m.star))?;
            let r = cat.dir(m.catalog.into())?;
            let [bx, by, bz] = meas.dir;
            if bz <= 1e-6 {
                return None;
            }
            let (ju, jw, [u, w]) = jacobian(q.rotate(r), s)?;
            let sigma_t = meas.sigma_rad / (bz * libm::sqrt(bz));
            let wt = 1.0 / (sigma_t * sigma_t);
            let (ru, rw) = (bx / bz - s * u, by / bz - s * w);
            for (r_i, row) in normal.iter_mut().enumerate() {
                let (a, b) = (ju.get(r_i).copied()?, jw.get(r_i).copied()?);
                if let Some(x) = rhs.get_mut(r_i) {
                    *x += wt * (a * ru + b * rw);
                }
                for (c_i, x) in row.iter_mut().enumerate() {
                    *x += wt * (a * ju.get(c_i).copied()? + b * jw.get(c_i).copied()?);
                }
            }
        }
        cov = inverse4(&normal)?;
        if step == JOINT_STEPS {
            break;
        }
        let mut delta = [0.0f64; 4];
        for (d, row) in delta.iter_mut().zip(cov.iter()) {
            *d = row.iter().zip(rhs.iter()).map(|(a, b)| a * b).sum();
        }
        q = (Quat::from_rotation_vector([delta[0], delta[1], delta[2]]) * q).normalized()?;
        s += delta[3];
        if !(0.5..2.0).contains(&s) {
            return None;
        }
    }
    let cov_rad2 = [
        [cov[0][0], cov[0][1], cov[0][2]],
        [cov[1][0], cov[1][1], cov[1][2]],
        [cov[2][0], cov[2][1], cov[2][2]],
    ];
    let sigma = libm::sqrt(cov[3][3]);
    if !sigma.is_finite() {
        return None;
    }
    Some(Joint {
        attitude: Attitude { q, cov_rad2 },
        scale: FocalScale { value: s, sigma },
        cov,
    })
}

/// The inverse of a symmetric positive definite 4 x 4 matrix (Gauss-Jordan with partial
/// pivoting); `None` when it is singular.
fn inverse4(m: &[[f64; 4]; 4]) -> Option<[[f64; 4]; 4]> {
    let mut a = *m;
    let mut inv = [[0.0f64; 4]; 4];
    for (i, row) in inv.iter_mut().enumerate() {
        if let Some(x) = row.get_mut(i) {
            *x = 1.0;
        }
    }
    let scale = a.iter().flatten().fold(0.0f64, |acc, x| acc.max(x.abs()));
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    for col in 0..4 {
        let pivot = (col..4).max_by(|&x, &y| {
            let ax = a.get(x).and_then(|r| r.get(col)).map_or(0.0, |v| v.abs());
            let ay = a.get(y).and_then(|r| r.get(col)).map_or(0.0, |v| v.abs());
            ax.total_cmp(&ay)
        })?;
        a.swap(col, pivot);
        inv.swap(col, pivot);
        let p = a.get(col).and_then(|r| r.get(col)).copied()?;
        if p.abs() <= scale * 1e-14 {
            return None;
        }
        for c in 0..4 {
            if let Some(x) = a.get_mut(col).and_then(|r| r.get_mut(c)) {
                *x /= p;
            }
            if let Some(x) = inv.get_mut(col).and_then(|r| r.get_mut(c)) {
                *x /= p;
            }
        }
        let (arow, irow) = (*a.get(col)?, *inv.get(col)?);
        for r in 0..4 {
            if r == col {
                continue;
            }
            let f = a.get(r).and_then(|x| x.get(col)).copied()?;
            for c in 0..4 {
                if let Some(x) = a.get_mut(r).and_then(|x| x.get_mut(c)) {
                    *x -= f * arow.get(c).copied().unwrap_or(0.0);
                }
                if let Some(x) = inv.get_mut(r).and_then(|x| x.get_mut(c)) {
                    *x -= f * irow.get(c).copied().unwrap_or(0.0);
                }
            }
        }
    }
    Some(inv)
}

/// The attitude of an identification refit from directions corrected for each matched
/// star's colour: the star at `stars_px[m.star]` (column, row) is turned into a direction
/// through `camera` in its catalog B-V ([`Camera::direction_of`](attitude::Camera::direction_of)),
/// so the lateral colour the camera model holds is removed before Wahba's problem is solved.
/// Identification itself runs on uncorrected directions (the colours are not known before
/// it); the colour shifts are a fraction of a pixel, well inside its match radius. A star
/// whose direction the model cannot invert is left out; the focal-length scale is fitted
/// with the attitude as in identification, and the covariance is the fit's. Cost: one
/// undistortion and one catalog read a match, then the q-method and the joint fit (a few
/// thousand flops).
pub fn colour_corrected(
    cat: &Catalog<'_>,
    camera: &attitude::Camera,
    stars_px: &[[f64; 2]],
    sigma_px: f64,
    sol: &Solution,
) -> Result<Attitude, attitude::AttitudeError> {
    let mut meas: heapless::Vec<Measured, MAX_STARS> = heapless::Vec::new();
    let mut matches: heapless::Vec<Match, MAX_STARS> = heapless::Vec::new();
    for m in &sol.matches {
        let (Some(p), Some(s)) = (
            stars_px.get(usize::from(m.star)),
            cat.star(usize::from(m.catalog)),
        ) else {
            continue;
        };
        let bv_mag = f64::from(s.bv_mmag) / 1000.0;
        let Ok(dir) = camera.direction_of(p[0], p[1], bv_mag) else {
            continue;
        };
        let star = u8::try_from(meas.len()).unwrap_or(u8::MAX);
        let o = Measured {
            dir,
            sigma_rad: sigma_px / camera.focal_length_px * libm::pow(dir[2], 1.5),
            inst_mag: None,
        };
        if meas.push(o).is_err()
            || matches
                .push(Match {
                    star,
                    catalog: m.catalog,
                })
                .is_err()
        {
            break;
        }
    }
    if matches.len() < 3 {
        return Err(attitude::AttitudeError::TooFewStars);
    }
    // The scale is fitted again: the colour terms move stars along the radius, which the
    // uncorrected identification's scale partly absorbed.
    fit(cat, &meas, &matches, sol.scale.value, None)
        .map(|j| j.attitude)
        .ok_or(attitude::AttitudeError::Degenerate)
}
