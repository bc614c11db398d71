//! Telegraph (random telegraph signal) pixels from the longest time-ordered dark series: the
//! darks of the one (EXPTIME, CCDTEMP) setting with the most frames, at least
//! [`MIN_SERIES_FRAMES`].
//!
//! A pixel that switches between two levels has a temporal variance above what its own dark
//! and the read noise allow: `var > RTS_VARIANCE_RATIO x (mean / gain + read^2 + 1/12)` in
//! ADU^2 (for a normal pixel of a 30-frame series the ratio 3 is a 5-sigma chi-square
//! excursion: about 2e-7 false per pixel). A single outlier (a cosmic-ray hit) also raises the
//! variance, but then one frame holds most of it: a pixel whose largest value alone explains
//! more than [`SINGLE_FRAME_SHARE`] of the variance is not flagged. Each frame is referred to
//! its outputs' mean over-scan level (not the per-line median, whose own noise would add to
//! every pixel's variance).
//!
//! Memory: three maps (sum, sum of squares, largest value) of the full readout, whatever the
//! series' length; cost: a few operations per sample.

use super::ptc::overscan_mean;
use startrack_core::geometry::{ReadoutGeometry, Segment};
use startrack_sim::fits::RawFrame;

/// Fewest frames a series needs for telegraph detection.
pub const MIN_SERIES_FRAMES: u32 = 10;
/// Variance over the expected one above which a pixel is flagged.
pub const RTS_VARIANCE_RATIO: f64 = 3.0;
/// Largest share of the variance a single frame may hold in a flagged pixel.
pub const SINGLE_FRAME_SHARE: f64 = 0.5;

/// Running moments of the series.
#[derive(Clone, Debug)]
pub struct SeriesAccum {
    g: ReadoutGeometry,
    sum: Vec<f64>,
    sum_sq: Vec<f64>,
    max: Vec<f32>,
    frames: u32,
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
            frames: 0,
        }
    }

    /// Adds the next frame of the series; `column_bias_adu` per raw column.
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
        for (i, &v) in f.data_adu.iter().enumerate() {
            let x = f64::from(v) - refs.get(i % len).copied().unwrap_or(0.0);
            if let (Some(s), Some(q), Some(m)) = (
                self.sum.get_mut(i),
                self.sum_sq.get_mut(i),
                self.max.get_mut(i),
            ) {
                *s += x;
                *q += x * x;
                *m = m.max(x as f32);
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
        let g = self.g;
        let len = g.line_len();
        let n = f64::from(self.frames);
        if self.frames < 2 {
            return Vec::new();
        }
        let mut found = Vec::new();
        for (i, ((&s, &q), &mx)) in self.sum.iter().zip(&self.sum_sq).zip(&self.max).enumerate() {
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
            let expected = mean.max(0.0) / gain + bv;
            if var <= RTS_VARIANCE_RATIO * expected {
                continue;
            }
            let top = f64::from(mx) - mean;
            if top * top > SINGLE_FRAME_SHARE * (n - 1.0) * var {
                continue;
            }
            found.push((col, i / len));
        }
        found
    }
}
