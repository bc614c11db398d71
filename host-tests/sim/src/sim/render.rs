//! Raw samples of the simulated sensor, computed on demand: the basic sensor (stars, dark,
//! flat, bias, gains, noise, ADC) and the per-pixel draws of the optional effects that
//! [`super::effects`] describes (dark law, hot, telegraph and cosmic-ray charge, CTI).
//! Cost: per raw sample, up to six ChaCha8 streams (column bias, relative dark, flat, photon,
//! dark and read noise) and an erf difference per axis for each star within 8 sigma + 1 px.

use super::bright::{BloomedColumn, BrightFrame, bloom_column};
use super::effects::{COSMIC_CORE, PsfShape};
use super::params::{SensorParams, Star};
use super::psf::{pixel_fraction, sigma_of_a};
use super::rng::{FIXED, Purpose, stream};
use rand::RngExt;
use rand_distr::{Distribution, Normal, Poisson};
use startrack_core::geometry::Segment;
use startrack_core::window::Rect;
use std::collections::HashMap;

/// What stops a pixel's signal from rising ([`Simulator::saturation_e`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SaturationLimit {
    /// The pixel's full well.
    FullWell,
    /// The ADC's top code, 65535.
    Adc,
}

/// A sensor looking at a scene, for one frame at a time.
#[derive(Clone, Debug)]
pub struct Simulator {
    /// The sensor.
    pub params: SensorParams,
    /// The scene.
    pub stars: Vec<Star>,
    /// The frame number: noise differs from frame to frame, fixed patterns do not.
    pub frame: u32,
    /// Stars that move during the exposure, each its mean image along its path
    /// ([`crate::trail::TrailedImage`], Gaussian whatever [`super::effects::PsfShape`] the
    /// still stars have), added to the still `stars`' light. Empty by default.
    pub trails: Vec<crate::trail::TrailedImage>,
    /// The Moon, the Earth, stray light, proton hits and blooming ([`super::bright`]);
    /// `None` by default (and then every sample is the sensor's without them).
    pub bright: Option<std::sync::Arc<BrightFrame>>,
    /// The frame's bloomed columns (active column to its rows), made on first use by
    /// [`Self::bloomed`]: a cache, left as [`Simulator::new`] makes it.
    pub bloomed_cache: std::sync::OnceLock<std::sync::Arc<HashMap<usize, BloomedColumn>>>,
}

fn normal(r: &mut rand_chacha::ChaCha8Rng) -> f64 {
    Normal::new(0.0, 1.0).map_or(0.0, |n| n.sample(r))
}

fn poisson(mean: f64, r: &mut rand_chacha::ChaCha8Rng) -> f64 {
    if mean <= 0.0 {
        0.0
    } else {
        Poisson::new(mean).map_or(mean, |p| p.sample(r))
    }
}

impl Simulator {
    /// A simulator of `params` looking at `stars`, at frame 0.
    pub fn new(params: SensorParams, stars: Vec<Star>) -> Self {
        Self {
            params,
            stars,
            frame: 0,
            trails: Vec::new(),
            bright: None,
            bloomed_cache: std::sync::OnceLock::new(),
        }
    }

    /// Column bias of raw column `col`, ADU (0 on the over-scan, which defines the level).
    pub fn column_bias_adu(&self, col: usize) -> f64 {
        let p = &self.params;
        match p.geometry.segment(col) {
            Some(Segment::Covered | Segment::Active) if p.column_bias_sigma_adu > 0.0 => {
                p.column_bias_sigma_adu
                    * normal(&mut stream(p.seed, FIXED, col, 0, Purpose::ColumnBias))
            }
            _ => 0.0,
        }
    }

    /// The signal at which the samples of raw column `col` stop rising, and the limit that
    /// sets it: e- above bias and column bias referred through the output's gain (read noise
    /// aside), the smaller of the pixel's full well as the output reads it
    /// (`full_well_e (1 - k)`, `k` its non-linearity at full well) and the ADC's 65535 ADU.
    /// The serial register and the summing well hold more than a pixel (sensor doc) and are
    /// not modelled.
    pub fn saturation_e(&self, col: usize) -> (f64, SaturationLimit) {
        let p = &self.params;
        let out = usize::from(p.geometry.output_of_col(col).0).min(1);
        let well = p.full_well_e * (1.0 - p.nonlinearity_at_full_well[out]);
        let adc = (65535.0 - p.bias_adu[out] - self.column_bias_adu(col)) * p.gain_e_per_adu[out];
        if adc < well {
            (adc, SaturationLimit::Adc)
        } else {
            (well, SaturationLimit::FullWell)
        }
    }

    /// The raw level at and above which a sample may be a full pixel or the ADC's top, for
    /// the calibration table: over both outputs the lowest of 65535 and the full well as the
    /// output reads it ([`Self::saturation_e`]'s limit through the output's bias and gain),
    /// less 5 column-bias sigmas and 3 read-noise sigmas (a full pixel of the lowest column
    /// bias, read low, is still flagged).
    pub fn saturation_level_adu(&self) -> u16 {
        let p = &self.params;
        let level = (0..2)
            .map(|out| {
                let well = p.full_well_e * (1.0 - p.nonlinearity_at_full_well[out]);
                p.bias_adu[out] + well / p.gain_e_per_adu[out]
                    - 5.0 * p.column_bias_sigma_adu
                    - 3.0 * p.read_noise_e / p.gain_e_per_adu[out]
            })
            .fold(65535.0f64, f64::min);
        level.floor().clamp(1.0, 65535.0) as u16
    }

    /// Relative dark of raw element (`col`, `line`): 1 + dsnu N(0,1), clipped at 0.
    pub fn dark_rel(&self, col: usize, line: usize) -> f64 {
        let p = &self.params;
        if p.dsnu == 0.0 {
            return 1.0;
        }
        (1.0 + p.dsnu * normal(&mut stream(p.seed, FIXED, col, line, Purpose::Dsnu))).max(0.0)
    }

    /// Flat-field response of active pixel (`x`, `y`): 1 + prnu N(0,1), at least 0.05.
    pub fn flat(&self, x: usize, y: usize) -> f64 {
        let p = &self.params;
        if p.prnu == 0.0 {
            return 1.0;
        }
        let col = p.geometry.raw_col_of_x(x);
        (1.0 + p.prnu * normal(&mut stream(p.seed, FIXED, col, y, Purpose::Prnu))).max(0.05)
    }

    /// Expected star electrons in active pixel (`x`, `y`) before the flat: the still stars'
    /// and the trailed stars'.
    pub fn star_e(&self, x: usize, y: usize) -> f64 {
        let still = self.still_star_e(x, y);
        if self.trails.is_empty() {
            return still;
        }
        still + self.trails.iter().map(|t| t.at(x, y)).sum::<f64>()
    }

    /// Expected light of the bright scene (the Moon, the Earth, stray light) in active pixel
    /// (`x`, `y`) before the flat, e- (0 without one).
    pub fn extended_e(&self, x: usize, y: usize) -> f64 {
        self.bright.as_ref().map_or(0.0, |b| b.light_e(x, y))
    }

    /// The active column of raw element (`col`, `line`), if it is an active pixel.
    fn active_x(&self, col: usize, line: usize) -> Option<usize> {
        let g = &self.params.geometry;
        (matches!(g.segment(col), Some(Segment::Active)) && line < usize::from(g.active_rows))
            .then(|| col - g.first_active_col())
    }

    /// The frame's bloomed columns, by active column ([`super::bright`]); made once a frame.
    /// Only columns that may pass the full well are evaluated: those of the Moon's and the
    /// Earth's light and of stars whose brightest pixel may reach half the well.
    pub fn bloomed(&self) -> &HashMap<usize, BloomedColumn> {
        self.bloomed_cache
            .get_or_init(|| std::sync::Arc::new(self.bloom_columns()))
    }

    fn bloom_columns(&self) -> HashMap<usize, BloomedColumn> {
        let mut out = HashMap::new();
        let Some(b) = self.bright.as_ref().filter(|b| b.bloom) else {
            return out;
        };
        let g = self.params.geometry;
        let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
        let fw = self.params.full_well_e;
        let mut candidate = vec![false; cols];
        let mut mark = |lo: f64, hi: f64| {
            let lo = lo.floor().max(0.0) as usize;
            let hi = (hi.ceil().max(0.0) as usize).min(cols.saturating_sub(1));
            for c in candidate.iter_mut().take(hi + 1).skip(lo) {
                *c = true;
            }
        };
        if let Some(m) = b.moon {
            mark(
                m.centre_px[0] - m.radius_px - 1.0,
                m.centre_px[0] + m.radius_px + 1.0,
            );
        }
        if let Some(e) = b.earth {
            for x in 0..cols {
                let touched = (0..rows)
                    .step_by(4)
                    .chain([rows.saturating_sub(1)])
                    .any(|y| e.inside_px(x as f64, y as f64) > -4.0);
                if touched {
                    mark(x as f64, x as f64);
                }
            }
        }
        for s in &self.stars {
            let sig = sigma_of_a(s.a_px);
            let peak = s.signal_e * pixel_fraction(0.0, 0.0, sig).powi(2) * 1.2;
            if peak > 0.5 * fw {
                let reach = 8.0 * sig + 1.0;
                mark(s.x_px - reach, s.x_px + reach);
            }
        }
        let first = g.first_active_col();
        for (x, _) in candidate.iter().enumerate().filter(|(_, c)| **c) {
            // Bright light alone that overfills the column (through the lowest flat the
            // PRNU gives) fills it whole.
            let light: f64 = (0..rows).map(|y| b.light_e(x, y)).sum();
            let floor = (1.0 - 5.0 * self.params.prnu).max(0.05);
            if light * floor >= 1.05 * fw * rows as f64 {
                out.insert(x, BloomedColumn::Full);
                continue;
            }
            let q: Vec<f64> = (0..rows)
                .map(|y| {
                    let (l, d) = self.expected_e(first + x, y);
                    l + d + b.proton_e(x, y)
                })
                .collect();
            if let Some(c) = bloom_column(&q, fw) {
                out.insert(x, c);
            }
        }
        out
    }

    /// Expected electrons of the still stars in active pixel (`x`, `y`) before the flat.
    fn still_star_e(&self, x: usize, y: usize) -> f64 {
        let (xf, yf) = (x as f64, y as f64);
        let shape = self.params.effects.psf;
        if shape != PsfShape::Gaussian {
            return self
                .stars
                .iter()
                .map(|s| {
                    shape
                        .parts(s.a_px)
                        .iter()
                        .filter_map(|q| {
                            let (cx, cy) = (s.x_px + q.dx_px, s.y_px + q.dy_px);
                            let reach = 8.0 * q.sigma_px + 1.0;
                            ((xf - cx).abs() < reach && (yf - cy).abs() < reach).then(|| {
                                s.signal_e
                                    * q.weight
                                    * pixel_fraction(xf, cx, q.sigma_px)
                                    * pixel_fraction(yf, cy, q.sigma_px)
                            })
                        })
                        .sum::<f64>()
                })
                .sum();
        }
        self.stars
            .iter()
            .filter_map(|s| {
                let sig = sigma_of_a(s.a_px);
                let reach = 8.0 * sig + 1.0;
                ((xf - s.x_px).abs() < reach && (yf - s.y_px).abs() < reach).then(|| {
                    s.signal_e * pixel_fraction(xf, s.x_px, sig) * pixel_fraction(yf, s.y_px, sig)
                })
            })
            .sum()
    }

    /// Expected dark electrons of raw element (`col`, `line`) in this frame before CTI: the
    /// regular dark (with its temperature law) or, for a hot pixel, its own dark; plus a
    /// telegraph pixel's level (0 on the over-scan, which has no pixel behind it).
    pub fn expected_dark_e(&self, col: usize, line: usize) -> f64 {
        match self.params.geometry.segment(col) {
            Some(Segment::Active | Segment::Covered) => {
                let e = &self.params.effects;
                let mut d = self.params.dark_mean_e * self.dark_rel(col, line);
                if e.dark_law.is_some() {
                    d *= self.dark_law_factor();
                }
                if e.hot.is_some() && self.hot_rate_e_per_s(col, line).is_some() {
                    // A hot pixel's own generation replaces the regular dark (the core's
                    // `Correct` policy subtracts only the hot law).
                    d = self.hot_dark_e(col, line);
                }
                if e.telegraph.is_some() {
                    d += self.telegraph_e(col, line);
                }
                d
            }
            _ => 0.0,
        }
    }

    /// Expected (light, dark) electrons of raw element (`col`, `line`) after CTI and charge
    /// traps, before shot noise; cosmic-ray charge ([`Self::cosmic_e`]) comes on top.
    pub fn expected_e(&self, col: usize, line: usize) -> (f64, f64) {
        let Some(traps) = self.params.effects.traps else {
            return self.expected_cti_e(col, line);
        };
        let g = &self.params.geometry;
        let w = traps.weights();
        let eps = traps.serial_per_transfer;
        // The serial step on the parallel step's output, along this output's half line.
        let left = g.output_of_col(col).0 == 0;
        let transfers = |c: usize| {
            if left {
                (c + 1) as f64
            } else {
                g.line_len().saturating_sub(c) as f64
            }
        };
        let (l0, d0) = self.expected_parallel_e(&traps, &w, col, line);
        let keep = 1.0 - traps.deferred_fraction(eps, transfers(col), l0 + d0);
        let (mut light, mut dark) = (keep * l0, keep * d0);
        for (k, wk) in w.iter().enumerate() {
            let src = if left {
                col.checked_sub(k + 1)
            } else {
                Some(col + k + 1).filter(|&c| c < g.line_len())
            };
            let Some(src) = src.filter(|&c| g.output_of_col(c) == g.output_of_col(col)) else {
                break;
            };
            let (l, d) = self.expected_parallel_e(&traps, &w, src, line);
            let f = traps.deferred_fraction(eps, transfers(src), l + d);
            light += f * wk * l;
            dark += f * wk * d;
        }
        (light, dark)
    }

    /// The parallel trap step: (light, dark) of raw element (`col`, `line`) after the parallel
    /// transfers, from [`Self::expected_cti_e`] of this and the previous lines.
    fn expected_parallel_e(
        &self,
        traps: &super::effects::ChargeTraps,
        w: &[f64],
        col: usize,
        line: usize,
    ) -> (f64, f64) {
        let eps = traps.parallel_per_transfer;
        let (l0, d0) = self.expected_cti_e(col, line);
        let keep = 1.0 - traps.deferred_fraction(eps, (line + 1) as f64, l0 + d0);
        let (mut light, mut dark) = (keep * l0, keep * d0);
        for (k, wk) in w.iter().enumerate() {
            let Some(src) = line.checked_sub(k + 1) else {
                break;
            };
            let (l, d) = self.expected_cti_e(col, src);
            let f = traps.deferred_fraction(eps, (src + 1) as f64, l + d);
            light += f * wk * l;
            dark += f * wk * d;
        }
        (light, dark)
    }

    /// Expected (light, dark) electrons of raw element (`col`, `line`) after the simple
    /// parallel CTI trail ([`super::effects::Cti`]), before the charge traps.
    pub fn expected_cti_e(&self, col: usize, line: usize) -> (f64, f64) {
        let Some(cti) = self.params.effects.cti else {
            return self.expected_parts_e(col, line);
        };
        let f = cti.fraction.clamp(0.0, 1.0);
        let (l0, d0) = self.expected_parts_e(col, line);
        let (mut light, mut dark) = ((1.0 - f) * l0, (1.0 - f) * d0);
        for (k, w) in cti.weights().iter().enumerate() {
            let Some(src) = line.checked_sub(k + 1) else {
                break;
            };
            let (l, d) = self.expected_parts_e(col, src);
            light += f * w * l;
            dark += f * w * d;
        }
        (light, dark)
    }

    /// Expected electrons collected by raw element (`col`, `line`): star light through the
    /// flat plus dark charge (what a perfect calibration recovers is the star part).
    fn expected_parts_e(&self, col: usize, line: usize) -> (f64, f64) {
        let g = &self.params.geometry;
        let dark = self.expected_dark_e(col, line);
        match g.segment(col) {
            Some(Segment::Active) if line < usize::from(g.active_rows) => {
                let x = col - g.first_active_col();
                (
                    (self.star_e(x, line) + self.params.sky_e + self.extended_e(x, line))
                        * self.flat(x, line),
                    dark,
                )
            }
            Some(Segment::Active | Segment::Covered) => (0.0, dark),
            _ => (0.0, 0.0),
        }
    }

    /// The raw ADC word of element (`col`, `line`) of this frame (0 outside the readout).
    pub fn raw_sample(&self, col: usize, line: usize) -> u16 {
        let p = &self.params;
        let g = &p.geometry;
        if col >= g.line_len() || line >= usize::from(g.lines) {
            return 0;
        }
        let (light, dark) = self.expected_e(col, line);
        let (mut e, read) = if p.noise {
            let s = |purpose| stream(p.seed, self.frame, col, line, purpose);
            (
                poisson(light, &mut s(Purpose::Photon)) + poisson(dark, &mut s(Purpose::Dark)),
                p.read_noise_e * normal(&mut s(Purpose::Read)),
            )
        } else {
            (light + dark, 0.0)
        };
        if p.effects.cosmics.is_some() {
            e += self.cosmic_e(col, line);
        }
        if let Some(b) = &self.bright
            && let Some(x) = self.active_x(col, line)
        {
            e += b.proton_e(x, line);
            if b.bloom
                && let Some(c) = self.bloomed().get(&x)
            {
                e = match c.at(line) {
                    None => p.full_well_e,
                    Some(spill) => e + spill,
                };
            }
        }
        e = e.min(p.full_well_e);
        let out = usize::from(g.output_of_col(col).0);
        let k = p.nonlinearity_at_full_well[out];
        if k != 0.0 && p.full_well_e > 0.0 {
            e *= 1.0 - k * e / p.full_well_e;
        }
        let adu = p.bias_adu[out] + self.column_bias_adu(col) + (e + read) / p.gain_e_per_adu[out];
        adu.round().clamp(0.0, 65535.0) as u16
    }

    /// A whole raw line, as the readout delivers it.
    pub fn render_line(&self, line: usize, out: &mut [u16]) {
        for (col, v) in out.iter_mut().enumerate() {
            *v = self.raw_sample(col, line);
        }
    }

    /// The raw samples of an active-area rectangle, row-major.
    pub fn render_window(&self, rect: Rect) -> Vec<u16> {
        let g = &self.params.geometry;
        (rect.y0..rect.y0 + rect.height)
            .flat_map(|y| {
                (rect.x0..rect.x0 + rect.width)
                    .map(move |x| self.raw_sample(g.raw_col_of_x(usize::from(x)), usize::from(y)))
            })
            .collect()
    }
}

/// True for raw elements with a pixel behind them (active or covered, any line).
fn is_pixel(sim: &Simulator, col: usize) -> bool {
    matches!(
        sim.params.geometry.segment(col),
        Some(Segment::Active | Segment::Covered)
    )
}

// The optional effects' per-pixel draws.
impl Simulator {
    /// Factor of the regular dark at the sensor's temperature (1 without a [`DarkLaw`](super::effects::DarkLaw)).
    pub fn dark_law_factor(&self) -> f64 {
        let e = &self.params.effects;
        e.dark_law.map_or(1.0, |l| {
            if l.doubling_k > 0.0 {
                2f64.powf((e.temperature_k - l.reference_k) / l.doubling_k)
            } else {
                1.0
            }
        })
    }

    /// The hot pixel at raw (`col`, `line`): its rate at the reference temperature, e-/s,
    /// or `None` if the pixel is not hot (or hot pixels are off).
    pub fn hot_rate_e_per_s(&self, col: usize, line: usize) -> Option<f64> {
        let h = self.params.effects.hot?;
        if !is_pixel(self, col) {
            return None;
        }
        let mut r = stream(self.params.seed, FIXED, col, line, Purpose::Defect);
        let u: f64 = r.random();
        let v: f64 = r.random();
        (u < h.fraction).then(|| {
            let (lo, hi) = (h.rate_min_e_per_s.max(1e-9), h.rate_max_e_per_s.max(1e-9));
            (lo.ln() + v * (hi.ln() - lo.ln())).exp()
        })
    }

    /// Hot-pixel dark of raw (`col`, `line`) in this exposure at the sensor's temperature,
    /// e- (0 for a normal pixel).
    pub fn hot_dark_e(&self, col: usize, line: usize) -> f64 {
        let Some(h) = self.params.effects.hot else {
            return 0.0;
        };
        self.hot_rate_e_per_s(col, line).map_or(0.0, |rate| {
            let law = if h.doubling_k > 0.0 {
                2f64.powf((self.params.effects.temperature_k - h.reference_k) / h.doubling_k)
            } else {
                1.0
            };
            rate * h.exposure_s * law
        })
    }

    /// The telegraph pixel at raw (`col`, `line`): its step between levels, e-, or `None`.
    pub fn telegraph_step_e(&self, col: usize, line: usize) -> Option<f64> {
        let t = self.params.effects.telegraph?;
        if !is_pixel(self, col) {
            return None;
        }
        let mut r = stream(self.params.seed, FIXED, col, line, Purpose::Defect);
        // The first two draws belong to the hot-pixel test.
        let _: (f64, f64) = (r.random(), r.random());
        let u: f64 = r.random();
        let amp: f64 = r.random();
        (u < t.fraction).then_some(t.amplitude_e * (0.5 + amp))
    }

    /// Telegraph charge of raw (`col`, `line`) in this frame, e- (the step when high).
    pub fn telegraph_e(&self, col: usize, line: usize) -> f64 {
        let (Some(t), Some(step)) = (
            self.params.effects.telegraph,
            self.telegraph_step_e(col, line),
        ) else {
            return 0.0;
        };
        let mut r = stream(self.params.seed, self.frame, col, line, Purpose::Event);
        // The first two draws belong to the cosmic-ray test.
        let _: (f64, f64) = (r.random(), r.random());
        let u: f64 = r.random();
        if u < t.p_high { step } else { 0.0 }
    }

    /// The cosmic-ray deposit centred on raw (`col`, `line`) in this frame, e- (0: no hit).
    pub fn cosmic_hit_e(&self, col: usize, line: usize) -> f64 {
        let Some(c) = self.params.effects.cosmics else {
            return 0.0;
        };
        if !is_pixel(self, col) || line >= usize::from(self.params.geometry.lines) {
            return 0.0;
        }
        let mut r = stream(self.params.seed, self.frame, col, line, Purpose::Event);
        let u: f64 = r.random();
        let v: f64 = r.random();
        if u < c.rate_per_px {
            c.mean_e * (0.5 + v)
        } else {
            0.0
        }
    }

    /// Cosmic-ray charge collected by raw (`col`, `line`) in this frame: its own hit's core
    /// plus a quarter of the rest of each direct neighbour's hit, e-.
    pub fn cosmic_e(&self, col: usize, line: usize) -> f64 {
        if self.params.effects.cosmics.is_none() || !is_pixel(self, col) {
            return 0.0;
        }
        let side = (1.0 - COSMIC_CORE) / 4.0;
        let mut e = COSMIC_CORE * self.cosmic_hit_e(col, line);
        let neighbours = [
            (col.wrapping_sub(1), line),
            (col + 1, line),
            (col, line.wrapping_sub(1)),
            (col, line + 1),
        ];
        for (c, l) in neighbours {
            if c < self.params.geometry.line_len() && l != usize::MAX {
                e += side * self.cosmic_hit_e(c, l);
            }
        }
        e
    }
}
