//! `startrack catalog build`: the on-board star catalog (`startrack_core::catalog`) from the
//! derived Hipparcos list; `startrack catalog case`: a `startrack solve` case rendered from
//! it at random attitudes, with the true attitudes.
//!
//! A case folder holds `case.json` (`focal_length_px`, `principal_point_px` [x, y], `k1`,
//! `centroid_sigma_px`), `fields/NNNNNN.csv` (`x_px,y_px,flux_e`, brightest first) and
//! `truth.csv` (`field,qw,qx,qy,qz`: ICRS to camera, Hamilton, scalar first), and with
//! `--prior-error-deg` a `prior.csv` of the same form for tracking.

use super::{CliError, LabError, write_file};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use startrack_core::attitude::Quat;
use startrack_core::catalog::Catalog;
use startrack_sim::sky::build::{BuildSpec, Built, build};
use startrack_sim::sky::field::{self, FieldSpec};
use startrack_sim::sky::{default_list_path, read_list};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Options of `startrack catalog build`.
#[derive(Clone, Debug, clap::Args)]
pub struct CatalogBuildArgs {
    /// Output file (flash it into the catalog slot).
    #[arg(long)]
    pub out: PathBuf,
    /// Star list (default: the repo's `host-tests/data/hip_bright.csv`).
    #[arg(long)]
    pub list: Option<PathBuf>,
    /// Faintest star kept, Hp.
    #[arg(long, default_value_t = 6.5)]
    pub mag_limit: f64,
    /// Side of the square field of view, deg (sets the field cone: half the diagonal).
    #[arg(long, default_value_t = 15.0)]
    pub fov_deg: f64,
    /// Largest pair separation in the identification database, deg.
    #[arg(long, default_value_t = 12.0)]
    pub max_separation_deg: f64,
}

/// The spec for these options.
pub fn spec(args: &CatalogBuildArgs) -> Result<BuildSpec, CliError> {
    if !(0.5..=60.0).contains(&args.fov_deg) || !(0.5..=90.0).contains(&args.max_separation_deg) {
        return Err(CliError::Usage(
            "--fov-deg must be in 0.5..=60 and --max-separation-deg in 0.5..=90".into(),
        ));
    }
    let half = (args.fov_deg / 2.0).to_radians();
    Ok(BuildSpec {
        mag_limit: args.mag_limit,
        max_separation_rad: args.max_separation_deg.to_radians(),
        field_radius_rad: (half.tan() * 2f64.sqrt()).atan(),
        ..BuildSpec::fov_15deg()
    })
}

/// Builds and writes the catalog; returns what was built.
pub fn run_build(args: &CatalogBuildArgs) -> Result<Built, CliError> {
    let path = args.list.clone().unwrap_or_else(default_list_path);
    let list = read_list(&path).map_err(|e| LabError::Csv {
        path: e.path.clone(),
        line: e.line,
        msg: e.msg,
    })?;
    let built = build(&list, &spec(args)?).map_err(|e| CliError::Usage(e.to_string()))?;
    write_file(&args.out, &built.bytes)?;
    Ok(built)
}

/// Options of `startrack catalog case`.
#[derive(Clone, Debug, clap::Args)]
pub struct CatalogCaseArgs {
    /// Output folder (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Fields.
    #[arg(long, default_value_t = 100)]
    pub fields: usize,
    /// Seed of the attitudes and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Centroid 1-sigma, px.
    #[arg(long, default_value_t = 0.3)]
    pub sigma_px: f64,
    /// False stars per field.
    #[arg(long, default_value_t = 3)]
    pub false_stars: usize,
    /// Probability that a star is missing.
    #[arg(long, default_value_t = 0.1)]
    pub dropout: f64,
    /// Also write `prior.csv` (`field,qw,qx,qy,qz`): each true attitude turned by this
    /// many degrees about a random axis, the prior of `startrack solve --prior`.
    #[arg(long)]
    pub prior_error_deg: Option<f64>,
}

/// Writes a case rendered from the repo's catalog (15 degree field, CCD47-20).
pub fn run_case(args: &CatalogCaseArgs) -> Result<(), CliError> {
    let built =
        startrack_sim::sky::build::default_catalog().map_err(|e| CliError::Usage(e.to_string()))?;
    let cat = Catalog::parse(&built.bytes).map_err(|e| CliError::Usage(e.to_string()))?;
    let mut spec = FieldSpec::ccd47_15deg(args.sigma_px);
    spec.false_stars = args.false_stars;
    spec.dropout = args.dropout;
    let dir = &args.out;
    let fields_dir = dir.join("fields");
    std::fs::create_dir_all(&fields_dir).map_err(|e| LabError::Io {
        path: fields_dir.clone(),
        msg: e.to_string(),
    })?;
    let json = format!(
        "{{\"focal_length_px\": {}, \"principal_point_px\": [{}, {}], \"k1\": {}, \"centroid_sigma_px\": {}}}\n",
        spec.camera.focal_length_px,
        spec.camera.principal_point_px[0],
        spec.camera.principal_point_px[1],
        spec.camera.k1,
        args.sigma_px
    );
    write_file(&dir.join("case.json"), json.as_bytes())?;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let mut truth = String::from("field,qw,qx,qy,qz\n");
    let mut prior = truth.clone();
    // The priors draw from their own generator, so a case is the same with or without them.
    let mut prior_rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0x005e_ed0f_9e10);
    for i in 0..args.fields {
        let q = field::random_attitude(&mut rng);
        let stars = field::render(&cat, q, &spec, &mut rng);
        let mut csv = String::from("x_px,y_px,flux_e\n");
        for s in &stars {
            let _ = writeln!(csv, "{:.4},{:.4},{:.1}", s.x_px, s.y_px, s.flux_e);
        }
        let name = format!("{i:06}");
        write_file(&fields_dir.join(format!("{name}.csv")), csv.as_bytes())?;
        let [w, x, y, z] = q.0;
        let _ = writeln!(truth, "{name},{w:.12},{x:.12},{y:.12},{z:.12}");
        if let Some(deg) = args.prior_error_deg {
            let axis = field::random_attitude(&mut prior_rng).rotate([0.0, 0.0, 1.0]);
            let p = (Quat::from_axis_angle(axis, deg.to_radians()) * q)
                .normalized()
                .unwrap_or(q);
            let [w, x, y, z] = p.0;
            let _ = writeln!(prior, "{name},{w:.12},{x:.12},{y:.12},{z:.12}");
        }
    }
    if args.prior_error_deg.is_some() {
        write_file(&dir.join("prior.csv"), prior.as_bytes())?;
    }
    write_file(&dir.join("truth.csv"), truth.as_bytes())
}
