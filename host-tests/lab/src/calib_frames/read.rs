//! Reading and sorting the raw frames of a lab set: each file's header is read first (shape
//! and the keywords), every problem is one [`FramesError`] naming the file and the keyword,
//! and the frames are sorted by kind, then by `DATE-OBS`, and grouped the way a lab takes
//! them.
//!
//! Keywords, in the spellings of common acquisition programs:
//! - `IMAGETYP`: `BIAS`, `ZERO`, `OFFSET`, `Bias Frame`; `DARK`, `Dark Frame`; `FLAT`,
//!   `FLATFIELD`, `Flat Field`, `Flat Frame`, `SKYFLAT`, `DOMEFLAT`; light frames (`LIGHT`,
//!   `Light Frame`, `OBJECT`, `SCIENCE`) are counted and left out (case, spaces, `_` and `-`
//!   ignored);
//! - the exposure, s: `EXPTIME`, else `EXPOSURE`;
//! - the temperature: `CCDTEMP` in K, else `CCD-TEMP` in deg C (MaxIm DL, SBIG and ASCOM
//!   drivers; converted with 273.15);
//! - `DATE-OBS` (ISO 8601, which sorts as text).
//!
//! The image is the first HDU holding a 2-D image (the primary, or HDU 1 of a tile-compressed
//! `.fits.fz`; extra HDUs are ignored); its header is read first, then the primary's. CFITSIO
//! opens `.fits.gz` and `.fits.fz` itself, so a frame reads the same samples and keywords
//! whichever way it was written.
//!
//! Groups ([`group_darks`], [`Inventory`]): temperatures within [`Grouping::temperature_tolerance_k`]
//! of their group's median (a sensor regulated within a band wanders by hundredths of a kelvin
//! from frame to frame) are one temperature, exposures within [`EXPOSURE_ROUNDING_S`] or
//! [`EXPOSURE_ROUNDING_REL`] of each other one exposure; a set whose temperatures do not fall
//! into such bands is refused with the file and keyword that breaks it. Flats are paired in
//! time order within each exposure (photon transfer needs pairs of equal illumination).
//! Cost: opening each file once for its header; the samples are read later, once per file
//! ([`read_frame`]).

use fitsio::hdu::HduInfo;
use startrack_core::geometry::ReadoutGeometry;
use startrack_sim::fits::{FitsError, RawFrame, read_raw_frame_at};
use std::fmt;
use std::path::{Path, PathBuf};

/// Fewest flat pairs the photon transfer fit accepts.
pub const MIN_FLAT_PAIRS: usize = 3;
/// Fewest bias frames (one pair for the read noise).
pub const MIN_BIAS_FRAMES: usize = 2;

/// Exposures closer than this, s, are one exposure (a program's rounding of the time it
/// writes).
pub const EXPOSURE_ROUNDING_S: f64 = 1e-3;
/// Exposures closer than this fraction of the longer are one exposure.
pub const EXPOSURE_ROUNDING_REL: f64 = 1e-3;
/// Default regulation band: temperatures within this of their group's median are one
/// temperature, K.
pub const DEFAULT_TEMPERATURE_TOLERANCE_K: f64 = 0.5;
/// Celsius to kelvin (the definition of the kelvin scale's offset, SI Brochure 9th ed.).
pub const CELSIUS_TO_KELVIN: f64 = 273.15;

/// How frames are grouped into settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grouping {
    /// Temperatures within this of their group's median are one temperature, K (the
    /// regulation band of the sensor's temperature control).
    pub temperature_tolerance_k: f64,
}

impl Default for Grouping {
    fn default() -> Self {
        Self {
            temperature_tolerance_k: DEFAULT_TEMPERATURE_TOLERANCE_K,
        }
    }
}

/// What a frame is, from `IMAGETYP`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum FrameKind {
    /// Zero exposure, shutter closed.
    Bias,
    /// Shutter closed.
    Dark,
    /// Uniformly lit.
    Flat,
    /// A sky or star frame: not a calibration frame, left out.
    Light,
}

/// The frame kind an `IMAGETYP` value names (case, spaces, `_` and `-` ignored), or `None`.
pub fn frame_kind(imagetyp: &str) -> Option<FrameKind> {
    let k: String = imagetyp
        .chars()
        .filter(|c| !matches!(c, ' ' | '_' | '-'))
        .map(|c| c.to_ascii_uppercase())
        .collect();
    let k = k.strip_suffix("FRAME").unwrap_or(&k);
    Some(match k {
        "BIAS" | "ZERO" | "OFFSET" => FrameKind::Bias,
        "DARK" => FrameKind::Dark,
        "FLAT" | "FLATFIELD" | "SKYFLAT" | "DOMEFLAT" | "TWILIGHTFLAT" => FrameKind::Flat,
        "LIGHT" | "OBJECT" | "SCIENCE" => FrameKind::Light,
        _ => return None,
    })
}

/// One frame's header.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameInfo {
    /// The file.
    pub path: PathBuf,
    /// `IMAGETYP`.
    pub kind: FrameKind,
    /// `EXPTIME` (or `EXPOSURE`), s.
    pub exptime_s: f64,
    /// `CCDTEMP` (or `CCD-TEMP` converted from deg C), K.
    pub ccdtemp_k: f64,
    /// `DATE-OBS` as written (ISO 8601 sorts as text).
    pub date_obs: String,
    /// The HDU holding the image (0: primary).
    pub hdu: usize,
    /// The keyword the temperature came from.
    pub temperature_key: &'static str,
}

/// Why the frames cannot be calibrated: one line naming the file and the problem.
#[derive(Clone, Debug, PartialEq)]
pub enum FramesError {
    /// A file could not be read as FITS.
    Fits(FitsError),
    /// A header keyword is missing or unusable.
    Keyword {
        /// The file.
        path: PathBuf,
        /// The keyword.
        key: &'static str,
        /// What is wrong.
        msg: String,
    },
    /// The file's readout shape differs from the geometry (or from the other files).
    Geometry {
        /// The file.
        path: PathBuf,
        /// (lines, columns) found.
        found: (usize, usize),
        /// (lines, columns) expected.
        expected: (usize, usize),
    },
    /// A flat is saturated while a flat of equal or longer exposure is not (a flat past
    /// saturation belongs at the top of the exposure ladder only: a lamp flash or a broken
    /// frame otherwise).
    Saturated {
        /// The file.
        path: PathBuf,
        /// Fraction of the active pixels at the ADC's top.
        fraction: f64,
        /// The flat of equal or longer exposure with fewer pixels at the top.
        unsaturated: PathBuf,
    },
    /// The set lacks frames a product needs, or the geometry cannot give one.
    Missing(String),
}

impl fmt::Display for FramesError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Fits(e) => write!(f, "{e}"),
            Self::Keyword { path, key, msg } => write!(f, "{}: {key}: {msg}", path.display()),
            Self::Geometry {
                path,
                found,
                expected,
            } => write!(
                f,
                "{}: mixed geometry: {} lines x {} columns, the set is {} x {}",
                path.display(),
                found.0,
                found.1,
                expected.0,
                expected.1
            ),
            Self::Saturated {
                path,
                fraction,
                unsaturated,
            } => write!(
                f,
                "{}: saturated flat: {:.2} % of the active pixels at 65535 ADU, but {} of equal or longer EXPTIME is not",
                path.display(),
                100.0 * fraction,
                unsaturated.display()
            ),
            Self::Missing(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for FramesError {}

impl From<FitsError> for FramesError {
    fn from(e: FitsError) -> Self {
        Self::Fits(e)
    }
}

/// The frames of a set, sorted.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Inventory {
    /// Bias frames, by `DATE-OBS`.
    pub bias: Vec<FrameInfo>,
    /// Flat pairs: consecutive frames of one exposure, by `DATE-OBS`.
    pub flat_pairs: Vec<(FrameInfo, FrameInfo)>,
    /// Flats left without a partner.
    pub unpaired_flats: Vec<FrameInfo>,
    /// Dark frames, by `DATE-OBS`.
    pub darks: Vec<FrameInfo>,
    /// The darks' settings, by temperature then exposure; `darks` index into it through
    /// [`Self::dark_setting`].
    pub dark_groups: Vec<DarkGroup>,
    /// Per dark of [`Self::darks`], its group in [`Self::dark_groups`].
    pub dark_setting: Vec<usize>,
    /// Flat exposures found (s, frames), shortest first.
    pub flat_groups: Vec<(f64, usize)>,
    /// Light frames left out.
    pub lights: usize,
}

/// Darks of one setting: one temperature (within the regulation band) and one exposure
/// (within rounding).
#[derive(Clone, Debug, PartialEq)]
pub struct DarkGroup {
    /// The temperature group's mean CCDTEMP, K (every dark of that temperature, all
    /// exposures).
    pub temperature_k: f64,
    /// Largest minus smallest CCDTEMP of the temperature group, K.
    pub temperature_span_k: f64,
    /// The exposure's median EXPTIME, s.
    pub exptime_s: f64,
    /// Frames.
    pub frames: usize,
    /// First and last DATE-OBS.
    pub dates: (String, String),
}

fn keyword_err(path: &Path, key: &'static str, msg: impl Into<String>) -> FramesError {
    FramesError::Keyword {
        path: path.to_path_buf(),
        key,
        msg: msg.into(),
    }
}

/// Reads one file's header and checks its shape against `geometry`.
pub fn read_info(path: &Path, geometry: &ReadoutGeometry) -> Result<FrameInfo, FramesError> {
    std::fs::File::open(path).map_err(|e| FitsError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    let mut f = fitsio::FitsFile::open(path).map_err(|e| FitsError::NotFits {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    let cfitsio = |e: fitsio::errors::Error| FitsError::Cfitsio {
        path: path.to_path_buf(),
        msg: e.to_string(),
    };
    let hdus = f.num_hdus().map_err(cfitsio)?;
    let mut image = None;
    let mut first_shape = None;
    for i in 0..hdus {
        let hdu = f.hdu(i).map_err(cfitsio)?;
        if let HduInfo::ImageInfo { shape, .. } = &hdu.info {
            if let [rows, cols] = shape[..] {
                image = Some((i, hdu, (rows, cols)));
                break;
            }
            first_shape.get_or_insert_with(|| shape.clone());
        }
    }
    let Some((index, hdu, found)) = image else {
        return Err(FitsError::NotImage {
            path: path.to_path_buf(),
            shape: first_shape.unwrap_or_default(),
        }
        .into());
    };
    let expected = (usize::from(geometry.lines), geometry.line_len());
    if found != expected {
        return Err(FramesError::Geometry {
            path: path.to_path_buf(),
            found,
            expected,
        });
    }
    let primary = f.primary_hdu().map_err(cfitsio)?;
    // A keyword from the image's header, else the primary's.
    let text = |f: &mut fitsio::FitsFile, key: &'static str| -> Option<String> {
        hdu.read_key::<String>(f, key)
            .or_else(|_| primary.read_key::<String>(f, key))
            .ok()
            .map(|s| s.trim().to_string())
    };
    let number =
        |f: &mut fitsio::FitsFile, key: &'static str| -> Option<Result<f64, FramesError>> {
            text(f, key)?;
            let v: Result<f64, _> = hdu.read_key(f, key).or_else(|_| primary.read_key(f, key));
            Some(
                v.map_err(|e| keyword_err(path, key, format!("not a number ({e})")))
                    .and_then(|v| {
                        if v.is_finite() {
                            Ok(v)
                        } else {
                            Err(keyword_err(path, key, format!("{v}: not finite")))
                        }
                    }),
            )
        };
    let imagetyp =
        text(&mut f, "IMAGETYP").ok_or_else(|| keyword_err(path, "IMAGETYP", "missing"))?;
    let kind = frame_kind(&imagetyp).ok_or_else(|| {
        keyword_err(
            path,
            "IMAGETYP",
            format!("{imagetyp:?}: expected a bias, dark, flat or light frame"),
        )
    })?;
    let (exp_key, exptime_s) = match number(&mut f, "EXPTIME") {
        Some(v) => ("EXPTIME", v?),
        None => match number(&mut f, "EXPOSURE") {
            Some(v) => ("EXPOSURE", v?),
            None => return Err(keyword_err(path, "EXPTIME", "missing (nor EXPOSURE)")),
        },
    };
    if exptime_s < 0.0 {
        return Err(keyword_err(
            path,
            exp_key,
            format!("{exptime_s}: must be 0 or more"),
        ));
    }
    let (temperature_key, ccdtemp_k) = match number(&mut f, "CCDTEMP") {
        Some(v) => ("CCDTEMP", v?),
        None => match number(&mut f, "CCD-TEMP") {
            Some(v) => ("CCD-TEMP", v? + CELSIUS_TO_KELVIN),
            None => {
                return Err(keyword_err(
                    path,
                    "CCDTEMP",
                    "missing (nor CCD-TEMP in deg C)",
                ));
            }
        },
    };
    if ccdtemp_k <= 0.0 {
        let shown = if temperature_key == "CCD-TEMP" {
            format!("{} deg C", ccdtemp_k - CELSIUS_TO_KELVIN)
        } else {
            format!("{ccdtemp_k} K")
        };
        return Err(keyword_err(
            path,
            temperature_key,
            format!("{shown}: below absolute zero (CCDTEMP is in K, CCD-TEMP in deg C)"),
        ));
    }
    let date_obs =
        text(&mut f, "DATE-OBS").ok_or_else(|| keyword_err(path, "DATE-OBS", "missing"))?;
    Ok(FrameInfo {
        path: path.to_path_buf(),
        kind,
        exptime_s,
        ccdtemp_k,
        date_obs,
        hdu: index,
        temperature_key,
    })
}

/// True when exposures `a` and `b`, s, are one exposure within rounding.
pub fn same_exposure(a: f64, b: f64) -> bool {
    (a - b).abs() <= EXPOSURE_ROUNDING_S.max(EXPOSURE_ROUNDING_REL * a.abs().max(b.abs()))
}

/// Groups of `values` (indices into it): sorted, split where two neighbours are not `close`.
fn clusters(values: &[f64], close: &dyn Fn(f64, f64) -> bool) -> Vec<Vec<usize>> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut out: Vec<Vec<usize>> = Vec::new();
    for i in order {
        match out.last_mut() {
            Some(g) if g.last().is_some_and(|&j| close(values[j], values[i])) => g.push(i),
            _ => out.push(vec![i]),
        }
    }
    out
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The darks' settings: temperature groups (within `grouping`'s band of their median), then
/// exposures within rounding in each. Returns the groups and each dark's group; a dark
/// further than the band from its group's median (temperatures that chain across more than
/// the band) is refused, naming the file and its temperature keyword.
pub fn group_darks(
    darks: &[FrameInfo],
    grouping: &Grouping,
) -> Result<(Vec<DarkGroup>, Vec<usize>), FramesError> {
    let tol = grouping.temperature_tolerance_k;
    if !(tol.is_finite() && tol >= 0.0) {
        return Err(FramesError::Missing(format!(
            "temperature tolerance {tol} K: must be 0 or more"
        )));
    }
    let temps: Vec<f64> = darks.iter().map(|d| d.ccdtemp_k).collect();
    let mut groups = Vec::new();
    let mut setting = vec![0usize; darks.len()];
    for t_group in clusters(&temps, &|a, b| b - a <= tol) {
        let mut ts: Vec<f64> = t_group.iter().map(|&i| temps[i]).collect();
        let med = median(&mut ts);
        let (lo, hi) = (
            ts.first().copied().unwrap_or(med),
            ts.last().copied().unwrap_or(med),
        );
        if let Some(&far) = t_group
            .iter()
            .filter(|&&i| (temps[i] - med).abs() > tol)
            .max_by(|&&a, &&b| (temps[a] - med).abs().total_cmp(&(temps[b] - med).abs()))
        {
            let d = &darks[far];
            return Err(keyword_err(
                &d.path,
                d.temperature_key,
                format!(
                    "{:.3} K is {:.3} K from the median {med:.3} K of the darks it chains to ({lo:.3} to {hi:.3} K): the temperatures do not fall into regulation bands of {tol} K (set the band with --temperature-tolerance-k)",
                    d.ccdtemp_k,
                    (d.ccdtemp_k - med).abs()
                ),
            ));
        }
        let mean_t = ts.iter().sum::<f64>() / ts.len().max(1) as f64;
        let exps: Vec<f64> = t_group.iter().map(|&i| darks[i].exptime_s).collect();
        for e_group in clusters(&exps, &same_exposure) {
            let members: Vec<usize> = e_group.iter().map(|&k| t_group[k]).collect();
            let mut es: Vec<f64> = members.iter().map(|&i| darks[i].exptime_s).collect();
            let mut dates: Vec<&String> = members.iter().map(|&i| &darks[i].date_obs).collect();
            dates.sort();
            for &i in &members {
                setting[i] = groups.len();
            }
            groups.push(DarkGroup {
                temperature_k: mean_t,
                temperature_span_k: hi - lo,
                exptime_s: median(&mut es),
                frames: members.len(),
                dates: (
                    dates.first().map(|s| (*s).clone()).unwrap_or_default(),
                    dates.last().map(|s| (*s).clone()).unwrap_or_default(),
                ),
            });
        }
    }
    Ok((groups, setting))
}

/// Reads every header and sorts the frames; fails on the first bad file or on a set that
/// lacks bias frames, flat pairs or darks, or a geometry without covered columns.
pub fn inventory(paths: &[PathBuf], geometry: &ReadoutGeometry) -> Result<Inventory, FramesError> {
    inventory_with(paths, geometry, &Grouping::default())
}

/// [`inventory`] with the grouping's regulation band.
pub fn inventory_with(
    paths: &[PathBuf],
    geometry: &ReadoutGeometry,
    grouping: &Grouping,
) -> Result<Inventory, FramesError> {
    if geometry.covered_px == 0 {
        return Err(FramesError::Missing(
            "the geometry has no covered columns: the dark map cannot be normalised".into(),
        ));
    }
    let mut infos = paths
        .iter()
        .map(|p| read_info(p, geometry))
        .collect::<Result<Vec<_>, _>>()?;
    infos.sort_by(|a, b| (a.kind, &a.date_obs, &a.path).cmp(&(b.kind, &b.date_obs, &b.path)));
    let mut inv = Inventory::default();
    let mut flats = Vec::new();
    for i in infos {
        match i.kind {
            FrameKind::Bias => inv.bias.push(i),
            FrameKind::Dark => inv.darks.push(i),
            FrameKind::Flat => flats.push(i),
            FrameKind::Light => inv.lights += 1,
        }
    }
    let (groups, setting) = group_darks(&inv.darks, grouping)?;
    inv.dark_groups = groups;
    inv.dark_setting = setting;
    // Pair flats of one exposure (within rounding) in time order.
    let exps: Vec<f64> = flats.iter().map(|f| f.exptime_s).collect();
    let mut by_exposure: Vec<Vec<FrameInfo>> = clusters(&exps, &same_exposure)
        .into_iter()
        .map(|g| g.into_iter().map(|i| flats[i].clone()).collect())
        .collect();
    for group in &mut by_exposure {
        group.sort_by(|a, b| (&a.date_obs, &a.path).cmp(&(&b.date_obs, &b.path)));
        let mut es: Vec<f64> = group.iter().map(|f| f.exptime_s).collect();
        inv.flat_groups.push((median(&mut es), group.len()));
        let mut it = group.drain(..);
        while let Some(a) = it.next() {
            match it.next() {
                Some(b) => inv.flat_pairs.push((a, b)),
                None => inv.unpaired_flats.push(a),
            }
        }
    }
    if inv.bias.len() < MIN_BIAS_FRAMES {
        return Err(FramesError::Missing(format!(
            "{} bias frames: the read noise needs at least {MIN_BIAS_FRAMES}",
            inv.bias.len()
        )));
    }
    if inv.flat_pairs.len() < MIN_FLAT_PAIRS {
        return Err(FramesError::Missing(format!(
            "too few flats: {} pairs of equal EXPTIME, photon transfer needs at least {MIN_FLAT_PAIRS}",
            inv.flat_pairs.len()
        )));
    }
    if inv.darks.is_empty() {
        return Err(FramesError::Missing(
            "no dark frames: no dark map or hot pixels".into(),
        ));
    }
    Ok(inv)
}

/// Reads the samples of a frame whose header [`read_info`] accepted.
pub fn read_frame(info: &FrameInfo, geometry: &ReadoutGeometry) -> Result<RawFrame, FramesError> {
    Ok(read_raw_frame_at(&info.path, geometry, info.hdu)?)
}
