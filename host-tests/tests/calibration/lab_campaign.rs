//! A second lab-frame generator, written apart from `LabSet` and the simulator so that
//! `calib frames` is judged on frames it was not developed on: its own random draws (one
//! seeded ChaCha8 stream drawn in order), its own sensor model and population, the keyword
//! spellings of other acquisition programs, and a recording order unlike `LabSet`'s.
//!
//! The campaign, as a lab records it with a temperature-regulated camera:
//! - 30 bias frames, 10 flat pairs (a lamp ladder of 1 to 10 units, taken in a shuffled
//!   order of exposure), darks at 4 temperatures x 4 exposures x 5 frames (exposures
//!   interleaved within each temperature), a 100-frame dark stack at one temperature and
//!   exposure, and 5 light frames that must be left out: 235 frames;
//! - every frame's temperature is its setpoint plus a wander of [`Campaign::wander_k`] RMS
//!   from frame to frame (an AR(1) walk of the regulation loop), written as `CCD-TEMP` in
//!   deg C with two decimals (the sensor's true temperature is the written one);
//! - `IMAGETYP` `Bias Frame`, `Dark Frame`, `Flat Field`, `Light Frame`; the exposure as
//!   `EXPOSURE`; the files named in a shuffled order, darks in `darks/` and the rest in
//!   `cal/`, each as plain FITS, `.fits.gz` or tile-compressed `.fits.fz` (image in HDU 1).
//!
//! The sensor: per output a gain, a read noise and a bias level that moves by a few ADU from
//! frame to frame (the over-scan follows it); a column bias; a regular dark of
//! `dark_rate_e_per_s_at_293k` doubling every `dark_doubling_k`, times a per-pixel DSNU
//! (log-normal, 8 %), covered pixels alike; a PRNU of 1.5 % on a gentle gradient; hot pixels
//! (0.3 %, 60 to 8 000 e-/s at 293 K log-uniform, each with its own doubling temperature
//! uniform in 5 to 10 K; a hot pixel's dark is its own law alone, as the core applies it);
//! telegraph pixels (0.3 %, a step of 3 to 15 read-noise sigmas, two-state Markov dwell with
//! mean dwells of 1.5 to 20 frames high and 2 to 40 frames low, a tenth of them on hot pixels);
//! cosmic-ray hits (2e-7 per pixel per second, 200 to 3 000 e- in one pixel). Shot noise is
//! Poisson, read noise Gaussian, samples rounded and clipped to 16 bits.
//!
//! Cost: one Poisson and one Gaussian draw per sample: about a second for the 235 frames of
//! the 128 x 128 test readout in the dev profile, minutes for the CCD47-20's.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson};
use startrack_core::geometry::{ReadoutGeometry, Segment};
use std::path::{Path, PathBuf};

/// How a frame file is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Plain FITS, the image in the primary HDU, `.fits`.
    Plain,
    /// Gzipped FITS, `.fits.gz`.
    Gzip,
    /// Tile-compressed FITS (Rice), an empty primary and the image in HDU 1, `.fits.fz`.
    TileCompressed,
}

/// A hot pixel of the campaign's sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hot {
    /// Raw column.
    pub col: usize,
    /// Raw line.
    pub line: usize,
    /// Dark rate at 293 K, e-/s.
    pub rate_e_per_s_at_293k: f64,
    /// Its own doubling temperature, K.
    pub doubling_k: f64,
}

/// A telegraph pixel of the campaign's sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Telegraph {
    /// Raw column.
    pub col: usize,
    /// Raw line.
    pub line: usize,
    /// Step between the levels, e-.
    pub step_e: f64,
    /// Mean dwell in the high state, frames.
    pub dwell_high: f64,
    /// Mean dwell in the low state, frames.
    pub dwell_low: f64,
}

/// One frame of the plan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shot {
    /// `IMAGETYP` as written.
    pub imagetyp: &'static str,
    /// Exposure, s.
    pub exposure_s: f64,
    /// Sensor temperature (as written, rounded to 0.01 deg C), K.
    pub temperature_k: f64,
    /// Lamp on.
    pub lamp: bool,
    /// Part of the long dark stack.
    pub stack: bool,
}

/// The campaign and its sensor's truth.
#[derive(Clone, Debug)]
pub struct Campaign {
    /// Readout geometry.
    pub geometry: ReadoutGeometry,
    /// Seed of every draw.
    pub seed: u64,
    /// Gain per output, e-/ADU.
    pub gain_e_per_adu: [f64; 2],
    /// Read noise per output, e- RMS.
    pub read_noise_e: [f64; 2],
    /// Bias level per output, ADU.
    pub bias_adu: [f64; 2],
    /// Column bias per raw column, ADU.
    pub column_bias_adu: Vec<f64>,
    /// Regular dark at 293 K, e-/s.
    pub dark_rate_e_per_s_at_293k: f64,
    /// Its doubling temperature, K.
    pub dark_doubling_k: f64,
    /// Relative dark (DSNU) per raw element, mean about 1.
    pub dsnu: Vec<f64>,
    /// Flat (PRNU) per raw element (1 outside the active area).
    pub prnu: Vec<f64>,
    /// Hot pixels.
    pub hot: Vec<Hot>,
    /// Telegraph pixels.
    pub telegraph: Vec<Telegraph>,
    /// Lamp, e- per second per pixel.
    pub lamp_e_per_s: f64,
    /// Temperature wander from frame to frame, K RMS.
    pub wander_k: f64,
    /// The frames in recording order.
    pub plan: Vec<Shot>,
    /// Per telegraph pixel, its state (high = true) in every frame of the plan.
    pub telegraph_states: Vec<Vec<bool>>,
    /// Per raw element, its index in `hot` (`u32::MAX`: none).
    hot_index: Vec<u32>,
    /// Per raw element, true for a telegraph pixel.
    telegraph_at: Vec<bool>,
}

/// Cosmic-ray hits per pixel per second of exposure: the sea-level muon flux, about 1 per
/// cm^2 per minute (PDG, Review of Particle Physics, "Cosmic rays"), on a 13 um pixel
/// (1.7e-6 cm^2), times a few pixels per track and the radioactivity of the window and
/// package, rounded up.
const COSMIC_PER_PX_S: f64 = 2e-7;
/// Hot-pixel reference temperature of the truth, K.
pub const REFERENCE_K: f64 = 293.0;

fn normal(r: &mut ChaCha8Rng) -> f64 {
    Normal::new(0.0, 1.0).map_or(0.0, |n| n.sample(r))
}

fn poisson(r: &mut ChaCha8Rng, mean: f64) -> f64 {
    if mean <= 0.0 {
        return 0.0;
    }
    Poisson::new(mean).map_or(mean, |p| p.sample(r))
}

impl Campaign {
    /// The campaign on `geometry` (two outputs) from `seed`.
    pub fn new(geometry: ReadoutGeometry, seed: u64) -> Self {
        let mut r = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_1ab5_ca3f_u64);
        let g = geometry;
        let (lines, len) = (usize::from(g.lines), g.line_len());
        let gain_e_per_adu = [r.random_range(1.3..1.8), r.random_range(1.3..1.8)];
        let read_noise_e = [r.random_range(4.2..6.0), r.random_range(4.2..6.0)];
        let bias_adu = [r.random_range(900.0..1300.0), r.random_range(900.0..1300.0)];
        let column_bias_adu: Vec<f64> = (0..len).map(|_| 1.5 * normal(&mut r)).collect();
        let dark_rate_e_per_s_at_293k = r.random_range(12.0..30.0);
        let dark_doubling_k = r.random_range(6.0..7.5);
        let dsnu: Vec<f64> = (0..lines * len)
            .map(|_| (0.08 * normal(&mut r) - 0.5 * 0.08 * 0.08).exp())
            .collect();
        let (x0, cols, rows) = (
            g.first_active_col(),
            usize::from(g.active_cols),
            usize::from(g.active_rows),
        );
        let prnu: Vec<f64> = (0..lines * len)
            .map(|i| {
                let (l, c) = (i / len, i % len);
                let p = 1.0 + 0.015 * normal(&mut r);
                if g.segment(c) == Some(Segment::Active) && l < rows {
                    let (x, y) = ((c - x0) as f64 / cols as f64, l as f64 / rows as f64);
                    p * (1.0 + 0.03 * (x - 0.5) - 0.02 * (y - 0.5))
                } else {
                    1.0
                }
            })
            .collect();
        let mut hot = Vec::new();
        let mut telegraph = Vec::new();
        for line in 0..lines {
            for col in 0..len {
                if !matches!(g.segment(col), Some(Segment::Active | Segment::Covered)) {
                    continue;
                }
                let u: f64 = r.random();
                let is_hot = u < 0.003;
                let is_tel = (0.003..0.006).contains(&u) || (is_hot && r.random::<f64>() < 0.1);
                if is_hot {
                    hot.push(Hot {
                        col,
                        line,
                        rate_e_per_s_at_293k: (r.random_range(60f64.ln()..8000f64.ln())).exp(),
                        doubling_k: r.random_range(5.0..10.0),
                    });
                }
                if is_tel {
                    let o = usize::from(g.output_of_col(col).0).min(1);
                    telegraph.push(Telegraph {
                        col,
                        line,
                        step_e: r.random_range(3.0..15.0) * read_noise_e[o],
                        dwell_high: r.random_range(1.5..20.0),
                        dwell_low: r.random_range(2.0..40.0),
                    });
                }
            }
        }
        let wander_k = 0.02;
        let plan = Self::plan(&mut r, wander_k);
        // Each telegraph pixel's two-state chain over the whole recording, from its
        // stationary distribution.
        let telegraph_states = telegraph
            .iter()
            .map(|t| {
                let p_high = t.dwell_high / (t.dwell_high + t.dwell_low);
                let mut high = r.random::<f64>() < p_high;
                (0..plan.len())
                    .map(|_| {
                        let leave = if high {
                            1.0 / t.dwell_high
                        } else {
                            1.0 / t.dwell_low
                        };
                        let s = high;
                        if r.random::<f64>() < leave {
                            high = !high;
                        }
                        s
                    })
                    .collect()
            })
            .collect();
        let mut hot_index = vec![u32::MAX; lines * len];
        for (k, h) in hot.iter().enumerate() {
            hot_index[h.line * len + h.col] = k as u32;
        }
        let mut telegraph_at = vec![false; lines * len];
        for t in &telegraph {
            telegraph_at[t.line * len + t.col] = true;
        }
        Self {
            hot_index,
            telegraph_at,
            geometry,
            seed,
            gain_e_per_adu,
            read_noise_e,
            bias_adu,
            column_bias_adu,
            dark_rate_e_per_s_at_293k,
            dark_doubling_k,
            dsnu,
            prnu,
            hot,
            telegraph,
            lamp_e_per_s: 4500.0,
            wander_k,
            plan,
            telegraph_states,
        }
    }

    /// The recording order: bias, flats in a shuffled order of exposure, darks by temperature
    /// with the exposures interleaved, the stack, a few light frames.
    fn plan(r: &mut ChaCha8Rng, wander_k: f64) -> Vec<Shot> {
        let mut plan = Vec::new();
        // The regulation loop's wander: AR(1) with correlation 0.7 and `wander_k` RMS.
        let mut w = 0.0f64;
        let mut temp = |r: &mut ChaCha8Rng, setpoint_k: f64| {
            w = 0.7 * w + (1.0f64 - 0.49).sqrt() * wander_k * normal(r);
            // CCD-TEMP in deg C with two decimals, read back in K.
            ((setpoint_k + w - 273.15) * 100.0).round() / 100.0 + 273.15
        };
        let shot = |imagetyp, exposure_s, temperature_k, lamp, stack| Shot {
            imagetyp,
            exposure_s,
            temperature_k,
            lamp,
            stack,
        };
        for _ in 0..30 {
            let t = temp(r, 263.0);
            plan.push(shot("Bias Frame", 0.0, t, false, false));
        }
        let mut flats: Vec<f64> = (1..=10).map(f64::from).collect();
        for i in (1..flats.len()).rev() {
            let j = r.random_range(0..=i);
            flats.swap(i, j);
        }
        for e in flats {
            for _ in 0..2 {
                let t = temp(r, 263.0);
                plan.push(shot("Flat Field", e, t, true, false));
            }
        }
        for setpoint in [263.0, 268.0, 273.0, 283.0] {
            for _ in 0..5 {
                for e in [20.0, 2.0, 10.0, 5.0] {
                    let t = temp(r, setpoint);
                    plan.push(shot("Dark Frame", e, t, false, false));
                }
            }
        }
        for _ in 0..100 {
            let t = temp(r, 283.0);
            plan.push(shot("Dark Frame", 2.0, t, false, true));
        }
        for _ in 0..5 {
            let t = temp(r, 283.0);
            plan.push(shot("Light Frame", 1.0, t, false, false));
        }
        plan
    }

    /// Regular dark rate of a pixel of relative dark 1 at `temperature_k`, e-/s.
    pub fn regular_rate_e_per_s(&self, temperature_k: f64) -> f64 {
        self.dark_rate_e_per_s_at_293k
            * 2f64.powf((temperature_k - REFERENCE_K) / self.dark_doubling_k)
    }

    /// The hot pixel at raw (`col`, `line`), if any.
    pub fn hot_at(&self, col: usize, line: usize) -> Option<&Hot> {
        let i = *self.hot_index.get(line * self.geometry.line_len() + col)?;
        self.hot.get(i as usize)
    }

    /// True for a telegraph pixel at raw (`col`, `line`).
    pub fn telegraph_at(&self, col: usize, line: usize) -> bool {
        self.telegraph_at
            .get(line * self.geometry.line_len() + col)
            .copied()
            .unwrap_or(false)
    }

    /// Expected dark of raw element `i` in `exposure_s` at `temperature_k`, e- (telegraph
    /// step not included).
    pub fn dark_e(&self, i: usize, exposure_s: f64, temperature_k: f64) -> f64 {
        let len = self.geometry.line_len();
        match self.hot_at(i % len, i / len) {
            Some(h) => {
                h.rate_e_per_s_at_293k
                    * 2f64.powf((temperature_k - REFERENCE_K) / h.doubling_k)
                    * exposure_s
            }
            None => {
                let c = i % len;
                let charge_holding = matches!(
                    self.geometry.segment(c),
                    Some(Segment::Active | Segment::Covered)
                );
                if charge_holding {
                    self.dsnu.get(i).copied().unwrap_or(1.0)
                        * self.regular_rate_e_per_s(temperature_k)
                        * exposure_s
                } else {
                    0.0
                }
            }
        }
    }

    /// Renders frame `index` of the plan: raw samples, row-major. The draws of frame `index`
    /// come from their own stream, so frames render in any order.
    pub fn render(&self, index: usize) -> Vec<u16> {
        let g = self.geometry;
        let (lines, len) = (usize::from(g.lines), g.line_len());
        let Some(shot) = self.plan.get(index) else {
            return Vec::new();
        };
        let mut r = ChaCha8Rng::seed_from_u64(self.seed ^ 0xf4a3_e000_u64);
        r.set_stream(index as u64 + 1);
        let mut e = vec![0.0f64; lines * len];
        let active_rows = usize::from(g.active_rows);
        for (i, v) in e.iter_mut().enumerate() {
            let (l, c) = (i / len, i % len);
            let mut mean = self.dark_e(i, shot.exposure_s, shot.temperature_k);
            if shot.lamp && g.segment(c) == Some(Segment::Active) && l < active_rows {
                mean +=
                    self.lamp_e_per_s * shot.exposure_s * self.prnu.get(i).copied().unwrap_or(1.0);
            }
            *v = mean;
        }
        for (t, states) in self.telegraph.iter().zip(&self.telegraph_states) {
            if states.get(index).copied().unwrap_or(false)
                && let Some(v) = e.get_mut(t.line * len + t.col)
            {
                *v += t.step_e;
            }
        }
        let bias_jitter = [2.0 * normal(&mut r), 2.0 * normal(&mut r)];
        for (i, v) in e.iter_mut().enumerate() {
            let c = i % len;
            let mut q = poisson(&mut r, *v);
            if matches!(g.segment(c), Some(Segment::Active | Segment::Covered))
                && r.random::<f64>() < COSMIC_PER_PX_S * shot.exposure_s
            {
                q += r.random_range(200.0..3000.0);
            }
            *v = q;
        }
        e.iter()
            .enumerate()
            .map(|(i, &q)| {
                let c = i % len;
                let o = usize::from(g.output_of_col(c).0).min(1);
                let q = q.min(110_000.0);
                let adu = self.bias_adu[o]
                    + bias_jitter[o]
                    + self.column_bias_adu.get(c).copied().unwrap_or(0.0)
                    + (q + self.read_noise_e[o] * normal(&mut r)) / self.gain_e_per_adu[o];
                adu.round().clamp(0.0, 65535.0) as u16
            })
            .collect()
    }

    /// Writes every frame, files named in a shuffled order, darks in `dir/darks/`, the rest
    /// in `dir/cal/`, each in `format`; returns the paths in recording order.
    pub fn write(&self, dir: &Path, format: Format) -> Vec<PathBuf> {
        let mut names: Vec<usize> = (0..self.plan.len()).collect();
        let mut r = ChaCha8Rng::seed_from_u64(self.seed ^ 0x0000_a3e5_u64);
        for i in (1..names.len()).rev() {
            let j = r.random_range(0..=i);
            names.swap(i, j);
        }
        for sub in ["darks", "cal"] {
            std::fs::create_dir_all(dir.join(sub)).expect("folder");
        }
        let ext = match format {
            Format::Plain => "fits",
            Format::Gzip => "fits.gz",
            Format::TileCompressed => "fits.fz",
        };
        let mut paths = Vec::new();
        for (i, shot) in self.plan.iter().enumerate() {
            let sub = if shot.imagetyp == "Dark Frame" {
                "darks"
            } else {
                "cal"
            };
            let path = dir.join(sub).join(format!("img{:04}.{ext}", names[i]));
            // Ten seconds apart, from an evening of a fixed day.
            let s = 20 * 3600 + 10 * i;
            let date = format!(
                "2026-11-14T{:02}:{:02}:{:02}.250",
                s / 3600,
                (s / 60) % 60,
                s % 60
            );
            write_frame(&path, &self.geometry, &self.render(i), shot, &date, format);
            paths.push(path);
        }
        paths
    }

    /// The frame numbers of the long stack, in recording order.
    pub fn stack_frames(&self) -> Vec<usize> {
        (0..self.plan.len())
            .filter(|&i| self.plan[i].stack)
            .collect()
    }
}

/// Writes one frame as a lab program would: BITPIX 16 + BZERO 32768, `IMAGETYP`, `EXPOSURE`
/// (s), `CCD-TEMP` (deg C), `DATE-OBS`, and for the plain files an extra binary table HDU.
fn write_frame(
    path: &Path,
    g: &ReadoutGeometry,
    data: &[u16],
    shot: &Shot,
    date: &str,
    format: Format,
) {
    use fitsio::FitsFile;
    use fitsio::images::{ImageDescription, ImageType};
    let dims = [usize::from(g.lines), g.line_len()];
    let desc = ImageDescription {
        data_type: ImageType::UnsignedShort,
        dimensions: &dims,
    };
    let _ = std::fs::remove_file(path);
    let (mut f, hdu) = match format {
        Format::Plain | Format::Gzip => {
            let mut f = FitsFile::create(path)
                .with_custom_primary(&desc)
                .open()
                .expect("create");
            let hdu = f.primary_hdu().expect("primary");
            (f, hdu)
        }
        Format::TileCompressed => {
            let spec = format!("{}[compress R]", path.display());
            let mut f = FitsFile::create(spec).open().expect("create compressed");
            let hdu = f.create_image("SCI", &desc).expect("image extension");
            (f, hdu)
        }
    };
    hdu.write_image(&mut f, data).expect("samples");
    hdu.write_key(&mut f, "IMAGETYP", shot.imagetyp)
        .expect("key");
    hdu.write_key(&mut f, "EXPOSURE", shot.exposure_s)
        .expect("key");
    let celsius = ((shot.temperature_k - 273.15) * 100.0).round() / 100.0;
    hdu.write_key(&mut f, "CCD-TEMP", celsius).expect("key");
    hdu.write_key(&mut f, "DATE-OBS", date).expect("key");
    hdu.write_key(&mut f, "INSTRUME", "CCD47-20 lab camera")
        .expect("key");
    if format == Format::Plain {
        use fitsio::tables::{ColumnDataType, ColumnDescription};
        let col = ColumnDescription::new("SETPOINT")
            .with_type(ColumnDataType::Double)
            .create()
            .expect("column");
        let t = f.create_table("LOG", &[col]).expect("table");
        t.write_col(&mut f, "SETPOINT", &[celsius]).expect("row");
    }
}
