//! f64 references for the centroid tests: the paper's pixel-integrated Gaussian PSF (eq. 3 and
//! 5), reference centroids (CoG power 1 and 2), the Cramer-Rao bound (from the library,
//! shared with `startrack accuracy`), and a seeded Gaussian noise source.
//!
//! Self-contained (no `libm`): erf/erfc are a Taylor series below |x| = 2.5 and a continued
//! fraction above, both good to ~1e-14, checked in `centroid_math`.

use startrack_core::units::Electrons;

/// Gaussian sigma per unit of the paper's `a` (radius holding 80 % of the signal): sqrt(0.31).
pub fn sigma_of_a(a: f64) -> f64 {
    0.31f64.sqrt() * a
}

/// erf(x) to ~1e-14.
pub fn erf(x: f64) -> f64 {
    if x.abs() < 2.5 {
        // 2/sqrt(pi) sum (-1)^n x^(2n+1) / (n! (2n+1))
        let x2 = x * x;
        let (mut term, mut sum) = (x, x);
        for n in 1..200 {
            term *= -x2 / n as f64;
            let t = term / (2 * n + 1) as f64;
            sum += t;
            if t.abs() < 1e-17 * sum.abs() {
                break;
            }
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    } else {
        x.signum() * (1.0 - erfc(x.abs()))
    }
}

/// erfc(x) to ~1e-14 relative in the tail.
pub fn erfc(x: f64) -> f64 {
    if x < 2.5 {
        return 1.0 - erf(x);
    }
    // erfc(x) = exp(-x^2)/sqrt(pi) / (x + (1/2)/(x + 1/(x + (3/2)/(x + ...))))
    let mut t = x;
    for k in (1..=200).rev() {
        t = x + (k as f64 / 2.0) / t;
    }
    (-x * x).exp() / std::f64::consts::PI.sqrt() / t
}

/// Standard normal CDF.
pub fn norm_cdf(z: f64) -> f64 {
    0.5 * erfc(-z / std::f64::consts::SQRT_2)
}

/// Fraction of a unit-flux 1-D Gaussian (centre `c`, sigma `s`) falling in the pixel centred at
/// integer `i` (eq. 3): Phi((i + 1/2 - c)/s) - Phi((i - 1/2 - c)/s), computed on the side of
/// the tail for precision.
pub fn pixel_frac(i: f64, c: f64, s: f64) -> f64 {
    let (lo, hi) = ((i - 0.5 - c) / s, (i + 0.5 - c) / s);
    if lo > 0.0 {
        norm_cdf(-lo) - norm_cdf(-hi)
    } else {
        norm_cdf(hi) - norm_cdf(lo)
    }
}

/// A star in active-area coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Star {
    pub x: f64,
    pub y: f64,
    /// Gaussian sigma, px.
    pub sigma: f64,
    /// Total signal, e-.
    pub flux: f64,
}

/// Window geometry in active-area pixels.
#[derive(Clone, Copy, Debug)]
pub struct Win {
    pub x0: u16,
    pub y0: u16,
    pub w: u16,
    pub h: u16,
}

impl Win {
    pub fn rect(&self) -> startrack_core::window::Rect {
        startrack_core::window::Rect {
            x0: self.x0,
            y0: self.y0,
            width: self.w,
            height: self.h,
        }
    }

    /// A square of side n whose centre pixel is (cx, cy).
    pub fn centred(cx: u16, cy: u16, n: u16) -> Self {
        Self {
            x0: cx - n / 2,
            y0: cy - n / 2,
            w: n,
            h: n,
        }
    }
}

/// Noise-free pixel means (row-major) of `star` on a flat `background`, e-.
pub fn render(win: Win, star: Star, background: f64) -> Vec<f64> {
    let px: Vec<f64> = (0..win.w)
        .map(|c| pixel_frac(f64::from(win.x0 + c), star.x, star.sigma))
        .collect();
    let py: Vec<f64> = (0..win.h)
        .map(|r| pixel_frac(f64::from(win.y0 + r), star.y, star.sigma))
        .collect();
    py.iter()
        .flat_map(|fy| px.iter().map(move |fx| background + star.flux * fx * fy))
        .collect()
}

pub fn to_electrons(v: &[f64]) -> Vec<Electrons> {
    v.iter()
        .map(|&x| Electrons::from_num(x.clamp(-33_554_431.0, 33_554_431.0)))
        .collect()
}

/// Back to f64 (so references see exactly the quantised values the core sees).
pub fn to_f64(v: &[Electrons]) -> Vec<f64> {
    v.iter().map(|e| e.to_num::<f64>()).collect()
}

/// Index of the brightest value (first on ties), as (col, row).
pub fn peak(v: &[f64], w: u16) -> (u16, u16) {
    let mut best = 0;
    for (i, x) in v.iter().enumerate() {
        if *x > v[best] {
            best = i;
        }
    }
    (
        (best % usize::from(w)) as u16,
        (best / usize::from(w)) as u16,
    )
}

#[allow(clippy::too_many_arguments)]
/// Reference CoG (window-relative) of the box of half-size `half` around `anchor` (clipped),
/// on `v - bg`. Power 2 uses `F^2 - F - var_bg` like the core (noise-unbiased weights);
/// `unbiased = false` gives the plain `F^2` of eq. 6.
pub fn ref_cog(
    v: &[f64],
    w: u16,
    h: u16,
    anchor: (u16, u16),
    half: u16,
    power: u8,
    bg: f64,
    var_bg: f64,
    unbiased: bool,
) -> Option<(f64, f64)> {
    let c0 = anchor.0.saturating_sub(half);
    let c1 = (anchor.0 + half).min(w - 1);
    let r0 = anchor.1.saturating_sub(half);
    let r1 = (anchor.1 + half).min(h - 1);
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for r in r0..=r1 {
        for c in c0..=c1 {
            let f = v[usize::from(r) * usize::from(w) + usize::from(c)] - bg;
            let wt = match (power, unbiased) {
                (1, _) => f,
                (_, true) => f * f - f - var_bg,
                (_, false) => f * f,
            };
            s += wt;
            sx += wt * f64::from(c);
            sy += wt * f64::from(r);
        }
    }
    (s > 0.0).then(|| (sx / s, sy / s))
}

/// Cramer-Rao bound on x for the pixelated Gaussian in `win` (accuracy-theory.md), px: the
/// library's [`startrack_analysis::accuracy::crlb_x_px`] in active-area coordinates.
pub fn crlb_x(win: Win, star: Star, background: f64, read_noise: f64) -> f64 {
    startrack_analysis::accuracy::crlb_x_px(
        win.w,
        win.h,
        star.x - f64::from(win.x0),
        star.y - f64::from(win.y0),
        star.sigma,
        star.flux,
        background,
        read_noise,
    )
}

/// Seeded splitmix64 with Box-Muller normals: deterministic and dependency-free.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// `mean` plus Gaussian noise of variance `max(signal, 0) + var_bg` (shot noise of the star
/// and of the background, read noise), per pixel; `bg` is the background part of `mean`.
pub fn add_noise(mean: &[f64], bg: f64, var_bg: f64, rng: &mut Rng) -> Vec<f64> {
    mean.iter()
        .map(|&m| m + ((m - bg).max(0.0) + var_bg).sqrt() * rng.normal())
        .collect()
}

/// Mean and standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

/// Flux in an n x n box giving `snr` by eq. 8 with per-pixel background variance `var_bg`.
#[allow(unused_imports)]
pub use startrack_analysis::accuracy::flux_for_snr;

// ---------------------------------------------------------------------------------------------
// The two loops every centroid test runs: a noise-free sweep over pixel phases and a seeded
// Monte Carlo under noise, each taking the method under test as a closure.

/// PSF widths (the paper's a, px) the noise-free sweeps cover.
pub const WIDTHS_A: [f64; 7] = [0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0];

/// Pixel phases over the central pixel, avoiding the +-1/2 edges (ties of the peak).
pub fn phases() -> impl Iterator<Item = f64> {
    (0..10).map(|i| -0.45 + 0.1 * f64::from(i))
}

/// A noise-free sweep: a star of width `a` at every pair of [`phases`] around the window's
/// centre pixel, `flux` e- on a flat `background`.
#[derive(Clone, Copy, Debug)]
pub struct Sweep {
    pub win: Win,
    pub flux: f64,
    pub background: f64,
    /// Largest allowed |core - reference|, px.
    pub tol_px: f64,
    /// Flags the core must not set.
    pub forbidden: startrack_core::centroid::CentroidFlags,
}

/// What a sweep measured.
#[derive(Clone, Copy, Debug)]
pub struct SweepResult {
    /// RMS over the phases of the reference's x error against the truth (the method's
    /// systematic error), px.
    pub systematic_rms_px: f64,
    /// Largest |core - reference| in x or y, px.
    pub worst_px: f64,
}

impl Sweep {
    /// Runs `core` on each rendered window and `reference` (window-relative, on the values the
    /// core saw, quantised back to f64, and the star) and asserts they agree within `tol_px`.
    pub fn run(
        &self,
        a: f64,
        label: &str,
        core: impl Fn(startrack_core::window::Window<'_>) -> startrack_core::centroid::Centroid,
        reference: impl Fn(&[f64], &Star) -> (f64, f64),
    ) -> SweepResult {
        let win = self.win;
        let (cx, cy) = (f64::from(win.x0 + win.w / 2), f64::from(win.y0 + win.h / 2));
        let (mut sys_sq, mut n, mut worst) = (0.0, 0.0, 0.0f64);
        for px in phases() {
            for py in phases() {
                let star = Star {
                    x: cx + px,
                    y: cy + py,
                    sigma: sigma_of_a(a),
                    flux: self.flux,
                };
                let e = to_electrons(&render(win, star, self.background));
                let q = to_f64(&e);
                let c = core(startrack_core::window::Window::new(win.rect(), &e).unwrap());
                let (rx, ry) = reference(&q, &star);
                let (rx, ry) = (rx + f64::from(win.x0), ry + f64::from(win.y0));
                let err = (f64::from(c.x_px) - rx)
                    .abs()
                    .max((f64::from(c.y_px) - ry).abs());
                worst = worst.max(err);
                assert!(
                    err < self.tol_px,
                    "{label} a {a} ({px},{py}): core ({}, {}) ref ({rx}, {ry})",
                    c.x_px,
                    c.y_px
                );
                assert!(
                    !c.flags.intersects(self.forbidden),
                    "{label} a {a} ({px},{py}): {c:?}"
                );
                sys_sq += (rx - star.x).powi(2);
                n += 1.0;
            }
        }
        SweepResult {
            systematic_rms_px: (sys_sq / n).sqrt(),
            worst_px: worst,
        }
    }
}

/// A seeded Monte Carlo of one star under Gaussian noise of variance
/// `max(signal, 0) + var_bg` (see [`add_noise`]).
#[derive(Clone, Copy, Debug)]
pub struct MonteCarlo {
    pub win: Win,
    pub star: Star,
    pub background: f64,
    pub var_bg: f64,
    pub trials: usize,
    pub seed: u64,
    /// Results with any of these flags are counted as failed and left out.
    pub fail_flags: startrack_core::centroid::CentroidFlags,
}

/// What a Monte Carlo measured (the results that did not fail).
#[derive(Clone, Debug, Default)]
pub struct McResult {
    /// Estimated x minus the true x, px.
    pub dx: Vec<f64>,
    /// The method's sigma_x, px.
    pub sigma_x: Vec<f64>,
    pub snr: Vec<f64>,
    pub flux: Vec<f64>,
    pub failed: usize,
}

impl McResult {
    /// RMS of the method's own error estimate, px.
    pub fn estimate_rms(&self) -> f64 {
        (self.sigma_x.iter().map(|s| s * s).sum::<f64>() / self.sigma_x.len() as f64).sqrt()
    }
}

impl MonteCarlo {
    /// Runs `method` on `trials` noisy windows; it gets the window and the same pixels as f64
    /// (for references computed on the same data).
    pub fn run(
        &self,
        mut method: impl FnMut(
            startrack_core::window::Window<'_>,
            &[f64],
        ) -> startrack_core::centroid::Centroid,
    ) -> McResult {
        let mean = render(self.win, self.star, self.background);
        let mut rng = Rng::new(self.seed);
        let mut r = McResult::default();
        for _ in 0..self.trials {
            let e = to_electrons(&add_noise(&mean, self.background, self.var_bg, &mut rng));
            let q = to_f64(&e);
            let c = method(
                startrack_core::window::Window::new(self.win.rect(), &e).unwrap(),
                &q,
            );
            if c.flags.intersects(self.fail_flags) {
                r.failed += 1;
                continue;
            }
            r.dx.push(f64::from(c.x_px) - self.star.x);
            r.sigma_x.push(f64::from(c.sigma_x_px));
            r.snr.push(f64::from(c.snr));
            r.flux.push(f64::from(c.flux_e));
        }
        r
    }
}

/// Background (e-/px) and read noise (e-) of the standard noisy scene.
pub const NOISE_BG_E: f64 = 100.0;
pub const NOISE_READ_E: f64 = 5.0;

/// The standard noisy scene: a 9x9 window centred on pixel (100, 100), a star of width `a` at
/// (100 + `offset`), eq. 8 SNR `snr` in a 5x5 box on [`NOISE_BG_E`] with [`NOISE_READ_E`].
pub fn standard_scene(a: f64, snr: f64, offset: (f64, f64)) -> (Win, Star) {
    let var_bg = NOISE_BG_E + NOISE_READ_E * NOISE_READ_E;
    (
        Win::centred(100, 100, 9),
        Star {
            x: 100.0 + offset.0,
            y: 100.0 + offset.1,
            sigma: sigma_of_a(a),
            flux: flux_for_snr(snr, 5.0, var_bg),
        },
    )
}

/// [`MonteCarlo`] on [`standard_scene`].
pub fn standard_monte_carlo(
    a: f64,
    snr: f64,
    offset: (f64, f64),
    seed: u64,
    trials: usize,
    fail_flags: startrack_core::centroid::CentroidFlags,
) -> MonteCarlo {
    let (win, star) = standard_scene(a, snr, offset);
    MonteCarlo {
        win,
        star,
        background: NOISE_BG_E,
        var_bg: NOISE_BG_E + NOISE_READ_E * NOISE_READ_E,
        trials,
        seed,
        fail_flags,
    }
}

/// The border ring of a row-major `w`-wide window, in row-major order.
pub fn border(v: &[f64], w: usize) -> Vec<f64> {
    let h = v.len() / w;
    v.iter()
        .enumerate()
        .filter(|(i, _)| {
            let (c, r) = (i % w, i / w);
            c == 0 || r == 0 || c + 1 == w || r + 1 == h
        })
        .map(|(_, x)| *x)
        .collect()
}
