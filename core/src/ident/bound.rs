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
//! is at most `alpha s_j`, `s_j = 1 / (2 j (j + 1)) + 1 / (2 H_max)`: a wrong acceptance is
//! some wrong `j`-th hypothesis passing, so its probability is at most
//! `alpha sum_j s_j <= alpha (1/2 + 1/2)`, whatever the order and however many the search
//! tries. A hypothesis early in the search (the true triangle of a field is among its first
//! few dozen in most fields) is held to a level up to 1,250 times looser than the flat
//! `alpha / H_max`, a late one to half of it.
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
//!   `GATE_SIGMAS sqrt(sigma^2 + v)`, `v` its predicted variance per axis. No model error is
//!   added: this count serves a calibrated camera, whose model error is a fraction of the
//!   centroid sigma (`startrack optics fit`); an uncalibrated one falls back on the wide
//!   count. `p` shrinks with the gate squared: at 0.3 px a 4-sigma gate of 1.2 px holds a
//!   quarter of the 2.5 px match radius's area.
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

/// The share of the level spent on the `j`-th hypothesis (from 1) of a search of at most
/// `h_max`: `1 / (2 j (j + 1)) + 1 / (2 h_max)`; the shares of `h_max` hypotheses sum to at
/// most 1.
pub fn level_share(j: u32, h_max: u32) -> f64 {
    let j = f64::from(j.max(1));
    0.5 / (j * (j + 1.0)) + 0.5 / f64::from(h_max.max(1))
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

/// Probability that at least `m` of independent events of probabilities `p` happen (the
/// Poisson binomial's tail, by the recurrence over the events: `len(p)^2 / 2` multiply-adds).
pub(crate) fn poisson_binomial_tail(p: &[f64], m: usize) -> f64 {
    if m == 0 {
        return 1.0;
    }
    if m > p.len() {
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
    let tail: f64 = dist.iter().skip(m).sum();
    tail.clamp(0.0, 1.0)
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
    let local = cat
        .cone(boresight, cat.field_radius_rad() + cfg.match_radius_rad)
        .count();
    // Never above the densest field's count: the bound is at most the densest one.
    let local = (local as f64).min(densest_stars);
    wide(local).min(gated(cat, cfg, h, local))
}

/// The gated count's bound (module documentation) with `field_stars` catalog stars in the
/// field.
fn gated(cat: &Catalog<'_>, cfg: &IdentConfig, h: &Verified<'_>, field_stars: f64) -> f64 {
    let s = h.joint.scale.value;
    let scaled = rescaled(h.stars, h.n, s);
    let q = h.joint.attitude.q;
    let mut p = [0.0f64; MAX_STARS];
    let (mut len, mut counted) = (0usize, 0usize);
    for (i, st) in scaled.iter().enumerate().take(h.n) {
        if h.basis.iter().any(|&(b, _)| b == i) {
            continue;
        }
        let var = st.sigma_rad * st.sigma_rad;
        let ps = predicted_sigma(st.dir, &h.joint.cov, s);
        let v_pred = 0.5 * ps * ps;
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
                    counted +=
                        usize::from(resid <= GATE_SIGMAS * st.sigma_rad * libm::sqrt(1.0 - lev));
                    GATE_SIGMAS * st.sigma_rad / libm::sqrt(1.0 - lev)
                }
            }
            None => GATE_SIGMAS * libm::sqrt(var + v_pred),
        };
        if let Some(x) = p.get_mut(len) {
            *x = gate_probability(field_stars, gate, cat.field_radius_rad());
            len += 1;
        }
    }
    let tail = poisson_binomial_tail(p.get(..len).unwrap_or(&[]), counted);
    reported(tail, h.j, cfg)
}

/// The bound of a field of `n` measured stars, every one matched, in a field holding
/// `field_stars` catalog stars, as the `j`-th hypothesis of the search, each star with the
/// angular sigma `sigma_rad` and no prediction error (the fit's covariance only widens a
/// gate): the smaller of the two counts', as [`false_match_bound`] has it. What a field needs
/// to be solved: the floor of sparse fields.
pub fn bound_with_field_stars(
    cat: &Catalog<'_>,
    cfg: &IdentConfig,
    n: usize,
    field_stars: f64,
    sigma_rad: f64,
    j: u32,
) -> f64 {
    let others = n.saturating_sub(3);
    let wide = gate_probability(field_stars, cfg.match_radius_rad, cat.field_radius_rad());
    let gated = gate_probability(field_stars, GATE_SIGMAS * sigma_rad, cat.field_radius_rad());
    let tail = binomial_tail(others, others, wide).min(binomial_tail(others, others, gated));
    reported(tail, j, cfg)
}
