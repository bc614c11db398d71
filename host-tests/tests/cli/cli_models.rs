//! The model sections through the command line: `calib psf-model` on synthetic star lists
//! (a known width field, noise and outliers), `calib build --cti --psf-model` into a table
//! that parses back to the same values, and one-line errors for bad inputs.

use crate::common_cli;

use common_cli::startrack;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use startrack_core::table::CalibTable;
use startrack_host::cli::calib_models::{PsfModelArgs, run_psf_model};
use startrack_lab::cti::{CtiCoeffsJson, CtiOutputJson};
use startrack_lab::psf_model::{PsfFitError, StarWidth, fit, norm, read_stars_csv};
use startrack_lab::table_build::{CalibBuildArgs, build};

/// The true width field: a = 1.1 + 0.15 u - 0.1 v + 0.3 u^2 + 0.05 u v + 0.2 v^2 px.
fn true_a(x: f64, y: f64) -> f64 {
    let (u, v) = (norm(x, 1024), norm(y, 1024));
    1.1 + 0.15 * u - 0.1 * v + 0.3 * u * u + 0.05 * u * v + 0.2 * v * v
}

/// `n` stars uniform over the CCD47-20's active area, widths with `noise_px` Gaussian scatter,
/// and every 25th star a blend or hit with a width 1.5-3 px too large.
fn stars(n: usize, noise_px: f64, seed: u64) -> (String, usize) {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let z = Normal::new(0.0, noise_px).unwrap();
    let mut csv = String::from("x_px,y_px,flux_e,psf_a_px,chi2_dof\n");
    let mut outliers = 0;
    for i in 0..n {
        let (x, y) = (r.random_range(0.0..1023.0), r.random_range(0.0..1023.0));
        let mut a = true_a(x, y) + z.sample(&mut r);
        if i % 25 == 7 {
            a += r.random_range(1.5..3.0);
            outliers += 1;
        }
        csv.push_str(&format!("{x:.3},{y:.3},5000,{a:.4},1.0\n"));
    }
    // A star the fit did not measure: no width.
    csv.push_str("100,100,200,,\n");
    (csv, outliers)
}

#[test]
fn psf_model_recovers_the_width_field_and_rejects_outliers() {
    let (csv, outliers) = stars(800, 0.05, 3);
    let s = read_stars_csv(&csv).expect("reads");
    assert_eq!(s.len(), 800);
    let m = fit(&s, 2, 1024, 1024).expect("fits");
    // Every planted outlier is left out, and few good stars (3-sigma clipping: ~0.3 %).
    println!(
        "degree 2 on 800 stars (32 outliers): kept {}, rejected {}, scatter {:.4} px",
        m.stars, m.rejected, m.scatter_px
    );
    assert!(m.rejected >= outliers && m.rejected <= outliers + 8);
    // The scatter is the width noise, to its sampling error (~2.5 % for 770 stars, x 4).
    assert!((m.scatter_px / 0.05 - 1.0).abs() < 0.1, "{}", m.scatter_px);
    // The model matches the true field to well under the per-star noise everywhere: the
    // standard error of a 6-term fit on ~770 stars is ~0.05 sqrt(6 / 770) = 0.0044 px on
    // average, a few times that in the corners where the quadratic terms have leverage.
    let mut worst: f64 = 0.0;
    for y in (0..1024).step_by(64) {
        for x in (0..1024).step_by(64) {
            worst = worst.max(
                (m.a_px(f64::from(x), f64::from(y)) - true_a(f64::from(x), f64::from(y))).abs(),
            );
        }
    }
    println!("worst model error over the field: {worst:.4} px");
    assert!(worst < 0.02, "{worst}");
    // The table's fixed-point value gives the same width (I16F16 coefficients).
    let t = m.to_table().expect("in range");
    for (x, y) in [(0.0, 0.0), (511.5, 300.0), (1023.0, 1023.0)] {
        let core = f64::from(t.a_px(x as f32, y as f32, 1024, 1024));
        assert!(
            (core - m.a_px(x, y)).abs() < 1e-4,
            "{core} {}",
            m.a_px(x, y)
        );
    }
    // Too few stars for the degree, and a degree the table cannot hold.
    assert_eq!(
        fit(&s[..11], 2, 1024, 1024),
        Err(PsfFitError::TooFewStars {
            usable: 11,
            needed: 12
        })
    );
    assert_eq!(fit(&s, 4, 1024, 1024), Err(PsfFitError::Degree(4)));
    // A cubic fitted to stars in one corner only, with widths alternating +-0.5 px: the
    // model is either refused or stays in range over the whole field (never stored wild).
    let corner: Vec<StarWidth> = s
        .iter()
        .copied()
        .filter(|p| p.x_px < 200.0 && p.y_px < 200.0)
        .collect();
    let spiky: Vec<StarWidth> = corner
        .iter()
        .enumerate()
        .map(|(i, p)| StarWidth {
            a_px: p.a_px + if i % 2 == 0 { 0.5 } else { -0.5 } * p.x_px / 200.0,
            ..*p
        })
        .collect();
    match fit(&spiky, 3, 1024, 1024) {
        Ok(m) => {
            for (x, y) in [(0.0, 0.0), (1023.0, 0.0), (0.0, 1023.0), (1023.0, 1023.0)] {
                assert!(m.a_px(x, y) > 0.0 && m.a_px(x, y) < 256.0);
            }
        }
        Err(e) => assert_eq!(e, PsfFitError::OutOfRange),
    }
}

#[test]
fn calib_build_writes_both_model_sections() {
    let dir = tempfile::tempdir().unwrap();
    let (csv, _) = stars(400, 0.05, 5);
    let stars_path = dir.path().join("stars.csv");
    std::fs::write(&stars_path, csv).unwrap();
    let model_path = dir.path().join("psf.json");
    let m = run_psf_model(&PsfModelArgs {
        stars: vec![stars_path.clone()],
        out: model_path.clone(),
        degree: 2,
    })
    .expect("fits");
    let cti = CtiCoeffsJson {
        reference_flux_e: 10_000,
        flux_offset_e: 400,
        alpha: 0.25,
        outputs: vec![
            CtiOutputJson {
                parallel_px_per_transfer: 2.0e-5,
                serial_px_per_transfer: 1.2e-5,
            },
            CtiOutputJson {
                parallel_px_per_transfer: 2.1e-5,
                serial_px_per_transfer: 1.3e-5,
            },
        ],
    };
    let cti_path = dir.path().join("cti.json");
    std::fs::write(&cti_path, serde_json::to_string(&cti).unwrap()).unwrap();
    let args = CalibBuildArgs {
        gains: Some("1.5,1.6".into()),
        cti: Some(cti_path.clone()),
        psf_model: Some(model_path.clone()),
        ..base_args(dir.path())
    };
    let (bytes, report) = build(&args).expect("builds");
    for n in &report.notes {
        println!("{n}");
    }
    let t = CalibTable::parse(&bytes).expect("parses");
    let c = t.cti().expect("CTI section");
    assert_eq!(CtiCoeffsJson::from_coeffs(&c, 2).flux_offset_e, 400);
    assert!((c.alpha.to_num::<f64>() - 0.25).abs() < 2e-5);
    assert!((c.outputs[1].serial_px.to_num::<f64>() - 1.3e-5).abs() < 1e-9);
    let p = t.psf_model().expect("PSF model section");
    assert_eq!(usize::from(p.stars), m.stars);
    assert!((f64::from(p.a_px(100.0, 900.0, 1024, 1024)) - m.a_px(100.0, 900.0)).abs() < 1e-4);
    assert!(report.notes.iter().any(|n| n.starts_with("CTI:")));
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.starts_with("field PSF model:"))
    );

    // Through the binary: bad inputs are one line naming the file.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, "{\"reference_flux_e\": 0}").unwrap();
    let out = dir.path().join("t.bin");
    let (ok, _, err) = startrack(&[
        "calib",
        "build",
        "--out",
        out.to_str().unwrap(),
        "--gains",
        "1.5,1.6",
        "--cti",
        bad.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.lines().count() == 1 && err.contains("bad.json"),
        "{err}"
    );
    let mut one = cti.clone();
    one.outputs.pop();
    std::fs::write(&bad, serde_json::to_string(&one).unwrap()).unwrap();
    let (ok, _, err) = startrack(&[
        "calib",
        "build",
        "--out",
        out.to_str().unwrap(),
        "--gains",
        "1.5,1.6",
        "--cti",
        bad.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("1 outputs' coefficients for a readout of 2"),
        "{err}"
    );
    std::fs::write(&bad, "x_px,y_px\n1,2\n").unwrap();
    let (ok, _, err) = startrack(&[
        "calib",
        "psf-model",
        bad.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.lines().count() == 1 && err.contains("psf_a_px"),
        "{err}"
    );
}

fn base_args(dir: &std::path::Path) -> CalibBuildArgs {
    common_cli::bare_args(dir.join("t.bin"))
}
