//! A simulated lab frame set: what a ground calibration of the CCD47-20 records, written as
//! raw FITS frames with the standard keywords, from the simulator ([`startrack_sim::sim`]) so that
//! every product of [`super`] can be checked against the sensor's truth.
//!
//! The set ([`LabSet`]): bias frames (0 s), flat pairs at several exposures of a constant lamp
//! (photon transfer), darks at several exposures and temperatures, one long time-ordered dark
//! series at one setting (telegraph pixels), and last a ladder of flat pairs from the top of
//! the linear range to past saturation (full well and linearity error, as EMVA 1288 measures
//! saturation capacity: the exposure raised until the mean stops rising). The ladder is
//! recorded last so that every earlier frame is the same with or without it. Each frame is a raw readout
//! (BITPIX 16 + BZERO 32768) with `IMAGETYP` (`BIAS`, `DARK`, `FLAT`), `EXPTIME` (s),
//! `CCDTEMP` (K) and `DATE-OBS` (ISO 8601, one second apart in recording order).
//!
//! Physics switched on ([`LabSet::sensor`]): the regular dark follows a doubling law
//! (`dark_rate_e_per_s_at_293k`, `dark_doubling_k`) scaled by the exposure; hot pixels with
//! their own rate (log-uniform) and doubling; telegraph pixels (a step added with probability
//! 1/2 in each frame); read noise, column bias, DSNU and PRNU as the basic sensor; the output
//! chains' quadratic non-linearity ([`LabSet::nonlinearity_at_full_well`], 0 in the standard
//! sets). With the simulator's gains and biases, output 0 saturates at the ADC's 65535
//! (96.8 ke- through its 1.5 e-/ADU above a 1000 ADU bias) before the pixel's 100 ke- full
//! well, output 1 at the full well (its ADC top is 103 ke-).
//!
//! Cost: one rendered raw sample per element of every frame (the basic sensor's cost, see
//! [`startrack_sim::sim::render`]); the small set of the tests ([`LabSet::small`]) is 98 frames of
//! 22 880 samples (78 and the 20 of the ladder), the CCD47-20 set ([`LabSet::ccd47_20`]) 98
//! frames of 1.1 M.

use startrack_core::geometry::ReadoutGeometry;
use startrack_sim::fits::{FitsError, RawFrame, write_raw_frame};
use startrack_sim::sim::effects::{ChargeTraps, DarkLaw, HotPixels, TelegraphPixels};
use startrack_sim::sim::{SensorParams, Simulator};
use std::path::{Path, PathBuf};

/// The frames of a lab set and the sensor they are taken of.
#[derive(Clone, Debug, PartialEq)]
pub struct LabSet {
    /// Readout geometry.
    pub geometry: ReadoutGeometry,
    /// Seed of the sensor and of every frame's noise.
    pub seed: u64,
    /// Regular dark rate of a covered pixel at 293 K, e-/s.
    pub dark_rate_e_per_s_at_293k: f64,
    /// Temperature rise that doubles the regular dark, K.
    pub dark_doubling_k: f64,
    /// Hot pixels (their `exposure_s` and the sensor temperature are set per frame).
    pub hot: HotPixels,
    /// Telegraph pixels.
    pub telegraph: TelegraphPixels,
    /// Number of bias frames (consecutive pairs measure the read noise).
    pub bias_frames: u32,
    /// Flat lamp, e- per pixel per second (before the flat).
    pub lamp_e_per_s: f64,
    /// Exposures of the flat pairs, s (two frames each).
    pub flat_exposures_s: Vec<f64>,
    /// Temperature of the flats and biases, K.
    pub flat_temperature_k: f64,
    /// Dark temperatures, K.
    pub dark_temperatures_k: Vec<f64>,
    /// Dark exposures, s (each at every temperature).
    pub dark_exposures_s: Vec<f64>,
    /// Dark frames per (exposure, temperature).
    pub darks_per_setting: u32,
    /// Frames of the time-ordered dark series.
    pub series_frames: u32,
    /// Exposure of the series, s.
    pub series_exposure_s: f64,
    /// Temperature of the series, K.
    pub series_temperature_k: f64,
    /// Charge traps of the sensor (none in the standard sets).
    pub traps: Option<ChargeTraps>,
    /// Exposures of the saturation ladder's flat pairs, s (two frames each, recorded after
    /// everything else); empty: no ladder.
    pub saturation_exposures_s: Vec<f64>,
    /// Each output chain's response non-linearity, the fraction a full well reads low
    /// ([`SensorParams::nonlinearity_at_full_well`]).
    pub nonlinearity_at_full_well: [f64; 2],
}

/// Hot-pixel reference temperature of the lab set, K (the `hot.csv` rates hold there).
pub const REFERENCE_K: f64 = 293.0;

impl LabSet {
    /// The test set: a 128 x 128 active area with the CCD47-20's over-scan and covered
    /// strips, two outputs, 10 bias frames, 10 flat pairs (5 000 to 50 000 e-), darks at 3
    /// temperatures x 2 exposures x 3 frames, a 30-frame series, and a saturation ladder of
    /// 10 flat pairs from 15 to 26 s (75 000 to 130 000 e-: four pairs on output 0 and
    /// five on output 1 inside 95 % of saturation, the last two past it on every pixel of
    /// both outputs).
    pub fn small(seed: u64) -> Self {
        Self {
            geometry: ReadoutGeometry {
                overscan_px: 8,
                covered_px: 16,
                active_cols: 128,
                active_rows: 128,
                lines: 130,
                outputs: 2,
            },
            seed,
            dark_rate_e_per_s_at_293k: 20.0,
            dark_doubling_k: 6.5,
            hot: HotPixels {
                fraction: 0.004,
                rate_min_e_per_s: 100.0,
                rate_max_e_per_s: 5000.0,
                reference_k: REFERENCE_K,
                doubling_k: 5.0,
                exposure_s: 0.0,
            },
            telegraph: TelegraphPixels {
                fraction: 0.002,
                amplitude_e: 60.0,
                p_high: 0.5,
            },
            bias_frames: 10,
            lamp_e_per_s: 5000.0,
            flat_exposures_s: (1..=10).map(f64::from).collect(),
            flat_temperature_k: 253.0,
            dark_temperatures_k: vec![263.0, 273.0, 283.0],
            dark_exposures_s: vec![10.0, 30.0],
            darks_per_setting: 3,
            series_frames: 30,
            series_exposure_s: 10.0,
            series_temperature_k: 263.0,
            traps: None,
            saturation_exposures_s: vec![
                15.0, 16.0, 17.0, 18.0, 18.5, 19.5, 20.5, 22.0, 24.0, 26.0,
            ],
            nonlinearity_at_full_well: [0.0, 0.0],
        }
    }

    /// The same set at the CCD47-20's full readout (1033 x 1072).
    pub fn ccd47_20(seed: u64) -> Self {
        Self {
            geometry: ReadoutGeometry::CCD47_20_DUAL,
            ..Self::small(seed)
        }
    }

    /// The sensor, with its temperature and exposure still to be set per frame.
    pub fn sensor(&self) -> Simulator {
        let params = SensorParams {
            geometry: self.geometry,
            seed: self.seed,
            dark_mean_e: 0.0,
            nonlinearity_at_full_well: self.nonlinearity_at_full_well,
            effects: startrack_sim::sim::Effects {
                temperature_k: REFERENCE_K,
                dark_law: Some(DarkLaw {
                    reference_k: REFERENCE_K,
                    doubling_k: self.dark_doubling_k,
                }),
                hot: Some(self.hot),
                telegraph: Some(self.telegraph),
                traps: self.traps,
                ..Default::default()
            },
            ..SensorParams::default()
        };
        Simulator::new(params, Vec::new())
    }

    /// The sensor as one frame sees it: `frame` number, exposure, temperature, lamp.
    pub fn frame_sensor(
        &self,
        frame: u32,
        exposure_s: f64,
        temperature_k: f64,
        lamp: bool,
    ) -> Simulator {
        let mut s = self.sensor();
        s.frame = frame;
        let p = &mut s.params;
        // The regular dark at the reference temperature in this exposure; the law scales it.
        p.dark_mean_e = self.dark_rate_e_per_s_at_293k * exposure_s;
        p.effects.temperature_k = temperature_k;
        if let Some(h) = p.effects.hot.as_mut() {
            h.exposure_s = exposure_s;
        }
        p.sky_e = if lamp {
            self.lamp_e_per_s * exposure_s
        } else {
            0.0
        };
        s
    }

    /// Every frame of the set in recording order: (IMAGETYP, EXPTIME s, CCDTEMP K).
    pub fn plan(&self) -> Vec<(&'static str, f64, f64)> {
        let mut v = Vec::new();
        for _ in 0..self.bias_frames {
            v.push(("BIAS", 0.0, self.flat_temperature_k));
        }
        for &t in &self.flat_exposures_s {
            v.push(("FLAT", t, self.flat_temperature_k));
            v.push(("FLAT", t, self.flat_temperature_k));
        }
        for &temp in &self.dark_temperatures_k {
            for &t in &self.dark_exposures_s {
                for _ in 0..self.darks_per_setting {
                    v.push(("DARK", t, temp));
                }
            }
        }
        for _ in 0..self.series_frames {
            v.push(("DARK", self.series_exposure_s, self.series_temperature_k));
        }
        for &t in &self.saturation_exposures_s {
            v.push(("FLAT", t, self.flat_temperature_k));
            v.push(("FLAT", t, self.flat_temperature_k));
        }
        v
    }

    /// Renders frame `index` of [`Self::plan`] (frame numbers start at 1: 0 is the scene's).
    pub fn render(&self, index: usize) -> Option<(RawFrame, &'static str, f64, f64)> {
        let (kind, t, temp) = *self.plan().get(index)?;
        let s = self.frame_sensor(index as u32 + 1, t, temp, kind == "FLAT");
        let g = self.geometry;
        let (lines, len) = (usize::from(g.lines), g.line_len());
        let mut data_adu = vec![0u16; lines * len];
        for (l, line) in data_adu.chunks_exact_mut(len).enumerate() {
            s.render_line(l, line);
        }
        Some((
            RawFrame {
                lines,
                cols: len,
                data_adu,
            },
            kind,
            t,
            temp,
        ))
    }

    /// Writes every frame into `dir` (created if needed) as `NNNN_KIND.fits`; returns the paths.
    pub fn write(&self, dir: &Path) -> Result<Vec<PathBuf>, FitsError> {
        std::fs::create_dir_all(dir).map_err(|e| FitsError::Io {
            path: dir.to_path_buf(),
            msg: e.to_string(),
        })?;
        let mut paths = Vec::new();
        for i in 0..self.plan().len() {
            let Some((frame, kind, t, temp)) = self.render(i) else {
                break;
            };
            let path = dir.join(format!("{i:04}_{}.fits", kind.to_ascii_lowercase()));
            write_raw_frame(&path, &frame, &[("EXPTIME", t), ("CCDTEMP", temp)])?;
            // One second apart, starting at midnight of a fixed day.
            let date = format!(
                "2026-03-01T{:02}:{:02}:{:02}",
                i / 3600,
                (i / 60) % 60,
                i % 60
            );
            write_string_keys(&path, &[("IMAGETYP", kind), ("DATE-OBS", &date)])?;
            paths.push(path);
        }
        Ok(paths)
    }
}

impl LabSet {
    /// Writes the sensor's truth for the products into `dir` (not a folder of frames:
    /// `calib frames` would refuse these files): `flat.fits` (active area, each output's mean
    /// 1), `dark_rel.fits` (full readout, the regular relative dark over the mean of the
    /// covered pixels that are neither hot nor telegraph, as the core's estimator sees them),
    /// `column_bias.fits` (one line, ADU) and `defects.fits` (full readout, 1 for a hot or
    /// telegraph pixel). Cost: a few draws per element of the readout.
    pub fn write_truth(&self, dir: &Path) -> Result<Vec<PathBuf>, FitsError> {
        use startrack_sim::fits::{MapF32, write_map};
        std::fs::create_dir_all(dir).map_err(|e| FitsError::Io {
            path: dir.to_path_buf(),
            msg: e.to_string(),
        })?;
        let s = self.sensor();
        let g = self.geometry;
        let (lines, len) = (usize::from(g.lines), g.line_len());
        let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
        let defect = |c: usize, l: usize| {
            s.hot_rate_e_per_s(c, l).is_some() || s.telegraph_step_e(c, l).is_some()
        };
        let (mut sum, mut n) = (0.0, 0usize);
        for l in 0..lines {
            for (a, b) in g.covered_cols() {
                for c in (a..b).filter(|&c| !defect(c, l)) {
                    sum += s.dark_rel(c, l);
                    n += 1;
                }
            }
        }
        let norm = if n == 0 { 1.0 } else { sum / n as f64 };
        let map = |rows: usize, cols: usize, f: &dyn Fn(usize, usize) -> f64| MapF32 {
            rows,
            cols,
            data: (0..rows * cols)
                .map(|i| f(i / cols, i % cols) as f32)
                .collect(),
            keys: Vec::new(),
        };
        let half = cols / usize::from(g.outputs).max(1);
        let mut mean = [0.0f64; 2];
        for y in 0..rows {
            for x in 0..cols {
                if let Some(m) = mean.get_mut((x / half.max(1)).min(1)) {
                    *m += s.flat(x, y) / (half * rows) as f64;
                }
            }
        }
        let files = [
            (
                "flat.fits",
                map(rows, cols, &|y, x| {
                    s.flat(x, y) / mean.get((x / half.max(1)).min(1)).copied().unwrap_or(1.0)
                }),
            ),
            (
                "dark_rel.fits",
                map(lines, len, &|l, c| s.dark_rel(c, l) / norm),
            ),
            (
                "column_bias.fits",
                map(1, len, &|_, c| s.column_bias_adu(c)),
            ),
            (
                "defects.fits",
                map(lines, len, &|l, c| f64::from(u8::from(defect(c, l)))),
            ),
        ];
        let mut paths = Vec::new();
        for (name, m) in files {
            let p = dir.join(name);
            write_map(&p, &m)?;
            paths.push(p);
        }
        Ok(paths)
    }
}

impl LabSet {
    /// The expected mean signal above bias of `output`'s active pixels in a flat of
    /// `exposure_s`, ADU, from the sensor's truth: each pixel's expected charge `m` (lamp
    /// through its flat, plus its dark) read through the output's non-linearity
    /// (`E[e (1 - k e / W)] = m - k (m^2 + m) / W` for a Poisson charge) and gain. Below
    /// saturation only (the full well and the ADC's top are not applied). Cost: one expected
    /// charge per active pixel of the output.
    pub fn expected_flat_mean_adu(&self, exposure_s: f64, output: u8) -> f64 {
        let s = self.frame_sensor(0, exposure_s, self.flat_temperature_k, true);
        let p = &s.params;
        let g = self.geometry;
        let o = usize::from(output).min(1);
        let (k, well) = (p.nonlinearity_at_full_well[o], p.full_well_e.max(1.0));
        let (mut sum, mut n) = (0.0, 0usize);
        for line in 0..usize::from(g.active_rows) {
            for col in (0..g.line_len()).filter(|&c| {
                g.segment(c) == Some(startrack_core::geometry::Segment::Active)
                    && g.output_of_col(c).0 == output
            }) {
                let (light, dark) = s.expected_e(col, line);
                let m = light + dark;
                sum += m - k * (m * m + m) / well;
                n += 1;
            }
        }
        sum / n.max(1) as f64 / p.gain_e_per_adu[o]
    }
}

/// Adds string keywords to the primary header of an existing FITS file.
pub fn write_string_keys(path: &Path, keys: &[(&str, &str)]) -> Result<(), FitsError> {
    let err = |e: fitsio::errors::Error| FitsError::Cfitsio {
        path: path.to_path_buf(),
        msg: e.to_string(),
    };
    let mut f = fitsio::FitsFile::edit(path).map_err(err)?;
    let hdu = f.primary_hdu().map_err(err)?;
    for (k, v) in keys {
        hdu.write_key(&mut f, k, *v).map_err(err)?;
    }
    Ok(())
}
