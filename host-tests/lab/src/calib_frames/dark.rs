//! The relative dark map and the hot pixels from the dark frames.
//!
//! Every dark is bias-subtracted line by line as the core does it (the over-scan level of
//! [`LineLevels::measure`] and the column bias) and converted with its output's gain. Its dark
//! scale is the core's own estimate from the covered pixels ([`DarkScaleEstimator`]: robust
//! against hot covered pixels and cosmic rays), so the map is normalised exactly as the core
//! will use it: `dark_rel = sum(pixel e-) / sum(frame's dark scale e-)` over every dark, at
//! any exposure and temperature (the regular dark scales the same everywhere).
//!
//! Hot pixels have their own temperature law, so they are taken apart: per temperature group
//! (darks within the regulation band, at their mean CCDTEMP), a pixel's rate is the slope of
//! its charge on the exposure when the group's exposures spread (a factor 2 or more), else
//! `sum(e-) / sum(EXPTIME)`: the slope leaves out what does not grow with the exposure (a
//! telegraph pixel's step in each frame is a dark-like excess in short darks only). A pixel
//! whose rate at the warmest temperature is above [`HOT_DETECT_FACTOR`] times the covered
//! pixels' rate there is hot. Its law
//! `rate(T) = rate_293 2^((T - 293 K) / doubling)` is what the core subtracts instead of the
//! regular dark, so it is fitted to the pixel's whole dark (regular part included, as the core
//! applies it): the rates themselves, not their logarithms (whose mean is biased low by
//! `var / (2 mu^2)` and undefined for a rate at or below 0), by iteratively reweighted
//! Gauss-Newton least squares with each point's variance from the law itself (its shot
//! noise at the law's rate and the read noise of its frames; weights from the measured charges would pull the law towards the
//! points that fluctuated high), started from the log-linear fit. The inverse of the normal
//! matrix gives each law's uncertainty: the rate's (relative, from `ln rate_293`) and the
//! doubling temperature's (`ln 2 sigma_b / b^2` for the slope `b` of `ln rate`).
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
    /// Per raw element, sum of e- times EXPTIME, e- s (the charge's regression on the
    /// exposure).
    pub sum_e_t: Vec<f32>,
    /// Sums of EXPTIME^2 and EXPTIME^3, s^2 and s^3.
    pub sum_t2: f64,
    /// See [`Self::sum_t2`].
    pub sum_t3: f64,
    /// Per raw element, its largest charge in one frame, e-, and that frame's number.
    pub max_e: Vec<f32>,
    /// See [`Self::max_e`].
    pub max_frame: Vec<u32>,
}

/// A frame whose charge in a pixel lies this many sigmas above what the pixel's other darks
/// of its temperature predict is a cosmic-ray hit there, and left out of that pixel's sums
/// (one frame per pixel and temperature; a Gaussian 6-sigma excursion has odds of 1e-9).
pub const HIT_REJECT_SIGMAS: f64 = 6.0;

/// One pixel's sums over a temperature group's frames (a rejected hit taken out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelSums {
    /// Frames.
    pub n: f64,
    /// Sum of EXPTIME, s.
    pub st: f64,
    /// Sum of EXPTIME^2.
    pub st2: f64,
    /// Sum of EXPTIME^3.
    pub st3: f64,
    /// Sum of e-.
    pub se: f64,
    /// Sum of e- times EXPTIME.
    pub set: f64,
}

impl PixelSums {
    /// Spread of the exposures, `sum (t - mean t)^2`, s^2.
    pub fn sxx(&self) -> f64 {
        self.st2 - self.st * self.st / self.n.max(1.0)
    }

    /// True when the exposures spread enough for a slope: `sxx` at least a quarter of
    /// `sum t^2` (the shortest and longest a factor 2 or more apart, in effect).
    pub fn has_slope(&self) -> bool {
        self.n >= 3.0 && self.sxx() >= 0.25 * self.st2
    }

    /// The charge predicted at exposure `t`, e-: intercept and slope when the exposures
    /// spread, else the rate through the origin.
    pub fn predict(&self, t: f64) -> Option<f64> {
        if self.st <= 0.0 || self.n < 1.0 {
            return None;
        }
        if self.has_slope() {
            let slope = (self.set - self.se * self.st / self.n) / self.sxx();
            Some((self.se - slope * self.st) / self.n + slope * t)
        } else {
            Some(self.se / self.st * t)
        }
    }

    /// The dark rate, e-/s, and its variance as `(a, b)` with `var = a rate + b` for read
    /// noise `read_e`: the slope of charge on exposure when the exposures spread (a per-frame
    /// offset, such as a telegraph pixel's step, does not enter it), else the charge over
    /// the exposure.
    pub fn rate(&self, read_e: f64) -> Option<(f64, f64, f64)> {
        if self.st <= 0.0 {
            return None;
        }
        let r2 = read_e * read_e;
        if self.has_slope() {
            let sxx = self.sxx();
            let slope = (self.set - self.se * self.st / self.n) / sxx;
            // var(slope) = sum (t - tm)^2 (rate t + read^2) / sxx^2.
            let tm = self.st / self.n;
            let w = self.st3 - 2.0 * tm * self.st2 + tm * tm * self.st;
            Some((slope, w / (sxx * sxx), r2 / sxx))
        } else {
            Some((
                self.se / self.st,
                1.0 / self.st,
                self.n * r2 / (self.st * self.st),
            ))
        }
    }
}

impl TempGroup {
    /// Element `i`'s sums, with its largest frame left out when that frame is a hit
    /// ([`HIT_REJECT_SIGMAS`] above what the other frames predict); `exptime_s` is every
    /// dark's EXPTIME by frame number. Also the frame left out.
    pub fn pixel_sums(
        &self,
        i: usize,
        read_e: f64,
        exptime_s: &[f64],
    ) -> Option<(PixelSums, Option<u32>)> {
        let all = PixelSums {
            n: f64::from(self.frames),
            st: self.sum_exptime_s,
            st2: self.sum_t2,
            st3: self.sum_t3,
            se: f64::from(*self.sum_e.get(i)?),
            set: f64::from(*self.sum_e_t.get(i)?),
        };
        let (Some(&e), Some(&k)) = (self.max_e.get(i), self.max_frame.get(i)) else {
            return Some((all, None));
        };
        let Some(&t) = exptime_s.get(k as usize) else {
            return Some((all, None));
        };
        let (e, t2) = (f64::from(e), t * t);
        let rest = PixelSums {
            n: all.n - 1.0,
            st: all.st - t,
            st2: all.st2 - t2,
            st3: all.st3 - t2 * t,
            se: all.se - e,
            set: all.set - e * t,
        };
        if rest.n < 2.0 {
            return Some((all, None));
        }
        let Some(mu) = rest.predict(t) else {
            return Some((all, None));
        };
        let sigma = (mu.max(0.0) + read_e * read_e).sqrt();
        if e - mu > HIT_REJECT_SIGMAS * sigma {
            Some((rest, Some(k)))
        } else {
            Some((all, None))
        }
    }
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
    /// Every dark's scale, e-, and EXPTIME, s, by frame number.
    frame_scale_e: Vec<f64>,
    frame_exptime_s: Vec<f64>,
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
    /// Standard error of the rate at 293 K, e-/s.
    pub rate_sigma_e_per_s: f64,
    /// Standard error of the doubling temperature, K.
    pub doubling_sigma_k: f64,
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
            frame_scale_e: Vec::new(),
            frame_exptime_s: Vec::new(),
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
                    sum_e_t: vec![0.0; self.sum_e.len()],
                    sum_t2: 0.0,
                    sum_t3: 0.0,
                    max_e: vec![f32::MIN; self.sum_e.len()],
                    max_frame: vec![0; self.sum_e.len()],
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
                if let Some(s) = group.sum_e_t.get_mut(at + i) {
                    *s += (*v * exptime_s) as f32;
                }
                if let (Some(m), Some(k)) =
                    (group.max_e.get_mut(at + i), group.max_frame.get_mut(at + i))
                    && (*v as f32) > *m
                {
                    *m = *v as f32;
                    *k = self.frames;
                }
            }
        }
        let scale = est.estimate()?.to_num::<f64>();
        self.sum_scale_e += scale;
        group.sum_exptime_s += exptime_s;
        group.sum_t2 += exptime_s * exptime_s;
        group.sum_t3 += exptime_s * exptime_s * exptime_s;
        group.sum_scale_e += scale;
        group.frames += 1;
        self.frames += 1;
        self.frame_scale_e.push(scale);
        self.frame_exptime_s.push(exptime_s);
        Some(scale)
    }

    /// Darks added.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// The relative dark map of the full readout (covered dark scale = 1), each pixel's
    /// cosmic-ray hits ([`TempGroup::pixel_sums`]) left out of its sums with their frame's
    /// scale; `read_noise_e` per output. `None` when the darks' scales do not sum to a
    /// positive value.
    pub fn relative_map(&self, read_noise_e: &[f64]) -> Option<MapF32> {
        if !(self.sum_scale_e.is_finite() && self.sum_scale_e > 0.0) {
            return None;
        }
        let len = self.g.line_len();
        let data = self
            .sum_e
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let read = read_noise_e
                    .get(usize::from(self.g.output_of_col(i % len).0))
                    .copied()
                    .unwrap_or(0.0);
                let (mut e, mut scale) = (*s, self.sum_scale_e);
                for t in &self.groups {
                    if let Some((_, Some(k))) = t.pixel_sums(i, read, &self.frame_exptime_s) {
                        e -= f64::from(t.max_e.get(i).copied().unwrap_or(0.0));
                        scale -= self.frame_scale_e.get(k as usize).copied().unwrap_or(0.0);
                    }
                }
                if scale > 0.0 {
                    (e / scale) as f32
                } else {
                    (*s / self.sum_scale_e) as f32
                }
            })
            .collect();
        Some(MapF32 {
            rows: usize::from(self.g.lines),
            cols: len,
            data,
            keys: Vec::new(),
        })
    }

    /// The relative dark's frame-limited floor, RMS over the active and covered pixels of
    /// relative dark below 3 (hot pixels apart): `sqrt(sum e- + frames x read^2) / sum scale`.
    pub fn floor_rms(&self, read_noise_e: &[f64]) -> f64 {
        let len = self.g.line_len();
        let (mut v, mut n) = (0.0, 0usize);
        for (i, s) in self.sum_e.iter().enumerate() {
            let c = i % len;
            if !matches!(self.g.segment(c), Some(Segment::Active | Segment::Covered))
                || *s > 3.0 * self.sum_scale_e
            {
                continue;
            }
            let read = read_noise_e
                .get(usize::from(self.g.output_of_col(c).0))
                .copied()
                .unwrap_or(0.0);
            v += s.max(0.0) + f64::from(self.frames) * read * read;
            n += 1;
        }
        if n == 0 || self.sum_scale_e <= 0.0 {
            return 0.0;
        }
        (v / n as f64).sqrt() / self.sum_scale_e
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
        for i in 0..warm.sum_e.len() {
            let (row, col) = (i / len, i % len);
            if !matches!(g.segment(col), Some(Segment::Active | Segment::Covered)) {
                continue;
            }
            let read = read_noise_e
                .get(usize::from(g.output_of_col(col).0))
                .copied()
                .unwrap_or(0.0);
            if warm
                .pixel_sums(i, read, &self.frame_exptime_s)
                .and_then(|(p, _)| p.rate(read))
                .is_none_or(|r| r.0 <= threshold)
            {
                continue;
            }
            match self.fit_law(i, read) {
                Some(law) => hot.push(HotFit { col, row, ..law }),
                None => unfitted += 1,
            }
        }
        (hot, unfitted)
    }

    /// The law of element `i` (its `col`, `row` left 0), or `None` with fewer than two
    /// temperatures, a law that does not rise or a fit that does not converge.
    fn fit_law(&self, i: usize, read_e: f64) -> Option<HotFit> {
        // (T - 293 K, rate e-/s, variance a rate + b) per temperature.
        let pts: Vec<(f64, f64, f64, f64)> = self
            .groups
            .iter()
            .filter_map(|t| {
                let (r, a, b) = t
                    .pixel_sums(i, read_e, &self.frame_exptime_s)?
                    .0
                    .rate(read_e)?;
                Some((t.temperature_k - HOT_REFERENCE_K, r, a, b))
            })
            .collect();
        fit_hot_law(&pts)
    }
}

/// Fits `rate(T) = exp(a + b x)` (x = T - 293 K) to the rates `pts` ((x K, rate e-/s,
/// `va`, `vb`), each rate's variance `va rate + vb` at its true rate), as the module says;
/// `None` with fewer than two points, a slope at or below 0, or no convergence.
pub fn fit_hot_law(pts: &[(f64, f64, f64, f64)]) -> Option<HotFit> {
    if pts.len() < 2 {
        return None;
    }
    let var = |mu: f64, va: f64, vb: f64| (va * mu.max(0.0) + vb).max(1e-18);
    // Start: log-linear fit over the positive rates, weights from the measured rates (only a
    // start: the iterations below re-weight from the law).
    let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for &(x, r, va, vb) in pts {
        if r <= 0.0 {
            continue;
        }
        let w = r * r / var(r, va, vb);
        let y = r.ln();
        sw += w;
        sx += w * x;
        sy += w * y;
        sxx += w * x * x;
        sxy += w * x * y;
    }
    let det = sw * sxx - sx * sx;
    if det.is_nan() || det <= 0.0 {
        return None;
    }
    let mut b = (sw * sxy - sx * sy) / det;
    let mut a = (sy - b * sx) / sw;
    let mut cov = [0.0f64; 3];
    let mut converged = false;
    for _ in 0..30 {
        // Normal equations of the linearised model mu = e exp(a + b x), weights 1 / var(mu).
        let (mut h00, mut h01, mut h11, mut g0, mut g1) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(x, s, va, vb) in pts {
            let mu = (a + b * x).exp();
            if !mu.is_finite() {
                return None;
            }
            let w = 1.0 / var(mu, va, vb);
            // d mu / d a = mu, d mu / d b = mu x.
            let (j0, j1) = (mu, mu * x);
            h00 += w * j0 * j0;
            h01 += w * j0 * j1;
            h11 += w * j1 * j1;
            g0 += w * j0 * (s - mu);
            g1 += w * j1 * (s - mu);
        }
        let det = h00 * h11 - h01 * h01;
        if det.is_nan() || det <= 0.0 {
            return None;
        }
        cov = [h11 / det, -h01 / det, h00 / det];
        let da = (h11 * g0 - h01 * g1) / det;
        let db = (h00 * g1 - h01 * g0) / det;
        // Damped: a step of more than a factor e in the rate is cut to it.
        let scale = (1.0 / da.abs().max(db.abs() * 30.0).max(1.0)).min(1.0);
        a += scale * da;
        b += scale * db;
        if da.abs() < 1e-9 && db.abs() < 1e-10 {
            converged = true;
            break;
        }
    }
    if !converged || b.is_nan() || b <= 0.0 || !a.is_finite() {
        return None;
    }
    let rate = a.exp();
    let doubling = std::f64::consts::LN_2 / b;
    Some(HotFit {
        col: 0,
        row: 0,
        rate_e_per_s_at_293k: rate,
        doubling_k: doubling,
        rate_sigma_e_per_s: rate * cov[0].max(0.0).sqrt(),
        doubling_sigma_k: std::f64::consts::LN_2 * cov[2].max(0.0).sqrt() / (b * b),
    })
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
