//! The false-match bound of a hypothesis: an upper bound on the probability that the search
//! accepts a wrong identification, from the stars a hypothesis matched beyond its triangle.
//!
//! # The model
//! Under a wrong hypothesis the sky its attitude puts behind the camera is unrelated to the
//! measured stars: the catalog stars near each non-basis measured star are a random
//! (Poisson) sample of the field's sky, so a gate of radius `g` about where a star is
//! predicted holds a catalog star with probability at most `p = N (1 - cos g) / (1 - cos R)`,
//! `N` the catalog stars in a field cone of radius `R`. The non-basis stars' gates are
//! disjoint patches of that sky, so their matches are independent: the chance that `c` or
//! more of them match is the tail `T` of the Poisson binomial of their `p_i` (a binomial
//! when they are equal).
//!
//! # The hypotheses: a level spent along the search
//! The search tries hypotheses one after the other and stops at the first accepted, after at
//! most `H_max` ([`IdentConfig::max_hypotheses`]). The `j`-th is accepted only when its tail
//! is at most `alpha s_j`, `s_j = 1 / (2 j L) + 1 / (2 H_max)`, `L` an upper bound of the
//! harmonic number `H_{H_max}` (9.1 for 5,000): a wrong acceptance is some wrong `j`-th
//! hypothesis passing, so its probability is at most `alpha sum_j s_j <= alpha`, whatever
//! the order and however many the search tries. The true triangle of a sparse field comes
//! 30th in the median and 100th at the 90th percentile; the 30th is held to a level 9
//! times looser than the flat `alpha / H_max`, the 100th 3.7 times, the last to half of it.
//!
//! # Two counts, each held to half the level
//! - Wide: the matches of the verification, at the match radius
//!   ([`IdentConfig::match_radius_rad`]: 5 sigma plus 1 px of catalog and camera-model
//!   error), `N` the densest field's count from the catalog header, or, when that fails, the
//!   count in the cone the hypothesis's own triangle attitude points at (it depends on the
//!   triangle only, not on the stars it then counts; never above the densest).
//! - Gated: each non-basis star's gate is [`GATE_SIGMAS`] of its leave-one-out prediction
//!   error, the star's own sigma and the fit's covariance together: a star in the fit with
//!   leverage `h` (its predicted variance per axis over its own) has a leave-one-out
//!   residual `r / (1 - h)` of variance `sigma^2 / (1 - h)`, so it counts when its residual
//!   `r <= GATE_SIGMAS sigma sqrt(1 - h)`, and its gate has radius
//!   `GATE_SIGMAS sigma / sqrt(1 - h)`; a star not matched has the gate
//!   `GATE_SIGMAS sqrt(sigma^2 + v)`, `v` its predicted variance per axis. How close a
//!   counted star falls counts too: under a wrong hypothesis a catalog star in a gate is
//!   anywhere in it, so its squared distance over the gate's radius squared, `u`, is
//!   uniform; the outcome is ranked by the count, then by the product `x` of the counted
//!   stars' `u` (each at least [`MIN_CLOSENESS`]), and its tail is
//!   `P(C > c) + P(C = c) F_c(x)`, `F_c(x) = x sum_{s < c} (-ln x)^s / s!` the
//!   distribution of a product of `c` uniforms: never above the count's `P(C >= c)`, and
//!   for three stars at a true star's median residual (1.18 sigma) about 1/40 of it. No
//!   model error is added: this count serves a calibrated camera, whose model error is a
//!   fraction of the centroid sigma (`startrack optics fit`); an uncalibrated one falls
//!   back on the wide count. `p` shrinks with the gate squared: at 0.3 px a 4-sigma gate of 1.2 px holds a
//!   quarter of the 2.5 px match radius's area. It is made only when the hypothesis
//!   explains the field: its matched non-basis stars at least as many as the stars it left
//!   unmatched (`2 m >= n + 3`). The model covers a wrong sky, not a partly right one: a
//!   cluster of true stars with one wrong neighbour, its roll bent, matches its cluster in
//!   tight gates and leaves the rest of the field unmatched (a field of 32 stars with
//!   distortion not in the model, 8 matched, 6.5 mrad off, passed the gated count at
//!   1.8e-10 without this test; the wide count put it at 3.9e-7).
//!
//! The reported bound is `2 T / s_j` of the count that passes (accepted when at most
//! `alpha`, [`IdentConfig::max_false_probability`]). Cost: the densest-field test is a
//! binomial tail (about 30 multiplications); only when it fails, one cone scan of the field
//! (about 1,000 catalog stars), a predicted sigma per star (a 4 x 4 quadratic form) and the
//! Poisson binomial (`n^2 / 2` multiply-adds).

use super::{IdentConfig, Joint, MAX_STARS, Match, Measured, predicted_sigma, rescaled};
use crate::attitude::{Quat, angle_between};
use crate::catalog::Catalog;

/// The two counts (wide, gated), each held to `1 / TIERS` of the level.
const TIERS: f64 = 2.0;

/// The gated count's gate in sigmas of a star's leave-one-out prediction error (a true star
/// misses it with probability `exp(-GATE_SIGMAS^2 / 2)`, 3.4e-4: it is then only not
/// counted).
pub const GATE_SIGMAS: f64 = 4.0;

/// A counted star's squared distance over its gate's radius squared is taken as at least
/// this (a residual of a tenth of its leave-one-out sigma, `(0.1 / GATE_SIGMAS)^2`): a
/// position is not known better than that (the camera model's error is a fraction of the
/// centroid sigma), so no star carries more evidence than one a tenth of a sigma from its
/// prediction. A true star falls closer with probability 0.5 %.
const MIN_CLOSENESS: f64 = 0.1 * 0.1 / (GATE_SIGMAS * GATE_SIGMAS);

/// The share of the level spent on the `j`-th hypothesis (from 1) of a search of at most
/// `h_max`: `1 / (2 j L) + 1 / (2 h_max)`, `L` an upper bound of the harmonic number
/// `H_{h_max}` (9.1 for 5,000); the shares of `h_max` hypotheses sum to at most 1.
pub fn level_share(j: u32, h_max: u32) -> f64 {
    let (j, h) = (f64::from(j.max(1)), f64::from(h_max.max(1)));
    // ln h + Euler's gamma + 1 / (2 h): above the harmonic number H_h = sum 1 / k.
    let harmonic = libm::log(h) + 0.577_215_664_901_532_9 + 0.5 / h;
    0.5 / (j * harmonic) + 0.5 / h
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

/// The tail of the gated count: the probability that independent gates of probabilities
/// `p` (each a catalog star uniformly within it when it holds one) give a count above
/// `counted`, or `counted` with the product of the counted stars' squared distances over
/// their gates' radii squared at most `closeness`: `P(C > c) + P(C = c) F_c(closeness)`,
/// `C` the Poisson binomial of `p` and `F_c(x) = x sum_{s < c} (-ln x)^s / s!` the
/// distribution of a product of `c` uniforms. At most the tail `P(C >= c)` of the count
/// alone (`F_c <= 1`). Cost: `len(p)^2 / 2` multiply-adds and `c` more.
pub(crate) fn counted_tail(p: &[f64], counted: usize, closeness: f64) -> f64 {
    if counted > p.len() {
        return 0.0;
    }
    // dist[c]: the probability of exactly c events among those seen so far.
    let mut dist = [0.0f64; MAX_STARS + 1];
    dist[0] = 1.0;
    for (seen, &pi) in p.iter().take(MAX_STARS).enumerate() {
        let pi = pi.clamp(0.0, 1.0);
        for c in (0..=seen + 1).rev() {
            let stay = dist.get(c).copied().unwrap_or(0.0) * (1.0 - pi);
            let step = if c > 0 {
                dist.get(c - 1).copied().unwrap_or(0.0) * pi
            } else {
                0.0
            };
            if let Some(x) = dist.get_mut(c) {
                *x = stay + step;
            }
        }
    }
    let above: f64 = dist.iter().skip(counted + 1).sum();
    let at = dist.get(counted).copied().unwrap_or(0.0);
    (above + at * product_of_uniforms_cdf(counted, closeness)).clamp(0.0, 1.0)
}

/// `P(U_1 ... U_c <= x)` for `c` independent uniforms on `[0, 1]`: `x sum_{s < c} (-ln
/// x)^s / s!` (1 for `c = 0` or `x >= 1`).
pub(crate) fn product_of_uniforms_cdf(c: usize, x: f64) -> f64 {
    if c == 0 || x >= 1.0 || x.is_nan() {
        return 1.0;
    }
    if x <= 0.0 {
        return 0.0;
    }
    let l = -libm::log(x);
    let (mut term, mut sum) = (1.0f64, 0.0f64);
    for s in 0..c {
        sum += term;
        term *= l / (s + 1) as f64;
    }
    (x * sum).min(1.0)
}

/// The probability that a gate of radius `gate_rad` holds one of `field_stars` catalog stars
/// spread over a field cone of radius `field_radius_rad`.
fn gate_probability(field_stars: f64, gate_rad: f64, field_radius_rad: f64) -> f64 {
    let field = 1.0 - libm::cos(field_radius_rad);
    (field_stars * (1.0 - libm::cos(gate_rad)) / field).clamp(0.0, 1.0)
}

/// The reported bound of a count's tail `tail` for the `j`-th hypothesis.
fn reported(tail: f64, j: u32, cfg: &IdentConfig) -> f64 {
    (TIERS * tail / level_share(j, cfg.max_hypotheses)).min(1.0)
}

/// A hypothesis ready for its bound: the measured stars (`n` of them), its triangle, its
/// matches after verification, their joint fit, its 3-star attitude and its place `j` in
/// the search.
pub(crate) struct Verified<'s> {
    pub stars: &'s [Measured],
    pub n: usize,
    pub basis: [(usize, u16); 3],
    pub matches: &'s [Match],
    pub joint: &'s Joint,
    pub triangle_q: Quat,
    pub j: u32,
}

/// The bound of the module documentation for hypothesis `h`: the smaller of the wide and
/// the gated counts' (each `2 T / s_j`).
pub(crate) fn false_match_bound(cat: &Catalog<'_>, cfg: &IdentConfig, h: &Verified<'_>) -> f64 {
    let non_basis = h.n.saturating_sub(3);
    let wide_matched = h.matches.len().saturating_sub(3);
    let wide = |field_stars: f64| {
        let p = gate_probability(field_stars, cfg.match_radius_rad, cat.field_radius_rad());
        reported(binomial_tail(non_basis, wide_matched, p), h.j, cfg)
    };
    let densest_stars = f64::from(cat.max_field_stars());
    let densest = wide(densest_stars);
    if densest <= cfg.max_false_probability {
        return densest;
    }
    let boresight = h.triangle_q.rotate_inv([0.0, 0.0, 1.0]);
    let mut by_mag = MagHistogram::default();
    for (idx, _) in cat.cone(boresight, cat.field_radius_rad() + cfg.match_radius_rad) {
        by_mag.add(cat.star(idx).map_or(i16::MAX, |s| s.hp_mmag));
    }
    // Never above the densest field's count: the bound is at most the densest one.
    let local = f64::from(by_mag.total).min(densest_stars);
    // The gated count only for a hypothesis that explains the field (module documentation).
    if 2 * h.matches.len() < h.n + 3 {
        return wide(local);
    }
    wide(local).min(gated(cat, cfg, h, local, &by_mag))
}

/// The bound of identities given beforehand ([`super::confirm`]: `matched` of `n` stars kept,
/// `q` the fitted attitude): the wide count held to the flat `alpha / H_max`, `H_max T`,
/// `N` the densest field's count or, when that fails, the count in the field `q` points at
/// (never above the densest). No triangle, no place in a search: the strictest level.
pub(crate) fn given_identities_bound(
    cat: &Catalog<'_>,
    cfg: &IdentConfig,
    n: usize,
    matched: usize,
    q: Quat,
) -> f64 {
    let tail = |field_stars: f64| {
        let p = gate_probability(field_stars, cfg.match_radius_rad, cat.field_radius_rad());
        let t = binomial_tail(n.saturating_sub(3), matched.saturating_sub(3), p);
        (f64::from(cfg.max_hypotheses) * t).min(1.0)
    };
    let densest_stars = f64::from(cat.max_field_stars());
    let densest = tail(densest_stars);
    if densest <= cfg.max_false_probability {
        return densest;
    }
    let boresight = q.rotate_inv([0.0, 0.0, 1.0]);
    let local = cat
        .cone(boresight, cat.field_radius_rad() + cfg.match_radius_rad)
        .count();
    tail((local as f64).min(densest_stars))
}

/// Bins of [`MagHistogram`], 0.1 mag each from Hp -2 (the last holds everything fainter than
/// Hp 10.7).
const MAG_BINS: usize = 128;

/// The catalog stars of a field counted by Hp, 0.1 mag a bin from Hp -2.
struct MagHistogram {
    bins: [u16; MAG_BINS],
    total: u32,
}

impl Default for MagHistogram {
    fn default() -> Self {
        Self {
            bins: [0; MAG_BINS],
            total: 0,
        }
    }
}

impl MagHistogram {
    fn bin(hp_mmag: i32) -> usize {
        usize::try_from((hp_mmag + 2000).div_euclid(100))
            .unwrap_or(0)
            .min(MAG_BINS - 1)
    }

    fn add(&mut self, hp_mmag: i16) {
        if let Some(b) = self.bins.get_mut(Self::bin(i32::from(hp_mmag))) {
            *b = b.saturating_add(1);
        }
        self.total = self.total.saturating_add(1);
    }

    /// The stars in every bin that overlaps `[lo, hi]` mag (so at least those within it).
    fn within(&self, lo_mag: f64, hi_mag: f64) -> u32 {
        let mmag = |m: f64| (m * 1000.0).clamp(-1e6, 1e6) as i32;
        let (a, b) = (Self::bin(mmag(lo_mag)), Self::bin(mmag(hi_mag)));
        self.bins
            .get(a..=b.max(a))
            .map_or(0, |s| s.iter().map(|&x| u32::from(x)).sum())
    }
}

/// The zero point of a triangle `basis` (measured index, catalog index): catalog Hp minus
/// instrumental magnitude, the median of its three stars (the mean of two when one has no
/// magnitude; `None` with fewer).
fn zero_point(cat: &Catalog<'_>, stars: &[Measured], basis: &[(usize, u16); 3]) -> Option<f64> {
    let mut d = [0.0f64; 3];
    let mut k = 0;
    for &(m, c) in basis {
        let (Some(inst), Some(s)) = (stars.get(m).and_then(|s| s.inst_mag), cat.star(c.into()))
        else {
            continue;
        };
        if let Some(x) = d.get_mut(k) {
            *x = f64::from(s.hp_mmag) / 1000.0 - f64::from(inst);
            k += 1;
        }
    }
    match k {
        3 => {
            let [a, b, c] = d;
            Some(a.max(b).min(a.min(b).max(c)))
        }
        2 => Some(0.5 * (d[0] + d[1])),
        _ => None,
    }
}

/// Whether the triangle `basis` agrees in brightness: each of its stars with a magnitude
/// within `tol_mag` of its catalog Hp less the triangle's zero point (the rule the gated
/// count holds every other star to). True when fewer than two magnitudes are known. It
/// reads the triangle only, never the stars a bound counts, so a search may leave the
/// triangles that fail it out of its hypotheses' count. Cost: six catalog reads (kept out
/// of line: the search's inner loop over the catalog pairs stays as lean as without it).
#[inline(never)]
pub(crate) fn triangle_agrees(
    cat: &Catalog<'_>,
    stars: &[Measured],
    basis: &[(usize, u16); 3],
    tol_mag: f64,
) -> bool {
    let Some(zp) = zero_point(cat, stars, basis) else {
        return true;
    };
    basis.iter().all(
        |&(m, c)| match (stars.get(m).and_then(|s| s.inst_mag), cat.star(c.into())) {
            (Some(inst), Some(s)) => {
                (f64::from(s.hp_mmag) / 1000.0 - f64::from(inst) - zp).abs() <= tol_mag
            }
            _ => true,
        },
    )
}

/// The gated count's bound (module documentation) with `field_stars` catalog stars in the
/// field.
fn gated(
    cat: &Catalog<'_>,
    cfg: &IdentConfig,
    h: &Verified<'_>,
    field_stars: f64,
    by_mag: &MagHistogram,
) -> f64 {
    let zp = zero_point(cat, h.stars, &h.basis);
    let tol = cfg.photometric_tolerance_mag;
    let s = h.joint.scale.value;
    let scaled = rescaled(h.stars, h.n, s);
    let q = h.joint.attitude.q;
    let mut p = [0.0f64; MAX_STARS];
    let (mut len, mut counted, mut closeness) = (0usize, 0usize, 1.0f64);
    for (i, st) in scaled.iter().enumerate().take(h.n) {
        if h.basis.iter().any(|&(b, _)| b == i) {
            continue;
        }
        let var = st.sigma_rad * st.sigma_rad;
        let ps = predicted_sigma(st.dir, &h.joint.cov, s);
        let v_pred = 0.5 * ps * ps;
        // The catalog Hp the star's brightness predicts, when both are known: only the
        // field's stars that agree with it can match.
        let predicted_hp = zp.zip(st.inst_mag).map(|(z, m)| z + f64::from(m));
        let agreeing = predicted_hp.map_or(field_stars, |c| {
            f64::from(by_mag.within(c - tol, c + tol).max(1)).min(field_stars)
        });
        let agrees = |catalog: u16| {
            predicted_hp.is_none_or(|c| {
                cat.star(catalog.into())
                    .is_some_and(|x| (f64::from(x.hp_mmag) / 1000.0 - c).abs() <= tol)
            })
        };
        let matched = h.matches.iter().find(|m| usize::from(m.star) == i);
        let gate = match matched {
            Some(m) => {
                let lev = v_pred / var;
                if lev >= super::LEVERAGE_MAX {
                    // Followed by the fit, not checked by it: certain to match, not counted.
                    1.0
                } else {
                    let resid = cat
                        .dir(m.catalog.into())
                        .map_or(f64::INFINITY, |r| angle_between(q.rotate(r), st.dir));
                    let gate = GATE_SIGMAS * st.sigma_rad / libm::sqrt(1.0 - lev);
                    // The leave-one-out residual `r / (1 - h)` over the gate, squared.
                    let v = (resid / (1.0 - lev) / gate) * (resid / (1.0 - lev) / gate);
                    if v <= 1.0 && agrees(m.catalog) {
                        counted += 1;
                        closeness *= v.max(MIN_CLOSENESS);
                    }
                    gate
                }
            }
            None => GATE_SIGMAS * libm::sqrt(var + v_pred),
        };
        if let Some(x) = p.get_mut(len) {
            *x = gate_probability(agreeing, gate, cat.field_radius_rad());
            len += 1;
        }
    }
    let tail = counted_tail(p.get(..len).unwrap_or(&[]), counted, closeness);
    reported(tail, h.j, cfg)
}

/// The bound of a field of `n` measured stars, every one matched, in a field holding
/// `field_stars` catalog stars, as the `j`-th hypothesis of the search, each star with the
/// angular sigma `sigma_rad`, no prediction error (the fit's covariance only widens a
/// gate) and its residual the median of a true star's (1.18 of its sigmas: a squared
/// distance of `2 ln 2` sigma^2): the smaller of the two counts', as the search's bound has
/// it. What a field needs to be solved: the floor of sparse fields.
pub fn bound_with_field_stars(
    cat: &Catalog<'_>,
    cfg: &IdentConfig,
    n: usize,
    field_stars: f64,
    sigma_rad: f64,
    j: u32,
) -> f64 {
    let others = n.saturating_sub(3).min(MAX_STARS);
    let wide = gate_probability(field_stars, cfg.match_radius_rad, cat.field_radius_rad());
    let gated = gate_probability(field_stars, GATE_SIGMAS * sigma_rad, cat.field_radius_rad());
    let median_closeness = 2.0 * core::f64::consts::LN_2 / (GATE_SIGMAS * GATE_SIGMAS);
    let closeness = libm::pow(median_closeness, others as f64);
    let gates = [gated; MAX_STARS];
    let gated_tail = counted_tail(gates.get(..others).unwrap_or(&[]), others, closeness);
    let tail = binomial_tail(others, others, wide).min(gated_tail);
    reported(tail, j, cfg)
}

#[cfg(test)]
mod tests {
    use super::{counted_tail, product_of_uniforms_cdf};

    /// A uniform on [0, 1) from a 64-bit LCG (Knuth's MMIX constants).
    fn uniform(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The tail of the gated count against a simulation of its null: each gate holds a
    /// star with its probability, uniformly over its area (the squared distance over the
    /// radius squared uniform), and the outcome is as extreme when the count is larger, or
    /// equal with a product of squared distances no larger. Within 4 binomial sigmas.
    #[test]
    fn the_gated_tail_is_its_null_distribution() {
        let p = [0.3, 0.1, 0.5, 0.05];
        let mut state = 7u64;
        for (counted, closeness) in [(1, 0.2), (2, 0.05), (2, 1.0), (3, 0.01), (0, 1.0)] {
            let want = counted_tail(&p, counted, closeness);
            let trials = 400_000;
            let mut hits = 0u32;
            for _ in 0..trials {
                let (mut c, mut x) = (0usize, 1.0f64);
                for &pi in &p {
                    if uniform(&mut state) < pi {
                        c += 1;
                        x *= uniform(&mut state);
                    }
                }
                hits += u32::from(c > counted || (c == counted && x <= closeness));
            }
            let got = f64::from(hits) / f64::from(trials);
            let sigma = (want * (1.0 - want) / f64::from(trials)).sqrt();
            assert!(
                (got - want).abs() <= 4.0 * sigma + 1e-12,
                "{counted} {closeness}: {got} against {want}"
            );
        }
    }

    /// The product of uniforms' distribution in closed form at two and one, and never above
    /// the count alone.
    #[test]
    fn the_product_of_uniforms_has_its_closed_form() {
        for x in [1e-12, 1e-3, 0.2, 0.9] {
            let f2 = x * (1.0 - libm::log(x));
            assert!((product_of_uniforms_cdf(2, x) - f2).abs() < 1e-15 + 1e-12 * f2);
            assert_eq!(product_of_uniforms_cdf(1, x), x);
            assert!(counted_tail(&[1e-4; 5], 3, x) <= counted_tail(&[1e-4; 5], 3, 1.0));
        }
        assert_eq!(product_of_uniforms_cdf(0, 0.1), 1.0);
        assert_eq!(product_of_uniforms_cdf(3, 0.0), 0.0);
    }
}
