//! Reading and sorting the raw frames of a lab set: each file's header is read first
//! (shape and the keywords `IMAGETYP`, `EXPTIME`, `CCDTEMP`, `DATE-OBS`), every problem is one
//! [`FramesError`] naming the file, and the frames are sorted by kind, then by `DATE-OBS`.
//! Flats are paired in time order within each exposure (photon transfer needs pairs of equal
//! illumination). Cost: opening each file once for its header; the samples are read later,
//! once per file ([`read_frame`]).

use fitsio::hdu::HduInfo;
use startrack_core::geometry::ReadoutGeometry;
use startrack_sim::fits::{FitsError, RawFrame, read_raw_frame};
use std::fmt;
use std::path::{Path, PathBuf};

/// Fewest flat pairs the photon transfer fit accepts.
pub const MIN_FLAT_PAIRS: usize = 3;
/// Fewest bias frames (one pair for the read noise).
pub const MIN_BIAS_FRAMES: usize = 2;

/// What a frame is, from `IMAGETYP`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum FrameKind {
    /// Zero exposure, shutter closed.
    Bias,
    /// Shutter closed.
    Dark,
    /// Uniformly lit.
    Flat,
}

/// One frame's header.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameInfo {
    /// The file.
    pub path: PathBuf,
    /// `IMAGETYP`.
    pub kind: FrameKind,
    /// `EXPTIME`, s.
    pub exptime_s: f64,
    /// `CCDTEMP`, K.
    pub ccdtemp_k: f64,
    /// `DATE-OBS` as written (ISO 8601 sorts as text).
    pub date_obs: String,
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
    let hdu = f.primary_hdu().map_err(|e| FitsError::Cfitsio {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    let expected = (usize::from(geometry.lines), geometry.line_len());
    let found = match &hdu.info {
        HduInfo::ImageInfo { shape, .. } => match shape[..] {
            [rows, cols] => (rows, cols),
            _ => {
                return Err(FitsError::NotImage {
                    path: path.to_path_buf(),
                    shape: shape.clone(),
                }
                .into());
            }
        },
        _ => {
            return Err(FitsError::NotImage {
                path: path.to_path_buf(),
                shape: Vec::new(),
            }
            .into());
        }
    };
    if found != expected {
        return Err(FramesError::Geometry {
            path: path.to_path_buf(),
            found,
            expected,
        });
    }
    let text = |f: &mut fitsio::FitsFile, key: &'static str| -> Result<String, FramesError> {
        hdu.read_key::<String>(f, key)
            .map(|s| s.trim().to_string())
            .map_err(|_| keyword_err(path, key, "missing"))
    };
    let number = |f: &mut fitsio::FitsFile, key: &'static str| -> Result<f64, FramesError> {
        let _ = text(f, key)?;
        let v: f64 = hdu
            .read_key(f, key)
            .map_err(|e| keyword_err(path, key, format!("not a number ({e})")))?;
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(keyword_err(path, key, format!("{v}: must be 0 or more")))
        }
    };
    let kind = match text(&mut f, "IMAGETYP")?.to_ascii_uppercase().as_str() {
        "BIAS" | "ZERO" => FrameKind::Bias,
        "DARK" => FrameKind::Dark,
        "FLAT" | "FLATFIELD" => FrameKind::Flat,
        other => {
            return Err(keyword_err(
                path,
                "IMAGETYP",
                format!("{other:?}: expected BIAS, DARK or FLAT"),
            ));
        }
    };
    let exptime_s = number(&mut f, "EXPTIME")?;
    let ccdtemp_k = number(&mut f, "CCDTEMP")?;
    let date_obs = text(&mut f, "DATE-OBS")?;
    Ok(FrameInfo {
        path: path.to_path_buf(),
        kind,
        exptime_s,
        ccdtemp_k,
        date_obs,
    })
}

/// Reads every header and sorts the frames; fails on the first bad file or on a set that
/// lacks bias frames, flat pairs or darks, or a geometry without covered columns.
pub fn inventory(paths: &[PathBuf], geometry: &ReadoutGeometry) -> Result<Inventory, FramesError> {
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
        }
    }
    // Pair flats of equal exposure in time order.
    flats.sort_by(|a, b| {
        a.exptime_s
            .total_cmp(&b.exptime_s)
            .then_with(|| a.date_obs.cmp(&b.date_obs))
    });
    let mut it = flats.into_iter().peekable();
    while let Some(a) = it.next() {
        match it.peek() {
            Some(b) if b.exptime_s == a.exptime_s => {
                if let Some(b) = it.next() {
                    inv.flat_pairs.push((a, b));
                }
            }
            _ => inv.unpaired_flats.push(a),
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
    Ok(read_raw_frame(&info.path, geometry)?)
}
