//! `startrack solve-image IMAGE... --fov-deg F [--fov-max-error E] [--focal-length-px P]
//! [--catalog FILE] [--out DIR]`: real images to attitudes ([`startrack_lab::realsky`]).
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

use super::{CliError, read_file, write_file};
use startrack_core::attitude::angle_between;
use startrack_core::catalog::Catalog;
use startrack_lab::realsky::picture;
use startrack_lab::realsky::solve::{self, ImageSolution, SolveSpec};
use startrack_lab::realsky::stars::{self, StarField};
use startrack_lab::realsky::wcs;
use startrack_sim::sky::{SkyStar, default_list_path, read_list};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of `startrack solve-image`.
#[derive(Clone, Debug, clap::Args)]
pub struct SolveImageArgs {
    /// Images: FITS (any BITPIX), TIFF (8/16-bit), PNG, JPEG.
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
    /// Horizontal field of view (across the columns), deg.
    #[arg(long)]
    pub fov_deg: f64,
    /// Relative error of the field of view (0.1: 10 %); focal lengths within it are tried.
    #[arg(long, default_value_t = 0.1)]
    pub fov_max_error: f64,
    /// Focal length, px (instead of the one from --fov-deg).
    #[arg(long)]
    pub focal_length_px: Option<f64>,
    /// Catalog file from `startrack catalog build` (default: built at the start of the run
    /// from the star list, every star to Hp 7.5, for a square field of --fov-deg).
    #[arg(long)]
    pub catalog: Option<PathBuf>,
    /// Star list (default: the repo's `host-tests/data/hip_7p5.csv`, Hp <= 7.5): the
    /// default catalog's stars and the HIP numbers of the matched stars.
    #[arg(long)]
    pub list: Option<PathBuf>,
    /// Output folder (created if needed).
    #[arg(long, default_value = "solve-image-out")]
    pub out: PathBuf,
    /// Pixel values times this are taken as electrons (the fit's shot-noise term).
    #[arg(long, default_value_t = 1.0)]
    pub gain_e_per_adu: f64,
    /// Smallest centroid sigma believed, px (optics and catalog errors).
    #[arg(long, default_value_t = 0.5)]
    pub sigma_floor_px: f64,
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

/// Checks the options (one line for each misuse).
pub fn check(args: &SolveImageArgs) -> Result<(), CliError> {
    if !(args.fov_deg > 0.5 && args.fov_deg < 60.0) {
        return Err(CliError::Usage(format!(
            "--fov-deg {} out of range (0.5 < F < 60 deg)",
            args.fov_deg
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
    Ok(())
}

/// Solves every image and writes the outputs (see the module docs). `Err` only for what
/// stops the whole run (options, catalog, output folder); an image's failure is in its
/// outcome.
pub fn run(args: &SolveImageArgs) -> Result<SolveImageSummary, CliError> {
    check(args)?;
    let list_path = args.list.clone().unwrap_or_else(deep_list_path);
    let list = read_list(&list_path).map_err(|e| CliError::Csv {
        path: e.path.clone(),
        line: e.line,
        msg: e.msg,
    })?;
    let bytes = match &args.catalog {
        Some(p) => read_file(p)?,
        None => {
            let spec = super::catalog::spec(&super::catalog::CatalogBuildArgs {
                out: PathBuf::new(),
                list: None,
                mag_limit: DEFAULT_MAG_LIMIT,
                fov_deg: args.fov_deg,
                max_separation_deg: 12.0,
            })?;
            startrack_sim::sky::build::build(&list, &spec)
                .map_err(|e| CliError::Usage(e.to_string()))?
                .bytes
        }
    };
    let cat = Catalog::parse(&bytes).map_err(|e| CliError::Usage(format!("catalog: {e}")))?;
    std::fs::create_dir_all(&args.out).map_err(|e| CliError::Io {
        path: args.out.clone(),
        msg: e.to_string(),
    })?;
    let mut csv =
        String::from("image,solved,ra_deg,dec_deg,roll_deg,fov_deg,matched,rmse_arcsec,time_ms\n");
    let mut images = Vec::new();
    for path in &args.images {
        let t0 = Instant::now();
        let outcome = solve_one(path, args, &cat);
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
                let (ra, dec) = solve::ra_dec_deg(sol.attitude.q.rotate_inv([0.0, 0.0, 1.0]));
                let _ = writeln!(
                    csv,
                    "{name},1,{ra:.6},{dec:.6},{:.6},{:.5},{},{:.2},{time_ms:.1}",
                    solve::roll_tetra3_deg(sol.attitude.q),
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

fn solve_one(path: &Path, args: &SolveImageArgs, cat: &Catalog<'_>) -> Result<Solved, CliError> {
    let pic = picture::load(path)?;
    let field = stars::find_stars(&pic, args.gain_e_per_adu);
    let spec = SolveSpec {
        size_px: [pic.width, pic.height],
        focal_length_px: args
            .focal_length_px
            .unwrap_or_else(|| solve::focal_length_px(pic.width, args.fov_deg)),
        focal_length_error: args.fov_max_error,
        sigma_floor_px: args.sigma_floor_px,
    };
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
