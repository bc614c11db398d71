//! `startrack solve --case DIR --out FILE`: lost-in-space identification (or, with
//! `--prior`, tracking identification from a prior attitude) and attitude of every field of
//! a case (see [`super::catalog`] for the folder layout), with the core's
//! `ident` and `attitude` exactly as the firmware runs them.
//!
//! `FILE` gets one row per field: `field,solved,qw,qx,qy,qz,time_us`, then the attitude
//! covariance in the camera frame (`cov_xx_rad2,cov_xy_rad2,cov_xz_rad2,cov_yy_rad2,
//! cov_yz_rad2,cov_zz_rad2`; x, y across the boresight, z roll), the stars matched and the
//! false-match probability bound, then the focal-length scale fitted with the attitude and
//! its 1-sigma (`focal_scale`, `focal_scale_sigma`: the true focal length over
//! `case.json`'s). `time_us` is the wall time of identification and
//! attitude (directions from pixels included, file reading not).

use super::{CliError, LabError, read_file, write_file};
use serde::Deserialize;
use startrack_core::attitude::{Camera, Quat};
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig, Measured};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of `startrack solve`.
#[derive(Clone, Debug, clap::Args)]
pub struct SolveArgs {
    /// Case folder: `case.json` and `fields/*.csv`.
    #[arg(long)]
    pub case: PathBuf,
    /// Output CSV.
    #[arg(long)]
    pub out: PathBuf,
    /// Catalog file from `startrack catalog build` (default: built from the repo's list for
    /// a 15 degree field).
    #[arg(long)]
    pub catalog: Option<PathBuf>,
    /// Track instead of lost in space: the prior attitude of each field, a CSV
    /// `field,qw,qx,qy,qz` (as `catalog case --prior-error-deg` writes).
    #[arg(long)]
    pub prior: Option<PathBuf>,
    /// How far off the priors may be, deg (any axis).
    #[arg(long, default_value_t = 2.0)]
    pub prior_error_deg: f64,
}

/// `case.json`.
#[derive(Clone, Debug, Deserialize)]
pub struct CaseJson {
    /// Focal length, px.
    pub focal_length_px: f64,
    /// Principal point (column, row), px.
    pub principal_point_px: [f64; 2],
    /// Radial distortion, normalised units.
    #[serde(default)]
    pub k1: f64,
    /// Centroid 1-sigma, px (default 0.3).
    #[serde(default = "default_sigma")]
    pub centroid_sigma_px: f64,
}

fn default_sigma() -> f64 {
    0.3
}

/// What a run did.
#[derive(Clone, Debug, PartialEq)]
pub struct SolveSummary {
    /// Fields read.
    pub fields: usize,
    /// Fields solved.
    pub solved: usize,
    /// Median time per field, us.
    pub median_us: f64,
    /// 99th-percentile time per field, us.
    pub p99_us: f64,
}

fn read_field(path: &Path) -> Result<Vec<[f64; 3]>, CliError> {
    let text = String::from_utf8(read_file(path)?).map_err(|_| LabError::Csv {
        path: path.to_path_buf(),
        line: 0,
        msg: "not UTF-8".into(),
    })?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with("x_px") || line.starts_with('#') {
            continue;
        }
        let v: Result<Vec<f64>, _> = line.split(',').map(|f| f.trim().parse::<f64>()).collect();
        match v {
            Ok(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => {
                out.push([v[0], v[1], v[2]])
            }
            _ => {
                return Err(LabError::Csv {
                    path: path.to_path_buf(),
                    line: n + 1,
                    msg: "expected x_px,y_px,flux_e".into(),
                }
                .into());
            }
        }
    }
    Ok(out)
}

/// The priors file: field name to attitude.
fn read_priors(path: &Path) -> Result<std::collections::HashMap<String, Quat>, CliError> {
    let text = String::from_utf8(read_file(path)?).unwrap_or_default();
    let mut out = std::collections::HashMap::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let q: Option<Vec<f64>> = f
            .get(1..5)
            .map(|v| v.iter().filter_map(|x| x.trim().parse().ok()).collect());
        match (f.first(), q) {
            (Some(name), Some(q)) if q.len() == 4 => {
                out.insert((*name).to_string(), Quat([q[0], q[1], q[2], q[3]]));
            }
            _ => {
                return Err(LabError::Csv {
                    path: path.to_path_buf(),
                    line: n + 1,
                    msg: "expected field,qw,qx,qy,qz".into(),
                }
                .into());
            }
        }
    }
    Ok(out)
}

/// Solves every field of the case and writes the CSV.
pub fn run(args: &SolveArgs) -> Result<SolveSummary, CliError> {
    let json_path = args.case.join("case.json");
    let case: CaseJson =
        serde_json::from_slice(&read_file(&json_path)?).map_err(|e| LabError::Csv {
            path: json_path.clone(),
            line: e.line(),
            msg: e.to_string(),
        })?;
    if !(case.focal_length_px > 0.0 && case.centroid_sigma_px > 0.0) {
        return Err(CliError::Usage(format!(
            "{}: focal_length_px and centroid_sigma_px must be positive",
            json_path.display()
        )));
    }
    let bytes = match &args.catalog {
        Some(p) => read_file(p)?,
        None => {
            startrack_sim::sky::build::default_catalog()
                .map_err(|e| CliError::Usage(e.to_string()))?
                .bytes
        }
    };
    let cat = Catalog::parse(&bytes).map_err(|e| CliError::Usage(format!("catalog: {e}")))?;
    let camera = Camera {
        k1: case.k1,
        ..Camera::pinhole(case.focal_length_px, case.principal_point_px)
    };
    let cfg = IdentConfig::for_camera(case.focal_length_px, case.centroid_sigma_px);
    let priors = args.prior.as_deref().map(read_priors).transpose()?;
    let fields_dir = args.case.join("fields");
    let mut names: Vec<PathBuf> = std::fs::read_dir(&fields_dir)
        .map_err(|e| LabError::Io {
            path: fields_dir.clone(),
            msg: e.to_string(),
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    names.sort();
    let mut csv = String::from(
        "field,solved,qw,qx,qy,qz,time_us,cov_xx_rad2,cov_xy_rad2,cov_xz_rad2,cov_yy_rad2,cov_yz_rad2,cov_zz_rad2,matched,false_probability,focal_scale,focal_scale_sigma\n",
    );
    let mut times = Vec::with_capacity(names.len());
    let mut solved = 0;
    for path in &names {
        let stars = read_field(path)?;
        let name = path
            .file_stem()
            .map_or(String::new(), |s| s.to_string_lossy().into_owned());
        let t0 = Instant::now();
        let meas: Vec<Measured> = stars
            .iter()
            .take(ident::MAX_STARS)
            .map(|s| {
                let dir = camera.direction(s[0], s[1]);
                Measured {
                    dir,
                    sigma_rad: case.centroid_sigma_px / case.focal_length_px * dir[2].powf(1.5),
                }
            })
            .collect();
        let result = match &priors {
            None => ident::lost_in_space(&cat, &meas, &cfg),
            Some(p) => match p.get(&name) {
                Some(q) => ident::track(&cat, &meas, *q, args.prior_error_deg.to_radians(), &cfg),
                None => Err(ident::IdentError::BadInput),
            },
        };
        let us = t0.elapsed().as_secs_f64() * 1e6;
        times.push(us);
        match result {
            Ok(sol) => {
                solved += 1;
                let [w, x, y, z] = sol.attitude.q.0;
                let c = sol.attitude.cov_rad2;
                let _ = writeln!(
                    csv,
                    "{name},1,{w:.12},{x:.12},{y:.12},{z:.12},{us:.1},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{},{:.1e},{:.7},{:.1e}",
                    c[0][0],
                    c[0][1],
                    c[0][2],
                    c[1][1],
                    c[1][2],
                    c[2][2],
                    sol.matches.len(),
                    sol.false_probability,
                    sol.scale.value,
                    sol.scale.sigma
                );
            }
            Err(_) => {
                let _ = writeln!(csv, "{name},0,,,,,{us:.1},,,,,,,0,,,");
            }
        }
    }
    write_file(&args.out, csv.as_bytes())?;
    times.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        times
            .get(((times.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    Ok(SolveSummary {
        fields: names.len(),
        solved,
        median_us: pct(0.5),
        p99_us: pct(0.99),
    })
}
