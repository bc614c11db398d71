//! The relative dark map and the hot pixels from the dark frames.
//!
//! Every dark is bias-subtracted line by line as the core does it (the over-scan level of
//! [`LineLevels::measure`] and the column bias) and converted with its output's gain. Its dark
//! scale is the core's own estimate from the covered pixels ([`DarkScaleEstimator`]: robust
//! against hot covered pixels and cosmic rays), so the map is normalised exactly as the core
//! will use it: `dark_rel = sum(pixel e-) / sum(frame's dark scale e-)` over every dark, at
//! any exposure and temperature (the regular dark scales the same everywhere).
//!
//! Hot pixels have their own temperature law, so they are taken apart: per temperature, a
//! pixel's rate is `sum(e-) / sum(EXPTIME)`; a pixel whose rate at the warmest temperature
//! is above [`HOT_DETECT_FACTOR`] times the covered pixels' rate there is hot, and its
//! `ln rate = ln rate_293 + (T - 293 K) ln 2 / doubling` is fitted by weighted least squares
//! over the temperatures (weights from the Poisson and read noise of each rate).
//!
//! Error: a normal pixel's relative dark has the standard error
//! `sqrt(sum(dark_e + read_e^2)) / sum(scale_e)`. Memory: one f64 map of the full readout and
//! one f32 map per dark temperature, whatever the number of frames. Cost per dark: a median of
//! the over-scan and one sort of the covered pixels per line, one multiply per sample.

use startrack_core::calib::{DarkScaleEstimator, LineLevels};
use startrack_core::geometry::{ReadoutGeometry, Segment};
use startrack_core::table::CalibTable;
use startrack_sim::fits::{MapF32, RawFrame};

/// Reference temperature of the hot-pixel rates, K.
pub const HOT_REFERENCE_K: f64 = 293.0;

/// A pixel above this many times the covered pixels' dark rate at the warmest temperature is
/// hot (below the 5x the targets are stated for, so noise at the border cannot lose one).
pub const HOT_DETECT_FACTOR: f64 = 3.0;

/// Darks at one temperature.
#[derive(Clone, Debug)]
pub struct TempGroup {
    /// `CCDTEMP`, K.
    pub temperature_k: f64,
    /// Per raw element, sum of e- over the frames.
    pub sum_e: Vec<f32>,
    /// Sum of EXPTIME, s.
    pub sum_exptime_s: f64,
    /// Sum of the frames' dark scales, e-.
    pub sum_scale_e: f64,
    /// Frames.
    pub frames: u32,
}

/// Running sums of the darks.
#[derive(Clone, Debug)]
pub struct DarkAccum {
    g: ReadoutGeometry,
    sum_e: Vec<f64>,
    sum_scale_e: f64,
    /// Per temperature, in the order met.
    pub groups: Vec<TempGroup>,
    frames: u32,
}

/// A hot pixel with its own law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HotFit {
    /// Raw column.
    pub col: usize,
    /// Raw line.
    pub row: usize,
    /// Dark rate at 293 K, e-/s.
    pub rate_e_per_s_at_293k: f64,
    /// Temperature rise that doubles it, K.
    pub doubling_k: f64,
}

/// Electrons above bias of each element of `line` (levels measured on it as the core does).
pub fn line_electrons(table: &CalibTable<'_>, line: &[u16], levels: &LineLevels, out: &mut [f64]) {
    let g = table.geometry();
    for (c, (o, &v)) in out.iter_mut().zip(line).enumerate() {
        let op = g.output_of_col(c);
        let bias = levels.bias(op).to_num::<f64>() + table.column_bias(c).to_num::<f64>();
        *o = (f64::from(v) - bias) * table.gain(op).to_num::<f64>();
    }
}

impl DarkAccum {
    /// Empty sums for `g`.
    pub fn new(g: &ReadoutGeometry) -> Self {
        Self {
            g: *g,
            sum_e: vec![0.0; usize::from(g.lines) * g.line_len()],
            sum_scale_e: 0.0,
            groups: Vec::new(),
            frames: 0,
        }
    }

    /// Adds one dark of `exptime_s` at `temperature_k`, with `table` (gains and column bias);
    /// returns the frame's dark scale, e- (`None`: no covered sample, or a line the core
    /// cannot measure).
    pub fn add(
        &mut self,
        f: &RawFrame,
        table: &CalibTable<'_>,
        exptime_s: f64,
        temperature_k: f64,
    ) -> Option<f64> {
        let len = self.g.line_len();
        let mut est = DarkScaleEstimator::new();
        let mut e = vec![0.0f64; len];
        let gi = match self
            .groups
            .iter()
            .position(|t| t.temperature_k == temperature_k)
        {
            Some(i) => i,
            None => {
                self.groups.push(TempGroup {
                    temperature_k,
                    sum_e: vec![0.0; self.sum_e.len()],
                    sum_exptime_s: 0.0,
                    sum_scale_e: 0.0,
                    frames: 0,
                });
                self.groups.len() - 1
            }
        };
        let group = self.groups.get_mut(gi)?;
        for (l, line) in f.lines().enumerate() {
            let levels = LineLevels::measure(&self.g, line).ok()?;
            est.add_line(table, line, &levels).ok()?;
            line_electrons(table, line, &levels, &mut e);
            let at = l * len;
            for (i, v) in e.iter().enumerate() {
                if let Some(s) = self.sum_e.get_mut(at + i) {
                    *s += v;
                }
                if let Some(s) = group.sum_e.get_mut(at + i) {
                    *s += *v as f32;
                }
            }
        }
        let scale = est.estimate()?.to_num::<f64>();
        self.sum_scale_e += scale;
        group.sum_exptime_s += exptime_s;
        group.sum_scale_e += scale;
        group.frames += 1;
        self.frames += 1;
        Some(scale)
    }

    /// Darks added.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The relative dark map of the full readout (covered dark scale = 1); `None` when the
    /// darks' scales do not sum to a positive value.
    pub fn relative_map(&self) -> Option<MapF32> {
        if !(self.sum_scale_e.is_finite() && self.sum_scale_e > 0.0) {
            return None;
        }
        Some(MapF32 {
            rows: usize::from(self.g.lines),
            cols: self.g.line_len(),
            data: self
                .sum_e
                .iter()
                .map(|s| (s / self.sum_scale_e) as f32)
                .collect(),
            keys: Vec::new(),
        })
    }

    /// The covered pixels' dark rate at each temperature, e-/s, sorted by temperature.
    pub fn covered_rates(&self) -> Vec<(f64, f64)> {
        let mut v: Vec<(f64, f64)> = self
            .groups
            .iter()
            .filter(|t| t.sum_exptime_s > 0.0)
            .map(|t| (t.temperature_k, t.sum_scale_e / t.sum_exptime_s))
            .collect();
        v.sort_by(|a, b| a.0.total_cmp(&b.0));
        v
    }

    /// The hot pixels and how many candidates had no usable law; `read_noise_e` per output.
    pub fn hot_pixels(&self, read_noise_e: &[f64]) -> (Vec<HotFit>, usize) {
        let g = self.g;
        let len = g.line_len();
        let Some(warm) = self
            .groups
            .iter()
            .filter(|t| t.sum_exptime_s > 0.0 && t.sum_scale_e > 0.0)
            .max_by(|a, b| a.temperature_k.total_cmp(&b.temperature_k))
        else {
            return (Vec::new(), 0);
        };
        let threshold = HOT_DETECT_FACTOR * warm.sum_scale_e / warm.sum_exptime_s;
        let (mut hot, mut unfitted) = (Vec::new(), 0usize);
        for (i, s) in warm.sum_e.iter().enumerate() {
            let (row, col) = (i / len, i % len);
            if !matches!(g.segment(col), Some(Segment::Active | Segment::Covered)) {
                continue;
            }
            if f64::from(*s) / warm.sum_exptime_s <= threshold {
                continue;
            }
            let read = read_noise_e
                .get(usize::from(g.output_of_col(col).0))
                .copied()
                .unwrap_or(0.0);
            match self.fit_law(i, read) {
                Some((rate, doubling)) => hot.push(HotFit {
                    col,
                    row,
                    rate_e_per_s_at_293k: rate,
                    doubling_k: doubling,
                }),
                None => unfitted += 1,
            }
        }
        (hot, unfitted)
    }

    /// Weighted fit of `ln rate` against temperature for element `i`: (rate at 293 K,
    /// doubling K), or `None` with fewer than two usable temperatures or no rise.
    fn fit_law(&self, i: usize, read_e: f64) -> Option<(f64, f64)> {
        let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut n = 0;
        for t in &self.groups {
            let s = f64::from(*t.sum_e.get(i)?);
            if t.sum_exptime_s <= 0.0 || s <= 0.0 {
                continue;
            }
            let var = s + f64::from(t.frames) * read_e * read_e;
            let rel = var.sqrt() / s;
            if rel > 0.5 {
                continue;
            }
            let (x, y, w) = (
                t.temperature_k - HOT_REFERENCE_K,
                (s / t.sum_exptime_s).ln(),
                1.0 / (rel * rel),
            );
            sw += w;
            sx += w * x;
            sy += w * y;
            sxx += w * x * x;
            sxy += w * x * y;
            n += 1;
        }
        if n < 2 {
            return None;
        }
        let det = sw * sxx - sx * sx;
        if det <= 0.0 {
            return None;
        }
        let b = (sw * sxy - sx * sy) / det;
        let a = (sy - b * sx) / sw;
        (b > 0.0).then(|| (a.exp(), std::f64::consts::LN_2 / b))
    }
}

/// The covered pixels' dark law fitted across the darks' temperatures: the law the tracker
/// measures its dark drift against (table section 11, `covered_dark_law` in `report.json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoveredLaw {
    /// Mean dark rate of the covered pixels at [`HOT_REFERENCE_K`], e-/px/s (the core's
    /// covered dark scale per second).
    pub rate_e_per_s_at_293k: f64,
    /// The rate doubles every this many kelvin.
    pub doubling_k: f64,
}

/// Least-squares fit of `ln rate` against temperature over `rates` ((K, e-/s), one per
/// temperature, as [`DarkAccum::covered_rates`] gives them): `None` with fewer than
/// two temperatures of positive rate, or a rate that does not rise with temperature. Each
/// temperature weighs the same: its rate is the mean over all its darks of a few thousand
/// covered pixels, a relative error of about 1 %, far below the spread of the rates.
pub fn fit_covered_law(rates: &[(f64, f64)]) -> Option<CoveredLaw> {
    let pts: Vec<(f64, f64)> = rates
        .iter()
        .filter(|(t, r)| t.is_finite() && r.is_finite() && *r > 0.0)
        .map(|(t, r)| (t - HOT_REFERENCE_K, r.ln()))
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let n = pts.len() as f64;
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let b = sxy / sxx;
    let a = my - b * mx;
    (b > 0.0).then(|| CoveredLaw {
        rate_e_per_s_at_293k: a.exp(),
        doubling_k: std::f64::consts::LN_2 / b,
    })
}
