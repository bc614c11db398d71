//! Three-point parabolic peak fit per axis around the brightest pixel.
//!
//! # Formula
//! With `a, b, c` the background-subtracted values left of, at, and right of the brightest
//! pixel (rows likewise for y), the vertex offset from the brightest pixel is
//! ```text
//! d = (a - c) / (2 (a - 2b + c))
//! ```
//! clamped to +-1/2 (the vertex of a concave parabola through a maximum lies within half a
//! pixel of it). It is independent of the background level.
//!
//! # Error estimate
//! First-order propagation: `d(d)/da = (c - b)/D^2`, `d(d)/db = (a - c)/D^2`,
//! `d(d)/dc = (b - a)/D^2` with `D = a - 2b + c`, times each pixel's variance
//! (`max(F, 0) + var_bg`). An axis without a usable fit reports 1/sqrt(12) px (the pixel's
//! own quantisation). Flux and SNR are those of the 3x3 box around the peak.
//!
//! # Cost
//! Per star: a pass over the window for the peak (and the perimeter for the background), then
//! 9 pixels, 2 divides per axis. The cheapest method here.
//!
//! # Where it fails
//! - Biased towards the peak pixel, most for compact stars. Measured RMS over phases (host
//!   test `centroid_quadratic`): 0.156 px at a = 0.5, 0.080 at 1, 0.043 at 1.5, 0.026 at 2,
//!   0.012 at 3.
//! - Wide PSFs: three points see only the flat top, so the random error grows (it uses 3 of
//!   the star's pixels per axis); the error estimate matched the scatter within 7 % at SNR
//!   20..100 (a = 1.5).
//! - Faint stars: the peak pixel may be a noise spike.
//! - A peak on the window border or next to an excluded pixel: that axis keeps the peak
//!   pixel's centre (flags `PEAK_AT_EDGE`, `EXCLUDED_PIXEL`).
//!
//! (The log-parabolic "Gaussian" variant and the Gaussian-windowed IWC centroid were removed:
//! on the Cortex-M7 they sat on the speed/accuracy frontier in no scene; see the README's
//! method list.)

use super::{Background, Centroid, CentroidFlags, CentroidInput, Measured, Prepared, math};

/// Parameters of [`quadratic`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct QuadraticParams {
    /// Background source.
    pub background: Background,
}

/// 1/sqrt(12): the error of a position known only to be inside a pixel.
const PIXEL_SIGMA: f32 = 0.288_675_13;

/// A fitted axis: offset and its standard deviation; `None` when no fit was possible.
fn fit_axis(a: f32, b: f32, c: f32, var: impl Fn(f32) -> f32) -> Option<(f32, f32)> {
    let d = a - 2.0 * b + c;
    if d.is_nan() || d >= 0.0 {
        return None;
    }
    let off = (0.5 * (a - c) / d).clamp(-0.5, 0.5);
    let d2 = d * d;
    let (ga, gb, gc) = ((c - b) / d2, (a - c) / d2, (b - a) / d2);
    let v = ga * ga * var(a) + gb * gb * var(b) + gc * gc * var(c);
    Some((off, math::sqrt(v)))
}

/// The three-point peak fit of `input` (see the module docs).
pub fn quadratic(input: &CentroidInput<'_>, params: &QuadraticParams) -> Centroid {
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return c,
    };
    let Some((pc, pr)) = p.peak() else {
        return p.degenerate(CentroidFlags::empty());
    };
    let Some(b) = p.signal(pc, pr).filter(|b| *b > 0.0) else {
        return p.degenerate(CentroidFlags::empty());
    };
    let mut extra = CentroidFlags::empty();
    let var = |f: f32| p.variance(f);
    let var_level = p.bg.level_variance_e2;
    let mut axis = |left: Option<(u16, u16)>, right: (u16, u16)| {
        let (l, r) = match (left, right) {
            (Some(l), r) if r.0 < p.width && r.1 < p.height => (l, r),
            _ => {
                extra |= CentroidFlags::PEAK_AT_EDGE;
                return (0.0, PIXEL_SIGMA);
            }
        };
        match (p.signal(l.0, l.1), p.signal(r.0, r.1)) {
            (Some(a), Some(c)) => fit_axis(a, b, c, var).unwrap_or((0.0, PIXEL_SIGMA)),
            _ => (0.0, PIXEL_SIGMA),
        }
    };
    let left = pc.checked_sub(1).map(|c| (c, pr));
    let (ox, sx) = axis(left, (pc.saturating_add(1), pr));
    let up = pr.checked_sub(1).map(|r| (pc, r));
    let (oy, sy) = axis(up, (pc, pr.saturating_add(1)));
    // Flux and SNR of the 3x3 box.
    let (bx, _) = p.box_around(pc, pr, 3);
    let (mut flux, mut flux_var, mut n) = (0.0f32, 0.0f32, 0.0f32);
    for (_, _, f) in p.box_pixels(bx) {
        flux += f;
        flux_var += p.variance(f);
        n += 1.0;
    }
    let snr = flux / math::sqrt(flux_var + n * n * var_level).max(f32::MIN_POSITIVE);
    let m = Measured {
        col: f32::from(pc) + ox,
        row: f32::from(pr) + oy,
        flux_e: flux,
        snr,
        sigma_col: sx,
        sigma_row: sy,
    };
    p.finish(m, extra)
}
