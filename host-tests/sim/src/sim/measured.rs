//! Calibration maps *measured* the way a ground calibration measures them: from N simulated
//! dark frames (or flat frames), with the calibration noise that leaves, instead of the
//! simulator's truth.
//!
//! Dark: every frame's pixels are bias-subtracted with the over-scan level the core measures
//! on that line ([`LineLevels::measure`]) and converted with the output's gain; the relative
//! dark of a pixel is its sum over the frames divided by the sum of the frames' covered-pixel
//! means (the quantity the core's dark scale estimates), so the map is normalised like the
//! core expects. Its noise per pixel is `sqrt(dark + read^2) / (dark sqrt(N))` relative
//! (e.g. 250 e- dark, 5 e- read, N = 32: 0.012).
//!
//! Flat: N frames of uniform illumination of `level_e` per pixel, dark-subtracted with the
//! true dark, normalised to their mean over the measured region; its noise is about
//! `1 / sqrt(N level_e)` relative.
//!
//! Cost: one rendered sample per pixel of the region per frame, plus the 48 reference
//! elements (over-scan and covered) of each of its lines.

use super::render::Simulator;
use startrack_core::calib::{LineError, LineLevels};
use startrack_core::geometry::{Output, Segment};
use startrack_core::window::Rect;

/// A measured map over the whole active area (row-major, `active_cols` x `active_rows`):
/// measured inside `region`, 1 (no correction) outside.
#[derive(Clone, Debug, PartialEq)]
pub struct MeasuredMap {
    /// The map values.
    pub values: Vec<f64>,
    /// Where it was measured.
    pub region: Rect,
    /// Number of frames averaged.
    pub frames: u32,
}

impl MeasuredMap {
    /// The map of per-pixel sums `sum` (the active area, row-major, `cols` wide):
    /// `value(sum)` inside `region`, 1 (no correction) outside it and where `value` gives
    /// `None`.
    fn from_sums(
        sum: &[f64],
        cols: usize,
        region: Rect,
        frames: u32,
        value: impl Fn(f64) -> Option<f64>,
    ) -> Self {
        let values = sum
            .iter()
            .enumerate()
            .map(|(i, &s)| {
                let (x, y) = ((i % cols) as u16, (i / cols) as u16);
                region
                    .contains(x, y)
                    .then(|| value(s))
                    .flatten()
                    .unwrap_or(1.0)
            })
            .collect();
        Self {
            values,
            region,
            frames,
        }
    }
}

impl Simulator {
    /// Fills `out` (a whole raw line) with only the over-scan and covered elements of `line`
    /// rendered, zeros elsewhere: what the core's levels need, at 48 samples instead of 1072.
    pub fn render_reference_line(&self, line: usize, out: &mut [u16]) {
        let g = self.params.geometry;
        for (col, v) in out.iter_mut().enumerate() {
            *v = match g.segment(col) {
                Some(Segment::OverScan | Segment::Covered) => self.raw_sample(col, line),
                _ => 0,
            };
        }
    }

    /// Electrons of raw sample `raw` at raw column `col` with the line's measured levels:
    /// `(raw - bias - column bias) * gain`. Gains and the column bias are known to calibration
    /// before the dark: the bias map comes from many bias frames, whose noise is neglected
    /// here. Leaving the column bias in would put the bias pattern into the dark map, which
    /// `calib build` would then subtract twice.
    fn electrons_of(&self, raw: u16, col: usize, levels: &LineLevels) -> f64 {
        let g = self.params.geometry;
        let Output(o) = g.output_of_col(col);
        let bias = levels.bias(Output(o)).to_num::<f64>() + self.column_bias_adu(col);
        (f64::from(raw) - bias) * self.params.gain_e_per_adu[usize::from(o)]
    }

    /// Adds to `sum` (the active area, row-major) the electrons of each pixel of `region`
    /// (clipped to the active area) in this frame, minus `minus_e(raw column, line)`:
    /// `(raw - bias) * gain - minus_e`, the bias being the over-scan level of each line as the
    /// core measures it plus the column bias ([`Self::electrons_of`]). `line` is scratch for a whole raw line. Fails where a line's levels cannot
    /// be measured.
    fn add_region_e(
        &self,
        region: Rect,
        sum: &mut [f64],
        line: &mut [u16],
        minus_e: impl Fn(usize, usize) -> f64,
    ) -> Result<(), LineError> {
        let g = self.params.geometry;
        let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
        for y in region.y0..region.y0.saturating_add(region.height) {
            let y = usize::from(y);
            if y >= rows {
                break;
            }
            self.render_reference_line(y, line);
            let lv = LineLevels::measure(&g, line)?;
            for x in region.x0..region.x0.saturating_add(region.width) {
                let x = usize::from(x);
                if x >= cols {
                    break;
                }
                let col = g.raw_col_of_x(x);
                if let Some(v) = sum.get_mut(y * cols + x) {
                    *v += self.electrons_of(self.raw_sample(col, y), col, &lv) - minus_e(col, y);
                }
            }
        }
        Ok(())
    }

    /// The relative dark map measured from `frames` dark frames (frame numbers
    /// `first_frame ..`) of this sensor (its stars are ignored), over `region`, normalised to
    /// the mean of the covered pixels of `covered_lines`: the lines whose covered columns
    /// give the dark scale in use (the whole frame, `0..lines`, on the firmware). Normalising
    /// to other covered pixels than the scale's would leave their fixed-pattern difference as
    /// a uniform dark error.
    pub fn measure_dark_map(
        &self,
        frames: u32,
        first_frame: u32,
        region: Rect,
        covered_lines: std::ops::Range<usize>,
    ) -> Result<MeasuredMap, LineError> {
        let g = self.params.geometry;
        let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
        let mut sum = vec![0.0f64; cols * rows];
        let (mut covered_sum, mut covered_n) = (0.0f64, 0usize);
        let mut line = vec![0u16; g.line_len()];
        for k in 0..frames {
            let dark = Simulator {
                frame: first_frame.wrapping_add(k),
                ..Simulator::new(self.params.clone(), Vec::new())
            };
            for y in covered_lines.clone() {
                if y >= usize::from(g.lines) {
                    break;
                }
                dark.render_reference_line(y, &mut line);
                let lv = LineLevels::measure(&g, &line)?;
                for (s, e) in g.covered_cols() {
                    for col in s..e {
                        covered_sum += dark.electrons_of(dark.raw_sample(col, y), col, &lv);
                        covered_n += 1;
                    }
                }
            }
            dark.add_region_e(region, &mut sum, &mut line, |_, _| 0.0)?;
        }
        let covered_mean_sum = if covered_n == 0 {
            0.0
        } else {
            covered_sum / covered_n as f64 * f64::from(frames)
        };
        Ok(MeasuredMap::from_sums(&sum, cols, region, frames, |s| {
            (covered_mean_sum > 0.0).then(|| s / covered_mean_sum)
        }))
    }

    /// The inverse flat map measured from `frames` uniformly lit frames of `level_e` e- per
    /// pixel (frame numbers `first_frame ..`), over `region`: each pixel's mean of
    /// `(raw - bias) * gain - true dark`, inverted relative to the region's mean.
    pub fn measure_flat_inv_map(
        &self,
        frames: u32,
        first_frame: u32,
        level_e: f64,
        region: Rect,
    ) -> Result<MeasuredMap, LineError> {
        let g = self.params.geometry;
        let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
        let mut sum = vec![0.0f64; cols * rows];
        let mut line = vec![0u16; g.line_len()];
        let mut lit = Simulator::new(
            super::SensorParams {
                sky_e: level_e,
                ..self.params.clone()
            },
            Vec::new(),
        );
        for k in 0..frames {
            lit.frame = first_frame.wrapping_add(k);
            lit.add_region_e(region, &mut sum, &mut line, |col, y| {
                lit.expected_dark_e(col, y)
            })?;
        }
        let inside = |i: usize| region.contains((i % cols) as u16, (i / cols) as u16);
        let (mut tot, mut n) = (0.0, 0usize);
        for (i, s) in sum.iter().enumerate() {
            if inside(i) {
                tot += s;
                n += 1;
            }
        }
        let mean = if n == 0 { 0.0 } else { tot / n as f64 };
        Ok(MeasuredMap::from_sums(&sum, cols, region, frames, |s| {
            (s > 0.0 && mean > 0.0).then(|| mean / s)
        }))
    }
}
