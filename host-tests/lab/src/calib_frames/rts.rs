//! Telegraph (random telegraph signal) pixels from the longest time-ordered dark series: the
//! darks of the one setting (a temperature within the regulation band, an exposure within
//! rounding) with the most frames, at least [`MIN_SERIES_FRAMES`], in `DATE-OBS` order.
//!
//! A pixel's temporal noise in the series is known without looking at its own scatter:
//! `sigma^2 = mean / gain + var_bias` in ADU^2 (its dark's shot noise, the read noise and the
//! rounding, measured on the bias pairs). Two tests against it, each with a false-alarm
//! probability of [`FALSE_ALARM_PER_TEST`] per pixel on pure Gaussian noise, so that at most
//! `2 x FALSE_ALARM_PER_TEST` (20 per million) normal pixels are flagged:
//! - variance: `(n - 1) var / sigma^2` above the chi-square quantile of `n - 1` degrees
//!   (Wilson-Hilferty), which finds telegraph pixels that switch often or spend a fair share
//!   of the series in each state; a pixel whose largest value alone explains more than
//!   [`SINGLE_FRAME_SHARE`] of the variance is not flagged by it (a cosmic-ray hit);
//! - dwell scan: the highest `min(x_t, x_t+1)` over consecutive frame pairs above the mean
//!   (without the largest frame, which one cosmic-ray hit would pull up), or that mean above
//!   the lowest `max(x_t, x_t+1)`, by more than `a sigma`, with
//!   `2 (n - 1) Q(a)^2 = FALSE_ALARM_PER_TEST` (Q the normal tail; a union bound over the
//!   pairs, so the rate is at most that). Two frames in a row in the other state are needed,
//!   so one cosmic-ray hit never passes; it finds the pixels that visit their rarer state
//!   for a few frames only, which the variance misses.
//!
//! A telegraph step is found when it is about 5 times the pixel's temporal noise (5 read-noise
//! sigmas in short darks; a hot pixel's own shot noise raises its noise, and the step it
//! needs, with its dark) and the pixel dwells two frames or more in each state at least once.
//! Each frame is referred to its outputs' mean over-scan level (not the per-line median,
//! whose own noise would add to every pixel's variance).
//!
//! Memory: six maps (sum and sum of squares in f64; the previous frame, the largest value and
//! the two pair extremes in f32) of the full readout, whatever the series' length; cost: a
//! few operations per sample.

use super::ptc::overscan_mean;
use startrack_core::geometry::{ReadoutGeometry, Segment};
use startrack_sim::fits::RawFrame;

/// Fewest frames a series needs for telegraph detection.
pub const MIN_SERIES_FRAMES: u32 = 10;
/// False-alarm probability per pixel of each of the two tests on pure Gaussian noise.
pub const FALSE_ALARM_PER_TEST: f64 = 1e-5;
/// Largest share of the variance a single frame may hold in a pixel the variance test flags.
pub const SINGLE_FRAME_SHARE: f64 = 0.5;

/// Upper tail of the standard normal, `P(Z > z)`.
pub fn normal_tail(z: f64) -> f64 {
    0.5 * libm::erfc(z / std::f64::consts::SQRT_2)
}

/// The `z` with `normal_tail(z) = p`, for `p` in (0, 0.5] (bisection to 1e-10; `p` outside
/// that range is clamped).
pub fn normal_upper_quantile(p: f64) -> f64 {
    let p = p.clamp(1e-300, 0.5);
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if normal_tail(mid) > p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-10 {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// Upper `p` quantile of the chi-square distribution of `nu` degrees, by Wilson-Hilferty:
/// `nu (1 - 2 / (9 nu) + z sqrt(2 / (9 nu)))^3` (a relative error below 1 % of the quantile
/// for `nu >= 9` at `p = 1e-5`, checked against the exact tail in the tests).
pub fn chi_square_upper_quantile(nu: f64, p: f64) -> f64 {
    let z = normal_upper_quantile(p);
    let k = 2.0 / (9.0 * nu.max(1.0));
    nu * (1.0 - k + z * k.sqrt()).max(0.0).powi(3)
}

/// The dwell scan's threshold `a`, sigmas, for `frames` frames: `2 (n - 1) Q(a)^2 = p`.
pub fn scan_threshold_sigma(frames: u32, p: f64) -> f64 {
    let pairs = f64::from(frames.saturating_sub(1).max(1));
    normal_upper_quantile((p / (2.0 * pairs)).sqrt())
}

/// The variance test's threshold, the ratio `var / sigma^2`, for `frames` frames.
pub fn variance_threshold_ratio(frames: u32, p: f64) -> f64 {
    let nu = f64::from(frames.saturating_sub(1).max(1));
    chi_square_upper_quantile(nu, p) / nu
}

/// Running moments and pair extremes of the series.
#[derive(Clone, Debug)]
pub struct SeriesAccum {
    g: ReadoutGeometry,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    max: Vec<f32>,
    prev: Vec<f32>,
    /// Highest min(x_t, x_t+1).
    pair_high: Vec<f32>,
    /// Lowest max(x_t, x_t+1).
    pair_low: Vec<f32>,
    frames: u32,
}

/// Why a pixel is flagged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Test {
    /// Its variance.
    Variance,
    /// Its dwell scan.
    Scan,
}

impl SeriesAccum {
    /// Empty moments for `g`.
    pub fn new(g: &ReadoutGeometry) -> Self {
        let n = usize::from(g.lines) * g.line_len();
        Self {
            g: *g,
            sum: vec![0.0; n],
            sum_sq: vec![0.0; n],
            max: vec![f32::MIN; n],
            prev: vec![0.0; n],
            pair_high: vec![f32::MIN; n],
            pair_low: vec![f32::MAX; n],
            frames: 0,
        }
    }

    /// Adds the next frame of the series (in time order); `column_bias_adu` per raw column.
    pub fn add(&mut self, f: &RawFrame, column_bias_adu: &[f64]) {
        let g = self.g;
        let len = g.line_len();
        let levels: Vec<f64> = (0..g.outputs)
            .map(|o| overscan_mean(f, &g, startrack_core::geometry::Output(o)))
            .collect();
        let refs: Vec<f64> = (0..len)
            .map(|c| {
                levels
                    .get(usize::from(g.output_of_col(c).0))
                    .copied()
                    .unwrap_or(0.0)
                    + column_bias_adu.get(c).copied().unwrap_or(0.0)
            })
            .collect();
        let first = self.frames == 0;
        for (i, &v) in f.data_adu.iter().enumerate() {
            let x = f64::from(v) - refs.get(i % len).copied().unwrap_or(0.0);
            let xf = x as f32;
            if let (Some(s), Some(q), Some(m), Some(p), Some(h), Some(l)) = (
                self.sum.get_mut(i),
                self.sum_sq.get_mut(i),
                self.max.get_mut(i),
                self.prev.get_mut(i),
                self.pair_high.get_mut(i),
                self.pair_low.get_mut(i),
            ) {
                *s += x;
                *q += x * x;
                *m = m.max(xf);
                if !first {
                    *h = h.max(p.min(xf));
                    *l = l.min(p.max(xf));
                }
                *p = xf;
            }
        }
        self.frames += 1;
    }

    /// Frames added.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The telegraph pixels (raw column, raw line), given each output's gain and bias-pair
    /// variance (read noise and rounding, ADU^2).
    pub fn telegraph(&self, gains: &[f64], bias_var_adu2: &[f64]) -> Vec<(usize, usize)> {
        self.telegraph_tests(gains, bias_var_adu2)
            .into_iter()
            .map(|(c, l, _)| (c, l))
            .collect()
    }

    /// [`Self::telegraph`] with the test that flagged each pixel (the variance's first).
    pub fn telegraph_tests(
        &self,
        gains: &[f64],
        bias_var_adu2: &[f64],
    ) -> Vec<(usize, usize, Test)> {
        let g = self.g;
        let len = g.line_len();
        if self.frames < 3 {
            return Vec::new();
        }
        let n = f64::from(self.frames);
        let var_ratio = variance_threshold_ratio(self.frames, FALSE_ALARM_PER_TEST);
        let scan_sigma = scan_threshold_sigma(self.frames, FALSE_ALARM_PER_TEST);
        let mut found = Vec::new();
        for (i, (((&s, &q), &mx), (&hi, &lo))) in self
            .sum
            .iter()
            .zip(&self.sum_sq)
            .zip(&self.max)
            .zip(self.pair_high.iter().zip(&self.pair_low))
            .enumerate()
        {
            let col = i % len;
            if !matches!(g.segment(col), Some(Segment::Active | Segment::Covered)) {
                continue;
            }
            let o = usize::from(g.output_of_col(col).0);
            let (gain, bv) = (
                gains.get(o).copied().unwrap_or(1.0),
                bias_var_adu2.get(o).copied().unwrap_or(0.0),
            );
            let mean = s / n;
            let var = (q - n * mean * mean) / (n - 1.0);
            // The level the scan is referred to: the mean without the largest frame, which a
            // cosmic-ray hit would otherwise pull up.
            let center = (s - f64::from(mx)) / (n - 1.0);
            let expected = center.max(0.0) / gain + bv;
            if expected.is_nan() || expected <= 0.0 {
                continue;
            }
            let top = f64::from(mx) - mean;
            if var > var_ratio * expected && top * top <= SINGLE_FRAME_SHARE * (n - 1.0) * var {
                found.push((col, i / len, Test::Variance));
                continue;
            }
            let sigma = expected.sqrt();
            let excursion = (f64::from(hi) - center).max(center - f64::from(lo));
            if excursion > scan_sigma * sigma {
                found.push((col, i / len, Test::Scan));
            }
        }
        found
    }
}
