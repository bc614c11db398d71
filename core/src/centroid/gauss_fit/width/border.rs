//! The background the width fit holds, from the window's border: the border's clipped
//! sample variance about the level, how much of the fitted star's wings the border holds,
//! and the level and variance again from the border's residuals to the fitted star. Each is
//! one pass over the border's pixels (the residuals' median sorts at most 4 x 16 of them).

use super::normal::Profiles;
use super::params::M;
use crate::centroid::BackgroundEstimate;
use crate::centroid::math;
use crate::centroid::prepared::Prepared;

/// The fitted star's largest share of a border pixel, e- (flux `n`, the profiles of
/// [`normal`]): the brightest edge column's or row's fraction times the other axis' peak.
pub(super) fn wings_on_border(p: &Prepared<'_>, prof: &Profiles, n: f32) -> f32 {
    let [px, _, _, py, _, _] = prof;
    let (w, h) = (usize::from(p.width), usize::from(p.height));
    let ends = |v: &[f32], len: usize| {
        let a = v.first().copied().unwrap_or(0.0);
        let b = v.get(len.saturating_sub(1)).copied().unwrap_or(0.0);
        a.max(b)
    };
    let peak = |v: &[f32], len: usize| v.iter().take(len).fold(0.0f32, |m, &x| m.max(x));
    n * (ends(px, w) * peak(py, h)).max(ends(py, h) * peak(px, w))
}

/// Calls `each` with `pixel - star` (bits, 1/64 e-) of every usable border pixel, the star of
/// flux `n` on the profiles of [`normal`] (`n` 0: the pixels themselves).
pub(super) fn border_walk<const CLEAN: bool>(
    p: &Prepared<'_>,
    prof: &Profiles,
    n: f32,
    mut each: impl FnMut(i32),
) {
    let [px, _, _, py, _, _] = prof;
    let (w, h) = (p.width, p.height);
    for r in 0..h {
        let fy = py.get(usize::from(r)).copied().unwrap_or(0.0);
        let edge_row = r == 0 || r + 1 == h;
        let step = if edge_row {
            1
        } else {
            w.saturating_sub(1).max(1)
        };
        let mut c = 0u16;
        while c < w {
            let i = usize::from(r) * usize::from(w) + usize::from(c);
            if CLEAN || p.usable(i) {
                let star_bits = if n > 0.0 {
                    let fx = px.get(usize::from(c)).copied().unwrap_or(0.0);
                    (n * fx * fy * 64.0) as i32
                } else {
                    0
                };
                let e = p.pixels.get(i).map_or(0, |e| e.to_bits());
                each(e.saturating_sub(star_bits));
            }
            c += step;
        }
    }
}

/// Border pixels further than this many sigmas (the MAD's) from the level are left out of
/// [`clipped_variance`] (a hot pixel, a cosmic ray): at 4 sigmas a Gaussian loses 0.006 %
/// of its samples and 0.1 % of its variance.
const CLIP_SIGMAS: f32 = 4.0;

/// The background estimate with its variance from the border's sample variance about the
/// held level (`pixel - star` as [`border_walk`]), clipped at [`CLIP_SIGMAS`] of the MAD's
/// sigma (`bg.variance_e2`): the MAD's variance of 16-24 pixels is itself noisy (relative
/// error ~24 % on sigma for 24 pixels, against ~15 % for the sample variance), and at low SNR
/// the position's sigma scales with it (its pulls would run ~7 % high). Unchanged when fewer
/// than 2 pixels pass. With the number of pixels the variance came from.
pub(super) fn clipped_variance<const CLEAN: bool>(
    p: &Prepared<'_>,
    prof: &Profiles,
    n: f32,
    bg: BackgroundEstimate,
) -> (BackgroundEstimate, u16) {
    let clip = CLIP_SIGMAS * math::sqrt(bg.variance_e2) * 64.0;
    let (mut ss, mut k, mut all) = (0.0f32, 0u16, 0u16);
    let level = bg.level_bits;
    border_walk::<CLEAN>(p, prof, n, |b| {
        let d = (i64::from(b) - level) as f32;
        all += 1;
        if d.abs() <= clip {
            ss += d * d;
            k += 1;
        }
    });
    if k < 2 {
        return (bg, all);
    }
    let var = ss / (f32::from(k - 1) * 4096.0);
    let est = BackgroundEstimate {
        variance_e2: var,
        level_variance_e2: var * core::f32::consts::FRAC_PI_2 / f32::from(all.max(1)),
        ..bg
    };
    (est, k)
}

/// The background from the border's residuals to the fitted star (flux `n`, the profiles
/// of [`normal`]): the median of `pixel - star` over the border's usable pixels, the
/// variance as [`clipped_variance`], with its pixel count. `None` for an empty border.
pub(super) fn border_residuals<const CLEAN: bool>(
    p: &Prepared<'_>,
    prof: &Profiles,
    n: f32,
) -> Option<(BackgroundEstimate, u16)> {
    let mut ring = [0i32; 4 * M];
    let mut k = 0usize;
    border_walk::<CLEAN>(p, prof, n, |b| {
        if let Some(slot) = ring.get_mut(k) {
            *slot = b;
            k += 1;
        }
    });
    let bg = crate::centroid::background::median_estimate(ring.get_mut(..k)?)?;
    Some(clipped_variance::<CLEAN>(p, prof, n, bg))
}
