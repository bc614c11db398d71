//! FITS input and output for the `startrack` command: raw CCD frames and calibration maps.
//!
//! - A raw frame is the readout as the sensor delivers it: one 2-D image in the primary HDU,
//!   16-bit unsigned samples stored the FITS way (BITPIX 16 with BZERO 32768, which CFITSIO
//!   reads back as `u16` exactly), `lines` rows (NAXIS2) of `line_len` columns (NAXIS1)
//!   including over-scan and covered columns: 1033 x 1072 for the CCD47-20
//!   ([`ReadoutGeometry::CCD47_20_DUAL`]). Row 0 is the first line read, column 0 the left-most
//!   serial register element.
//! - A map is a 2-D `f32` image (BITPIX -32; any numeric BITPIX is accepted on reading and
//!   converted) with optional numeric header keywords (e.g. `GAIN1`, `GAIN2`).
//!
//! The files are read and written with CFITSIO (the `fitsio` crate, bundled CFITSIO source),
//! so DS9 and astropy read what this writes. Every failure is one [`FitsError`] naming the
//! file; nothing here panics on a bad file.

use fitsio::FitsFile;
use fitsio::hdu::HduInfo;
use fitsio::images::{ImageDescription, ImageType};
use startrack_core::geometry::ReadoutGeometry;
use std::fmt;
use std::path::{Path, PathBuf};

/// Why a FITS file could not be read or written.
#[derive(Clone, Debug, PartialEq)]
pub enum FitsError {
    /// The file could not be opened, read or created (missing, unreadable, no space).
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        msg: String,
    },
    /// The file is not a FITS file (CFITSIO rejects its header).
    NotFits {
        /// The file.
        path: PathBuf,
        /// What CFITSIO said.
        msg: String,
    },
    /// The primary HDU holds no 2-D image.
    NotImage {
        /// The file.
        path: PathBuf,
        /// Dimensions found (empty for a table or no data).
        shape: Vec<usize>,
    },
    /// The image's sample type is not the one expected.
    WrongType {
        /// The file.
        path: PathBuf,
        /// Type found, as CFITSIO reports it (e.g. "BITPIX 16 signed (no BZERO 32768)").
        found: String,
        /// Type expected.
        expected: &'static str,
    },
    /// The image's shape is not the one expected.
    WrongShape {
        /// The file.
        path: PathBuf,
        /// (rows, columns) found.
        found: (usize, usize),
        /// (rows, columns) expected.
        expected: (usize, usize),
    },
    /// A map value is NaN or infinite.
    NotFinite {
        /// The file.
        path: PathBuf,
        /// Row of the first such value.
        row: usize,
        /// Column of the first such value.
        col: usize,
    },
    /// A header keyword is present but not a number.
    Keyword {
        /// The file.
        path: PathBuf,
        /// The keyword.
        key: String,
        /// What CFITSIO said.
        msg: String,
    },
    /// CFITSIO failed while reading or writing the data.
    Cfitsio {
        /// The file.
        path: PathBuf,
        /// What CFITSIO said.
        msg: String,
    },
}

impl fmt::Display for FitsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io { path, msg } => write!(f, "{}: {msg}", path.display()),
            Self::NotFits { path, msg } => {
                write!(f, "{}: not a FITS file ({msg})", path.display())
            }
            Self::NotImage { path, shape } => write!(
                f,
                "{}: the primary HDU holds no 2-D image (dimensions {shape:?})",
                path.display()
            ),
            Self::WrongType {
                path,
                found,
                expected,
            } => write!(
                f,
                "{}: wrong sample type: {found}, expected {expected}",
                path.display()
            ),
            Self::WrongShape {
                path,
                found,
                expected,
            } => write!(
                f,
                "{}: wrong shape: {} lines x {} columns, expected {} x {}",
                path.display(),
                found.0,
                found.1,
                expected.0,
                expected.1
            ),
            Self::NotFinite { path, row, col } => write!(
                f,
                "{}: value at row {row}, column {col} is NaN or infinite",
                path.display()
            ),
            Self::Keyword { path, key, msg } => {
                write!(f, "{}: keyword {key}: {msg}", path.display())
            }
            Self::Cfitsio { path, msg } => write!(f, "{}: FITS error: {msg}", path.display()),
        }
    }
}

impl std::error::Error for FitsError {}

/// A raw frame: `lines` x `cols` samples, row-major (row = line read).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawFrame {
    /// Lines (rows).
    pub lines: usize,
    /// Samples per line (columns).
    pub cols: usize,
    /// Samples, ADU, row-major.
    pub data_adu: Vec<u16>,
}

impl RawFrame {
    /// The raw lines, in readout order.
    pub fn lines(&self) -> impl Iterator<Item = &[u16]> {
        self.data_adu.chunks_exact(self.cols.max(1))
    }

    /// Line `i`, or `None` past the end.
    pub fn line(&self, i: usize) -> Option<&[u16]> {
        self.data_adu.get(i * self.cols..(i + 1) * self.cols)
    }
}

/// A 2-D map of `f32` values and the numeric header keywords read or to write.
#[derive(Clone, Debug, PartialEq)]
pub struct MapF32 {
    /// Rows (NAXIS2).
    pub rows: usize,
    /// Columns (NAXIS1).
    pub cols: usize,
    /// Values, row-major.
    pub data: Vec<f32>,
    /// Numeric keywords (name, value); on reading, the requested ones that are present.
    pub keys: Vec<(String, f64)>,
}

impl MapF32 {
    /// The value of keyword `key`, if present.
    pub fn key(&self, key: &str) -> Option<f64> {
        self.keys
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(key))
            .map(|(_, v)| *v)
    }

    /// Value at (`row`, `col`), or `None` outside the map.
    pub fn get(&self, row: usize, col: usize) -> Option<f32> {
        if col >= self.cols {
            return None;
        }
        self.data.get(row * self.cols + col).copied()
    }
}

fn cfitsio(path: &Path) -> impl Fn(fitsio::errors::Error) -> FitsError + '_ {
    move |e| FitsError::Cfitsio {
        path: path.to_path_buf(),
        msg: e.to_string(),
    }
}

/// Opens `path` read-only, telling a missing file from a file that is not FITS.
fn open(path: &Path) -> Result<FitsFile, FitsError> {
    // CFITSIO reports both as an open failure: look at the file first.
    std::fs::File::open(path).map_err(|e| FitsError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    FitsFile::open(path).map_err(|e| FitsError::NotFits {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// The primary HDU's image shape (rows, cols) and equivalent type.
fn image_info(
    fits: &mut FitsFile,
    path: &Path,
) -> Result<(fitsio::hdu::FitsHdu, (usize, usize), ImageType), FitsError> {
    image_info_at(fits, path, 0)
}

/// HDU `index`'s image shape (rows, cols) and equivalent type.
fn image_info_at(
    fits: &mut FitsFile,
    path: &Path,
    index: usize,
) -> Result<(fitsio::hdu::FitsHdu, (usize, usize), ImageType), FitsError> {
    let hdu = fits.hdu(index).map_err(cfitsio(path))?;
    match &hdu.info {
        HduInfo::ImageInfo { shape, image_type } => match shape[..] {
            [rows, cols] if rows > 0 && cols > 0 => {
                let t = *image_type;
                Ok((hdu, (rows, cols), t))
            }
            _ => Err(FitsError::NotImage {
                path: path.to_path_buf(),
                shape: shape.clone(),
            }),
        },
        _ => Err(FitsError::NotImage {
            path: path.to_path_buf(),
            shape: Vec::new(),
        }),
    }
}

fn type_name(t: ImageType) -> &'static str {
    match t {
        ImageType::UnsignedByte => "BITPIX 8 (unsigned bytes)",
        ImageType::Byte => "BITPIX 8 with BZERO -128 (signed bytes)",
        ImageType::Short => "BITPIX 16 signed (no BZERO 32768)",
        ImageType::UnsignedShort => "BITPIX 16 with BZERO 32768 (unsigned 16-bit)",
        ImageType::Long => "BITPIX 32",
        ImageType::UnsignedLong => "BITPIX 32 with BZERO 2^31",
        ImageType::LongLong => "BITPIX 64",
        ImageType::Float => "BITPIX -32 (float)",
        ImageType::Double => "BITPIX -64 (double)",
    }
}

/// Reads a raw frame of `geometry` (see the module docs) from `path`.
pub fn read_raw_frame(path: &Path, geometry: &ReadoutGeometry) -> Result<RawFrame, FitsError> {
    read_raw_frame_at(path, geometry, 0)
}

/// Reads a raw frame of `geometry` from HDU `index` of `path` (0: the primary; a
/// tile-compressed `.fits.fz` holds its image in HDU 1, which CFITSIO decompresses).
pub fn read_raw_frame_at(
    path: &Path,
    geometry: &ReadoutGeometry,
    index: usize,
) -> Result<RawFrame, FitsError> {
    let mut fits = open(path)?;
    let (hdu, (rows, cols), t) = image_info_at(&mut fits, path, index)?;
    if t != ImageType::UnsignedShort {
        return Err(FitsError::WrongType {
            path: path.to_path_buf(),
            found: type_name(t).to_string(),
            expected: type_name(ImageType::UnsignedShort),
        });
    }
    let expected = (usize::from(geometry.lines), geometry.line_len());
    if (rows, cols) != expected {
        return Err(FitsError::WrongShape {
            path: path.to_path_buf(),
            found: (rows, cols),
            expected,
        });
    }
    let data_adu: Vec<u16> = hdu.read_image(&mut fits).map_err(cfitsio(path))?;
    if data_adu.len() != rows * cols {
        return Err(FitsError::Cfitsio {
            path: path.to_path_buf(),
            msg: format!("read {} samples, expected {}", data_adu.len(), rows * cols),
        });
    }
    Ok(RawFrame {
        lines: rows,
        cols,
        data_adu,
    })
}

/// Creates (or replaces) `path` with an empty image of `data_type` and shape (rows, cols).
fn create(
    path: &Path,
    data_type: ImageType,
    rows: usize,
    cols: usize,
) -> Result<(FitsFile, fitsio::hdu::FitsHdu), FitsError> {
    let dims = [rows, cols];
    let desc = ImageDescription {
        data_type,
        dimensions: &dims,
    };
    let mut fits = FitsFile::create(path)
        .with_custom_primary(&desc)
        .overwrite()
        .open()
        .map_err(|e| FitsError::Io {
            path: path.to_path_buf(),
            msg: e.to_string(),
        })?;
    let hdu = fits.primary_hdu().map_err(cfitsio(path))?;
    Ok((fits, hdu))
}

/// Writes `frame` to `path` as BITPIX 16 with BZERO 32768, with numeric keywords `keys`
/// (e.g. `EXPTIME`, `CCDTEMP`).
pub fn write_raw_frame(
    path: &Path,
    frame: &RawFrame,
    keys: &[(&str, f64)],
) -> Result<(), FitsError> {
    if frame.data_adu.len() != frame.lines * frame.cols {
        return Err(FitsError::WrongShape {
            path: path.to_path_buf(),
            found: (frame.data_adu.len() / frame.cols.max(1), frame.cols),
            expected: (frame.lines, frame.cols),
        });
    }
    let (mut fits, hdu) = create(path, ImageType::UnsignedShort, frame.lines, frame.cols)?;
    hdu.write_image(&mut fits, &frame.data_adu)
        .map_err(cfitsio(path))?;
    for (k, v) in keys {
        hdu.write_key(&mut fits, k, *v).map_err(cfitsio(path))?;
    }
    Ok(())
}

/// Reads a map (any numeric BITPIX, converted to `f32`) and those of the keywords `keys` that
/// the header holds. NaN or infinite values are an error.
pub fn read_map(path: &Path, keys: &[&str]) -> Result<MapF32, FitsError> {
    let mut fits = open(path)?;
    let (hdu, (rows, cols), _) = image_info(&mut fits, path)?;
    let data: Vec<f32> = hdu.read_image(&mut fits).map_err(cfitsio(path))?;
    if data.len() != rows * cols {
        return Err(FitsError::Cfitsio {
            path: path.to_path_buf(),
            msg: format!("read {} values, expected {}", data.len(), rows * cols),
        });
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(FitsError::NotFinite {
            path: path.to_path_buf(),
            row: i / cols,
            col: i % cols,
        });
    }
    let found = keys_in(&mut fits, &hdu, path, keys)?;
    Ok(MapF32 {
        rows,
        cols,
        data,
        keys: found,
    })
}

/// The full scale of the primary image in physical values, `BZERO + BSCALE * largest stored
/// value` (255 for BITPIX 8, 65535 for BITPIX 16 with BZERO 32768), or `None` for a
/// floating-point image, which has none.
pub fn full_scale(path: &Path) -> Result<Option<f64>, FitsError> {
    let mut fits = open(path)?;
    let (hdu, _, _) = image_info(&mut fits, path)?;
    let bitpix: i64 = hdu.read_key(&mut fits, "BITPIX").map_err(cfitsio(path))?;
    let stored_max = match bitpix {
        8 => 255.0,
        16 => 32767.0,
        32 => 2147483647.0,
        64 => 9.223372036854776e18,
        _ => return Ok(None),
    };
    let bscale = hdu.read_key::<f64>(&mut fits, "BSCALE").unwrap_or(1.0);
    let bzero = hdu.read_key::<f64>(&mut fits, "BZERO").unwrap_or(0.0);
    Ok(Some(bzero + bscale * stored_max))
}

/// Reads a map and checks that it is `rows` x `cols`.
pub fn read_map_shaped(
    path: &Path,
    rows: usize,
    cols: usize,
    keys: &[&str],
) -> Result<MapF32, FitsError> {
    let m = read_map(path, keys)?;
    if (m.rows, m.cols) != (rows, cols) {
        return Err(FitsError::WrongShape {
            path: path.to_path_buf(),
            found: (m.rows, m.cols),
            expected: (rows, cols),
        });
    }
    Ok(m)
}

/// Writes `map` as BITPIX -32 with its keywords.
pub fn write_map(path: &Path, map: &MapF32) -> Result<(), FitsError> {
    if map.data.len() != map.rows * map.cols {
        return Err(FitsError::WrongShape {
            path: path.to_path_buf(),
            found: (map.data.len() / map.cols.max(1), map.cols),
            expected: (map.rows, map.cols),
        });
    }
    let (mut fits, hdu) = create(path, ImageType::Float, map.rows, map.cols)?;
    hdu.write_image(&mut fits, &map.data)
        .map_err(cfitsio(path))?;
    for (k, v) in &map.keys {
        hdu.write_key(&mut fits, k, *v).map_err(cfitsio(path))?;
    }
    Ok(())
}

/// Reads those of the numeric keywords `keys` that the primary header of `path` holds.
pub fn read_keys(path: &Path, keys: &[&str]) -> Result<Vec<(String, f64)>, FitsError> {
    let mut fits = open(path)?;
    let hdu = fits.primary_hdu().map_err(cfitsio(path))?;
    keys_in(&mut fits, &hdu, path, keys)
}

fn keys_in(
    fits: &mut FitsFile,
    hdu: &fitsio::hdu::FitsHdu,
    path: &Path,
    keys: &[&str],
) -> Result<Vec<(String, f64)>, FitsError> {
    let mut found = Vec::new();
    for k in keys {
        // A missing keyword is absent, not an error; one that is there must be a number.
        let present: Result<String, _> = hdu.read_key(fits, k);
        if present.is_err() {
            continue;
        }
        let v: f64 = hdu.read_key(fits, k).map_err(|e| FitsError::Keyword {
            path: path.to_path_buf(),
            key: (*k).to_string(),
            msg: e.to_string(),
        })?;
        found.push(((*k).to_string(), v));
    }
    Ok(found)
}
