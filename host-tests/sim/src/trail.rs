//! Trailed stars: a star that moves in a straight line during the exposure, its window
//! integrated along the path, with Poisson and read noise, and the Cramer-Rao bound of its
//! position.
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

/// The mean signal of each pixel of a `width` x `height` window (row-major, e-), star plus a
/// flat `background_e`.
pub fn mean_window(width: usize, height: usize, star: &TrailedStar, background_e: f64) -> Vec<f64> {
    let l = star.trail_dx_px.hypot(star.trail_dy_px);
    let k = ((l / PATH_STEP_PX).ceil() as usize).max(1);
    let mut out = vec![0.0; width * height];
    let (mut fx, mut fy) = (vec![0.0; width], vec![0.0; height]);
    let per_step = star.flux_e / k as f64;
    for step in 0..k {
        let t = (step as f64 + 0.5) / k as f64 - 0.5;
        let (cx, cy) = (
            star.x_px + t * star.trail_dx_px,
            star.y_px + t * star.trail_dy_px,
        );
        for (i, f) in fx.iter_mut().enumerate() {
            *f = pixel_frac(i, cx, star.psf_sigma_px);
        }
        for (j, f) in fy.iter_mut().enumerate() {
            *f = pixel_frac(j, cy, star.psf_sigma_px);
        }
        for (row, &gy) in out.chunks_exact_mut(width).zip(fy.iter()) {
            for (o, &gx) in row.iter_mut().zip(fx.iter()) {
                *o += per_step * gx * gy;
            }
        }
    }
    for o in &mut out {
        *o += background_e;
    }
    out
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
