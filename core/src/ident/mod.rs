//! Star identification: which catalog star each measured star is, lost in space (no prior)
//! or tracking (from a prior attitude several degrees off), with a bounded false-match
//! probability. No allocation: the work lives on the stack (lost in space about 12 KB, 8 KB
//! of it the sorted pairs of one separation window, `IK_CAPACITY`; tracking about 5 KB:
//! the high-water marks `cargo m7-bench` prints).
//!
//! # Lost in space: triangles from the pair database, then statistical verification
//! Measured triangles of the brightest [`IdentConfig::pattern_stars`] stars are tried in the
//! pyramid order (Mortari et al. 2004: indices spread so a false or missing star spoils few
//! triangles). For a triangle (i, j, k), the k-vector gives the catalog pairs whose separation
//! is within [`IdentConfig::pair_tolerance_rad`] of `d_ij`; for each orientation (a, b) the
//! pairs near `d_ik` holding `a` (sorted by star once per triangle) give `c`, and `c` must sit at `d_jk` from `b` (from the
//! catalog directions: no third search) with the same handedness. Each such catalog triangle
//! is a hypothesis: its 3-star attitude is checked against every measured star.
//!
//! Why this rather than 4-star geometric hashing: the pair database (8 bytes a pair, k-vector
//! 4 bytes a bin) is the smallest database that finds a pattern in O(1) per pair, fits
//! internal flash for a 15 degree field, and leaves the decision to the verification below,
//! which counts every star in the field rather than four.
//!
//! # Verification and the false-match bound
//! A hypothesis attitude maps each measured star to the sky; it matches when a catalog star
//! lies within [`IdentConfig::match_radius_rad`]. In rounds (at most `MAX_REFITS`, until
//! the matches stop changing) the attitude is refit from the matches, every star matched
//! again, the attitude refit, and a match whose residual exceeds `TIGHT_SIGMAS` of its own
//! sigma dropped (an attitude pulled by a false star or a wrong neighbour loses it here).
//! If the hypothesis is wrong, each of the `n - 3` non-basis stars
//! matches by chance with probability at most `p = N_max (1 - cos r) / (1 - cos R)`, `N_max`
//! the most catalog stars in any field cone of radius `R` (from the catalog header), `r` the
//! match radius. The chance that a wrong hypothesis matches `m` or more of them is the
//! binomial tail `T(n - 3, m, p)`, and over at most [`IdentConfig::max_hypotheses`]
//! hypotheses the false-match probability is at most `H_max T`. A solution is accepted only
//! when that bound is at most [`IdentConfig::max_false_probability`]; the bound is reported.
//!
//! # Tracking
//! The prior attitude maps each pattern star to the sky; its candidates are the catalog
//! stars within the prior error plus the pair tolerance (a rotation by `theta` moves any
//! direction by at most `theta`), at most `MAX_CANDIDATES` each. Triangles are formed from
//! candidates only and verified as above.
//!
//! Cost: a lost-in-space triangle costs a sort of `2 P_ik` entries and `2 P_ij` binary
//! searches (`P` the pairs in a tolerance window, a few hundred), a hypothesis a 3-star
//! q-method and `n` cone searches; a tracking triangle a few dozen angle checks. On the
//! Cortex-M7 (`cargo m7-bench`, 15 degree fields) lost in space takes about 1.6 M
//! instructions a field (median) and 6.7 M at the 99th percentile, tracking 0.39 M.

use crate::attitude::{self, Attitude, Observation, Quat, angle_between, cross, dot};
use crate::catalog::Catalog;

/// Most measured stars looked at (the brightest; the rest are ignored).
pub const MAX_STARS: usize = 32;
/// Most pattern stars (triangle vertices).
pub(crate) const MAX_PATTERN: usize = 16;
/// Most catalog candidates kept per pattern star in tracking.
pub(crate) const MAX_CANDIDATES: usize = 16;
/// A final match's residual is at most this many of its sigmas (a 2-D Gaussian passes
/// 5 sigma with probability 1 - 4e-6).
pub(crate) const TIGHT_SIGMAS: f64 = 5.0;
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
    /// Most hypotheses verified in one identification (the union bound's count).
    pub max_hypotheses: u32,
}

impl IdentConfig {
    /// Settings for a camera with focal length `focal_length_px` and centroid 1-sigma
    /// `sigma_px`: pair tolerance 6 sigma of a separation (two stars' errors) plus 1 px of
    /// catalog and model error, match radius 5 sigma plus 1 px, 10^-9 false-match bound.
    pub fn for_camera(focal_length_px: f64, sigma_px: f64) -> Self {
        let sep_sigma_px = sigma_px * core::f64::consts::SQRT_2;
        Self {
            pair_tolerance_rad: (6.0 * sep_sigma_px + 1.0) / focal_length_px,
            match_radius_rad: (5.0 * sigma_px + 1.0) / focal_length_px,
            max_false_probability: 1e-9,
            pattern_stars: 12,
            max_hypotheses: 5000,
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

/// Entries of the (star, partner) scratch of one triangle's `d_ik` pairs (8 KB).
pub(crate) const IK_CAPACITY: usize = 2048;

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
        && (3..=MAX_PATTERN).contains(&cfg.pattern_stars);
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

/// Identifies `stars` (brightest first) with no prior.
pub fn lost_in_space(
    cat: &Catalog<'_>,
    stars: &[Measured],
    cfg: &IdentConfig,
) -> Result<Solution, IdentError> {
    let n = check_input(stars, cfg)?;
    let np = n.min(cfg.pattern_stars);
    let tol = cfg.pair_tolerance_rad;
    let max_sep = cat.max_separation_rad();
    let mut scratch = [(0u16, 0u16); IK_CAPACITY];
    let mut hyps = 0u32;
    for (i, j, k) in Triangles::new(np) {
        let (vi, vj, vk) = (dir_of(stars, i), dir_of(stars, j), dir_of(stars, k));
        let (dij, dik, djk) = (
            angle_between(vi, vj),
            angle_between(vi, vk),
            angle_between(vj, vk),
        );
        if dij.max(dik).max(djk) + tol >= max_sep || dij.min(dik).min(djk) < 4.0 * tol {
            continue;
        }
        let hand = handedness(vi, vj, vk, tol * dij.min(dik));
        // The pairs near d_ik as (star, partner) both ways, sorted by star: the partners `c`
        // of a vertex `a` are then a binary search away. A range too long for the scratch
        // (never with the default tolerance) falls back to a scan of the range per `a`.
        let ik_range = cat.pairs_between(dik - tol, dik + tol);
        let fits = 2 * ik_range.len() <= IK_CAPACITY;
        let mut len = 0usize;
        if fits {
            for pk in ik_range.clone() {
                let Some(p) = cat.pair(pk) else { continue };
                for e in [(p.a, p.b), (p.b, p.a)] {
                    if let Some(slot) = scratch.get_mut(len) {
                        *slot = e;
                        len += 1;
                    }
                }
            }
        }
        let by_star = scratch.get_mut(..len).unwrap_or(&mut []);
        by_star.sort_unstable();
        let by_star = &*by_star;
        for pi in cat.pairs_between(dij - tol, dij + tol) {
            let Some(pij) = cat.pair(pi) else { continue };
            for (a, b) in [(pij.a, pij.b), (pij.b, pij.a)] {
                let lo = by_star.partition_point(|e| e.0 < a);
                let hi = by_star.partition_point(|e| e.0 <= a);
                if fits && lo == hi {
                    continue;
                }
                let (Some(ra), Some(rb)) = (cat.dir(a.into()), cat.dir(b.into())) else {
                    continue;
                };
                let sorted = by_star.get(lo..hi).unwrap_or(&[]).iter().map(|e| e.1);
                let scanned = (if fits { 0..0 } else { ik_range.clone() })
                    .filter_map(|pk| cat.pair(pk))
                    .filter_map(|p| {
                        if p.a == a {
                            Some(p.b)
                        } else if p.b == a {
                            Some(p.a)
                        } else {
                            None
                        }
                    });
                for c in sorted.chain(scanned) {
                    let Some(rc) = cat.dir(c.into()) else {
                        continue;
                    };
                    if c == b || (angle_between(rb, rc) - djk).abs() > tol {
                        continue;
                    }
                    if hand != 0 && handedness(ra, rb, rc, 0.0) != hand {
                        continue;
                    }
                    hyps += 1;
                    if let Some(sol) =
                        hypothesis(cat, stars, n, [(i, a), (j, b), (k, c)], cfg, hyps)
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

/// Identifies `stars` (brightest first) near the `prior` attitude, which may be off by up to
/// `prior_error_rad` (any axis).
pub fn track(
    cat: &Catalog<'_>,
    stars: &[Measured],
    prior: Quat,
    prior_error_rad: f64,
    cfg: &IdentConfig,
) -> Result<Solution, IdentError> {
    let n = check_input(stars, cfg)?;
    if !(0.0..0.2).contains(&prior_error_rad) {
        return Err(IdentError::BadInput);
    }
    let prior = prior.normalized().ok_or(IdentError::BadInput)?;
    let np = n.min(cfg.pattern_stars);
    let tol = cfg.pair_tolerance_rad;
    let mut cands: [heapless::Vec<u16, MAX_CANDIDATES>; MAX_PATTERN] =
        core::array::from_fn(|_| heapless::Vec::new());
    for (i, c) in cands.iter_mut().enumerate().take(np) {
        let sky = prior.rotate_inv(dir_of(stars, i));
        for (idx, _) in cat.cone(sky, prior_error_rad + tol) {
            // Past the capacity, the farther candidates are dropped: the triangle is
            // then found from other stars or not at all, never wrongly.
            let _ = c.push(u16::try_from(idx).unwrap_or(u16::MAX));
        }
    }
    let cand = |i: usize| cands.get(i).map_or(&[][..], |c| c.as_slice());
    let mut hyps = 0u32;
    for (i, j, k) in Triangles::new(np) {
        let (vi, vj, vk) = (dir_of(stars, i), dir_of(stars, j), dir_of(stars, k));
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
                if b == a || (angle_between(ra, rb) - dij).abs() > tol {
                    continue;
                }
                for &c in cand(k) {
                    let Some(rc) = cat.dir(c.into()) else {
                        continue;
                    };
                    if c == a
                        || c == b
                        || (angle_between(ra, rc) - dik).abs() > tol
                        || (angle_between(rb, rc) - djk).abs() > tol
                        || (hand != 0 && handedness(ra, rb, rc, 0.0) != hand)
                    {
                        continue;
                    }
                    hyps += 1;
                    if let Some(sol) =
                        hypothesis(cat, stars, n, [(i, a), (j, b), (k, c)], cfg, hyps)
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

/// Probability that `Binomial(n, p)` is at least `m`.
pub(crate) fn binomial_tail(n: usize, m: usize, p: f64) -> f64 {
    if m == 0 {
        return 1.0;
    }
    if m > n || p <= 0.0 {
        return 0.0;
    }
    let p = p.min(1.0);
    // term_j = C(n, j) p^j (1-p)^(n-j), built up from j = 0.
    let mut term = libm::pow(1.0 - p, n as f64);
    let mut tail = 0.0;
    for j in 0..=n {
        if j >= m {
            tail += term;
        }
        if j < n {
            term *= (n - j) as f64 / (j + 1) as f64 * p / (1.0 - p).max(f64::MIN_POSITIVE);
        }
    }
    tail.min(1.0)
}

/// Verifies the triangle `basis` (measured index, catalog index): the solution when its
/// false-match bound passes.
fn hypothesis(
    cat: &Catalog<'_>,
    stars: &[Measured],
    n: usize,
    basis: [(usize, u16); 3],
    cfg: &IdentConfig,
    hyps: u32,
) -> Option<Solution> {
    let mut obs = [Observation {
        camera: [0.0, 0.0, 1.0],
        icrs: [0.0, 0.0, 1.0],
        sigma_rad: 1.0,
    }; 3];
    for (o, &(m, c)) in obs.iter_mut().zip(basis.iter()) {
        o.camera = dir_of(stars, m);
        o.icrs = cat.dir(c.into())?;
    }
    let first = attitude::solve(&obs).ok()?;
    let (mut matches, _) = match_all(cat, stars, n, first.q, cfg.match_radius_rad);
    if matches.len() < MIN_MATCHES {
        return None;
    }
    // Rounds of: refit from the matches, match every star again, refit, and keep only the
    // stars within TIGHT_SIGMAS of their own sigma of that fit (an attitude pulled by a false
    // star or a wrong neighbour loses them here); until the matches stop changing. A
    // triangle's attitude can be off in roll enough that the stars far from it fall outside
    // the match radius, or on a neighbour, until a round brings them in. The largest set
    // seen is kept.
    let mut best: heapless::Vec<Match, MAX_STARS> = heapless::Vec::new();
    for _ in 0..MAX_REFITS {
        let refit = fit(cat, stars, &matches)?;
        let (all, _) = match_all(cat, stars, n, refit.q, cfg.match_radius_rad);
        let refit = fit(cat, stars, &all)?;
        let next = keep_consistent(cat, stars, &all, refit.q);
        let same = next == matches;
        matches = next;
        if matches.len() > best.len() {
            best = matches.clone();
        }
        if same || matches.len() < MIN_MATCHES {
            break;
        }
    }
    let matches = best;
    if matches.len() < MIN_MATCHES {
        return None;
    }
    let false_probability = false_match_bound(cat, n, matches.len(), cfg);
    if false_probability > cfg.max_false_probability {
        return None;
    }
    let attitude = fit(cat, stars, &matches)?;
    Some(Solution {
        attitude,
        matches,
        false_probability,
        hypotheses: hyps,
    })
}

/// `H_max T(n - 3, matched - 3, p)`: the bound in the module documentation.
pub(crate) fn false_match_bound(
    cat: &Catalog<'_>,
    n: usize,
    matched: usize,
    cfg: &IdentConfig,
) -> f64 {
    let cap = 1.0 - libm::cos(cfg.match_radius_rad);
    let field = 1.0 - libm::cos(cat.field_radius_rad());
    let p = (f64::from(cat.max_field_stars()) * cap / field).min(1.0);
    let tail = binomial_tail(n.saturating_sub(3), matched.saturating_sub(3), p);
    (f64::from(cfg.max_hypotheses) * tail).min(1.0)
}

/// Every measured star matched to its nearest catalog star within `radius` under `q` (a
/// catalog star is used once).
fn match_all(
    cat: &Catalog<'_>,
    stars: &[Measured],
    n: usize,
    q: Quat,
    radius: f64,
) -> (heapless::Vec<Match, MAX_STARS>, usize) {
    let mut out = heapless::Vec::new();
    for (m, s) in stars.iter().enumerate().take(n) {
        let sky = q.rotate_inv(s.dir);
        let mut best: Option<(usize, f64)> = None;
        for (idx, v) in cat.cone(sky, radius) {
            let d = dot(sky, v);
            if best.is_none_or(|(_, bd)| d > bd) {
                best = Some((idx, d));
            }
        }
        let Some((idx, _)) = best else { continue };
        let Ok(catalog) = u16::try_from(idx) else {
            continue;
        };
        if out.iter().any(|x: &Match| x.catalog == catalog) {
            continue;
        }
        let _ = out.push(Match {
            star: u8::try_from(m).unwrap_or(u8::MAX),
            catalog,
        });
    }
    let len = out.len();
    (out, len)
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

/// The q-method attitude from the matched stars with their sigmas.
fn fit(cat: &Catalog<'_>, stars: &[Measured], matches: &[Match]) -> Option<Attitude> {
    let mut obs = [Observation {
        camera: [0.0, 0.0, 1.0],
        icrs: [0.0, 0.0, 1.0],
        sigma_rad: 1.0,
    }; MAX_STARS];
    for (o, m) in obs.iter_mut().zip(matches) {
        let s = stars.get(usize::from(m.star))?;
        o.camera = s.dir;
        o.sigma_rad = s.sigma_rad;
        o.icrs = cat.dir(m.catalog.into())?;
    }
    attitude::solve(obs.get(..matches.len())?).ok()
}

/// The attitude of an identification refit from directions corrected for each matched
/// star's colour: the star at `stars_px[m.star]` (column, row) is turned into a direction
/// through `camera` in its catalog B-V ([`Camera::direction_of`](attitude::Camera::direction_of)),
/// so the lateral colour the camera model holds is removed before Wahba's problem is solved.
/// Identification itself runs on uncorrected directions (the colours are not known before
/// it); the colour shifts are a fraction of a pixel, well inside its match radius. A star
/// whose direction the model cannot invert is left out. Cost: one undistortion and one
/// catalog read a match, then the q-method (a few thousand flops).
pub fn colour_corrected(
    cat: &Catalog<'_>,
    camera: &attitude::Camera,
    stars_px: &[[f64; 2]],
    sigma_px: f64,
    sol: &Solution,
) -> Result<Attitude, attitude::AttitudeError> {
    let mut obs: heapless::Vec<Observation, MAX_STARS> = heapless::Vec::new();
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
        let o = Observation {
            camera: dir,
            icrs: s.dir,
            sigma_rad: sigma_px / camera.focal_length_px * libm::pow(dir[2], 1.5),
        };
        if obs.push(o).is_err() {
            break;
        }
    }
    attitude::solve(&obs)
}
