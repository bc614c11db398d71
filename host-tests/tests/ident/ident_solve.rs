//! `startrack catalog build`, `catalog case` and `solve` end to end: the catalog written to
//! a file solves a written case, and every attitude in the output agrees with the truth
//! within its own covariance.

use startrack_core::attitude::Quat;
use startrack_host::cli::catalog::{CatalogBuildArgs, CatalogCaseArgs, run_build, run_case};
use startrack_host::cli::solve::{SolveArgs, run};

fn read_csv(path: &std::path::Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{e}"))
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect()
}

#[test]
fn solve_writes_every_field_with_attitude_and_covariance() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let cat = dir.path().join("catalog.bin");
    let built = run_build(&CatalogBuildArgs {
        out: cat.clone(),
        list: None,
        mag_limit: 6.5,
        fov_deg: 15.0,
        max_separation_deg: 12.0,
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(
        std::fs::metadata(&cat).map(|m| m.len()).ok(),
        Some(built.bytes.len() as u64)
    );
    let case = dir.path().join("case");
    run_case(&CatalogCaseArgs {
        out: case.clone(),
        fields: 40,
        seed: 9,
        sigma_px: 0.2,
        false_stars: 3,
        dropout: 0.1,
        prior_error_deg: None,
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("out.csv");
    let s = run(&SolveArgs {
        case: case.clone(),
        out: out.clone(),
        catalog: Some(cat),
        prior: None,
        prior_error_deg: 2.0,
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((s.fields, s.solved), (40, 40));
    let rows = read_csv(&out);
    let truth = read_csv(&case.join("truth.csv"));
    assert_eq!(rows.len(), 40);
    let num = |r: &[String], i: usize| r[i].parse::<f64>().unwrap_or(f64::NAN);
    for (r, t) in rows.iter().zip(&truth) {
        assert_eq!(r[0], t[0]);
        assert_eq!(r[1], "1");
        let q = Quat([num(r, 2), num(r, 3), num(r, 4), num(r, 5)]);
        let qt = Quat([num(t, 1), num(t, 2), num(t, 3), num(t, 4)]);
        let e = q.error_vector(qt);
        // Each axis within 5 sigma of its own variance.
        for (k, var_col) in [(0, 7), (1, 10), (2, 12)] {
            let sigma = num(r, var_col).sqrt();
            assert!(
                e[k].abs() < 5.0 * sigma,
                "field {}: axis {k} error {:e} sigma {:e}",
                r[0],
                e[k],
                sigma
            );
        }
    }
}

#[test]
fn solve_names_a_bad_case() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    std::fs::write(
        dir.path().join("case.json"),
        "{\"focal_length_px\": -1, \"principal_point_px\": [0, 0]}",
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let err = run(&SolveArgs {
        case: dir.path().to_path_buf(),
        out: dir.path().join("o.csv"),
        catalog: None,
        prior: None,
        prior_error_deg: 2.0,
    });
    assert!(err.is_err());
    std::fs::write(dir.path().join("case.json"), "not json").unwrap_or_else(|e| panic!("{e}"));
    let msg = run(&SolveArgs {
        case: dir.path().to_path_buf(),
        out: dir.path().join("o.csv"),
        catalog: None,
        prior: None,
        prior_error_deg: 2.0,
    })
    .err()
    .map(|e| e.to_string())
    .unwrap_or_default();
    assert!(msg.contains("case.json"), "{msg}");
}

#[test]
fn solve_tracks_from_priors_2_degrees_off() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let case = dir.path().join("case");
    run_case(&CatalogCaseArgs {
        out: case.clone(),
        fields: 30,
        seed: 11,
        sigma_px: 0.3,
        false_stars: 3,
        dropout: 0.1,
        prior_error_deg: Some(2.0),
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let out = dir.path().join("out.csv");
    let s = run(&SolveArgs {
        case: case.clone(),
        out: out.clone(),
        catalog: None,
        prior: Some(case.join("prior.csv")),
        prior_error_deg: 2.0,
    })
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((s.fields, s.solved), (30, 30));
    // The priors really are 2 degrees off the truth.
    let truth = read_csv(&case.join("truth.csv"));
    let prior = read_csv(&case.join("prior.csv"));
    for (t, p) in truth.iter().zip(&prior) {
        let q = |r: &[String]| Quat([1, 2, 3, 4].map(|i| r[i].parse::<f64>().unwrap_or(f64::NAN)));
        let e = q(p).error_vector(q(t));
        let deg = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
            .sqrt()
            .to_degrees();
        assert!((deg - 2.0).abs() < 1e-6, "{deg}");
    }
}
