//! The field PSF model (table section 9, [`startrack_core::table::PsfModel`]) fitted to the
//! stars of processed frames: each star's position and measured width `psf_a_px` (the
//! `stars.csv` of `startrack process`), a 2-D polynomial of total degree 0..=3 in the core's
//! normalised coordinates, by least squares (nalgebra's SVD: the design matrix of a low
//! degree on clustered stars can be close to singular, and the SVD solves it stably).
//!
//! Robustness: a blend or a cosmic ray gives a width far from the field's, so the fit is
//! repeated with the stars beyond [`CLIP_SIGMA`] times the scatter left out, until none
//! changes (at most [`CLIP_ROUNDS`] rounds). The model's scatter (the RMS of the kept stars'
//! residuals) goes into the section, so flight code can flag a star whose width departs from
//! the model by more than a few of it.
//!
//! Cost: one SVD of a `stars x terms` matrix per round (10 terms at degree 3).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use startrack_core::table::PsfModel;
use startrack_core::table::{MAX_PSF_DEGREE, MAX_PSF_TERMS, psf_terms};

/// Stars further than this many scatters from the model are left out of the next round.
pub const CLIP_SIGMA: f64 = 3.0;
/// Most fitting rounds.
pub const CLIP_ROUNDS: usize = 10;

/// One star: active-area position and measured width, px.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StarWidth {
    /// Active column.
    pub x_px: f64,
    /// Active row.
    pub y_px: f64,
    /// Measured 80 %-energy radius, px.
    pub a_px: f64,
}

/// A fitted model, as `calib psf-model` writes it and `calib build --psf-model` reads it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PsfModelFit {
    /// Total degree.
    pub degree: u8,
    /// Coefficients in the core's term order (`1, u, v, u^2, u v, v^2, ...`), px.
    pub coeffs_px: Vec<f64>,
    /// RMS residual of the kept stars, px.
    pub scatter_px: f64,
    /// Stars kept.
    pub stars: usize,
    /// Stars left out as outliers.
    pub rejected: usize,
    /// Active columns of the sensor the coordinates are normalised by.
    pub active_cols: u16,
    /// Active rows.
    pub active_rows: u16,
}

/// Why no model could be fitted.
#[derive(Clone, Debug, PartialEq)]
pub enum PsfFitError {
    /// Degree above 3.
    Degree(u8),
    /// Fewer usable stars (finite, positive width, inside the area) than twice the terms.
    TooFewStars {
        /// Usable stars.
        usable: usize,
        /// Stars needed.
        needed: usize,
    },
    /// The model's width is not in (0, 256) px somewhere in the field, or a coefficient
    /// does not fit the table's I16F16.
    OutOfRange,
}

impl std::fmt::Display for PsfFitError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Degree(d) => write!(f, "PSF model degree {d}: at most {MAX_PSF_DEGREE}"),
            Self::TooFewStars { usable, needed } => write!(
                f,
                "PSF model: {usable} usable stars, need at least {needed} for this degree"
            ),
            Self::OutOfRange => f.write_str(
                "PSF model: the fitted width leaves (0, 256) px inside the field; use a lower degree",
            ),
        }
    }
}

impl std::error::Error for PsfFitError {}

/// The core's normalised coordinate of pixel `p` on an axis of `n` pixels.
pub fn norm(p: f64, n: u16) -> f64 {
    (2.0 * p + 1.0) / f64::from(n.max(1)) - 1.0
}

/// The terms `u^i v^j` of degree `degree` at (`u`, `v`), in the core's order.
pub fn terms(degree: u8, u: f64, v: f64) -> Vec<f64> {
    let mut t = Vec::with_capacity(psf_terms(degree));
    for total in 0..=i32::from(degree) {
        for j in 0..=total {
            t.push(u.powi(total - j) * v.powi(j));
        }
    }
    t
}

impl PsfModelFit {
    /// The model's width at active pixel (`x_px`, `y_px`), px.
    pub fn a_px(&self, x_px: f64, y_px: f64) -> f64 {
        let u = norm(x_px, self.active_cols);
        let v = norm(y_px, self.active_rows);
        terms(self.degree, u, v)
            .iter()
            .zip(&self.coeffs_px)
            .map(|(t, c)| t * c)
            .sum()
    }

    /// The table's section 9 value (coefficients rounded to I16F16, scatter to U8F8). The
    /// core checks it again when the table is written.
    pub fn to_table(&self) -> Result<PsfModel, PsfFitError> {
        use fixed::types::{I16F16, U8F8};
        let mut coeffs = [I16F16::ZERO; MAX_PSF_TERMS];
        for (c, v) in coeffs.iter_mut().zip(&self.coeffs_px) {
            *c = I16F16::checked_from_num(*v).ok_or(PsfFitError::OutOfRange)?;
        }
        Ok(PsfModel {
            degree: self.degree,
            scatter_px: U8F8::saturating_from_num(self.scatter_px),
            stars: u16::try_from(self.stars).unwrap_or(u16::MAX),
            coeffs,
        })
    }
}

/// Fits a model of `degree` to `stars` on an active area of `cols` x `rows`.
pub fn fit(
    stars: &[StarWidth],
    degree: u8,
    cols: u16,
    rows: u16,
) -> Result<PsfModelFit, PsfFitError> {
    if degree > MAX_PSF_DEGREE {
        return Err(PsfFitError::Degree(degree));
    }
    let n_terms = psf_terms(degree);
    let usable: Vec<StarWidth> = stars
        .iter()
        .copied()
        .filter(|s| {
            s.a_px.is_finite()
                && s.a_px > 0.0
                && (0.0..f64::from(cols)).contains(&s.x_px)
                && (0.0..f64::from(rows)).contains(&s.y_px)
        })
        .collect();
    let needed = 2 * n_terms;
    if usable.len() < needed {
        return Err(PsfFitError::TooFewStars {
            usable: usable.len(),
            needed,
        });
    }
    let rows_of = |s: &StarWidth| terms(degree, norm(s.x_px, cols), norm(s.y_px, rows));
    let mut keep = vec![true; usable.len()];
    let mut coeffs = vec![0.0; n_terms];
    let mut scatter = 0.0;
    for _ in 0..CLIP_ROUNDS {
        let kept: Vec<&StarWidth> = usable
            .iter()
            .zip(&keep)
            .filter_map(|(s, k)| k.then_some(s))
            .collect();
        if kept.len() < needed {
            return Err(PsfFitError::TooFewStars {
                usable: kept.len(),
                needed,
            });
        }
        let a = DMatrix::from_fn(kept.len(), n_terms, |i, j| {
            kept.get(i)
                .and_then(|s| rows_of(s).get(j).copied())
                .unwrap_or(0.0)
        });
        let b = DVector::from_iterator(kept.len(), kept.iter().map(|s| s.a_px));
        let sol = a
            .svd(true, true)
            .solve(&b, 1e-12)
            .map_err(|_| PsfFitError::OutOfRange)?;
        coeffs = sol.iter().copied().collect();
        let resid = |s: &StarWidth| {
            s.a_px
                - rows_of(s)
                    .iter()
                    .zip(&coeffs)
                    .map(|(t, c)| t * c)
                    .sum::<f64>()
        };
        let ss: f64 = kept.iter().map(|s| resid(s).powi(2)).sum();
        scatter = (ss / (kept.len() - n_terms).max(1) as f64).sqrt();
        let next: Vec<bool> = usable
            .iter()
            .map(|s| resid(s).abs() <= CLIP_SIGMA * scatter.max(1e-6))
            .collect();
        if next == keep {
            break;
        }
        keep = next;
    }
    let stars = keep.iter().filter(|k| **k).count();
    let m = PsfModelFit {
        degree,
        coeffs_px: coeffs,
        scatter_px: scatter,
        stars,
        rejected: usable.len() - stars,
        active_cols: cols,
        active_rows: rows,
    };
    // The same grid the core checks: the width must stay in (0, 256) px over the field.
    let grid = [-1.0, -0.5, 0.0, 0.5, 1.0];
    for u in grid {
        for v in grid {
            let a: f64 = terms(degree, u, v)
                .iter()
                .zip(&m.coeffs_px)
                .map(|(t, c)| t * c)
                .sum();
            if !(a > 0.0 && a < 256.0) {
                return Err(PsfFitError::OutOfRange);
            }
        }
    }
    Ok(m)
}

/// Reads the stars of a CSV with a header naming at least `x_px`, `y_px` and `psf_a_px` (any
/// other columns and any order; `process`'s `stars.csv`). Rows whose width is empty or not a
/// number are skipped (a star the fit did not measure); a malformed position is an error
/// naming the line.
pub fn read_stars_csv(text: &str) -> Result<Vec<StarWidth>, (usize, String)> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().ok_or((1, "empty file".to_string()))?;
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |n: &str| {
        names
            .iter()
            .position(|h| *h == n)
            .ok_or((1, format!("no `{n}` column in the header")))
    };
    let (ix, iy, ia) = (col("x_px")?, col("y_px")?, col("psf_a_px")?);
    let mut out = Vec::new();
    for (i, l) in lines {
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        let num = |k: usize, what: &str| {
            f.get(k)
                .and_then(|v| v.parse::<f64>().ok())
                .filter(|v| v.is_finite())
                .ok_or((i + 1, format!("{what} is not a number")))
        };
        let (x, y) = (num(ix, "x_px")?, num(iy, "y_px")?);
        if let Ok(a) = num(ia, "psf_a_px") {
            out.push(StarWidth {
                x_px: x,
                y_px: y,
                a_px: a,
            });
        }
    }
    Ok(out)
}
