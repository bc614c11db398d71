//! Position bias of every centroid method on non-Gaussian PSFs: the simulator's defocus ring
//! and coma tail ([`PsfShape`]), written as psf-shapes.csv (`startrack tradeoff --psf-shapes
//! --out DIR`).
//!
//! # The true centre
//! A star's position is the centroid (first moment) of its PSF: the point the distortion
//! calibration maps to a direction. The simulator places a star's photocentre at its
//! position: a ring's parts are symmetric about it and a coma's parts are shifted so that
//! their weighted mean offset is zero ([`PsfShape::parts`]). Every error below is measured
//! against that point; a method that finds the core of a coma instead reports a position
//! shifted towards the head, by an amount that depends on the aberration and not on the noise.
//!
//! # The experiment (one method, one shape)
//! A star of core width [`A_PX`] (each Gaussian part's 80 % radius) on a [`CANVAS`] x
//! [`CANVAS`] canvas, background [`BACKGROUND_E`] e-/px (Poisson) and [`READ_NOISE_E`] e- read
//! noise as in [`super::failures`], flux for eq. 8 SNR [`SNR`] of a Gaussian star in 5x5
//! ([`flux_for_snr`]; the same flux for every shape). The coma's tail points along +x, so
//! its bias is along x. Each method runs in its own window centred on the pixel that holds
//! the true centre, told the background and its variance, and (the Gauss fit, the corrected
//! CoGs) the core's width.
//! - Noise-free: the star at [`PHASES`] x [`PHASES`] pixel phases evenly over the centre
//!   pixel; `bias_x_px` is the mean signed x error, `sys_rms_px` the RMS error over the
//!   phases and both axes (the systematic error of [`super::failures`]).
//! - Noisy: `trials` stars at uniform random phases; `mean_err_x_px` is the mean signed x
//!   error with its standard error `mean_err_x_se_px`, `rms_px` the RMS error (both axes),
//!   `poor_fit_rate` the share flagged [`CentroidFlags::POOR_FIT`] (the width-free fit's
//!   chi2 test; no other method sets it), `failed` the results flagged degenerate or not
//!   converged (left out of the means).
//!
//! Seeded and deterministic. Cost: per star one canvas render of up to
//! [`startrack_sim::sim::effects::RING_PARTS`] separable Gaussian parts, shared by every method, and
//! one run of each method; `time startrack tradeoff --psf-shapes --out DIR` measures it.

use super::failures::{BACKGROUND_E, READ_NOISE_E};
use crate::accuracy::{Method, PreparedMethod, flux_for_snr};
use crate::figures::{FigureError, Written, csv::write_csv};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson, Uniform};
use startrack_core::centroid::{Centroid, CentroidFlags, CentroidInput};
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::sim::effects::PsfShape;
use startrack_sim::sim::psf::pixel_fraction;
use std::path::Path;

/// Core width of every shape: each Gaussian part's 80 % radius, px.
pub const A_PX: f64 = 1.0;
/// Eq. 8 SNR (5x5, a Gaussian star of the same flux) of the noisy stars.
pub const SNR: f64 = 100.0;
/// Side of the rendered canvas; the centre pixel holds the true centre.
pub const CANVAS: u16 = 15;
const CENTRE: u16 = CANVAS / 2;
/// Noise-free phases per axis.
pub const PHASES: usize = 10;

/// One shape of the experiment: its CSV name, size and the simulator's shape.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shape {
    /// `gaussian`, `defocus` or `coma`.
    pub name: &'static str,
    /// Ring radius or tail length, px (0 for the Gaussian).
    pub size_px: f64,
    /// The simulator's shape.
    pub psf: PsfShape,
}

/// The shapes: the Gaussian (reference), defocus rings of radius 1 and 2 px, coma tails of
/// 1, 2 and 4 px along +x.
pub fn shapes() -> Vec<Shape> {
    let mut v = vec![Shape {
        name: "gaussian",
        size_px: 0.0,
        psf: PsfShape::Gaussian,
    }];
    for r in [1.0, 2.0] {
        v.push(Shape {
            name: "defocus",
            size_px: r,
            psf: PsfShape::Defocus { ring_radius_px: r },
        });
    }
    for l in [1.0, 2.0, 4.0] {
        v.push(Shape {
            name: "coma",
            size_px: l,
            psf: PsfShape::Coma {
                length_px: l,
                angle_rad: 0.0,
            },
        });
    }
    v
}

/// What a run does.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeSpec {
    /// Noisy stars per method and shape.
    pub trials: usize,
    /// Seed.
    pub seed: u64,
}

impl ShapeSpec {
    /// 2000 noisy stars (`quick`: 300), seed 5.
    pub fn new(quick: bool) -> Self {
        Self {
            trials: if quick { 300 } else { 2000 },
            seed: 5,
        }
    }
}

/// One method on one shape.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeCell {
    /// The method.
    pub method: Method,
    /// The shape.
    pub shape: Shape,
    /// Noise-free mean signed x error, px.
    pub bias_x_px: f64,
    /// Noise-free mean signed y error, px.
    pub bias_y_px: f64,
    /// Noise-free RMS error over phases and both axes, px.
    pub sys_rms_px: f64,
    /// Noise-free results flagged POOR_FIT, of `PHASES^2`.
    pub sys_poor_fit: usize,
    /// Noisy: mean signed x error, px.
    pub mean_err_x_px: f64,
    /// Its standard error, px.
    pub mean_err_x_se_px: f64,
    /// Noisy: RMS error, both axes, px.
    pub rms_px: f64,
    /// Noisy: share flagged POOR_FIT.
    pub poor_fit_rate: f64,
    /// Noisy results flagged degenerate or not converged.
    pub failed: usize,
    /// Noisy stars drawn.
    pub trials: usize,
}

/// The mean electrons of `shape`'s star of `flux_e` centred at (`x`, `y`) on the canvas, on
/// the background: the simulator's sum of pixel-integrated Gaussian parts
/// ([`startrack_sim::sim::Simulator::star_e`] computes the same pixels), each part separable into a
/// row and a column profile.
pub fn render(shape: &PsfShape, x: f64, y: f64, flux_e: f64) -> Vec<f64> {
    let n = usize::from(CANVAS);
    let mut out = vec![BACKGROUND_E; n * n];
    for p in shape.parts(A_PX) {
        let fx: Vec<f64> = (0..CANVAS)
            .map(|c| pixel_fraction(f64::from(c), x + p.dx_px, p.sigma_px))
            .collect();
        let fy: Vec<f64> = (0..CANVAS)
            .map(|r| pixel_fraction(f64::from(r), y + p.dy_px, p.sigma_px))
            .collect();
        for (row, py) in out.chunks_mut(n).zip(&fy) {
            for (o, px) in row.iter_mut().zip(&fx) {
                *o += flux_e * p.weight * px * py;
            }
        }
    }
    out
}

/// The star's flux, e-.
pub fn flux_e() -> f64 {
    flux_for_snr(SNR, 5.0, BACKGROUND_E + READ_NOISE_E * READ_NOISE_E)
}

/// Runs `p` (a window of `side`) on `img`, centred on the canvas's centre pixel.
fn run_on(p: &PreparedMethod, side: u16, img: &[f64]) -> Option<Centroid> {
    let half = side / 2;
    let rect = Rect {
        x0: CENTRE.checked_sub(half)?,
        y0: CENTRE.checked_sub(half)?,
        width: side,
        height: side,
    };
    let mut e = Vec::with_capacity(rect.len());
    for r in rect.y0..rect.y0 + rect.height {
        for c in rect.x0..rect.x0 + rect.width {
            let v = img.get(usize::from(r * CANVAS + c)).copied().unwrap_or(0.0);
            e.push(Electrons::from_num(v.clamp(-33_554_431.0, 33_554_431.0)));
        }
    }
    Some(p.run(&CentroidInput::new(Window::new(rect, &e)?)))
}

/// A seed per shape: every method sees the same stars (common random numbers).
fn shape_seed(seed: u64, index: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (index as u64).rotate_left(23)
}

/// One method's accumulators.
#[derive(Clone, Copy, Default)]
struct Acc {
    bx: f64,
    by: f64,
    s2: f64,
    n0: usize,
    pf0: usize,
    ex: f64,
    ex2: f64,
    e2: f64,
    n: usize,
    pf: usize,
    failed: usize,
}

impl Acc {
    fn cell(&self, method: Method, shape: &Shape, trials: usize) -> ShapeCell {
        let or_nan = |n: usize, v: f64| if n == 0 { f64::NAN } else { v };
        let (n0, n) = (self.n0.max(1) as f64, self.n.max(1) as f64);
        let mean = self.ex / n;
        let var_x = (self.ex2 / n - mean * mean).max(0.0) * n / (n - 1.0).max(1.0);
        ShapeCell {
            method,
            shape: *shape,
            bias_x_px: or_nan(self.n0, self.bx / n0),
            bias_y_px: or_nan(self.n0, self.by / n0),
            sys_rms_px: or_nan(self.n0, (self.s2 / (2.0 * n0)).sqrt()),
            sys_poor_fit: self.pf0,
            mean_err_x_px: or_nan(self.n, mean),
            mean_err_x_se_px: or_nan(self.n, (var_x / n).sqrt()),
            rms_px: or_nan(self.n, (self.e2 / (2.0 * n)).sqrt()),
            poor_fit_rate: self.pf as f64 / trials.max(1) as f64,
            failed: self.failed,
            trials,
        }
    }
}

/// Every method of `methods` on shape number `index` of [`shapes`] (the same stars for
/// all); methods that do not apply (no correction curve at [`A_PX`]) are left out.
pub fn run_shape(
    methods: &[Method],
    shape: &Shape,
    index: usize,
    spec: &ShapeSpec,
) -> Vec<ShapeCell> {
    let var = BACKGROUND_E + READ_NOISE_E * READ_NOISE_E;
    let prepared: Vec<Option<PreparedMethod>> = methods
        .iter()
        .map(|&m| PreparedMethod::new(m, A_PX, BACKGROUND_E, var))
        .collect();
    let flux = flux_e();
    let centre = f64::from(CENTRE);
    let bad = CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED;
    let mut acc = vec![Acc::default(); methods.len()];
    // Noise-free, phases evenly over the centre pixel.
    let ph = |k: usize| (k as f64 + 0.5) / PHASES as f64 - 0.5;
    for i in 0..PHASES {
        for j in 0..PHASES {
            let (x, y) = (centre + ph(i), centre + ph(j));
            let img = render(&shape.psf, x, y, flux);
            for ((m, p), a) in methods.iter().zip(&prepared).zip(acc.iter_mut()) {
                let Some(c) = p.as_ref().and_then(|p| run_on(p, m.window_side(), &img)) else {
                    continue;
                };
                if c.flags.contains(CentroidFlags::POOR_FIT) {
                    a.pf0 += 1;
                }
                if c.flags.intersects(bad) {
                    continue;
                }
                let (dx, dy) = (f64::from(c.x_px) - x, f64::from(c.y_px) - y);
                a.bx += dx;
                a.by += dy;
                a.s2 += dx * dx + dy * dy;
                a.n0 += 1;
            }
        }
    }
    // Noisy stars.
    let mut rng = ChaCha8Rng::seed_from_u64(shape_seed(spec.seed, index));
    let (Ok(u), Ok(read)) = (Uniform::new(-0.5, 0.5), Normal::new(0.0, READ_NOISE_E)) else {
        return Vec::new();
    };
    for _ in 0..spec.trials {
        let (x, y) = (centre + u.sample(&mut rng), centre + u.sample(&mut rng));
        let noisy: Vec<f64> = render(&shape.psf, x, y, flux)
            .iter()
            .map(|&m| {
                Poisson::new(m.max(1e-9)).map_or(m, |d| d.sample(&mut rng)) + read.sample(&mut rng)
            })
            .collect();
        for ((m, p), a) in methods.iter().zip(&prepared).zip(acc.iter_mut()) {
            let Some(c) = p.as_ref().and_then(|p| run_on(p, m.window_side(), &noisy)) else {
                continue;
            };
            if c.flags.contains(CentroidFlags::POOR_FIT) {
                a.pf += 1;
            }
            if c.flags.intersects(bad) {
                a.failed += 1;
                continue;
            }
            let (dx, dy) = (f64::from(c.x_px) - x, f64::from(c.y_px) - y);
            a.ex += dx;
            a.ex2 += dx * dx;
            a.e2 += dx * dx + dy * dy;
            a.n += 1;
        }
    }
    methods
        .iter()
        .zip(&prepared)
        .zip(&acc)
        .filter(|((_, p), _)| p.is_some())
        .map(|((&m, _), a)| a.cell(m, shape, spec.trials))
        .collect()
}

/// Every method on every shape, shape-major.
pub fn run(methods: &[Method], spec: &ShapeSpec) -> Vec<ShapeCell> {
    shapes()
        .iter()
        .enumerate()
        .flat_map(|(i, s)| run_shape(methods, s, i, spec))
        .collect()
}

/// psf-shapes.csv's column names.
pub const COLUMNS: &str = "method,shape,size_px,bias_x_px,bias_y_px,sys_rms_px,sys_poor_fit,mean_err_x_px,mean_err_x_se_px,rms_px,poor_fit_rate,failed,trials";

/// One CSV row (see [`COLUMNS`]).
pub fn csv_row(c: &ShapeCell) -> String {
    format!(
        "{},{},{},{:.4},{:.4},{:.4},{},{:.5},{:.5},{:.5},{:.4},{},{}",
        c.method.name(),
        c.shape.name,
        c.shape.size_px,
        c.bias_x_px,
        c.bias_y_px,
        c.sys_rms_px,
        c.sys_poor_fit,
        c.mean_err_x_px,
        c.mean_err_x_se_px,
        c.rms_px,
        c.poor_fit_rate,
        c.failed,
        c.trials
    )
}

/// Writes psf-shapes.csv into `out`.
pub fn write(
    out: &Path,
    spec: &ShapeSpec,
    cells: &[ShapeCell],
    w: &mut Written,
) -> Result<(), FigureError> {
    let header = vec![
        "Position bias of every centroid method on non-Gaussian PSFs (startrack tradeoff --psf-shapes); definitions in host-tests/analysis/src/tradeoff/shapes.rs".to_string(),
        format!(
            "true centre: the PSF's centroid (first moment); core a = {A_PX} px per Gaussian part; defocus: ring of radius size_px; coma: tail of length size_px along +x; background {BACKGROUND_E} e-/px, read noise {READ_NOISE_E} e-"
        ),
        format!(
            "noise-free: {PHASES} x {PHASES} phases (bias_x_px, bias_y_px: mean signed error; sys_rms_px: RMS both axes; sys_poor_fit: of {}); noisy: {} stars at eq. 8 SNR {SNR} (5x5, Gaussian of the same flux), seed {}; failed = degenerate or not converged (left out)",
            PHASES * PHASES,
            spec.trials,
            spec.seed
        ),
    ];
    let lines: Vec<String> = cells.iter().map(csv_row).collect();
    write_csv(out, "psf-shapes.csv", &header, COLUMNS, &lines, w)
}
