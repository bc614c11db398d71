//! How close each centroid method of the core comes to the Cramer-Rao bound: a seeded Monte
//! Carlo of simulated stars against their true positions, and the bound itself.
//!
//! # The experiment
//! For a PSF width `a` and an SNR (paper eq. 8 in a 5x5 box, background `bg_e` e-/px and read
//! noise `read_e`): `trials` stars at true positions uniform over a pixel (both axes),
//! pixel-integrated Gaussian means (paper eq. 3 and 5, [`startrack_sim::sim::psf`]), Poisson photon
//! noise on star plus background and Gaussian read noise (as the simulator draws them). Each
//! method sees the same stars (one seed per `(a, SNR)`), in its own window centred on the
//! star's pixel, with the background given (level and variance: the detector's estimate), and
//! its result is compared with the truth:
//! - `rms_px`: RMS of the error over both axes (bias and noise);
//! - `crlb_px`: RMS over the same stars of the bound on a 9x9 window
//!   (accuracy-theory.md; larger windows add nothing at a <= 2 px), so `rms / crlb` is 1 for
//!   an efficient unbiased estimator;
//! - `scatter_px`: RMS of the estimate minus the same method on the noise-free image of the
//!   same star (the random part alone), against `sigma_est_px`, the RMS of the method's own
//!   error estimate (`sigma_x`, `sigma_y`);
//! - `failures`: results flagged degenerate or not converged, left out of the statistics.
//!
//! # Tolerances from the trial count
//! With `2 N` (x and y) near-Gaussian errors, an RMS has a relative standard error of about
//! `1 / sqrt(4 N)` ([`rms_relative_se`]): 1.1 % for N = 2000. The tests add 3.5 of these to
//! their bounds.
//!
//! Cost: a cell is `trials` x 2 method runs plus the bound; the default table runs every
//! method of [`Method::all`] at 4 widths and 3 SNRs with 2000 trials, a few seconds of CPU in
//! release (`time startrack accuracy` measures it).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};
use startrack_core::centroid::cog::{
    Anchor, CogParams, cog, sigma_unreliable as cog_sigma_unreliable,
};
use startrack_core::centroid::gauss_fit::{
    GaussFitParams, WidthFitParams, WidthPrior, gauss_fit, gauss_fit_width, gauss_fit_width_prior,
};
use startrack_core::centroid::{Background, Centroid, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::{PixCorr, PixCorrBackground};
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::pixcorr::{CurveSpec, build_curve};
use startrack_sim::sim::psf::{pixel_fraction, sigma_of_a};
use std::fmt::Write as _;

/// A centroid method and its window.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// Centre of gravity in an `n x n` box around the peak (window `n + 2`).
    Cog {
        /// Weights.
        power: CogPower,
        /// Box side.
        box_side: u8,
        /// With the pixel-phase correction for the star's `a`.
        corrected: bool,
    },
    /// Pixel-integrated Gaussian fit, PSF sigma known, on an `n x n` window.
    GaussFit {
        /// Window side.
        window: u8,
    },
    /// Pixel-integrated Gaussian fit of an assumed PSF width `a_px` whatever the star's
    /// (what a fixed-width configuration does on a field of mixed widths), `n x n` window.
    GaussFitAssumed {
        /// Window side.
        window: u8,
        /// The assumed 80 %-energy radius, px.
        a_px: f64,
    },
    /// The width-free Gaussian fit as the tracker's flight configuration runs it (PSF width
    /// not told, background the window border's median, held; start box `min(n - 2, 5)`).
    GaussFitWidth {
        /// Window side.
        window: u8,
    },
    /// The flight configuration's fit with a field PSF model in the table
    /// ([`gauss_fit_width_prior`]): each star's model width is its true `a` plus a seeded
    /// normal error of RMS `scatter_a_px` (a model as good as its stated scatter), the prior
    /// `N(a_model, scatter_a_px)`; otherwise as [`Method::GaussFitWidth`].
    GaussFitWidthModel {
        /// Window side.
        window: u8,
        /// The model's RMS scatter (and the error drawn), px.
        scatter_a_px: f64,
    },
}

impl Method {
    /// Every method of the table: CoG power 1 and 2 in 3/5/7 boxes, plain and corrected,
    /// the Gauss fit on 5x5 and 7x7.
    pub fn all() -> Vec<Method> {
        let mut v = Vec::new();
        for corrected in [false, true] {
            for power in [CogPower::One, CogPower::Two] {
                for box_side in [3, 5, 7] {
                    v.push(Method::Cog {
                        power,
                        box_side,
                        corrected,
                    });
                }
            }
        }
        v.push(Method::GaussFit { window: 5 });
        v.push(Method::GaussFit { window: 7 });
        v
    }

    /// A short name, e.g. `cog2 5x5 corrected`.
    pub fn name(&self) -> String {
        match self {
            Method::Cog {
                power,
                box_side,
                corrected,
            } => format!(
                "cog{} {box_side}x{box_side}{}",
                if *power == CogPower::One { 1 } else { 2 },
                if *corrected { " corrected" } else { "" }
            ),
            Method::GaussFit { window } => format!("gauss fit {window}x{window}"),
            Method::GaussFitAssumed { window, a_px } => {
                format!("gauss fit {window}x{window} a {a_px} assumed")
            }
            Method::GaussFitWidth { window } => format!("gauss fit width-free {window}x{window}"),
            Method::GaussFitWidthModel {
                window,
                scatter_a_px,
            } => format!(
                "gauss fit width-free {window}x{window} + field model (scatter {scatter_a_px})"
            ),
        }
    }

    /// The window side the method is given.
    pub fn window_side(&self) -> u16 {
        match self {
            Method::Cog { box_side, .. } => u16::from(*box_side) + 2,
            Method::GaussFit { window }
            | Method::GaussFitAssumed { window, .. }
            | Method::GaussFitWidth { window }
            | Method::GaussFitWidthModel { window, .. } => u16::from(*window),
        }
    }
}

/// The noise and the number of trials of one experiment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    /// Background (sky and dark), e- per pixel, Poisson.
    pub background_e: f64,
    /// Read noise, e- RMS.
    pub read_noise_e: f64,
    /// Stars per cell.
    pub trials: usize,
    /// Seed of the whole experiment.
    pub seed: u64,
}

impl Default for Noise {
    /// 100 e- of background, 5 e- read noise, 2000 trials, seed 1.
    fn default() -> Self {
        Self {
            background_e: 100.0,
            read_noise_e: 5.0,
            trials: 2000,
            seed: 1,
        }
    }
}

/// One method at one `(a, SNR)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Cell {
    /// The method.
    pub method: Method,
    /// PSF 80 %-energy radius, px.
    pub a_px: f64,
    /// Eq. 8 SNR in a 5x5 box.
    pub snr: f64,
    /// RMS error against the truth, px.
    pub rms_px: f64,
    /// RMS Cramer-Rao bound over the same stars, px.
    pub crlb_px: f64,
    /// RMS over the same stars of the bound for what the method knows of the width: unknown
    /// for the width-free fit ([`crlb_x_width_free_px`]), known to the model's scatter for
    /// the model fit ([`crlb_x_prior_px`]); NaN for the other methods, px.
    pub crlb_width_free_px: f64,
    /// RMS of the noise part of the error, px.
    pub scatter_px: f64,
    /// RMS of the method's own error estimate, px.
    pub sigma_est_px: f64,
    /// RMS of the error over the method's own sigma, per axis (the pull: 1 when the
    /// reported sigmas mean what they say).
    pub pull_rms: f64,
    /// The pull over the stars without [`CentroidFlags::SIGMA_UNRELIABLE`] (the CoGs':
    /// [`startrack_core::centroid::cog::sigma_unreliable`]); NaN when all are flagged.
    pub pull_rms_clean: f64,
    /// Stars flagged `SIGMA_UNRELIABLE`.
    pub sigma_flagged: usize,
    /// Stars flagged `PSF_MISMATCH` (the model methods; kept in the statistics).
    pub psf_mismatch: usize,
    /// Results flagged degenerate or not converged (left out).
    pub failures: usize,
    /// Stars used.
    pub trials: usize,
}

impl Cell {
    /// RMS error over the Cramer-Rao bound.
    pub fn efficiency_ratio(&self) -> f64 {
        self.rms_px / self.crlb_px
    }
}

/// Relative standard error of an RMS over `n` near-Gaussian samples: `1 / sqrt(2 n)`.
pub fn rms_relative_se(n: usize) -> f64 {
    1.0 / (2.0 * n.max(1) as f64).sqrt()
}

/// Flux (e-) whose eq. 8 SNR in an `n x n` box is `snr`, all the flux in the box, per-pixel
/// noise variance `var_bg` (e-^2): the root of `S^2 = snr^2 (S + n^2 var_bg)`.
pub fn flux_for_snr(snr: f64, n: f64, var_bg: f64) -> f64 {
    let k = snr * snr;
    0.5 * (k + (k * k + 4.0 * k * n * n * var_bg).sqrt())
}

/// Cramer-Rao bound on x (px) for a pixel-integrated Gaussian of sigma `sigma_px` and `flux_e`
/// at (`x`, `y`) on a `width x height` window whose pixel centres are at integers `0..`, on a
/// background of `background_e` e-/px (Poisson) with read noise `read_noise_e`
/// (accuracy-theory.md: `F = sum (d mu / d x)^2 / (mu + r^2)`, bound `1 / sqrt(F)`).
#[allow(clippy::too_many_arguments)]
pub fn crlb_x_px(
    width: u16,
    height: u16,
    x: f64,
    y: f64,
    sigma_px: f64,
    flux_e: f64,
    background_e: f64,
    read_noise_e: f64,
) -> f64 {
    let phi = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let mut fisher = 0.0;
    for r in 0..height {
        let yi = f64::from(r);
        let py = pixel_fraction(yi, y, sigma_px);
        for c in 0..width {
            let xi = f64::from(c);
            let px = pixel_fraction(xi, x, sigma_px);
            let dpx = (phi((xi - 0.5 - x) / sigma_px) - phi((xi + 0.5 - x) / sigma_px)) / sigma_px;
            let mu = flux_e * px * py + background_e;
            let d = flux_e * dpx * py;
            let v = mu + read_noise_e * read_noise_e;
            // A pixel with no expected signal and no noise carries no information.
            if v > 0.0 {
                fisher += d * d / v;
            }
        }
    }
    1.0 / fisher.sqrt()
}

/// The Cramer-Rao bound on x (px) when the PSF width is not known: the `(x, y, N, s)`
/// Fisher matrix of the same star and noise as [`crlb_x_px`], inverted, `sqrt([F^-1]_xx)`.
/// What any unbiased estimator that fits the width must pay; at least [`crlb_x_px`].
#[allow(clippy::too_many_arguments)]
pub fn crlb_x_width_free_px(
    width: u16,
    height: u16,
    x: f64,
    y: f64,
    sigma_px: f64,
    flux_e: f64,
    background_e: f64,
    read_noise_e: f64,
) -> f64 {
    crlb_x_prior_px(
        width,
        height,
        x,
        y,
        sigma_px,
        flux_e,
        (background_e, read_noise_e),
        0.0,
    )
}

/// The Cramer-Rao bound on x (px) when the PSF sigma is known only to a Gaussian prior of
/// information `prior_info` (`1 / sigma_s^2`, px^-2; 0: not known at all, the bound of
/// [`crlb_x_width_free_px`]): the `(x, y, N, s)` Fisher matrix plus the prior's information
/// on `s`, inverted (the Bayesian information bound at the star's true width).
#[allow(clippy::too_many_arguments)]
pub fn crlb_x_prior_px(
    width: u16,
    height: u16,
    x: f64,
    y: f64,
    sigma_px: f64,
    flux_e: f64,
    (background_e, read_noise_e): (f64, f64),
    prior_info: f64,
) -> f64 {
    let phi = |z: f64| (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt();
    // Fraction, d/dcentre, d/dsigma of pixel i for centre c.
    let prof = |i: f64, c: f64| {
        let (ul, uh) = ((i - 0.5 - c) / sigma_px, (i + 0.5 - c) / sigma_px);
        (
            pixel_fraction(i, c, sigma_px),
            (phi(ul) - phi(uh)) / sigma_px,
            (phi(ul) * ul - phi(uh) * uh) / sigma_px,
        )
    };
    let mut f = [[0.0f64; 4]; 4];
    for r in 0..height {
        let (fy, dy, wy) = prof(f64::from(r), y);
        for c in 0..width {
            let (fx, dx, wx) = prof(f64::from(c), x);
            let mu = flux_e * fx * fy + background_e;
            let v = mu + read_noise_e * read_noise_e;
            if v <= 0.0 {
                continue;
            }
            let j = [
                flux_e * dx * fy,
                flux_e * fx * dy,
                fx * fy,
                flux_e * (wx * fy + fx * wy),
            ];
            for (fi, ji) in f.iter_mut().zip(j) {
                for (fik, jk) in fi.iter_mut().zip(j) {
                    *fik += ji * jk / v;
                }
            }
        }
    }
    f[3][3] += prior_info;
    invert4(f).map_or(f64::INFINITY, |inv| inv[0][0].max(0.0).sqrt())
}

/// Inverse of a symmetric positive-definite 4x4 matrix by Gauss-Jordan elimination with
/// partial pivoting; `None` when singular.
fn invert4(mut a: [[f64; 4]; 4]) -> Option<[[f64; 4]; 4]> {
    let mut inv = [[0.0; 4]; 4];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for col in 0..4 {
        let p = (col..4).max_by(|&i, &k| a[i][col].abs().total_cmp(&a[k][col].abs()))?;
        a.swap(col, p);
        inv.swap(col, p);
        let d = a[col][col];
        if d.abs() < 1e-300 {
            return None;
        }
        for k in 0..4 {
            a[col][k] /= d;
            inv[col][k] /= d;
        }
        for r in 0..4 {
            if r != col {
                let m = a[r][col];
                for k in 0..4 {
                    a[r][k] -= m * a[col][k];
                    inv[r][k] -= m * inv[col][k];
                }
            }
        }
    }
    Some(inv)
}

/// Noise-free means (row-major) of a star at window coordinates (`x`, `y`), e-.
fn render(side: u16, x: f64, y: f64, sigma: f64, flux: f64, bg: f64) -> Vec<f64> {
    let fx: Vec<f64> = (0..side)
        .map(|c| pixel_fraction(f64::from(c), x, sigma))
        .collect();
    let fy: Vec<f64> = (0..side)
        .map(|r| pixel_fraction(f64::from(r), y, sigma))
        .collect();
    fy.iter()
        .flat_map(|py| fx.iter().map(move |px| bg + flux * px * py))
        .collect()
}

fn to_electrons(v: &[f64]) -> Vec<Electrons> {
    v.iter()
        .map(|&x| Electrons::from_num(x.clamp(-33_554_431.0, 33_554_431.0)))
        .collect()
}

/// A method ready to run: its parameters and, for a corrected CoG, its curve's bytes.
struct Prepared {
    method: Method,
    curve: Option<Vec<u8>>,
    sigma_px: f64,
    background: Background,
}

impl Prepared {
    /// `None` when the method has no curve for this `a` (the builder refuses it).
    fn new(method: Method, a_px: f64, var_bg: f64, bg: f64) -> Option<Self> {
        let curve = match method {
            Method::Cog {
                power,
                box_side,
                corrected: true,
            } => Some(
                build_curve(&CurveSpec {
                    a_px,
                    box_side,
                    power,
                    background: PixCorrBackground::Given,
                    knots: 33,
                })
                .ok()?
                .bytes,
            ),
            _ => None,
        };
        Some(Self {
            method,
            curve,
            sigma_px: sigma_of_a(a_px),
            background: Background::Given {
                level_e: bg as f32,
                variance_e2: var_bg as f32,
            },
        })
    }

    /// Runs the method; `a_model_px` is the field model's width at the star (only the
    /// model method uses it).
    fn run(&self, input: &CentroidInput<'_>, a_model_px: f64) -> Centroid {
        let s = self.sigma_px as f32;
        match self.method {
            Method::Cog {
                power, box_side, ..
            } => {
                let c = cog(
                    input,
                    &CogParams {
                        power,
                        box_side,
                        anchor: Anchor::Peak,
                        background: self.background,
                    },
                );
                match self.curve.as_deref().map(PixCorr::parse) {
                    Some(Ok((curve, _))) => curve.apply(c),
                    _ => c,
                }
            }
            Method::GaussFit { window } => gauss_fit(
                input,
                &GaussFitParams {
                    fit_background: false,
                    background: self.background,
                    start_box: window.min(5),
                    ..GaussFitParams::new(s)
                },
            ),
            Method::GaussFitAssumed { window, a_px } => gauss_fit(
                input,
                &GaussFitParams {
                    fit_background: false,
                    background: self.background,
                    start_box: window.min(5),
                    ..GaussFitParams::new(sigma_of_a(a_px) as f32)
                },
            ),
            Method::GaussFitWidth { window } => {
                gauss_fit_width(
                    input,
                    &WidthFitParams {
                        background: Background::PerimeterMedian,
                        start_box: window.saturating_sub(2).min(5),
                        ..WidthFitParams::new()
                    },
                )
                .centroid
            }
            Method::GaussFitWidthModel {
                window,
                scatter_a_px,
            } => {
                gauss_fit_width_prior(
                    input,
                    &WidthFitParams {
                        background: Background::PerimeterMedian,
                        start_box: window.saturating_sub(2).min(5),
                        ..WidthFitParams::new()
                    },
                    &WidthPrior {
                        a_px: a_model_px as f32,
                        scatter_px: scatter_a_px as f32,
                    },
                )
                .centroid
            }
        }
    }
}

/// True when `c`'s sigmas are flagged unreliable: the width-free fit's own flag, the CoGs'
/// rule for their power, box, correction and the star's width (the tracker applies it with
/// the configured width).
fn sigma_flag(method: Method, a_px: f64, c: &Centroid) -> bool {
    match method {
        Method::Cog {
            power,
            box_side,
            corrected,
        } => cog_sigma_unreliable(power, box_side, a_px as f32, corrected, c.snr),
        _ => c.flags.contains(CentroidFlags::SIGMA_UNRELIABLE),
    }
}

/// A seed for one `(a, SNR)` cell: the same stars for every method.
fn cell_seed(seed: u64, a_px: f64, snr: f64) -> u64 {
    seed ^ a_px.to_bits().rotate_left(17) ^ snr.to_bits().rotate_left(41)
}

/// Runs `method` at `(a_px, snr)`; `None` when it does not apply (no correction curve).
pub fn run_cell(method: Method, a_px: f64, snr: f64, noise: &Noise) -> Option<Cell> {
    let var_bg = noise.background_e + noise.read_noise_e.powi(2);
    let prepared = Prepared::new(method, a_px, var_bg, noise.background_e)?;
    let flux = flux_for_snr(snr, 5.0, var_bg);
    let sigma = sigma_of_a(a_px);
    let side = method.window_side();
    let centre = f64::from(side / 2);
    let mut rng = ChaCha8Rng::seed_from_u64(cell_seed(noise.seed, a_px, snr));
    let read = Normal::new(0.0, noise.read_noise_e.max(0.0)).ok()?;
    let rect = Rect {
        x0: 0,
        y0: 0,
        width: side,
        height: side,
    };
    let (mut err2, mut crlb2, mut scat2, mut est2, mut pull2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut crlb_free2 = 0.0;
    let (mut pull_clean2, mut flagged) = (0.0, 0usize);
    let width_free = matches!(method, Method::GaussFitWidth { .. });
    // The field model's error per star, from its own stream (the stars stay the same).
    let model_scatter = match method {
        Method::GaussFitWidthModel { scatter_a_px, .. } => Some(scatter_a_px),
        _ => None,
    };
    let mut model_rng = ChaCha8Rng::seed_from_u64(cell_seed(noise.seed, a_px, snr) ^ 0x5eed_a0de1);
    let unit = Normal::new(0.0, 1.0).ok()?;
    let mut mismatched = 0usize;
    let (mut used, mut failures) = (0usize, 0usize);
    let bad = CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED;
    let u = rand_distr::Uniform::new(-0.5, 0.5).ok()?;
    for _ in 0..noise.trials {
        let (x, y) = (centre + u.sample(&mut rng), centre + u.sample(&mut rng));
        let mean = render(side, x, y, sigma, flux, noise.background_e);
        let noisy: Vec<f64> = mean
            .iter()
            .map(|&m| {
                let photons = Poisson::new(m.max(1e-9)).map_or(m, |p| p.sample(&mut rng));
                photons + read.sample(&mut rng)
            })
            .collect();
        let e = to_electrons(&noisy);
        let e0 = to_electrons(&mean);
        let a_model = model_scatter.map_or(a_px, |sc| a_px + sc * unit.sample(&mut model_rng));
        let c = prepared.run(&CentroidInput::new(Window::new(rect, &e)?), a_model);
        let c0 = prepared.run(&CentroidInput::new(Window::new(rect, &e0)?), a_model);
        if c.flags.contains(CentroidFlags::PSF_MISMATCH) {
            mismatched += 1;
        }
        if c.flags.intersects(bad) || c0.flags.intersects(bad) {
            failures += 1;
            continue;
        }
        let (cx, cy) = (f64::from(c.x_px), f64::from(c.y_px));
        err2 += (cx - x).powi(2) + (cy - y).powi(2);
        scat2 += (cx - f64::from(c0.x_px)).powi(2) + (cy - f64::from(c0.y_px)).powi(2);
        est2 += f64::from(c.sigma_x_px).powi(2) + f64::from(c.sigma_y_px).powi(2);
        let pull = |e: f64, s: f32| {
            if s > 0.0 {
                e / f64::from(s)
            } else {
                f64::INFINITY
            }
        };
        let p2 = pull(cx - x, c.sigma_x_px).powi(2) + pull(cy - y, c.sigma_y_px).powi(2);
        pull2 += p2;
        if sigma_flag(method, a_px, &c) {
            flagged += 1;
        } else {
            pull_clean2 += p2;
        }
        // The bound on a 9x9 window around the star's pixel (symmetric in x and y).
        let bx = crlb_x_px(
            9,
            9,
            x - centre + 4.0,
            y - centre + 4.0,
            sigma,
            flux,
            noise.background_e,
            noise.read_noise_e,
        );
        let by = crlb_x_px(
            9,
            9,
            y - centre + 4.0,
            x - centre + 4.0,
            sigma,
            flux,
            noise.background_e,
            noise.read_noise_e,
        );
        crlb2 += bx * bx + by * by;
        if let Some(sc) = model_scatter {
            // The bound for a width known to the model's scatter: the prior's information.
            let info = 1.0 / (sc * sigma_of_a(1.0)).powi(2);
            let fx = crlb_x_prior_px(
                9,
                9,
                x - centre + 4.0,
                y - centre + 4.0,
                sigma,
                flux,
                (noise.background_e, noise.read_noise_e),
                info,
            );
            let fy = crlb_x_prior_px(
                9,
                9,
                y - centre + 4.0,
                x - centre + 4.0,
                sigma,
                flux,
                (noise.background_e, noise.read_noise_e),
                info,
            );
            crlb_free2 += fx * fx + fy * fy;
        } else if width_free {
            let fx = crlb_x_width_free_px(
                9,
                9,
                x - centre + 4.0,
                y - centre + 4.0,
                sigma,
                flux,
                noise.background_e,
                noise.read_noise_e,
            );
            let fy = crlb_x_width_free_px(
                9,
                9,
                y - centre + 4.0,
                x - centre + 4.0,
                sigma,
                flux,
                noise.background_e,
                noise.read_noise_e,
            );
            crlb_free2 += fx * fx + fy * fy;
        }
        used += 1;
    }
    let n = (2 * used.max(1)) as f64;
    Some(Cell {
        method,
        a_px,
        snr,
        rms_px: (err2 / n).sqrt(),
        crlb_px: (crlb2 / n).sqrt(),
        crlb_width_free_px: if width_free || model_scatter.is_some() {
            (crlb_free2 / n).sqrt()
        } else {
            f64::NAN
        },
        scatter_px: (scat2 / n).sqrt(),
        sigma_est_px: (est2 / n).sqrt(),
        pull_rms: (pull2 / n).sqrt(),
        pull_rms_clean: (pull_clean2 / (2 * (used - flagged.min(used))) as f64).sqrt(),
        sigma_flagged: flagged,
        psf_mismatch: mismatched,
        failures,
        trials: noise.trials,
    })
}

/// Every method at every `(a, SNR)` (cells that do not apply are left out).
pub fn run(methods: &[Method], widths_a_px: &[f64], snrs: &[f64], noise: &Noise) -> Vec<Cell> {
    let mut cells = Vec::new();
    for &a in widths_a_px {
        for &snr in snrs {
            for &m in methods {
                cells.extend(run_cell(m, a, snr, noise));
            }
        }
    }
    cells
}

/// A markdown table: one row per method, one column per `(a, SNR)`, each cell
/// `RMS / CRLB` (and the failures when any), then the error-estimate table
/// `sigma_est / scatter`.
pub fn markdown(
    cells: &[Cell],
    methods: &[Method],
    widths_a_px: &[f64],
    snrs: &[f64],
    noise: &Noise,
) -> String {
    let mut s = String::new();
    let cols: Vec<(f64, f64)> = widths_a_px
        .iter()
        .flat_map(|&a| snrs.iter().map(move |&snr| (a, snr)))
        .collect();
    let find = |m: &Method, a: f64, snr: f64| {
        cells
            .iter()
            .find(|c| c.method == *m && c.a_px == a && c.snr == snr)
    };
    let header = |s: &mut String, title: &str| {
        let _ = write!(s, "| {title} |");
        for (a, snr) in &cols {
            let _ = write!(s, " a {a} SNR {snr} |");
        }
        s.push('\n');
        s.push_str("|---|");
        for _ in &cols {
            s.push_str("---|");
        }
        s.push('\n');
    };
    // One row per method, each cell `cell` of the method's result there (`-` where none).
    let rows = |s: &mut String, cell: &dyn Fn(&Cell) -> String| {
        for m in methods {
            let _ = write!(s, "| {} |", m.name());
            for &(a, snr) in &cols {
                match find(m, a, snr) {
                    Some(c) => {
                        let _ = write!(s, " {} |", cell(c));
                    }
                    None => s.push_str(" - |"),
                }
            }
            s.push('\n');
        }
    };
    let _ = writeln!(
        s,
        "RMS error / Cramer-Rao bound ({} stars per cell, uniform pixel phase, background {} e-/px, read noise {} e-, seed {}; SNR by eq. 8 in 5x5; `-` = no correction curve):\n",
        noise.trials, noise.background_e, noise.read_noise_e, noise.seed
    );
    header(&mut s, "method");
    rows(&mut s, &|c| {
        if c.failures > 0 {
            format!("{:.2} ({} failed)", c.efficiency_ratio(), c.failures)
        } else {
            format!("{:.2}", c.efficiency_ratio())
        }
    });
    let _ = writeln!(s, "\nCRLB, px:\n");
    header(&mut s, "");
    s.push_str("| CRLB |");
    for &(a, snr) in &cols {
        match cells.iter().find(|c| c.a_px == a && c.snr == snr) {
            Some(c) => {
                let _ = write!(s, " {:.4} |", c.crlb_px);
            }
            None => s.push_str(" - |"),
        }
    }
    s.push('\n');
    let _ = writeln!(
        s,
        "\nError estimate / measured scatter (sigma_x, sigma_y against the noise part of the error):\n"
    );
    header(&mut s, "method");
    rows(&mut s, &|c| format!("{:.2}", c.sigma_est_px / c.scatter_px));
    let _ = writeln!(
        s,
        "\nPull: RMS of error / own sigma per axis (sigma_x, sigma_y against the whole error, bias included; 1 when the reported sigmas mean what they say); `flagged` where the stars carry SIGMA_UNRELIABLE (then the pull of the unflagged rest, if any, in brackets):\n"
    );
    header(&mut s, "method");
    rows(&mut s, &|c| pull_cell(c));
    s
}

/// The field model's scatter of the "width unknown" table's model rows, px of `a`.
pub const MODEL_SCATTER_A_PX: f64 = 0.02;

/// The methods of the "width unknown" table: the width-free fit as the flight configuration
/// runs it without and with a field PSF model (scatter [`MODEL_SCATTER_A_PX`]), and the fit
/// of the flight configuration's former fixed width, a = 1.2 px, on stars of every width,
/// all on 7x7 windows.
pub fn width_unknown_methods() -> [Method; 3] {
    [
        Method::GaussFitWidth { window: 7 },
        Method::GaussFitWidthModel {
            window: 7,
            scatter_a_px: MODEL_SCATTER_A_PX,
        },
        Method::GaussFitAssumed {
            window: 7,
            a_px: 1.2,
        },
    ]
}

/// The "width unknown" cells as CSV: `method,a_px,snr,rms_over_crlb,
/// rms_over_crlb_width_free,pull_rms,pull_rms_unflagged,sigma_flagged,failures,trials,
/// psf_mismatch` (`rms_over_crlb_width_free`: over the bound for what the method knows of
/// the width, [`Cell::crlb_width_free_px`]; empty for the assumed width).
pub fn width_unknown_csv(cells: &[Cell]) -> String {
    let mut s = String::from(
        "method,a_px,snr,rms_over_crlb,rms_over_crlb_width_free,pull_rms,pull_rms_unflagged,sigma_flagged,failures,trials,psf_mismatch\n",
    );
    for c in cells {
        let free = if c.crlb_width_free_px.is_finite() {
            format!("{:.3}", c.rms_px / c.crlb_width_free_px)
        } else {
            String::new()
        };
        let _ = writeln!(
            s,
            "{},{},{},{:.3},{free},{:.3},{:.3},{},{},{},{}",
            c.method.name(),
            c.a_px,
            c.snr,
            c.efficiency_ratio(),
            c.pull_rms,
            c.pull_rms_clean,
            c.sigma_flagged,
            c.failures,
            c.trials,
            c.psf_mismatch
        );
    }
    s
}

/// The "width unknown" table: one row per width and method, columns per SNR, each cell
/// `RMS / CRLB` (the known-width bound), then for the width-free fit `/ CRLB` with the width
/// unknown and the pull.
pub fn width_unknown_markdown(cells: &[Cell], snrs: &[f64], noise: &Noise) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Width unknown ({} stars per cell, uniform pixel phase, background {} e-/px, read noise {} e-, seed {}; SNR by eq. 8 in 5x5; each cell: RMS / CRLB of a star whose width is known, then for the width fits RMS / CRLB for what the fit knows of the width (unknown; the model's scatter) and the pull):\n",
        noise.trials, noise.background_e, noise.read_noise_e, noise.seed
    );
    let _ = write!(s, "| method | a |");
    for snr in snrs {
        let _ = write!(s, " SNR {snr} |");
    }
    s.push_str("\n|---|---|");
    for _ in snrs {
        s.push_str("---|");
    }
    s.push('\n');
    let mut rows: Vec<(String, f64)> = Vec::new();
    for c in cells {
        let key = (c.method.name(), c.a_px);
        if !rows.contains(&key) {
            rows.push(key);
        }
    }
    for (name, a) in rows {
        let _ = write!(s, "| {name} | {a} |");
        for &snr in snrs {
            match cells
                .iter()
                .find(|c| c.method.name() == name && c.a_px == a && c.snr == snr)
            {
                Some(c) if c.crlb_width_free_px.is_finite() => {
                    let mismatch = if c.psf_mismatch > 0 {
                        format!(", {} mismatched", c.psf_mismatch)
                    } else {
                        String::new()
                    };
                    let _ = write!(
                        s,
                        " {:.2} / {:.2} / pull {}{mismatch}{} |",
                        c.efficiency_ratio(),
                        c.rms_px / c.crlb_width_free_px,
                        pull_cell(c),
                        failed(c.failures)
                    );
                }
                Some(c) => {
                    let _ = write!(s, " {:.2}{} |", c.efficiency_ratio(), failed(c.failures));
                }
                None => s.push_str(" - |"),
            }
        }
        s.push('\n');
    }
    s
}

/// A pull-table cell: the pull, and the flagged share with the unflagged stars' pull.
fn pull_cell(c: &Cell) -> String {
    let used = c.trials - c.failures;
    match c.sigma_flagged {
        0 => format!("{:.2}", c.pull_rms),
        f if f >= used => format!("{:.2} flagged", c.pull_rms),
        f => format!(
            "{:.2}, {:.0} % flagged ({:.2})",
            c.pull_rms,
            100.0 * f as f64 / used.max(1) as f64,
            c.pull_rms_clean
        ),
    }
}

/// ` (N failed)` when any.
fn failed(n: usize) -> String {
    if n > 0 {
        format!(" ({n} failed)")
    } else {
        String::new()
    }
}

/// A method made ready once for a PSF width and a given background, to run on windows other
/// than [`run_cell`]'s (the failure maps of [`crate::tradeoff`] perturb the star first).
pub struct PreparedMethod(Prepared);

impl PreparedMethod {
    /// `method` for PSF width `a_px`, told the background level `background_e` (e-/px) and its
    /// per-pixel variance `variance_e2`; `None` when it has no correction curve for `a_px`.
    pub fn new(method: Method, a_px: f64, background_e: f64, variance_e2: f64) -> Option<Self> {
        Prepared::new(method, a_px, variance_e2, background_e).map(Self)
    }

    /// Runs the method on `input`.
    pub fn run(&self, input: &CentroidInput<'_>) -> Centroid {
        let a_px = self.0.sigma_px / sigma_of_a(1.0);
        self.0.run(input, a_px)
    }
}
