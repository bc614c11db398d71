//! Failure maps: where each centroid method stops working, over a grid of SNR x PSF width
//! and along sweeps of the sensor's defects, written as failures.csv.
//!
//! # The experiment (one scene)
//! A star of PSF width `a` (pixel-integrated Gaussian, paper eq. 3 and 5) at a true position
//! uniform over the centre pixel of a 9x9 canvas (both axes), on a background of 100 e-/px
//! (Poisson) with 5 e- read noise, as in [`crate::accuracy`]; its flux gives the requested
//! eq. 8 SNR in a 5x5 box ([`flux_for_snr`]). Every method sees the same stars (common random
//! numbers), each in its own window centred on the star's pixel, with the background level
//! and per-pixel variance given (the detector's estimate, which includes DSNU). Perturbations
//! ([`Perturb`]), one at a time:
//! - `dsnu`: a fixed dark pattern, per pixel `100 e- x dsnu x N(0,1)` (a new pattern per star);
//! - `hot_e`: an uncorrected hot pixel of that many e- one column right of the star's pixel;
//! - `telegraph_e`: an uncorrected pixel one row below the star's pixel that adds that many
//!   e- in half of the frames (random per star);
//! - `saturation`: the flux is set so that the brightest pixel's mean (star centred) is that
//!   multiple of the 100 ke- full well; pixels are clipped there and flagged saturated;
//! - `edge_px`: columns left of the star's pixel by more than this do not exist (the active
//!   area's edge): windows are clipped and flagged so;
//! - `pair_px`: a second star of equal flux that far to the right (same row phase);
//! - `true_a_px`: PSF-width mismatch: the star's true width `a` is this, the method is still
//!   configured for the scene's `a` (the sweep's 1.5 px: the Gauss fit's sigma, the corrected
//!   CoGs' curve). The width-free fit is told no width, so for it the sweep is the same star
//!   at another width, not a mismatch.
//!
//! # What is measured, and when a cell fails
//! - `bias_px`: the systematic error: RMS over stars (both axes) of the method's error on the
//!   star's noise-free image (with the fixed perturbations: DSNU pattern, hot pixel, clipping;
//!   not the telegraph state, which is noise). This is what averaging frames cannot remove.
//! - `rms_px`: RMS error (both axes) of the noisy results that have a position (not flagged
//!   degenerate or not converged); `crlb_px`: the RMS Cramer-Rao bound of the unperturbed star
//!   on the canvas pixels that exist ([`crlb_x_px`]).
//! - `detect_rate`: the fraction of stars the method reports usable and in the right place:
//!   no DEGENERATE, NOT_CONVERGED or LOW_SNR flag (LOW_SNR is the method's own measured eq. 8
//!   SNR below 3, the paper's detection threshold) and within 1 px of the truth on each axis.
//!
//! A cell fails (`fail` column, reasons joined by `+`) when `bias_px > 0.05`
//! ([`BIAS_LIMIT_PX`]), `rms_px > 2 crlb_px` ([`RMS_OVER_CRLB_LIMIT`]) or `detect_rate < 0.9`
//! ([`DETECT_LIMIT`]). A method that does not apply (a corrected CoG with no curve for this
//! `a`) gives `n/a`.
//!
//! # Tolerances
//! With N stars, `rms_px` has a relative standard error of `1/sqrt(4N)` (2N near-Gaussian
//! errors, [`crate::accuracy::rms_relative_se`]) and `detect_rate` a standard error of
//! `sqrt(p(1-p)/N)`; the tests pin only cells whose margin to a limit exceeds 4 of these.
//!
//! Cost: per star one 9x9 render, two bounds and two runs of every method; the full map is
//! every scene of [`MapSpec::new`] (its grid and sweeps) times its `trials` stars times every
//! method of [`super::methods`], most of `startrack tradeoff`'s time (`time
//! startrack tradeoff --out DIR` measures it).

use crate::accuracy::{Method, PreparedMethod, crlb_x_px, flux_for_snr};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson, Uniform};
use startrack_core::calib::PixelFlags;
use startrack_core::centroid::{CentroidFlags, CentroidInput};
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::sim::psf::{pixel_fraction, sigma_of_a};

/// A cell fails when the systematic error exceeds this, px.
pub const BIAS_LIMIT_PX: f64 = 0.05;
/// A cell fails when its RMS error exceeds this multiple of the Cramer-Rao bound.
pub const RMS_OVER_CRLB_LIMIT: f64 = 2.0;
/// A cell fails when fewer than this fraction of stars are detected.
pub const DETECT_LIMIT: f64 = 0.9;
/// Background of every scene, e-/px (Poisson).
pub const BACKGROUND_E: f64 = 100.0;
/// Read noise of every scene, e- RMS.
pub const READ_NOISE_E: f64 = 5.0;
/// Full well, e- (CCD47-20, about 100 ke-).
pub const FULL_WELL_E: f64 = 100_000.0;
/// Side of the rendered canvas; the star's pixel is its centre.
const CANVAS: u16 = 9;
const CENTRE: u16 = CANVAS / 2;

/// One perturbation of the base scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Perturb {
    /// The isolated star on a flat background.
    None,
    /// Dark signal non-uniformity, relative sigma of the 100 e- dark.
    Dsnu(f64),
    /// Uncorrected hot pixel next to the star's pixel, e-.
    HotPixel(f64),
    /// Uncorrected telegraph pixel below the star's pixel: adds this many e- in half the frames.
    Telegraph(f64),
    /// Brightest pixel's mean over the full well.
    Saturation(f64),
    /// Pixels from the star's pixel to the active area's left edge.
    Edge(u16),
    /// Separation of an equal second star to the right, px.
    Pair(f64),
    /// The star's true PSF width a, px; the method is configured for the scene's a.
    TrueWidth(f64),
}

impl Perturb {
    /// The CSV's `sweep` name and value.
    pub fn sweep(&self) -> (&'static str, f64) {
        match *self {
            Perturb::None => ("grid", 0.0),
            Perturb::Dsnu(v) => ("dsnu", v),
            Perturb::HotPixel(v) => ("hot_e", v),
            Perturb::Telegraph(v) => ("telegraph_e", v),
            Perturb::Saturation(v) => ("saturation", v),
            Perturb::Edge(v) => ("edge_px", f64::from(v)),
            Perturb::Pair(v) => ("pair_px", v),
            Perturb::TrueWidth(v) => ("true_a_px", v),
        }
    }
}

/// One scene: a PSF width, an SNR and a perturbation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scene {
    /// PSF 80 %-energy radius, px.
    pub a_px: f64,
    /// Eq. 8 SNR in a 5x5 box of the unperturbed star (ignored under [`Perturb::Saturation`],
    /// which sets the flux; the CSV then gives the resulting SNR).
    pub snr: f64,
    /// The perturbation.
    pub perturb: Perturb,
}

/// One method in one scene.
#[derive(Clone, Debug, PartialEq)]
pub struct FailCell {
    /// The method.
    pub method: Method,
    /// The scene.
    pub scene: Scene,
    /// Eq. 8 SNR of the star actually drawn.
    pub snr: f64,
    /// `None` when the method does not apply (no correction curve).
    pub stats: Option<Stats>,
}

/// What a cell measured.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stats {
    /// Systematic error (noise-free image), RMS over stars and axes, px.
    pub bias_px: f64,
    /// RMS error of the noisy results with a position, px.
    pub rms_px: f64,
    /// RMS Cramer-Rao bound, px.
    pub crlb_px: f64,
    /// Fraction of stars detected (see the module docs).
    pub detect_rate: f64,
    /// Stars drawn.
    pub trials: usize,
}

impl Stats {
    /// Why the cell fails: a subset of `bias`, `rms`, `detect`; empty when it passes.
    pub fn reasons(&self) -> Vec<&'static str> {
        let mut r = Vec::new();
        if self.bias_px.is_nan() || self.bias_px > BIAS_LIMIT_PX {
            r.push("bias");
        }
        if self.rms_px.is_nan() || self.rms_px > RMS_OVER_CRLB_LIMIT * self.crlb_px {
            r.push("rms");
        }
        if self.detect_rate.is_nan() || self.detect_rate < DETECT_LIMIT {
            r.push("detect");
        }
        r
    }

    /// True when the cell fails.
    pub fn fails(&self) -> bool {
        !self.reasons().is_empty()
    }
}

/// The grid and the sweeps of one run.
#[derive(Clone, Debug, PartialEq)]
pub struct MapSpec {
    /// Grid SNRs (log-spaced 1..100).
    pub grid_snr: Vec<f64>,
    /// Grid widths a, px (0.3..3).
    pub grid_a_px: Vec<f64>,
    /// Scene of the sweeps (a, SNR).
    pub sweep_a_px: f64,
    /// SNR of the sweeps.
    pub sweep_snr: f64,
    /// The sweeps' perturbations.
    pub sweeps: Vec<Perturb>,
    /// Stars per scene.
    pub trials: usize,
    /// Seed.
    pub seed: u64,
}

impl MapSpec {
    /// The full map (`quick == false`, 12 x 10 grid, 600 stars) or the coarse one (5 x 5,
    /// 150 stars).
    pub fn new(quick: bool) -> Self {
        let (ns, na, trials) = if quick { (5, 5, 150) } else { (12, 10, 600) };
        let mut sweeps = Vec::new();
        sweeps.extend([0.0, 0.05, 0.1, 0.2, 0.3, 0.5].map(Perturb::Dsnu));
        sweeps.extend([0.0, 30.0, 100.0, 300.0, 1000.0, 3000.0].map(Perturb::HotPixel));
        sweeps.extend([0.0, 30.0, 100.0, 300.0, 1000.0, 3000.0].map(Perturb::Telegraph));
        sweeps.extend([0.5, 0.9, 1.5, 3.0, 10.0].map(Perturb::Saturation));
        sweeps.extend([0u16, 1, 2, 3, 4].map(Perturb::Edge));
        sweeps.extend([1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0].map(Perturb::Pair));
        // True a over the configured 1.5 px: ratio 0.4-2.
        sweeps.extend(
            [
                0.6, 0.75, 0.9, 1.05, 1.2, 1.35, 1.5, 1.65, 1.8, 2.1, 2.4, 3.0,
            ]
            .map(Perturb::TrueWidth),
        );
        Self {
            grid_snr: crate::figures::log_space(1.0, 100.0, ns),
            grid_a_px: crate::figures::log_space(0.3, 3.0, na),
            sweep_a_px: 1.5,
            sweep_snr: 30.0,
            sweeps,
            trials,
            seed: 4,
        }
    }

    /// Every scene: the grid (SNR-major), then the sweeps.
    pub fn scenes(&self) -> Vec<Scene> {
        let mut v = Vec::new();
        for &snr in &self.grid_snr {
            for &a_px in &self.grid_a_px {
                v.push(Scene {
                    a_px,
                    snr,
                    perturb: Perturb::None,
                });
            }
        }
        for &perturb in &self.sweeps {
            v.push(Scene {
                a_px: self.sweep_a_px,
                snr: self.sweep_snr,
                perturb,
            });
        }
        v
    }
}

/// One method's accumulators.
#[derive(Clone, Copy, Default)]
struct Acc {
    bias2: f64,
    bias_n: usize,
    err2: f64,
    err_n: usize,
    detected: usize,
}

/// The star's flux, e-, and its eq. 8 SNR in a 5x5 box.
fn flux_of(scene: &Scene) -> (f64, f64) {
    let var = BACKGROUND_E + READ_NOISE_E * READ_NOISE_E;
    match scene.perturb {
        Perturb::Saturation(k) => {
            let peak = pixel_fraction(0.0, 0.0, sigma_of_a(scene.a_px)).powi(2);
            let flux = k * FULL_WELL_E / peak.max(1e-12);
            (flux, flux / (flux + 25.0 * var).sqrt())
        }
        _ => (flux_for_snr(scene.snr, 5.0, var), scene.snr),
    }
}

/// The star's true PSF width: the scene's, or the mismatch sweep's.
pub fn true_a_px(scene: &Scene) -> f64 {
    match scene.perturb {
        Perturb::TrueWidth(a) => a,
        _ => scene.a_px,
    }
}

/// The seed of scene number `index`: every method sees the same stars.
fn scene_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (index as u64).rotate_left(29)
}

/// Runs every method in `scene` (scene number `index` of the run, for its seed).
pub fn run_scene(
    methods: &[Method],
    scene: &Scene,
    index: usize,
    trials: usize,
    seed: u64,
) -> Vec<FailCell> {
    // The star's own width; the methods are prepared for the scene's.
    let sigma = sigma_of_a(true_a_px(scene));
    let (flux, snr) = flux_of(scene);
    let dsnu_e = match scene.perturb {
        Perturb::Dsnu(d) => BACKGROUND_E * d,
        _ => 0.0,
    };
    let var = BACKGROUND_E + READ_NOISE_E * READ_NOISE_E + dsnu_e * dsnu_e;
    let prepared: Vec<Option<PreparedMethod>> = methods
        .iter()
        .map(|&m| PreparedMethod::new(m, scene.a_px, BACKGROUND_E, var))
        .collect();
    // The first canvas column that exists.
    let first_col = match scene.perturb {
        Perturb::Edge(d) => CENTRE.saturating_sub(d),
        _ => 0,
    };
    let saturating = matches!(scene.perturb, Perturb::Saturation(_));
    let mut rng = ChaCha8Rng::seed_from_u64(scene_seed(seed, index));
    let (Ok(u), Ok(read), Ok(gauss)) = (
        Uniform::new(-0.5, 0.5),
        Normal::new(0.0, READ_NOISE_E),
        Normal::new(0.0, 1.0),
    ) else {
        return Vec::new();
    };
    let n = usize::from(CANVAS * CANVAS);
    let mut acc = vec![Acc::default(); methods.len()];
    let mut crlb2 = 0.0;
    let centre = f64::from(CENTRE);
    for _ in 0..trials {
        let (x, y) = (centre + u.sample(&mut rng), centre + u.sample(&mut rng));
        let mut mean = vec![0.0f64; n];
        let mut noisy = vec![0.0f64; n];
        let mut flags = vec![PixelFlags::empty(); n];
        let telegraph_on = u.sample(&mut rng) < 0.0;
        for r in 0..CANVAS {
            let py = pixel_fraction(f64::from(r), y, sigma);
            for c in 0..CANVAS {
                let k = usize::from(r * CANVAS + c);
                let cx = f64::from(c);
                let mut star = flux * pixel_fraction(cx, x, sigma) * py;
                if let Perturb::Pair(s) = scene.perturb {
                    star += flux * pixel_fraction(cx, x + s, sigma) * py;
                }
                let mut m = BACKGROUND_E + star;
                if dsnu_e > 0.0 {
                    m = (m + dsnu_e * gauss.sample(&mut rng)).max(0.0);
                }
                if let Perturb::HotPixel(h) = scene.perturb
                    && (c, r) == (CENTRE + 1, CENTRE)
                {
                    m += h;
                }
                let mut v = Poisson::new(m.max(1e-9)).map_or(m, |p| p.sample(&mut rng))
                    + read.sample(&mut rng);
                if let Perturb::Telegraph(t) = scene.perturb
                    && (c, r) == (CENTRE, CENTRE + 1)
                    && telegraph_on
                {
                    v += t;
                }
                if saturating {
                    if m >= FULL_WELL_E {
                        flags[k] |= PixelFlags::SATURATED;
                    }
                    m = m.min(FULL_WELL_E);
                    v = v.min(FULL_WELL_E);
                    if v >= FULL_WELL_E {
                        flags[k] |= PixelFlags::SATURATED;
                    }
                }
                mean[k] = m;
                noisy[k] = v;
            }
        }
        let w = CANVAS - first_col;
        let bx = crlb_x_px(
            w,
            CANVAS,
            x - f64::from(first_col),
            y,
            sigma,
            flux,
            BACKGROUND_E,
            READ_NOISE_E,
        );
        let by = crlb_x_px(
            CANVAS,
            w,
            y,
            x - f64::from(first_col),
            sigma,
            flux,
            BACKGROUND_E,
            READ_NOISE_E,
        );
        crlb2 += bx * bx + by * by;
        for ((m, p), a) in methods.iter().zip(&prepared).zip(acc.iter_mut()) {
            let Some(p) = p else { continue };
            let side = m.window_side();
            let half = side / 2;
            let want_x0 = CENTRE.saturating_sub(half);
            let x0 = want_x0.max(first_col);
            let rect = Rect {
                x0,
                y0: CENTRE.saturating_sub(half),
                width: side - (x0 - want_x0),
                height: side,
            };
            let crop = |img: &[f64]| -> Vec<Electrons> {
                let mut v = Vec::with_capacity(rect.len());
                for r in rect.y0..rect.y0 + rect.height {
                    for c in rect.x0..rect.x0 + rect.width {
                        let val = img.get(usize::from(r * CANVAS + c)).copied().unwrap_or(0.0);
                        v.push(Electrons::from_num(val.clamp(-33_554_431.0, 33_554_431.0)));
                    }
                }
                v
            };
            let fl: Vec<PixelFlags> = (rect.y0..rect.y0 + rect.height)
                .flat_map(|r| {
                    let fr = &flags;
                    (rect.x0..rect.x0 + rect.width).map(move |c| {
                        fr.get(usize::from(r * CANVAS + c))
                            .copied()
                            .unwrap_or_default()
                    })
                })
                .collect();
            let (e, e0) = (crop(&noisy), crop(&mean));
            let clipped = x0 != want_x0;
            let (Some(win), Some(win0)) = (Window::new(rect, &e), Window::new(rect, &e0)) else {
                continue;
            };
            let c = p.run(
                &CentroidInput::new(win)
                    .with_pixel_flags(&fl)
                    .with_clipped(clipped),
            );
            let c0 = p.run(
                &CentroidInput::new(win0)
                    .with_pixel_flags(&fl)
                    .with_clipped(clipped),
            );
            let bad = CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED;
            if !c0.flags.intersects(bad) {
                a.bias2 += (f64::from(c0.x_px) - x).powi(2) + (f64::from(c0.y_px) - y).powi(2);
                a.bias_n += 1;
            }
            if !c.flags.intersects(bad) {
                let (dx, dy) = (f64::from(c.x_px) - x, f64::from(c.y_px) - y);
                a.err2 += dx * dx + dy * dy;
                a.err_n += 1;
                if !c.flags.contains(CentroidFlags::LOW_SNR) && dx.abs() < 1.0 && dy.abs() < 1.0 {
                    a.detected += 1;
                }
            }
        }
    }
    let crlb = (crlb2 / (2 * trials.max(1)) as f64).sqrt();
    methods
        .iter()
        .zip(&prepared)
        .zip(&acc)
        .map(|((&method, p), a)| FailCell {
            method,
            scene: *scene,
            snr,
            stats: p.as_ref().map(|_| Stats {
                // No position at all counts as an infinite error.
                bias_px: if a.bias_n == 0 {
                    f64::INFINITY
                } else {
                    (a.bias2 / (2 * a.bias_n) as f64).sqrt()
                },
                rms_px: if a.err_n == 0 {
                    f64::INFINITY
                } else {
                    (a.err2 / (2 * a.err_n) as f64).sqrt()
                },
                crlb_px: crlb,
                detect_rate: a.detected as f64 / trials.max(1) as f64,
                trials,
            }),
        })
        .collect()
}

/// Every scene of `spec` for every method; `tick` is called once per scene done.
pub fn run(methods: &[Method], spec: &MapSpec, mut tick: impl FnMut()) -> Vec<FailCell> {
    let mut out = Vec::new();
    for (i, scene) in spec.scenes().iter().enumerate() {
        out.extend(run_scene(methods, scene, i, spec.trials, spec.seed));
        tick();
    }
    out
}

/// failures.csv's column names.
pub const COLUMNS: &str =
    "method,sweep,value,a_px,snr,bias_px,rms_px,crlb_px,rms_over_crlb,detect_rate,fail";

/// One CSV row (see [`COLUMNS`]).
pub fn csv_row(c: &FailCell) -> String {
    let (sweep, value) = c.scene.perturb.sweep();
    let head = format!(
        "{},{sweep},{value},{:.4},{:.3}",
        c.method.name(),
        c.scene.a_px,
        c.snr
    );
    match &c.stats {
        None => format!("{head},,,,,,n/a"),
        Some(s) => {
            let r = s.reasons();
            format!(
                "{head},{:.5},{:.5},{:.5},{:.3},{:.4},{}",
                s.bias_px,
                s.rms_px,
                s.crlb_px,
                s.rms_px / s.crlb_px,
                s.detect_rate,
                if r.is_empty() {
                    "pass".to_string()
                } else {
                    r.join("+")
                }
            )
        }
    }
}
