//! The centroid bias that charge traps cause, measured on the simulator, the CTI coefficients
//! (table section 8) fitted to it, and the Monte Carlo that checks the core's correction
//! ([`startrack_core::calib::cti`]) removes it.
//!
//! # The experiment
//! A star of flux `F` at (`x`, `y`) of the full readout geometry, PSF width `a`, on a uniform
//! background; its window (the method's side, centred on the star's pixel) is the simulator's
//! expected charge ([`Simulator::expected_e`]) with the trap law [`ChargeTraps`] on and off.
//! - [`CtiExperiment::noiseless_bias`]: the centroid with traps minus the centroid without,
//!   both noise-free: the CTI bias alone (the method's own pixel-phase bias cancels).
//! - [`CtiExperiment::fit`]: the coefficients `s_par`, `s_ser` (per output) and `alpha` of
//!   the core's model `shift = n s (F / F_ref)^-alpha` fitted to noise-free biases over a grid
//!   of fluxes and transfer distances (log-linear least squares on `shift / n`).
//! - [`CtiExperiment::monte_carlo`]: per (SNR, position) cell, `trials` noisy windows drawn in
//!   pairs (the same Gaussian draws, variance of the trap-free mean plus read noise, added to
//!   the trapped and the trap-free means): the bias is the mean of trapped minus trap-free
//!   centroid, the residual the same after the core's correction (which sees the trapped
//!   window's own measured flux). Pairing cancels the noise to first order, so a few dozen
//!   trials per cell measure a bias of a few millipixels.
//!
//! Cost: a window is `side^2 (1 + trail)^2` evaluations of the trap-free expected charge; a
//! Monte Carlo cell `trials` x 2 centroids.

use fixed::types::{U0F16, U0F32};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use startrack_analysis::accuracy::{Method, PreparedMethod, flux_for_snr};
use startrack_core::calib::cti::CtiCorrection;
use startrack_core::centroid::{Centroid, CentroidFlags, CentroidInput};
use startrack_core::geometry::{MAX_OUTPUTS, ReadoutGeometry};
use startrack_core::table::{CtiCoeffs, CtiOutput};
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::sim::effects::ChargeTraps;
use startrack_sim::sim::psf::sigma_of_a;
use startrack_sim::sim::{Effects, SensorParams, Simulator, Star};
use std::fmt::Write as _;

/// The fluxes of the CTI fit's noise-free grid, e- (`calib cti` and the lab's EPER fit).
pub const CTI_FIT_FLUXES_E: [f64; 8] = [
    300.0, 600.0, 1200.0, 2500.0, 5000.0, 10_000.0, 20_000.0, 45_000.0,
];

/// The trap law the docs and tests use: 5e-5 (parallel) and 3e-5 (serial) per transfer at
/// 1000 e-, alpha 0.5, a 3-pixel trail decaying by half (mean delay 1.57 px): for the flight
/// method about 0.038 px of bias for a 300 e- star on the far rows of the CCD47-20, 0.015 px
/// at 45,000 e- (`startrack calib cti`'s `cti_bias.csv`).
pub const DEFAULT_TRAPS: ChargeTraps = ChargeTraps {
    parallel_per_transfer: 5.0e-5,
    serial_per_transfer: 3.0e-5,
    reference_e: 1000.0,
    alpha: 0.5,
    trail_px: 3,
    decay: 0.5,
};

/// The reference flux of fitted coefficients, e-.
pub const REFERENCE_FLUX_E: u32 = 10_000;

/// One measured bias.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BiasPoint {
    /// Star flux, e-.
    pub flux_e: f64,
    /// The flux the method measures on the trapped window, e- (what the core's correction
    /// sees).
    pub measured_flux_e: f64,
    /// Active column of the star.
    pub x_px: f64,
    /// Active row of the star.
    pub y_px: f64,
    /// Parallel transfers of its charge.
    pub transfers_par: f64,
    /// Serial transfers of its charge.
    pub transfers_ser: f64,
    /// Output that read it.
    pub output: u8,
    /// Bias along x, px.
    pub bias_x_px: f64,
    /// Bias along y, px.
    pub bias_y_px: f64,
}

/// One Monte Carlo cell: bias and residual after the correction, with their standard errors.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct McCell {
    /// SNR of the star (eq. 8, 5x5 box).
    pub snr: f64,
    /// Its flux, e-.
    pub flux_e: f64,
    /// Active column, row of the star.
    pub x_px: f64,
    /// Active row of the star.
    pub y_px: f64,
    /// Mean trapped minus trap-free centroid (x, y), px.
    pub bias_px: (f64, f64),
    /// The same after the core's correction (x, y), px.
    pub residual_px: (f64, f64),
    /// Standard error of the residual's mean (x, y), px.
    pub residual_se_px: (f64, f64),
    /// Pairs used (neither centroid flagged degenerate or not converged).
    pub used: usize,
}

/// A CTI experiment: the sensor geometry, the trap law, the star's PSF and the method.
#[derive(Clone, Debug)]
pub struct CtiExperiment {
    /// Readout geometry.
    pub geometry: ReadoutGeometry,
    /// Trap law of the simulator.
    pub traps: ChargeTraps,
    /// PSF 80 %-energy radius, px.
    pub a_px: f64,
    /// Centroid method.
    pub method: Method,
    /// Background, e- per pixel.
    pub background_e: f64,
    /// Read noise, e- RMS.
    pub read_noise_e: f64,
}

impl CtiExperiment {
    /// The flight method (the Gauss fit on a 7x7 window, `TrackerConfig::FLIGHT`) on the
    /// CCD47-20 read through both outputs, a = 1.2 px, 100 e- of background, 5 e- read noise.
    pub fn flight(traps: ChargeTraps) -> Self {
        Self {
            geometry: ReadoutGeometry::CCD47_20_DUAL,
            traps,
            a_px: 1.2,
            method: Method::GaussFit { window: 7 },
            background_e: 100.0,
            read_noise_e: 5.0,
        }
    }

    fn simulator(&self, star: Star, traps: bool) -> Simulator {
        let params = SensorParams {
            geometry: self.geometry,
            noise: false,
            dark_mean_e: 0.0,
            dsnu: 0.0,
            prnu: 0.0,
            column_bias_sigma_adu: 0.0,
            sky_e: self.background_e,
            full_well_e: f64::INFINITY,
            effects: Effects {
                traps: traps.then_some(self.traps),
                ..Effects::default()
            },
            ..SensorParams::default()
        };
        Simulator::new(params, vec![star])
    }

    /// The method's window around (`x_px`, `y_px`) (clamped inside the active area).
    fn rect(&self, x_px: f64, y_px: f64) -> Rect {
        let side = self.method.window_side();
        let half = f64::from(side / 2);
        let g = &self.geometry;
        let x0 = (x_px.round() - half).clamp(0.0, f64::from(g.active_cols - side));
        let y0 = (y_px.round() - half).clamp(0.0, f64::from(g.active_rows - side));
        Rect {
            x0: x0 as u16,
            y0: y0 as u16,
            width: side,
            height: side,
        }
    }

    /// Expected electrons of the window, with traps or without, row-major.
    fn window_mean(&self, star: Star, rect: Rect, traps: bool) -> Vec<f64> {
        let sim = self.simulator(star, traps);
        let g = &self.geometry;
        (rect.y0..rect.y0 + rect.height)
            .flat_map(|y| (rect.x0..rect.x0 + rect.width).map(move |x| (x, y)))
            .map(|(x, y)| {
                sim.expected_e(g.raw_col_of_x(usize::from(x)), usize::from(y))
                    .0
            })
            .collect()
    }

    fn prepared(&self) -> Option<PreparedMethod> {
        let var = self.background_e + self.read_noise_e.powi(2);
        PreparedMethod::new(self.method, self.a_px, self.background_e, var)
    }

    fn centroid(p: &PreparedMethod, rect: Rect, v: &[f64]) -> Option<Centroid> {
        let e: Vec<Electrons> = v
            .iter()
            .map(|&x| Electrons::from_num(x.clamp(-3.3e7, 3.3e7)))
            .collect();
        let c = p.run(&CentroidInput::new(Window::new(rect, &e)?));
        (!c.flags
            .intersects(CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED))
        .then_some(c)
    }

    /// Transfers (parallel, serial) and output of the charge at (`x_px`, `y_px`), as the core
    /// counts them ([`startrack_core::calib::cti`]).
    pub fn transfers(&self, x_px: f64, y_px: f64) -> (f64, f64, u8) {
        let g = &self.geometry;
        let col = g.raw_col_of_x(x_px.round().max(0.0) as usize);
        let out = g.output_of_col(col).0;
        let n_ser = if out == 0 {
            col + 1
        } else {
            g.line_len() - col
        };
        (y_px.round() + 1.0, n_ser as f64, out)
    }

    /// The noise-free CTI bias (x, y) px of a star of `flux_e` at (`x_px`, `y_px`).
    pub fn noiseless_bias(&self, flux_e: f64, x_px: f64, y_px: f64) -> Option<BiasPoint> {
        let p = self.prepared()?;
        let star = Star {
            x_px,
            y_px,
            signal_e: flux_e,
            a_px: self.a_px,
        };
        let rect = self.rect(x_px, y_px);
        let with = Self::centroid(&p, rect, &self.window_mean(star, rect, true))?;
        let without = Self::centroid(&p, rect, &self.window_mean(star, rect, false))?;
        let (n_par, n_ser, output) = self.transfers(x_px, y_px);
        Some(BiasPoint {
            flux_e,
            measured_flux_e: f64::from(with.flux_e),
            x_px,
            y_px,
            transfers_par: n_par,
            transfers_ser: n_ser,
            output,
            bias_x_px: f64::from(with.x_px) - f64::from(without.x_px),
            bias_y_px: f64::from(with.y_px) - f64::from(without.y_px),
        })
    }

    /// Noise-free biases over `fluxes` and the positions `positions`.
    pub fn bias_grid(&self, fluxes: &[f64], positions: &[(f64, f64)]) -> Vec<BiasPoint> {
        fluxes
            .iter()
            .flat_map(|&f| positions.iter().map(move |&(x, y)| (f, x, y)))
            .filter_map(|(f, x, y)| self.noiseless_bias(f, x, y))
            .collect()
    }

    /// Star positions spanning the active area: `n` x `n` points from a few pixels inside one
    /// corner to the opposite one, each off the pixel grid by a different phase.
    pub fn positions(&self, n: usize) -> Vec<(f64, f64)> {
        let g = &self.geometry;
        let span = |len: u16, i: usize| {
            let lo = 6.0;
            let hi = f64::from(len) - 7.0;
            lo + (hi - lo) * i as f64 / (n.max(2) - 1) as f64
        };
        (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .map(|(i, j)| {
                let phase = 0.37 * ((i * 7 + j * 3) % 5) as f64 / 5.0 - 0.18;
                (
                    span(g.active_cols, i) + phase,
                    span(g.active_rows, j) - phase,
                )
            })
            .collect()
    }

    /// The own side's share of a star's flux minus the other side's at `x_px` (the core's
    /// `k(x)`, in f64; 1 with one output).
    pub fn split_factor(&self, x_px: f64) -> f64 {
        let g = &self.geometry;
        if g.outputs < 2 {
            return 1.0;
        }
        let d = (x_px - (f64::from(g.active_cols / 2) - 0.5)).abs();
        libm::erf(d / (sigma_of_a(self.a_px) * std::f64::consts::SQRT_2))
    }

    /// Fits the core's coefficients to `points` (noise-free biases, against the flux the
    /// method measures): the flux offset `F_0` by a scan of 0 and 40 values from 10 to 30,000
    /// e-, for each `alpha` (one slope) and `s_par`, `s_ser` per output (one intercept each) by
    /// log-linear least squares on the shift per transfer, weighted by the squared bias; the
    /// `F_0` of the least squares wins. A bias of the wrong sign or
    /// below 1e-6 px is left out of the logarithms, and so is the serial bias of a star whose
    /// split factor is under 1/2. `None` with fewer than 3 usable points.
    pub fn fit(&self, points: &[BiasPoint]) -> Option<CtiCoeffs> {
        std::iter::once(0.0)
            .chain((0..40).map(|i| 10.0 * 3000f64.powf(f64::from(i) / 39.0)))
            .filter_map(|f0| self.fit_with_offset(points, f0))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(c, _)| c)
    }

    /// The fit of [`Self::fit`] with the flux offset `f0_e` given, and its sum of squares.
    fn fit_with_offset(&self, points: &[BiasPoint], f0_e: f64) -> Option<(CtiCoeffs, f64)> {
        let fr = f64::from(REFERENCE_FLUX_E);
        // (ln((F + F_0) / F_ref), ln(shift per transfer), group = 2 output + axis, weight):
        // weighted by the squared bias, so the fit is close to least squares on the bias
        // itself (the large biases of faint stars far from the output are the ones to remove).
        let mut obs: Vec<(f64, f64, usize, f64)> = Vec::new();
        for p in points {
            let lf = ((p.measured_flux_e + f0_e) / fr).ln();
            let k = self.split_factor(p.x_px);
            let sx = if p.output == 0 {
                p.bias_x_px
            } else {
                -p.bias_x_px
            };
            let o = usize::from(p.output);
            if p.bias_y_px > 1e-6 {
                let w = p.bias_y_px.powi(2);
                obs.push((lf, (p.bias_y_px / p.transfers_par).ln(), 2 * o, w));
            }
            if sx > 1e-6 && k >= 0.5 {
                obs.push((lf, (sx / (p.transfers_ser * k)).ln(), 2 * o + 1, sx * sx));
            }
        }
        let groups = 2 * MAX_OUTPUTS;
        let mean = |g: usize| {
            let v: Vec<&(f64, f64, usize, f64)> = obs.iter().filter(|o| o.2 == g).collect();
            let w: f64 = v.iter().map(|o| o.3).sum();
            (w > 0.0).then(|| {
                (
                    v.iter().map(|o| o.3 * o.0).sum::<f64>() / w,
                    v.iter().map(|o| o.3 * o.1).sum::<f64>() / w,
                )
            })
        };
        let means: Vec<Option<(f64, f64)>> = (0..groups).map(mean).collect();
        let (mut sxy, mut sxx) = (0.0, 0.0);
        for o in &obs {
            let (mx, my) = means.get(o.2).copied().flatten()?;
            sxy += o.3 * (o.0 - mx) * (o.1 - my);
            sxx += o.3 * (o.0 - mx).powi(2);
        }
        if sxx <= 0.0 || obs.len() < 3 {
            return None;
        }
        let alpha = (-sxy / sxx).clamp(0.0, 0.9999);
        let mut sse = 0.0;
        for o in &obs {
            let (mx, my) = means.get(o.2).copied().flatten()?;
            sse += o.3 * (o.1 - my + alpha * (o.0 - mx)).powi(2);
        }
        let s = |g: usize| {
            means
                .get(g)
                .copied()
                .flatten()
                .map_or(0.0, |(mx, my)| (my + alpha * mx).exp())
        };
        let mut outputs = [CtiOutput::default(); MAX_OUTPUTS];
        for (o, out) in outputs.iter_mut().enumerate() {
            *out = CtiOutput {
                parallel_px: U0F32::saturating_from_num(s(2 * o)),
                serial_px: U0F32::saturating_from_num(s(2 * o + 1)),
            };
        }
        Some((
            CtiCoeffs {
                reference_flux_e: REFERENCE_FLUX_E,
                flux_offset_e: f0_e.round() as u32,
                alpha: U0F16::saturating_from_num(alpha),
                outputs,
            },
            sse,
        ))
    }

    /// The core's correction of `coeffs` for this experiment's geometry and PSF.
    pub fn correction(&self, coeffs: &CtiCoeffs) -> CtiCorrection {
        CtiCorrection::new(*coeffs, self.geometry, sigma_of_a(self.a_px) as f32)
    }

    /// The paired Monte Carlo of one (SNR, position) cell with the core's correction from
    /// `coeffs`; `None` when the method does not apply.
    pub fn monte_carlo_cell(
        &self,
        coeffs: &CtiCoeffs,
        snr: f64,
        x_px: f64,
        y_px: f64,
        trials: usize,
        seed: u64,
    ) -> Option<McCell> {
        let p = self.prepared()?;
        let corr = self.correction(coeffs);
        let var_bg = self.background_e + self.read_noise_e.powi(2);
        let flux_e = flux_for_snr(snr, 5.0, var_bg);
        let star = Star {
            x_px,
            y_px,
            signal_e: flux_e,
            a_px: self.a_px,
        };
        let rect = self.rect(x_px, y_px);
        let with = self.window_mean(star, rect, true);
        let without = self.window_mean(star, rect, false);
        let seed = seed ^ snr.to_bits().rotate_left(13) ^ x_px.to_bits() ^ y_px.to_bits() << 7;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let z = Normal::new(0.0, 1.0).ok()?;
        let (mut b, mut r, mut r2) = ([0.0f64; 2], [0.0f64; 2], [0.0f64; 2]);
        let mut used = 0usize;
        for _ in 0..trials {
            let draws: Vec<f64> = without
                .iter()
                .map(|&m| z.sample(&mut rng) * (m.max(0.0) + self.read_noise_e.powi(2)).sqrt())
                .collect();
            let noisy = |mean: &[f64]| -> Vec<f64> {
                mean.iter().zip(&draws).map(|(m, d)| m + d).collect()
            };
            let (Some(ct), Some(c0)) = (
                Self::centroid(&p, rect, &noisy(&with)),
                Self::centroid(&p, rect, &noisy(&without)),
            ) else {
                continue;
            };
            let cc = corr.corrected(ct);
            let d = [
                f64::from(ct.x_px) - f64::from(c0.x_px),
                f64::from(ct.y_px) - f64::from(c0.y_px),
            ];
            let e = [
                f64::from(cc.x_px) - f64::from(c0.x_px),
                f64::from(cc.y_px) - f64::from(c0.y_px),
            ];
            for k in 0..2 {
                b[k] += d[k];
                r[k] += e[k];
                r2[k] += e[k] * e[k];
            }
            used += 1;
        }
        let n = used.max(1) as f64;
        let se = |k: usize| {
            let m = r[k] / n;
            ((r2[k] / n - m * m).max(0.0) / (n - 1.0).max(1.0)).sqrt()
        };
        Some(McCell {
            snr,
            flux_e,
            x_px,
            y_px,
            bias_px: (b[0] / n, b[1] / n),
            residual_px: (r[0] / n, r[1] / n),
            residual_se_px: (se(0), se(1)),
            used,
        })
    }

    /// [`Self::monte_carlo_cell`] over every SNR and position.
    pub fn monte_carlo(
        &self,
        coeffs: &CtiCoeffs,
        snrs: &[f64],
        positions: &[(f64, f64)],
        trials: usize,
        seed: u64,
    ) -> Vec<McCell> {
        snrs.iter()
            .flat_map(|&s| positions.iter().map(move |&(x, y)| (s, x, y)))
            .filter_map(|(s, x, y)| self.monte_carlo_cell(coeffs, s, x, y, trials, seed))
            .collect()
    }
}

/// Summary of Monte Carlo cells: RMS over cells and both axes of the bias, of the residual,
/// and of the residual's standard error.
pub fn summarize(cells: &[McCell]) -> (f64, f64, f64) {
    let n = (2 * cells.len().max(1)) as f64;
    let rms = |f: &dyn Fn(&McCell) -> (f64, f64)| {
        (cells
            .iter()
            .map(|c| {
                let (a, b) = f(c);
                a * a + b * b
            })
            .sum::<f64>()
            / n)
            .sqrt()
    };
    (
        rms(&|c| c.bias_px),
        rms(&|c| c.residual_px),
        rms(&|c| c.residual_se_px),
    )
}

/// The noise-free biases as CSV:
/// `flux_e,measured_flux_e,x_px,y_px,transfers_par,transfers_ser,output,bias_x_px,bias_y_px`.
pub fn bias_csv(points: &[BiasPoint]) -> String {
    csv_text(
        "flux_e,measured_flux_e,x_px,y_px,transfers_par,transfers_ser,output,bias_x_px,bias_y_px",
        points,
        |s, p| {
            writeln!(
                s,
                "{:.1},{:.1},{:.2},{:.2},{},{},{},{:.6},{:.6}",
                p.flux_e,
                p.measured_flux_e,
                p.x_px,
                p.y_px,
                p.transfers_par,
                p.transfers_ser,
                p.output,
                p.bias_x_px,
                p.bias_y_px
            )
        },
    )
}

/// The Monte Carlo cells as CSV:
/// `snr,flux_e,x_px,y_px,bias_x_px,bias_y_px,residual_x_px,residual_y_px,se_x_px,se_y_px,pairs`.
pub fn mc_csv(cells: &[McCell]) -> String {
    csv_text(
        "snr,flux_e,x_px,y_px,bias_x_px,bias_y_px,residual_x_px,residual_y_px,se_x_px,se_y_px,pairs",
        cells,
        |s, c| {
            writeln!(
                s,
                "{},{:.1},{:.2},{:.2},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{}",
                c.snr,
                c.flux_e,
                c.x_px,
                c.y_px,
                c.bias_px.0,
                c.bias_px.1,
                c.residual_px.0,
                c.residual_px.1,
                c.residual_se_px.0,
                c.residual_se_px.1,
                c.used
            )
        },
    )
}

/// A CSV: the `header` line, then each item's line as `row` writes it.
fn csv_text<T>(
    header: &str,
    items: &[T],
    mut row: impl FnMut(&mut String, &T) -> std::fmt::Result,
) -> String {
    let mut s = format!("{header}\n");
    for item in items {
        // Writing into a String cannot fail.
        let _ = row(&mut s, item);
    }
    s
}

/// The CTI coefficients as `calib cti` and `calib frames` write them and `calib build --cti`
/// reads them (JSON): the table's values in plain units.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CtiCoeffsJson {
    /// Reference flux, e-.
    pub reference_flux_e: u32,
    /// Flux offset `F_0`, e-.
    pub flux_offset_e: u32,
    /// Signal exponent.
    pub alpha: f64,
    /// Per output (left first): centroid shift per transfer at the reference flux, px.
    pub outputs: Vec<CtiOutputJson>,
}

/// One output's coefficients in [`CtiCoeffsJson`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CtiOutputJson {
    /// Shift per parallel transfer, px.
    pub parallel_px_per_transfer: f64,
    /// Shift per serial transfer, px.
    pub serial_px_per_transfer: f64,
}

impl CtiCoeffsJson {
    /// The JSON form of `c` for a readout of `outputs` outputs.
    pub fn from_coeffs(c: &CtiCoeffs, outputs: u8) -> Self {
        Self {
            reference_flux_e: c.reference_flux_e,
            flux_offset_e: c.flux_offset_e,
            alpha: c.alpha.to_num(),
            outputs: c
                .outputs
                .iter()
                .take(usize::from(outputs))
                .map(|o| CtiOutputJson {
                    parallel_px_per_transfer: o.parallel_px.to_num(),
                    serial_px_per_transfer: o.serial_px.to_num(),
                })
                .collect(),
        }
    }

    /// The table's value for a readout of `outputs` outputs, or what is out of range.
    pub fn to_coeffs(&self, outputs: u8) -> Result<CtiCoeffs, String> {
        if self.outputs.len() != usize::from(outputs) {
            return Err(format!(
                "{} outputs' coefficients for a readout of {outputs}",
                self.outputs.len()
            ));
        }
        if self.reference_flux_e == 0 {
            return Err("reference_flux_e must be above 0".into());
        }
        let alpha = U0F16::checked_from_num(self.alpha)
            .ok_or_else(|| format!("alpha {}: must be 0 to below 1", self.alpha))?;
        let shift = |v: f64| {
            U0F32::checked_from_num(v)
                .ok_or_else(|| format!("shift per transfer {v} px: must be 0 to below 1"))
        };
        let mut out = [CtiOutput::default(); MAX_OUTPUTS];
        for (o, j) in out.iter_mut().zip(&self.outputs) {
            *o = CtiOutput {
                parallel_px: shift(j.parallel_px_per_transfer)?,
                serial_px: shift(j.serial_px_per_transfer)?,
            };
        }
        Ok(CtiCoeffs {
            reference_flux_e: self.reference_flux_e,
            flux_offset_e: self.flux_offset_e,
            alpha,
            outputs: out,
        })
    }
}
