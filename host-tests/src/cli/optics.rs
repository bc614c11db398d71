//! `startrack optics case|fit`: the camera model measured from identified stars over many
//! frames ([`startrack_lab::optics`]), written as JSON for `startrack calib build --camera-model`.
//!
//! `optics case --out DIR` writes simulated frames through distorted optics with lateral
//! colour (seeded): `DIR/fields/*.csv` (`x_px,y_px,flux_e`, brightest first), `case.json`
//! (the nominal camera the fit starts from and the centroid sigma, as `catalog case`
//! writes), `truth.csv` (`field,qw,qx,qy,qz`) and `camera_truth.json` (the true model).
//!
//! `optics fit --case DIR --out FILE` identifies the stars of every field, fits focal
//! length, principal point, k1, k2, p1, p2, the colour scale and each frame's attitude, and
//! writes the model with each parameter's formal 1-sigma (`FILE`, JSON). When the case holds
//! `camera_truth.json` and `truth.csv`, the report also gives each parameter's error against
//! the truth, the model's image error and the colour residual after correction.
//!
//! `optics fit --images IMAGE... --fov-deg F --out FILE` does it from real night-sky images
//! ([`startrack_lab::optics::sky`]): each image's stars found and identified as `solve-image` does
//! them (its camera options: `--fov-deg`, `--focal-length-px`, `--principal-point`,
//! `--camera`), then the model fitted over all images; the report gives each parameter with
//! its 1-sigma and the residual RMS through the pinhole `solve-image` had and through the
//! model, and with `--holdout` the model fitted on every other image and tested on the rest
//! (and the reverse). `--hold` keeps parameters at their start values; `--csv` writes the
//! figures. The file is the same JSON, for `calib build --camera-model` and `solve-image
//! --camera`.

pub mod images;

use super::solve_image::ImageCameraArgs;
use super::{CliError, LabError, read_file, write_file};
use serde::Deserialize;
use startrack_core::attitude::{Camera, Quat};
use startrack_core::catalog::Catalog;
use startrack_lab::optics::{self, CameraModelJson, FitOptions, PARAM_NAMES, read_camera_model};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Options of `startrack optics case`.
#[derive(Clone, Debug, clap::Args)]
pub struct OpticsCaseArgs {
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
    /// Frames.
    #[arg(long, default_value_t = 120)]
    pub frames: usize,
    /// Seed of the attitudes, noise, dropouts and false stars.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Centroid 1-sigma per axis, px.
    #[arg(long, default_value_t = 0.1)]
    pub sigma_px: f64,
}

/// Options of `startrack optics fit`.
#[derive(Clone, Debug, clap::Args)]
pub struct OpticsFitArgs {
    /// Case folder: `case.json` and `fields/*.csv` (and optionally the truth).
    #[arg(long, required_unless_present = "images", conflicts_with = "images")]
    pub case: Option<PathBuf>,
    /// Real night-sky images instead of a case (FITS, TIFF, PNG, JPEG), solved as
    /// `solve-image` solves them.
    #[arg(long, num_args = 1..)]
    pub images: Vec<PathBuf>,
    /// The images' camera and centroids (as `solve-image`'s).
    #[command(flatten)]
    pub sky: ImageCameraArgs,
    /// Output camera model (JSON).
    #[arg(long)]
    pub out: PathBuf,
    /// Catalog file from `startrack catalog build` (default: for a case, built from the
    /// repo's list for a 15 degree field; for images, as `solve-image` builds it).
    #[arg(long)]
    pub catalog: Option<PathBuf>,
    /// Star list of the images' default catalog (as `solve-image --list`).
    #[arg(long)]
    pub list: Option<PathBuf>,
    /// Hold the lateral colour scale at its start value (0: to see what the colour term
    /// removes).
    #[arg(long)]
    pub no_colour: bool,
    /// Parameters held at their start values (comma-separated).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub hold: Vec<Param>,
    /// Images only: also fit on every other image and test on the rest, and the reverse.
    #[arg(long)]
    pub holdout: bool,
    /// Images only: write the report's figures as CSV (`quantity,value,sigma`).
    #[arg(long)]
    pub csv: Option<PathBuf>,
}

impl OpticsFitArgs {
    /// Fits a simulated case, every parameter free.
    pub fn case(case: PathBuf, out: PathBuf) -> Self {
        Self {
            case: Some(case),
            images: Vec::new(),
            sky: ImageCameraArgs::default(),
            out,
            catalog: None,
            list: None,
            no_colour: false,
            hold: Vec::new(),
            holdout: false,
            csv: None,
        }
    }

    /// Fits images of a horizontal field of view `fov_deg`, every parameter free.
    pub fn images(images: Vec<PathBuf>, fov_deg: f64, out: PathBuf) -> Self {
        Self {
            case: None,
            images,
            sky: ImageCameraArgs::fov(fov_deg),
            ..Self::case(PathBuf::new(), out)
        }
    }

    fn options(&self) -> FitOptions {
        let held = |p: Param| self.hold.contains(&p);
        FitOptions {
            focal_length: !held(Param::FocalLength),
            principal_point: !held(Param::PrincipalPoint),
            k1: !held(Param::K1),
            k2: !held(Param::K2),
            tangential: !held(Param::Tangential),
            colour: !(self.no_colour || held(Param::Colour)),
            ..FitOptions::default()
        }
    }
}

/// A camera parameter (group) of `optics fit --hold`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Param {
    /// The focal length.
    FocalLength,
    /// The principal point (both coordinates).
    PrincipalPoint,
    /// The `r^2` radial term.
    K1,
    /// The `r^4` radial term.
    K2,
    /// The tangential terms `p1`, `p2`.
    Tangential,
    /// The lateral colour scale.
    Colour,
}

fn catalog_bytes(path: Option<&Path>) -> Result<Vec<u8>, CliError> {
    match path {
        Some(p) => read_file(p),
        None => Ok(startrack_sim::sky::build::default_catalog()
            .map_err(|e| CliError::Usage(e.to_string()))?
            .bytes),
    }
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> CliError + '_ {
    move |e| {
        LabError::Io {
            path: path.to_path_buf(),
            msg: e.to_string(),
        }
        .into()
    }
}

/// Writes a simulated case.
pub fn run_case(args: &OpticsCaseArgs) -> Result<(), CliError> {
    if !(args.sigma_px >= 0.0 && args.sigma_px.is_finite()) || args.frames == 0 {
        return Err(CliError::Usage(
            "--sigma-px must be >= 0 and --frames > 0".into(),
        ));
    }
    let bytes = catalog_bytes(None)?;
    let cat = Catalog::parse(&bytes).map_err(|e| CliError::Usage(format!("catalog: {e}")))?;
    let truth = optics::simulated_truth();
    let (qs, fields) = optics::simulate(&cat, &truth, args.frames, args.seed, args.sigma_px);
    let fields_dir = args.out.join("fields");
    std::fs::create_dir_all(&fields_dir).map_err(io(&fields_dir))?;
    let nominal = optics::nominal();
    let json = format!(
        "{{\"focal_length_px\": {}, \"principal_point_px\": [{}, {}], \"k1\": {}, \"centroid_sigma_px\": {}}}\n",
        nominal.focal_length_px,
        nominal.principal_point_px[0],
        nominal.principal_point_px[1],
        nominal.k1,
        args.sigma_px
    );
    write_file(&args.out.join("case.json"), json.as_bytes())?;
    let mut truth_csv = String::from("field,qw,qx,qy,qz\n");
    for (i, (q, stars)) in qs.iter().zip(&fields).enumerate() {
        let mut csv = String::from("x_px,y_px,flux_e\n");
        for s in stars {
            let _ = writeln!(csv, "{:.5},{:.5},{:.1}", s.x_px, s.y_px, s.flux_e);
        }
        let name = format!("{i:06}");
        write_file(&fields_dir.join(format!("{name}.csv")), csv.as_bytes())?;
        let [w, x, y, z] = q.0;
        let _ = writeln!(truth_csv, "{name},{w:.15},{x:.15},{y:.15},{z:.15}");
    }
    write_file(&args.out.join("truth.csv"), truth_csv.as_bytes())?;
    let t = serde_json::to_string_pretty(&CameraModelJson::of(&truth))
        .map_err(|e| CliError::Usage(e.to_string()))?;
    write_file(&args.out.join("camera_truth.json"), t.as_bytes())
}

/// `case.json` (the fields `optics fit` reads).
#[derive(Clone, Debug, Deserialize)]
struct CaseJson {
    focal_length_px: f64,
    principal_point_px: [f64; 2],
    #[serde(default)]
    k1: f64,
    #[serde(default = "default_sigma")]
    centroid_sigma_px: f64,
}

fn default_sigma() -> f64 {
    0.3
}

/// One field's pixel positions, brightest first (`x_px,y_px,flux_e`).
fn read_field(path: &Path) -> Result<Vec<[f64; 2]>, CliError> {
    let text = String::from_utf8(read_file(path)?).map_err(|e| LabError::Csv {
        path: path.to_path_buf(),
        line: 0,
        msg: e.to_string(),
    })?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("x_px") {
            continue;
        }
        let v: Vec<f64> = line
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| LabError::Csv {
                path: path.to_path_buf(),
                line: n + 1,
                msg: e.to_string(),
            })?;
        match v.as_slice() {
            [x, y, ..] if x.is_finite() && y.is_finite() => out.push([*x, *y]),
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

/// `field,qw,qx,qy,qz` rows in field order.
fn read_truth(path: &Path) -> Result<Vec<Quat>, CliError> {
    let text = String::from_utf8(read_file(path)?).map_err(|e| LabError::Csv {
        path: path.to_path_buf(),
        line: 0,
        msg: e.to_string(),
    })?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let v: Vec<f64> = line
            .split(',')
            .skip(1)
            .map(|s| s.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| LabError::Csv {
                path: path.to_path_buf(),
                line: n + 1,
                msg: e.to_string(),
            })?;
        let [w, x, y, z] = v[..] else {
            return Err(LabError::Csv {
                path: path.to_path_buf(),
                line: n + 1,
                msg: "expected field,qw,qx,qy,qz".into(),
            }
            .into());
        };
        out.push(Quat([w, x, y, z]));
    }
    Ok(out)
}

/// What `optics fit` found.
#[derive(Clone, Debug, PartialEq)]
pub struct FitReport {
    /// The fitted model and its formal sigmas.
    pub model: CameraModelJson,
    /// The report's lines.
    pub text: String,
    /// From images: the fit, and the holdout checks when asked for.
    pub sky: Option<images::SkyReport>,
}

/// Fits the camera model to a case or to images and writes it.
pub fn run_fit(args: &OpticsFitArgs) -> Result<FitReport, CliError> {
    match &args.case {
        Some(case) => run_fit_case(args, case),
        None => images::run(args),
    }
}

fn run_fit_case(args: &OpticsFitArgs, case_dir: &Path) -> Result<FitReport, CliError> {
    let json_path = case_dir.join("case.json");
    let case: CaseJson = serde_json::from_slice(&read_file(&json_path)?)
        .map_err(|e| CliError::Usage(format!("{}: {e}", json_path.display())))?;
    if !(case.focal_length_px > 0.0 && case.centroid_sigma_px > 0.0) {
        return Err(CliError::Usage(format!(
            "{}: focal_length_px and centroid_sigma_px must be positive",
            json_path.display()
        )));
    }
    let start = Camera {
        k1: case.k1,
        ..Camera::pinhole(case.focal_length_px, case.principal_point_px)
    };
    let bytes = catalog_bytes(args.catalog.as_deref())?;
    let cat = Catalog::parse(&bytes).map_err(|e| CliError::Usage(format!("catalog: {e}")))?;
    let fields_dir = case_dir.join("fields");
    let mut names: Vec<PathBuf> = std::fs::read_dir(&fields_dir)
        .map_err(io(&fields_dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    names.sort();
    let fields = names
        .iter()
        .map(|p| read_field(p))
        .collect::<Result<Vec<_>, _>>()?;
    let opts = args.options();
    let (frames, fit) =
        optics::identify_and_fit(&cat, &fields, &start, case.centroid_sigma_px, opts)
            .map_err(|e| CliError::Usage(e.to_string()))?;
    let model = CameraModelJson::of_fit(&fit, frames.len());
    let out = serde_json::to_string_pretty(&model).map_err(|e| CliError::Usage(e.to_string()))?;
    write_file(&args.out, out.as_bytes())?;

    let mut text = format!(
        "{} of {} fields identified, {} stars, {} iterations: residual RMS {:.4} px per axis (centroid sigma {} px)\n",
        frames.len(),
        fields.len(),
        fit.stars,
        fit.iterations,
        fit.residual_rms_px,
        case.centroid_sigma_px
    );
    let got = optics::params_of(&fit.camera);
    let truth_path = case_dir.join("camera_truth.json");
    let truth = if truth_path.exists() {
        Some(read_camera_model(&truth_path)?)
    } else {
        None
    };
    for (k, name) in PARAM_NAMES.iter().enumerate() {
        let _ = write!(text, "{name:>22} {:>15.8e} +- {:.2e}", got[k], fit.sigma[k]);
        if let Some(t) = &truth {
            let tv = optics::params_of(t)[k];
            if fit.sigma[k] > 0.0 {
                let _ = write!(
                    text,
                    "   truth {tv:>15.8e}, error {:+.2} sigma",
                    (got[k] - tv) / fit.sigma[k]
                );
            } else {
                let _ = write!(text, "   truth {tv:>15.8e}, held");
            }
        }
        text.push('\n');
    }
    if let Some(t) = &truth {
        let m = optics::model_error(&fit.camera, t, 1024, 1024);
        let _ = writeln!(
            text,
            "model image error against the truth (best rotation removed): RMS {:.4} px, max {:.4} px",
            m.rms_px, m.max_px
        );
        let truth_q = read_truth(&case_dir.join("truth.csv"))?;
        let c = optics::colour_error(&frames, &truth_q, &fit.camera, t);
        let _ = writeln!(
            text,
            "lateral colour of the identified stars: {:.4} px RMS ({:.4} max) uncorrected, {:.4} px RMS ({:.4} max) after correction",
            c.uncorrected_rms_px, c.uncorrected_max_px, c.residual_rms_px, c.residual_max_px
        );
    }
    Ok(FitReport {
        model,
        text,
        sky: None,
    })
}
