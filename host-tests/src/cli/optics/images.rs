//! `startrack optics fit --images IMAGE...`: the camera model from real night-sky images
//! ([`startrack_lab::optics::sky`]), each image read, its stars found and identified as
//! `solve-image` does ([`crate::cli::solve_image::solve_one`]).
//!
//! An image that cannot be read or solved is named in the report and left out; fewer than
//! two solved images, or images of different sizes, is an error. With `--holdout` the model
//! is also fitted on the images at even places in the order given and tested on the odd
//! ones, and the reverse.

use super::{CameraModelJson, FitReport, OpticsFitArgs, PARAM_NAMES};
use crate::cli::solve_image::{self, catalog_bytes, catalog_fov, read_star_list};
use crate::cli::{CliError, write_file};
use startrack_core::catalog::Catalog;
use startrack_lab::optics::sky::{self, Holdout, SkyFit, SkyImage};
use std::fmt::Write as _;
use std::path::Path;

/// What a fit from images did.
#[derive(Clone, Debug, PartialEq)]
pub struct SkyReport {
    /// The images solved and fitted.
    pub images: Vec<SkyImage>,
    /// One line for each image left out.
    pub left_out: Vec<String>,
    /// The fit over every solved image.
    pub fit: SkyFit,
    /// With `--holdout`: even places fitted and odd tested, then the reverse.
    pub holdouts: Vec<Holdout>,
}

fn stem(p: &Path) -> String {
    p.file_stem()
        .map_or_else(|| "image".into(), |s| s.to_string_lossy().into_owned())
}

fn fit_err(e: startrack_lab::optics::FitError) -> CliError {
    CliError::Usage(e.to_string())
}

/// Runs `optics fit --images` (see the module docs).
pub fn run(args: &OpticsFitArgs) -> Result<FitReport, CliError> {
    if args.images.is_empty() {
        return Err(CliError::Usage(
            "give --case DIR or --images IMAGE...".into(),
        ));
    }
    let camera = solve_image::check(&args.sky)?;
    let list = read_star_list(args.list.as_deref())?;
    let fov_deg = catalog_fov(&args.sky, camera.as_ref(), &args.images);
    let bytes = catalog_bytes(args.catalog.as_deref(), &list, fov_deg)?;
    let cat = Catalog::parse(&bytes).map_err(|e| CliError::Usage(format!("catalog: {e}")))?;
    let mut images = Vec::new();
    let mut left_out = Vec::new();
    for path in &args.images {
        match solve_image::solve_one(path, &args.sky, camera.as_ref(), &cat) {
            Ok((pic, field, Ok(sol))) => images.push(SkyImage {
                name: stem(path),
                size_px: [pic.width, pic.height],
                stars: field.stars,
                attitude: sol.attitude.q,
                focal_length_px: sol.focal_length_px,
                matches: sol.matches.iter().map(|m| (m.star, m.catalog)).collect(),
            }),
            Ok((_, _, Err(e))) => left_out.push(e),
            Err(e) => left_out.push(e.to_string()),
        }
    }
    if images.len() < 2 {
        return Err(CliError::Usage(format!(
            "optics fit: {} of {} images solved, at least 2 needed{}",
            images.len(),
            args.images.len(),
            left_out
                .first()
                .map_or(String::new(), |e| format!(" ({e})"))
        )));
    }
    let size = images[0].size_px;
    if let Some(other) = images.iter().find(|i| i.size_px != size) {
        return Err(CliError::Usage(format!(
            "optics fit: {} is {} x {} px, {} is {} x {} px: one camera's images only",
            images[0].name, size[0], size[1], other.name, other.size_px[0], other.size_px[1]
        )));
    }
    let start = match &camera {
        Some(_) => args.sky.spec(camera.as_ref(), size).camera,
        None => {
            let mut c = sky::pinhole_start(&images);
            if let Some(p) = args.sky.principal_point {
                c.principal_point_px = p;
            }
            c
        }
    };
    let opts = args.options();
    let floor = args.sky.sigma_floor_px;
    let fit = sky::fit_images(&cat, &images, &start, floor, opts).map_err(fit_err)?;
    let mut holdouts = Vec::new();
    if args.holdout {
        let even: Vec<usize> = (0..images.len()).step_by(2).collect();
        let odd: Vec<usize> = (1..images.len()).step_by(2).collect();
        for (train, test) in [(&even, &odd), (&odd, &even)] {
            holdouts.push(
                sky::holdout(&cat, &images, train, test, &start, floor, opts).map_err(fit_err)?,
            );
        }
    }
    let report = SkyReport {
        images,
        left_out,
        fit,
        holdouts,
    };
    let model = CameraModelJson::of_fit(&report.fit.fit, report.fit.frames.len());
    let json = serde_json::to_string_pretty(&model).map_err(|e| CliError::Usage(e.to_string()))?;
    write_file(&args.out, json.as_bytes())?;
    if let Some(p) = &args.csv {
        write_file(p, csv(&report, args).as_bytes())?;
    }
    Ok(FitReport {
        model,
        text: text(&report, args.images.len()),
        sky: Some(report),
    })
}

fn names(r: &SkyReport, idx: &[usize]) -> String {
    idx.iter()
        .filter_map(|&i| r.images.get(i))
        .map(|i| i.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The report's lines.
pub fn text(r: &SkyReport, given: usize) -> String {
    let f = &r.fit.fit;
    let mut t = format!(
        "{} of {given} images solved; {} stars matched, {} rounds, {} iterations\n",
        r.images.len(),
        f.stars,
        r.fit.rounds,
        f.iterations
    );
    for l in &r.left_out {
        let _ = writeln!(t, "left out: {l}");
    }
    let _ = writeln!(
        t,
        "residual RMS per axis: pinhole (focal length fitted) {:.4} px, model {:.4} px; chi2/dof {:.3}",
        r.fit.pinhole.residual_rms_px, f.residual_rms_px, f.chi2_per_dof
    );
    let params = startrack_lab::optics::params_of(&f.camera);
    for (k, name) in PARAM_NAMES.iter().enumerate() {
        if f.sigma[k] > 0.0 {
            let _ = writeln!(t, "{name:>22} {:>15.8e} +- {:.2e}", params[k], f.sigma[k]);
        } else {
            let _ = writeln!(t, "{name:>22} {:>15.8e} held", params[k]);
        }
    }
    for h in &r.holdouts {
        let _ = writeln!(
            t,
            "holdout: fitted on {}; tested on {} ({} stars): pinhole {:.4} px, model {:.4} px",
            names(r, &h.train),
            names(r, &h.test),
            h.test_stars,
            h.pinhole_rms_px,
            h.model_rms_px
        );
    }
    t
}

/// The report's figures as CSV: `quantity,value,sigma` (sigma empty where it has none;
/// `held` for a parameter not fitted), after a comment line with the options that matter.
pub fn csv(r: &SkyReport, args: &OpticsFitArgs) -> String {
    let f = &r.fit.fit;
    let held: Vec<String> = args
        .hold
        .iter()
        .filter_map(|p| clap::ValueEnum::to_possible_value(p).map(|v| v.get_name().to_string()))
        .collect();
    let mut out = format!(
        "# startrack optics fit --images: {} images, held {}, sigma floor {} px{}\n",
        r.images.len(),
        if held.is_empty() {
            "none".to_string()
        } else {
            held.join(",")
        },
        args.sky.sigma_floor_px,
        if args.holdout { ", --holdout" } else { "" }
    );
    out.push_str("quantity,value,sigma\n");
    let _ = writeln!(out, "images,{},", r.images.len());
    let _ = writeln!(out, "stars,{},", f.stars);
    let params = startrack_lab::optics::params_of(&f.camera);
    for (k, name) in PARAM_NAMES.iter().enumerate() {
        if f.sigma[k] > 0.0 {
            let _ = writeln!(out, "{name},{:.6e},{:.3e}", params[k], f.sigma[k]);
        } else {
            let _ = writeln!(out, "{name},{:.6e},held", params[k]);
        }
    }
    let _ = writeln!(out, "rms_pinhole_px,{:.4},", r.fit.pinhole.residual_rms_px);
    let _ = writeln!(out, "rms_model_px,{:.4},", f.residual_rms_px);
    let _ = writeln!(out, "chi2_per_dof,{:.4},", f.chi2_per_dof);
    for (n, h) in r.holdouts.iter().enumerate() {
        let _ = writeln!(out, "holdout{}_stars,{},", n + 1, h.test_stars);
        let _ = writeln!(
            out,
            "holdout{}_rms_pinhole_px,{:.4},",
            n + 1,
            h.pinhole_rms_px
        );
        let _ = writeln!(out, "holdout{}_rms_model_px,{:.4},", n + 1, h.model_rms_px);
    }
    out
}
