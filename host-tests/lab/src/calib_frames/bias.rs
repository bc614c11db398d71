//! Bias structure: the master bias (per raw element, the mean over the bias frames with the
//! highest and lowest value of each element left out once there are at least
//! [`MINMAX_CLIP_FRAMES`] frames, so a cosmic-ray hit or a glitch in one frame cannot pull it)
//! and from it the column bias against each line's over-scan level, computed by `calib
//! build`'s own conversion ([`crate::table_build::column_bias_from_map`]).
//! Cost: three running maps (sum, min, max) of the full readout; one pass per bias frame.

use startrack_core::geometry::ReadoutGeometry;
use startrack_sim::fits::{MapF32, RawFrame};

/// From this many frames on, each element's extreme values are rejected.
pub const MINMAX_CLIP_FRAMES: u32 = 5;

/// Running master bias.
#[derive(Clone, Debug)]
pub struct BiasAccum {
    sum: Vec<f64>,
    min: Vec<u16>,
    max: Vec<u16>,
    frames: u32,
    lines: usize,
    cols: usize,
}

impl BiasAccum {
    /// An empty accumulator for `g`'s full readout.
    pub fn new(g: &ReadoutGeometry) -> Self {
        let (lines, cols) = (usize::from(g.lines), g.line_len());
        Self {
            sum: vec![0.0; lines * cols],
            min: vec![u16::MAX; lines * cols],
            max: vec![0; lines * cols],
            frames: 0,
            lines,
            cols,
        }
    }

    /// Adds one bias frame (same shape as the geometry).
    pub fn add(&mut self, f: &RawFrame) {
        for (((s, lo), hi), &v) in self
            .sum
            .iter_mut()
            .zip(self.min.iter_mut())
            .zip(self.max.iter_mut())
            .zip(&f.data_adu)
        {
            *s += f64::from(v);
            *lo = (*lo).min(v);
            *hi = (*hi).max(v);
        }
        self.frames += 1;
    }

    /// Frames added.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The master bias, ADU, full readout.
    pub fn master(&self) -> MapF32 {
        let clip = self.frames >= MINMAX_CLIP_FRAMES;
        let data = self
            .sum
            .iter()
            .zip(self.min.iter().zip(&self.max))
            .map(|(&s, (&lo, &hi))| {
                if clip {
                    ((s - f64::from(lo) - f64::from(hi)) / f64::from(self.frames - 2)) as f32
                } else {
                    (s / f64::from(self.frames.max(1))) as f32
                }
            })
            .collect();
        MapF32 {
            rows: self.lines,
            cols: self.cols,
            data,
            keys: Vec::new(),
        }
    }
}
