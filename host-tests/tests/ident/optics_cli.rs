//! `startrack optics case`, `optics fit` and `calib build --camera-model` end to end: a
//! simulated case through distorted optics, the fitted model written as JSON and compared
//! with the truth, and the model stored in the calibration table and read back.

use startrack_test_support::cli as common_cli;

use startrack_core::table::CalibTable;
use startrack_host::cli::CliError;
use startrack_host::cli::optics::{OpticsCaseArgs, OpticsFitArgs, run_case, run_fit};
use startrack_lab::LabError;
use startrack_lab::optics::{CameraModelJson, read_camera_model, simulated_truth};
use startrack_lab::table_build::{CalibBuildArgs, build};

fn calib_args(out: std::path::PathBuf, camera_model: Option<std::path::PathBuf>) -> CalibBuildArgs {
    CalibBuildArgs {
        gains: Some("1.5,1.5".into()),
        camera_model,
        dark_law: None,
        ..common_cli::bare_args(out)
    }
}

#[test]
fn case_fit_and_table_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let case = dir.path().join("case");
    run_case(&OpticsCaseArgs {
        out: case.clone(),
        frames: 40,
        seed: 3,
        sigma_px: 0.1,
    })
    .unwrap();
    let model_path = dir.path().join("model.json");
    let report = run_fit(&OpticsFitArgs::case(case.clone(), model_path.clone())).unwrap();
    print!("{}", report.text);
    assert!(report.text.contains("after correction"), "{}", report.text);
    assert!(report.model.frames.unwrap_or(0) >= 36);
    let m: CameraModelJson = serde_json::from_slice(&std::fs::read(&model_path).unwrap()).unwrap();
    // The file holds the reported model (JSON's decimal floats: to 1e-12).
    let (a, b) = (
        startrack_lab::optics::params_of(&m.camera()),
        startrack_lab::optics::params_of(&report.model.camera()),
    );
    for k in 0..8 {
        assert!(
            (a[k] - b[k]).abs() <= 1e-12 * b[k].abs(),
            "{k}: {} {}",
            a[k],
            b[k]
        );
    }
    assert_eq!(m.sigma.len(), 8);
    // Within 4.5 formal sigmas of the truth on every parameter.
    let truth = startrack_lab::optics::params_of(&simulated_truth());
    let got = startrack_lab::optics::params_of(&m.camera());
    for k in 0..8 {
        assert!(
            ((got[k] - truth[k]) / m.sigma[k]).abs() < 4.5,
            "{}: {} vs {}",
            m.sigma_names[k],
            got[k],
            truth[k]
        );
    }

    // Into the calibration table and back.
    let table = dir.path().join("t.bin");
    let (bytes, rep) = build(&calib_args(table, Some(model_path.clone()))).unwrap();
    assert!(rep.notes.iter().any(|n| n.contains("camera model")));
    let back = CalibTable::parse(&bytes).unwrap().camera_model().unwrap();
    let cam = read_camera_model(&model_path).unwrap();
    let d = cam.direction_of(1000.0, 20.0, 1.4).unwrap();
    let p = back.project_of(d, 1.4).unwrap();
    assert!(
        (p[0] - 1000.0).abs() < 1e-4 && (p[1] - 20.0).abs() < 1e-4,
        "{p:?}"
    );
    let (plain, _) = build(&calib_args(dir.path().join("u.bin"), None)).unwrap();
    assert_eq!(CalibTable::parse(&plain).unwrap().camera_model(), None);
}

#[test]
fn bad_inputs_are_typed_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = run_fit(&OpticsFitArgs::case(
        dir.path().join("nothing"),
        dir.path().join("m.json"),
    ));
    assert!(
        matches!(missing, Err(CliError::Lab(LabError::Io { .. }))),
        "{missing:?}"
    );

    // A model that folds the image inside the frame is refused before any table is built.
    let folded = dir.path().join("folded.json");
    let mut m = CameraModelJson::of(&simulated_truth());
    m.k1 = -12.0;
    std::fs::write(&folded, serde_json::to_string(&m).unwrap()).unwrap();
    let r = build(&calib_args(dir.path().join("t.bin"), Some(folded)));
    assert!(
        matches!(r, Err(LabError::Invalid(ref s)) if s.contains("no inverse")),
        "{r:?}"
    );

    let garbage = dir.path().join("garbage.json");
    std::fs::write(&garbage, "{\"focal_length_px\": \"wide\"}").unwrap();
    assert!(matches!(
        read_camera_model(&garbage),
        Err(LabError::Invalid(_))
    ));
}
