//! `startrack solve-image IMAGE... --fov-deg F [--fov-max-error E] [--focal-length-px P]
//! [--principal-point X,Y] [--camera FILE] [--catalog FILE] [--out DIR]`: real images to
//! attitudes ([`startrack_lab::realsky`]).
//!
//! The camera: a pinhole about the image centre with the focal length from `--fov-deg`
//! (the horizontal field), or the model of `--camera` (a calibration table with a camera
//! section, or the JSON `optics fit` writes: focal length, principal point, distortion), with
//! `--focal-length-px` and `--principal-point` replacing those parts of either. The focal
//! length is then searched within `--fov-max-error` of that and refit per image; the
//! principal point and the distortion are held.
//!
//! `DIR/solutions.csv` gets one row per image:
//! `image,solved,ra_deg,dec_deg,roll_deg,fov_deg,matched,rmse_arcsec,time_ms`, with RA and
//! Dec of the image centre (ICRS, the catalog's epoch), roll as tetra3 defines it
//! ([`startrack_lab::realsky::solve::roll_tetra3_deg`]), the fitted horizontal field of view, the
//! stars matched, the RMS of their angular residuals and the wall time from reading the file
//! to the attitude. Per solved image, `DIR/<stem>.stars.csv` holds the matched stars:
//! `x_px,y_px,hip,ra_deg,dec_deg,mag,residual_arcsec` (catalog position and Hp magnitude),
//! its TAN WCS as a header-only FITS file `DIR/<stem>.wcs` and an annotated
//! `DIR/<stem>.png` ([`startrack_lab::realsky::wcs`]); and per image read
//! `DIR/<stem>.detections.csv` every star found (`x_px,y_px,flux_e,snr,sigma_px,flags`,
//! brightest first).
//! An image that cannot be read or solved gets a row with `solved` 0 and one line on stderr,
//! and the command then exits non-zero.

use super::{CliError, LabError, read_file, write_file};
use startrack_core::attitude::{Camera, angle_between};
use startrack_core::catalog::Catalog;
use startrack_lab::realsky::picture;
use startrack_lab::realsky::solve::{self, ImageSolution, SolveSpec};
use startrack_lab::realsky::stars::{self, StarField};
use startrack_lab::realsky::wcs;
use startrack_sim::sky::{SkyStar, default_list_path, read_list};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What an image command is told about the camera and the centroids (shared by
/// `solve-image` and `optics fit --images`).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct ImageCameraArgs {
    /// Horizontal field of view (across the columns), deg (needed unless --focal-length-px
    /// or --camera gives the focal length).
    #[arg(long)]
    pub fov_deg: Option<f64>,
    /// Relative error of the focal length (0.1: 10 %); focal lengths within it are tried.
    #[arg(long, default_value_t = 0.1)]
    pub fov_max_error: f64,
    /// Focal length, px (instead of the one from --fov-deg or --camera).
    #[arg(long)]
    pub focal_length_px: Option<f64>,
    /// Principal point, px: column,row, 0-based (default: the image centre, or --camera's).
    #[arg(long, value_parser = parse_point)]
    pub principal_point: Option<[f64; 2]>,
    /// Camera model: a calibration table with a camera section (`calib build
    /// --camera-model`) or the JSON `optics fit` writes.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Pixel values times this are taken as electrons (the fit's shot-noise term).
    #[arg(long, default_value_t = 1.0)]
    pub gain_e_per_adu: f64,
    /// Smallest centroid sigma believed, px (optics and catalog errors).
    #[arg(long, default_value_t = 0.5)]
    pub sigma_floor_px: f64,
}

impl ImageCameraArgs {
    /// The defaults with a field of view.
    pub fn fov(fov_deg: f64) -> Self {
        Self {
            fov_deg: Some(fov_deg),
            fov_max_error: 0.1,
            gain_e_per_adu: 1.0,
            sigma_floor_px: 0.5,
            ..Self::default()
        }
    }
}

/// `X,Y` as two finite numbers.
fn parse_point(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<&str> = s.split(',').collect();
    let [x, y] = v[..] else {
        return Err(format!("{s:?}: expected X,Y"));
    };
    let num = |t: &str| -> Result<f64, String> {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{t:?} is not a finite number"))
    };
    Ok([num(x)?, num(y)?])
}

/// Options of `startrack solve-image`.
#[derive(Clone, Debug, clap::Args)]
pub struct SolveImageArgs {
    /// Images: FITS (any BITPIX), TIFF (8/16-bit), PNG, JPEG.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// The camera and the centroids.
    #[command(flatten)]
    pub camera: ImageCameraArgs,
    /// Catalog file from `startrack catalog build` (default: built at the start of the run
    /// from the star list, every star to Hp 7.5, for a square field of --fov-deg, or of the
    /// focal length's field without it).
    #[arg(long)]
    pub catalog: Option<PathBuf>,
    /// Star list (default: the repo's `host-tests/data/hip_7p5.csv`, Hp <= 7.5): the
    /// default catalog's stars and the HIP numbers of the matched stars.
    #[arg(long)]
    pub list: Option<PathBuf>,
    /// Output folder (created if needed).
    #[arg(long, default_value = "solve-image-out")]
    pub out: PathBuf,
}

/// Faintest star of the default catalog, Hp: an 11 degree field holds a dozen stars to 6.5
/// in its sparser parts (two of the shared frames hold 8 and 9), too few for the false-match
/// bound; to 7.5 it holds about three times as many.
pub const DEFAULT_MAG_LIMIT: f64 = 7.5;

/// The repo's star list to Hp 7.5 (`host-tests/data/hip_7p5.csv`, from `hip_reduce.py 7.5`).
pub fn deep_list_path() -> PathBuf {
    default_list_path().with_file_name("hip_7p5.csv")
}

/// One image's outcome.
#[derive(Clone, Debug)]
pub struct ImageOutcome {
    /// The file.
    pub path: PathBuf,
    /// Its stars, when it was read.
    pub field: Option<StarField>,
    /// The image's size, px.
    pub size_px: [usize; 2],
    /// The solution, or why not (one line naming the file).
    pub result: Result<ImageSolution, String>,
    /// Wall time, ms.
    pub time_ms: f64,
}

/// What a run did.
#[derive(Clone, Debug)]
pub struct SolveImageSummary {
    /// Each image, in the order given.
    pub images: Vec<ImageOutcome>,
}

impl SolveImageSummary {
    /// Images solved.
    pub fn solved(&self) -> usize {
        self.images.iter().filter(|i| i.result.is_ok()).count()
    }
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map_or_else(|| "image".into(), |s| s.to_string_lossy().into_owned())
}

/// The HIP number of the list star within 2 arcsec of `dir`.
fn hip_of(list: &[SkyStar], dir: [f64; 3]) -> Option<&SkyStar> {
    // By angle, not by a dot product against cos(2"): the catalog's Q1.30 vectors are unit
    // only to 1e-9, twenty times 1 - cos(2").
    let lim_rad = (2.0f64 / 3600.0).to_radians();
    list.iter()
        .map(|s| (s, angle_between(s.dir(), dir)))
        .filter(|(_, a)| *a <= lim_rad)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(s, _)| s)
}

/// Checks the options (one line for each misuse) and reads `--camera`: the model it
/// gives, if any.
pub fn check(args: &ImageCameraArgs) -> Result<Option<Camera>, CliError> {
    if let Some(fov) = args.fov_deg
        && !(fov > 0.5 && fov < 60.0)
    {
        return Err(CliError::Usage(format!(
            "--fov-deg {fov} out of range (0.5 < F < 60 deg)"
        )));
    }
    if !(0.0..0.5).contains(&args.fov_max_error) {
        return Err(CliError::Usage("--fov-max-error must be in 0..0.5".into()));
    }
    if let Some(f) = args.focal_length_px
        && !(f.is_finite() && f > 1.0)
    {
        return Err(CliError::Usage("--focal-length-px must be above 1".into()));
    }
    if !(args.gain_e_per_adu.is_finite() && args.gain_e_per_adu > 0.0) {
        return Err(CliError::Usage("--gain-e-per-adu must be positive".into()));
    }
    if !(args.sigma_floor_px.is_finite() && args.sigma_floor_px > 0.0) {
        return Err(CliError::Usage("--sigma-floor-px must be positive".into()));
    }
    let camera = args
        .camera
        .as_deref()
        .map(startrack_lab::optics::read_camera_file)
        .transpose()?;
    if args.fov_deg.is_none() && args.focal_length_px.is_none() && camera.is_none() {
        return Err(CliError::Usage(
            "the focal length is needed: --fov-deg, --focal-length-px or --camera".into(),
        ));
    }
    Ok(camera)
}

impl ImageCameraArgs {
    /// The solver's spec for an image of `size_px`, `camera` the model `--camera` gave.
    pub fn spec(&self, camera: Option<&Camera>, size_px: [usize; 2]) -> SolveSpec {
        let base = match (camera, self.fov_deg) {
            (Some(c), _) => *c,
            (None, Some(fov)) => Camera::pinhole(
                solve::focal_length_px(size_px[0], fov),
                solve::centre(size_px),
            ),
            // `check` refuses this unless --focal-length-px is given (set below).
            (None, None) => Camera::pinhole(1.0, solve::centre(size_px)),
        };
        let mut cam = base;
        if let Some(f) = self.focal_length_px {
            cam.focal_length_px = f;
        }
        if let Some(p) = self.principal_point {
            cam.principal_point_px = p;
        }
        SolveSpec {
            size_px,
            camera: cam,
            focal_length_error: self.fov_max_error,
            sigma_floor_px: self.sigma_floor_px,
        }
    }

    /// The field of view the default catalog is built for, deg: `--fov-deg`, else the
    /// horizontal field of the focal length over an image of `width_px`.
    pub fn catalog_fov_deg(&self, camera: Option<&Camera>, width_px: usize) -> f64 {
        self.fov_deg.unwrap_or_else(|| {
            let f = self
                .focal_length_px
                .or(camera.map(|c| c.focal_length_px))
                .unwrap_or(1.0);
            solve::fov_deg(width_px, f)
        })
    }
}

/// The pattern-star cap radius of the default catalog for a field of `fov_deg`, deg: the
/// 15 degree build's 4 degrees (at most three pattern stars a cap) down to a 10 degree
/// field, then in proportion to the field, so that a narrower field holds as many pattern
/// stars as a 10 degree one (about four in a 4:3 field; with 4 degree caps a 6 degree field
/// holds under two, and lost in space needs three).
pub fn pattern_cap_deg(fov_deg: f64) -> f64 {
    4.0 * (fov_deg / 10.0).min(1.0)
}

/// The catalog `bytes` of `--catalog`, or the default one built for a square field of
/// `fov_deg` from `list`, every star to [`DEFAULT_MAG_LIMIT`], its pattern stars
/// [`pattern_cap_deg`] apart.
pub fn catalog_bytes(
    catalog: Option<&Path>,
    list: &[SkyStar],
    fov_deg: f64,
) -> Result<Vec<u8>, CliError> {
    match catalog {
        Some(p) => read_file(p),
        None => {
            let spec = startrack_sim::sky::build::BuildSpec {
                pattern_cap_rad: pattern_cap_deg(fov_deg).to_radians(),
                ..super::catalog::spec(&super::catalog::CatalogBuildArgs {
                    out: PathBuf::new(),
                    list: None,
                    mag_limit: DEFAULT_MAG_LIMIT,
                    fov_deg,
                    max_separation_deg: 12.0,
                })?
            };
            Ok(startrack_sim::sky::build::build(list, &spec)
                .map_err(|e| CliError::Usage(e.to_string()))?
                .bytes)
        }
    }
}

/// The star list of `--list` (default [`deep_list_path`]).
pub fn read_star_list(path: Option<&Path>) -> Result<Vec<SkyStar>, CliError> {
    let list_path = path.map_or_else(deep_list_path, Path::to_path_buf);
    read_list(&list_path).map_err(|e| {
        LabError::Csv {
            path: e.path.clone(),
            line: e.line,
            msg: e.msg,
        }
        .into()
    })
}

/// Solves every image and writes the outputs (see the module docs). `Err` only for what
/// stops the whole run (options, catalog, output folder); an image's failure is in its
/// outcome.
pub fn run(args: &SolveImageArgs) -> Result<SolveImageSummary, CliError> {
    let camera = check(&args.camera)?;
    let list = read_star_list(args.list.as_deref())?;
    let fov_deg = catalog_fov(&args.camera, camera.as_ref(), &args.images);
    let bytes = catalog_bytes(args.catalog.as_deref(), &list, fov_deg)?;
    let cat = Catalog::parse(&bytes).map_err(|e| CliError::Usage(format!("catalog: {e}")))?;
    std::fs::create_dir_all(&args.out).map_err(|e| LabError::Io {
        path: args.out.clone(),
        msg: e.to_string(),
    })?;
    let mut csv =
        String::from("image,solved,ra_deg,dec_deg,roll_deg,fov_deg,matched,rmse_arcsec,time_ms\n");
    let mut images = Vec::new();
    for path in &args.images {
        let t0 = Instant::now();
        let outcome = solve_one(path, &args.camera, camera.as_ref(), &cat);
        let time_ms = t0.elapsed().as_secs_f64() * 1e3;
        let (pic, field, size_px, result) = match outcome {
            Ok((pic, field, r)) => {
                let size = [pic.width, pic.height];
                (Some(pic), Some(field), size, r)
            }
            Err(e) => (None, None, [0, 0], Err(e.to_string())),
        };
        let name = stem(path);
        if let Some(f) = &field {
            write_file(
                &args.out.join(format!("{name}.detections.csv")),
                detections_csv(f).as_bytes(),
            )?;
        }
        match &result {
            Ok(sol) => {
                let q = solve::centre_attitude(sol.attitude.q, &sol.camera, size_px);
                let (ra, dec) = solve::ra_dec_deg(q.rotate_inv([0.0, 0.0, 1.0]));
                let _ = writeln!(
                    csv,
                    "{name},1,{ra:.6},{dec:.6},{:.6},{:.5},{},{:.2},{time_ms:.1}",
                    solve::roll_tetra3_deg(q),
                    solve::fov_deg(size_px[0], sol.focal_length_px),
                    sol.matches.len(),
                    sol.rmse_rad.to_degrees() * 3600.0,
                );
                let stars = field.as_ref().map_or(&[][..], |f| f.stars.as_slice());
                write_file(
                    &args.out.join(format!("{name}.stars.csv")),
                    stars_csv(&cat, &list, stars, sol).as_bytes(),
                )?;
                wcs::write_wcs(
                    &args.out.join(format!("{name}.wcs")),
                    &wcs::tan_wcs(sol, size_px),
                )?;
                if let (Some(pic), Some(field)) = (&pic, &field) {
                    let hip = |d: [f64; 3]| hip_of(&list, d).map_or(0, |h| h.hip);
                    wcs::write_annotated_png(
                        &args.out.join(format!("{name}.png")),
                        pic,
                        field,
                        sol,
                        &cat,
                        &hip,
                    )?;
                }
            }
            Err(_) => {
                let _ = writeln!(csv, "{name},0,,,,,0,,{time_ms:.1}");
            }
        }
        images.push(ImageOutcome {
            path: path.clone(),
            field,
            size_px,
            result,
            time_ms,
        });
    }
    write_file(&args.out.join("solutions.csv"), csv.as_bytes())?;
    Ok(SolveImageSummary { images })
}

type Solved = (picture::Picture, StarField, Result<ImageSolution, String>);

/// The field of view of the default catalog (see [`ImageCameraArgs::catalog_fov_deg`]),
/// the width from the first image that reads when `--fov-deg` is not given.
pub fn catalog_fov(args: &ImageCameraArgs, camera: Option<&Camera>, images: &[PathBuf]) -> f64 {
    let width = if args.fov_deg.is_some() {
        0
    } else {
        images
            .iter()
            .find_map(|p| picture::load(p).ok())
            .map_or(1024, |p| p.width)
    };
    args.catalog_fov_deg(camera, width)
}

/// Reads, finds the stars of and solves one image.
pub fn solve_one(
    path: &Path,
    args: &ImageCameraArgs,
    camera: Option<&Camera>,
    cat: &Catalog<'_>,
) -> Result<Solved, CliError> {
    let pic = picture::load(path)?;
    let field = stars::find_stars(&pic, args.gain_e_per_adu);
    let spec = args.spec(camera, [pic.width, pic.height]);
    let r = solve::solve(cat, &field.stars, &spec).map_err(|e| format!("{}: {e}", path.display()));
    Ok((pic, field, r))
}

/// Every star found in an image, brightest first, as CSV: position, the detector's signal
/// and SNR, the centroid's sigma and flags (bits of `CentroidFlags`).
pub fn detections_csv(field: &StarField) -> String {
    let mut out = String::from("x_px,y_px,flux_e,snr,sigma_px,flags\n");
    for s in &field.stars {
        let _ = writeln!(
            out,
            "{:.4},{:.4},{:.1},{:.1},{:.4},{}",
            s.x_px,
            s.y_px,
            s.flux_e,
            s.snr,
            s.sigma_px,
            s.flags.bits()
        );
    }
    out
}

/// The matched stars of one solution as CSV.
pub fn stars_csv(
    cat: &Catalog<'_>,
    list: &[SkyStar],
    stars: &[stars::ImageStar],
    sol: &ImageSolution,
) -> String {
    let mut out = String::from("x_px,y_px,hip,ra_deg,dec_deg,mag,residual_arcsec\n");
    for m in &sol.matches {
        let (Some(s), Some(c)) = (stars.get(m.star), cat.star(m.catalog)) else {
            continue;
        };
        let (ra, dec) = solve::ra_dec_deg(c.dir);
        let hip = hip_of(list, c.dir).map_or(0, |h| h.hip);
        let _ = writeln!(
            out,
            "{:.4},{:.4},{hip},{ra:.6},{dec:.6},{:.3},{:.2}",
            s.x_px,
            s.y_px,
            f64::from(c.hp_mmag) / 1000.0,
            m.residual_rad.to_degrees() * 3600.0
        );
    }
    out
}
