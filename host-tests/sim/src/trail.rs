//! Trailed stars: a star that moves in a straight line during the exposure, its window
//! integrated along the path, with Poisson and read noise, and the Cramer-Rao bound of its
//! position; and [`TrailedImage`], the same integration along any sampled path (a roll's
//! curved trail, a slew's accelerating one) on the sensor's active area, for the simulator.
//!
//! # Model
//! The star's PSF is a Gaussian of sigma `psf_sigma_px`, pixel-integrated exactly
//! (`Phi` differences per axis, paper eq. 3 and 5, `libm::erf` in f64). During the exposure
//! its centre moves uniformly from `mid - t/2` to `mid + t/2` (`t` the trail vector, px); the
//! mean of each pixel is the average of the pixel-integrated PSF over the path, by the
//! midpoint rule on `K = ceil(L / 0.02 px)` sub-steps (at least one). The rule's error on a
//! pixel is `h^2 / 24` of its second derivative along the path (`h <= 0.02 px`): below 2e-5
//! of the peak pixel for `sigma >= 0.5 px`, a position error far below 0.01 px (the
//! noise-free test `centroid_trail_fit` measures the fit's total model error against it).
//! Each pixel then gets `Poisson(mean)` electrons plus `Normal(0, read_noise)` read noise
//! from a seeded ChaCha8 stream: a window's noise is a function of (seed, star index) alone.
//!
//! # Bound
//! [`crlb`]: the Fisher information of the mean model for Poisson + read noise (variance
//! `mu + r^2`, the accuracy theory's form), `F = sum_k d mu_k/d theta d mu_k/d theta^T / v_k`
//! over the window, with the derivatives by central differences of the exact model (step
//! 1e-4 px and 1e-4 relative in the flux), over `(x, y, N)` or `(x, y, N, B)`; the bound is
//! the diagonal of `F^-1`, and along and across the trail its rotation.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};

/// Largest midpoint-rule step along the path, px.
pub const PATH_STEP_PX: f64 = 0.02;

/// A trailed star on a window (window-relative coordinates: pixel centres at integers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrailedStar {
    /// Column of the star at mid-exposure, px.
    pub x_px: f64,
    /// Row of the star at mid-exposure, px.
    pub y_px: f64,
    /// Total signal over the exposure, e-.
    pub flux_e: f64,
    /// Column displacement from exposure start to end, px.
    pub trail_dx_px: f64,
    /// Row displacement from exposure start to end, px.
    pub trail_dy_px: f64,
    /// Gaussian PSF sigma at rest, px.
    pub psf_sigma_px: f64,
}

fn norm_cdf(z: f64) -> f64 {
    0.5 * (1.0 + libm::erf(z * core::f64::consts::FRAC_1_SQRT_2))
}

/// Pixel `i`'s fraction of a unit Gaussian of sigma `s` centred at `c`.
fn pixel_frac(i: usize, c: f64, s: f64) -> f64 {
    let i = i as f64;
    let (hi, lo) = ((i + 0.5 - c) / s, (i - 0.5 - c) / s);
    // The tail side, so no two numbers near 1 are subtracted.
    if lo > 0.0 {
        norm_cdf(-lo) - norm_cdf(-hi)
    } else {
        norm_cdf(hi) - norm_cdf(lo)
    }
}

/// Adds `per_step_e` times the pixel-integrated Gaussian of sigma `sigma_px` centred at each
/// of `centres` to the patch `out` (row-major, `width` columns) whose pixel (0, 0) is the
/// pixel centred at `origin`: the midpoint rule along a path, one separable product per
/// step.
fn accumulate_path(
    out: &mut [f64],
    width: usize,
    origin: (f64, f64),
    centres: impl Iterator<Item = (f64, f64)>,
    per_step_e: f64,
    sigma_px: f64,
) {
    let height = out.len() / width.max(1);
    let (mut fx, mut fy) = (vec![0.0; width], vec![0.0; height]);
    for (cx, cy) in centres {
        for (i, f) in fx.iter_mut().enumerate() {
            *f = pixel_frac(i, cx - origin.0, sigma_px);
        }
        for (j, f) in fy.iter_mut().enumerate() {
            *f = pixel_frac(j, cy - origin.1, sigma_px);
        }
        for (row, &gy) in out.chunks_exact_mut(width).zip(fy.iter()) {
            for (o, &gx) in row.iter_mut().zip(fx.iter()) {
                *o += per_step_e * gx * gy;
            }
        }
    }
}

/// The mean signal of each pixel of a `width` x `height` window (row-major, e-), star plus a
/// flat `background_e`.
pub fn mean_window(width: usize, height: usize, star: &TrailedStar, background_e: f64) -> Vec<f64> {
    let l = star.trail_dx_px.hypot(star.trail_dy_px);
    let k = ((l / PATH_STEP_PX).ceil() as usize).max(1);
    let mut out = vec![0.0; width * height];
    let centres = (0..k).map(|step| {
        let t = (step as f64 + 0.5) / k as f64 - 0.5;
        (
            star.x_px + t * star.trail_dx_px,
            star.y_px + t * star.trail_dy_px,
        )
    });
    accumulate_path(
        &mut out,
        width,
        (0.0, 0.0),
        centres,
        star.flux_e / k as f64,
        star.psf_sigma_px,
    );
    for o in &mut out {
        *o += background_e;
    }
    out
}

/// Sub-steps of a path of `length_px` at [`PATH_STEP_PX`] (at least one).
pub fn path_steps(length_px: f64) -> usize {
    if length_px.is_finite() && length_px > 0.0 {
        ((length_px / PATH_STEP_PX).ceil() as usize).max(1)
    } else {
        1
    }
}

/// A star's mean image over an exposure along any path (straight, curved, accelerating), on
/// the patch of active-area pixels it reaches: what the simulated sensor adds for a star
/// that moves during the exposure ([`crate::sim::Simulator::trails`]).
///
/// Built from the star's centre at the midpoints of equal time steps (each step carries an
/// equal share of the signal: the midpoint rule in time, as [`mean_window`] is in path
/// length for a uniform motion). The patch spans the path's extent plus `8 sigma + 1` px each
/// side (the still star's reach in the simulator), clipped to the active area. Cost: per step
/// `width + height` erf differences and `width x height` products.
#[derive(Clone, Debug, PartialEq)]
pub struct TrailedImage {
    /// Active column of the patch's first pixel.
    pub x0: usize,
    /// Active row of the patch's first pixel.
    pub y0: usize,
    /// Patch columns.
    pub width: usize,
    /// Patch rows.
    pub height: usize,
    /// Mean star electrons of each patch pixel, row-major, before the flat.
    pub mean_e: Vec<f64>,
}

impl TrailedImage {
    /// The image of `flux_e` electrons spread evenly over the centres `path_px` (px, active
    /// area, one per equal time step), PSF sigma `psf_sigma_px`, on an active area of
    /// `active` columns and rows. `None` when the path is empty, not finite, or reaches no
    /// active pixel.
    pub fn along(
        path_px: &[[f64; 2]],
        flux_e: f64,
        psf_sigma_px: f64,
        active: [usize; 2],
    ) -> Option<Self> {
        if path_px.is_empty()
            || !(flux_e.is_finite() && psf_sigma_px.is_finite() && psf_sigma_px > 0.0)
            || path_px.iter().flatten().any(|c| !c.is_finite())
        {
            return None;
        }
        let reach = 8.0 * psf_sigma_px + 1.0;
        let lo = |a: usize| path_px.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min);
        let hi = |a: usize| {
            path_px
                .iter()
                .map(|p| p[a])
                .fold(f64::NEG_INFINITY, f64::max)
        };
        let span = |a: usize| -> Option<(usize, usize)> {
            let first = (lo(a) - reach).ceil().max(0.0);
            let last = (hi(a) + reach).floor().min(active[a] as f64 - 1.0);
            (last >= first).then(|| (first as usize, (last - first) as usize + 1))
        };
        let ((x0, width), (y0, height)) = (span(0)?, span(1)?);
        let mut mean_e = vec![0.0; width * height];
        accumulate_path(
            &mut mean_e,
            width,
            (x0 as f64, y0 as f64),
            path_px.iter().map(|p| (p[0], p[1])),
            flux_e / path_px.len() as f64,
            psf_sigma_px,
        );
        Some(Self {
            x0,
            y0,
            width,
            height,
            mean_e,
        })
    }

    /// The mean star electrons of active pixel (`x`, `y`) (0 off the patch).
    pub fn at(&self, x: usize, y: usize) -> f64 {
        match (x.checked_sub(self.x0), y.checked_sub(self.y0)) {
            (Some(i), Some(j)) if i < self.width && j < self.height => {
                self.mean_e.get(j * self.width + i).copied().unwrap_or(0.0)
            }
            _ => 0.0,
        }
    }

    /// The total signal on the patch, e- (the star's flux less what falls off the active
    /// area or beyond the reach).
    pub fn total_e(&self) -> f64 {
        self.mean_e.iter().sum()
    }
}

/// One noisy realisation of `mean` (e-): Poisson photons and dark plus Gaussian read noise of
/// `read_noise_e`, from the ChaCha8 stream `(seed, index)`.
pub fn noisy_window(mean: &[f64], read_noise_e: f64, seed: u64, index: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index);
    let read = Normal::new(0.0, read_noise_e.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).unwrap());
    mean.iter()
        .map(|&m| {
            let photons = if m > 0.0 {
                Poisson::new(m).map(|p| p.sample(&mut rng)).unwrap_or(m)
            } else {
                0.0
            };
            photons + read.sample(&mut rng)
        })
        .collect()
}

/// The Cramer-Rao bound of a trailed star's position (see the module docs), px.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrailBound {
    /// Column.
    pub sigma_x_px: f64,
    /// Row.
    pub sigma_y_px: f64,
    /// Along the trail (the column for a point).
    pub sigma_along_px: f64,
    /// Across the trail.
    pub sigma_across_px: f64,
}

/// The bound for `star` on a `width` x `height` window with a flat background and read
/// noise, the background known (`fit_background` false) or a free parameter.
pub fn crlb(
    width: usize,
    height: usize,
    star: &TrailedStar,
    background_e: f64,
    read_noise_e: f64,
    fit_background: bool,
) -> TrailBound {
    let n = if fit_background { 4 } else { 3 };
    let mu = mean_window(width, height, star, background_e);
    let h = 1e-4;
    let shifted = |i: usize, sign: f64| -> Vec<f64> {
        let mut s = *star;
        let mut bg = background_e;
        match i {
            0 => s.x_px += sign * h,
            1 => s.y_px += sign * h,
            2 => s.flux_e *= 1.0 + sign * h,
            _ => bg += sign * h,
        }
        mean_window(width, height, &s, bg)
    };
    let scale = [h, h, h * star.flux_e, h];
    let derivs: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let (p, m) = (shifted(i, 1.0), shifted(i, -1.0));
            p.iter()
                .zip(&m)
                .map(|(a, b)| (a - b) / (2.0 * scale[i]))
                .collect()
        })
        .collect();
    let mut f = [[0.0f64; 4]; 4];
    for (k, m) in mu.iter().enumerate() {
        let v = m.max(0.0) + read_noise_e * read_noise_e;
        for i in 0..n {
            for j in 0..n {
                f[i][j] += derivs[i][k] * derivs[j][k] / v;
            }
        }
    }
    let cov = invert(&f, n);
    let l = star.trail_dx_px.hypot(star.trail_dy_px);
    let (ex, ey) = if l > 0.0 {
        (star.trail_dx_px / l, star.trail_dy_px / l)
    } else {
        (1.0, 0.0)
    };
    let along = ex * ex * cov[0][0] + 2.0 * ex * ey * cov[0][1] + ey * ey * cov[1][1];
    let across = ey * ey * cov[0][0] - 2.0 * ex * ey * cov[0][1] + ex * ex * cov[1][1];
    TrailBound {
        sigma_x_px: cov[0][0].sqrt(),
        sigma_y_px: cov[1][1].sqrt(),
        sigma_along_px: along.sqrt(),
        sigma_across_px: across.sqrt(),
    }
}

/// The inverse of the leading `n` x `n` block of `a` by Gauss-Jordan with partial pivoting
/// (NaN where singular).
fn invert(a: &[[f64; 4]; 4], n: usize) -> [[f64; 4]; 4] {
    let mut m = *a;
    let mut inv = [[0.0f64; 4]; 4];
    for (i, r) in inv.iter_mut().enumerate().take(n) {
        r[i] = 1.0;
    }
    for c in 0..n {
        let p = (c..n)
            .max_by(|&i, &j| m[i][c].abs().total_cmp(&m[j][c].abs()))
            .unwrap_or(c);
        m.swap(c, p);
        inv.swap(c, p);
        let d = m[c][c];
        if d == 0.0 {
            return [[f64::NAN; 4]; 4];
        }
        for j in 0..n {
            m[c][j] /= d;
            inv[c][j] /= d;
        }
        for i in 0..n {
            if i != c {
                let k = m[i][c];
                for j in 0..n {
                    m[i][j] -= k * m[c][j];
                    inv[i][j] -= k * inv[c][j];
                }
            }
        }
    }
    inv
}
