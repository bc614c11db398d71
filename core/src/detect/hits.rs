//! The particle-hit test: is a measured window's image sharper than the optics can make?
//!
//! Every photon a star sends is spread by the optics' PSF before it reaches the silicon; a
//! proton's charge is made in the silicon and spread only by diffusion, a fraction of a
//! pixel. So a hit is narrower than any star along at least one direction: a point where it
//! crosses the silicon near the normal, a line narrower than a star across its length
//! otherwise. The test compares the brightest interior pixel `p` of the calibrated window
//! (background: the border median) with the mean of its two opposite neighbours along
//! each of the four directions (row, column, two diagonals). For a pixel-integrated
//! Gaussian of 80 % radius `a` the smallest such ratio, over every sub-pixel phase, is that
//! of the star centred on the pixel: `rho(a) = f1 / f0` along a row or column (`f0`, `f1`
//! the fractions a Gaussian puts in its central pixel and the next one, one axis) and
//! `rho(a)^2` along a diagonal; any wider image (a wider Gaussian, a defocused or comatic
//! PSF, a trailed star, a blend) has larger ratios. A window is a hit when along some
//! direction `(n1 + n2) / 2 + K s_n < rho (p - K s_p)`, `rho` that of the narrowest star
//! the optics can make ([`HitLimits`]), `K` = [`HIT_SIGMAS`], `s_n`, `s_p` the noise of the
//! neighbours' mean and of the peak (the border's variance and the shot noise): a star as
//! narrow as that limit is called a hit with a probability of about 3e-5 a direction.
//!
//! What it catches and what it misses, on the SIL's proton model (docs/tracker.md): points
//! and tracks along a row or column at any flux well above the noise; a track along a
//! diagonal only when it is very bright (its perpendicular diagonal ratio limit is `rho^2`):
//! the width-free fit's chi-square flags the bright ones `POOR_FIT`, the rest stay in the
//! list as false stars, which identification tolerates.
//!
//! Cost: the border median and variance (as the fit's background, most of it), a pass over
//! the window for its peak and eight neighbour reads: ~5,300 M7 instructions a 7x7 window
//! (`cargo m7-bench`, `particle_hit_7x7`), 0.16 M a 30-star frame.

use crate::calib::PixelFlags;
use crate::centroid::{Background, CentroidInput, estimate_background};

/// Noise sigmas a hit must clear the limit by.
pub const HIT_SIGMAS: f32 = 4.0;

/// The ratios of the narrowest star image the optics make, from its 80 % radius.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HitLimits {
    /// Along a row or a column: `f1 / f0`.
    pub axis: f32,
    /// Along a diagonal: `(f1 / f0)^2`.
    pub diagonal: f32,
}

impl HitLimits {
    /// The limits of a Gaussian of 80 % radius `min_a_px` (sigma `sqrt(0.31) a`), centred
    /// on a pixel.
    pub fn of_min_a(min_a_px: f32) -> Self {
        let s = libm::sqrtf(0.31) * min_a_px.max(0.05);
        let f0 = crate::centroid::math::pixel_fraction(0.0, 0.0, s);
        let f1 = crate::centroid::math::pixel_fraction(1.0, 0.0, s);
        let axis = if f0 > 0.0 { f1 / f0 } else { 0.0 };
        Self {
            axis,
            diagonal: axis * axis,
        }
    }
}

/// True when the calibrated window of `input` holds an image sharper than `limits` allow
/// (see the module doc); false when it cannot tell (no border background, the peak on the
/// border, an excluded or saturated pixel next to the peak, no positive peak).
pub fn is_particle_hit(input: &CentroidInput<'_>, limits: &HitLimits) -> bool {
    let r = input.window.rect;
    let (w, h) = (usize::from(r.width), usize::from(r.height));
    if w < 3 || h < 3 {
        return false;
    }
    let Some(bg) = estimate_background(input, Background::PerimeterMedian) else {
        return false;
    };
    let level = bg.level_e();
    let var = bg.variance_e2.max(0.0);
    let px = input.window.pixels_e;
    let value = |x: usize, y: usize| -> Option<f32> {
        let i = y * w + x;
        let bad = PixelFlags::SATURATED | PixelFlags::HOT_EXCLUDED | PixelFlags::TELEGRAPH;
        if input.pixel_flags.get(i).is_some_and(|f| f.intersects(bad)) {
            return None;
        }
        px.get(i).map(|e| e.to_num::<f32>() - level)
    };
    let (mut best, mut at) = (f32::MIN, (0, 0));
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if let Some(v) = value(x, y)
                && v > best
            {
                best = v;
                at = (x, y);
            }
        }
    }
    let p = best;
    if p <= 0.0 {
        return false;
    }
    let (x, y) = at;
    let s_p = libm::sqrtf(var + p);
    let pairs = [
        ((x - 1, y), (x + 1, y), limits.axis),
        ((x, y - 1), (x, y + 1), limits.axis),
        ((x - 1, y - 1), (x + 1, y + 1), limits.diagonal),
        ((x + 1, y - 1), (x - 1, y + 1), limits.diagonal),
    ];
    for ((ax, ay), (bx, by), rho) in pairs {
        let (Some(a), Some(b)) = (value(ax, ay), value(bx, by)) else {
            return false;
        };
        let mean = (a + b) / 2.0;
        let s_n = libm::sqrtf((var + mean.max(0.0)) / 2.0);
        if mean + HIT_SIGMAS * s_n < rho * (p - HIT_SIGMAS * s_p) {
            return true;
        }
    }
    false
}
