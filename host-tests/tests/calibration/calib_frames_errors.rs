//! Bad lab sets stop `calib frames` with one line naming the file and the problem, and no
//! table: a missing keyword, mixed geometry, too few flats, a saturated flat, a geometry
//! without covered pixels, temperatures that fall into no regulation band. Also the command
//! itself on a good minimal set, and the keyword spellings it reads.

use startrack_core::geometry::ReadoutGeometry;
use startrack_host::cli::calib_frames::{CalibFramesArgs, Sensor, run};
use startrack_lab::calib_frames::labset::{LabSet, write_string_keys};
use startrack_lab::calib_frames::{FramesError, calibrate};
use startrack_sim::fits::{RawFrame, write_raw_frame};
use std::path::{Path, PathBuf};

/// 2 bias, 3 flat pairs, 2 darks at two temperatures: the least `calib frames` accepts.
fn minimal() -> LabSet {
    LabSet {
        bias_frames: 2,
        flat_exposures_s: vec![1.0, 2.0, 3.0],
        dark_temperatures_k: vec![263.0, 273.0],
        dark_exposures_s: vec![10.0],
        darks_per_setting: 1,
        series_frames: 0,
        saturation_exposures_s: Vec::new(),
        ..LabSet::small(3)
    }
}

fn written(dir: &Path) -> (LabSet, Vec<PathBuf>) {
    let set = minimal();
    let paths = set.write(dir).expect("written");
    (set, paths)
}

fn err(paths: &[PathBuf], g: &ReadoutGeometry) -> String {
    let e = calibrate(paths, g, &|| ()).expect_err("must fail");
    let s = e.to_string();
    assert!(!s.contains('\n'), "one line: {s}");
    s
}

#[test]
fn the_minimal_set_runs_through_the_command() {
    let dir = tempfile::tempdir().unwrap();
    written(&dir.path().join("frames"));
    let args = CalibFramesArgs {
        dirs: vec![dir.path().join("frames")],
        out: dir.path().join("table.bin"),
        report_dir: dir.path().join("report"),
        tile_log2: 0,
        sensor: Sensor::Test128,
        temperature_tolerance_k: 0.5,
    };
    let p = run(&args).expect("runs");
    assert_eq!(p.frames, (2, 6, 2));
    assert!(p.rts_series.is_none(), "no series of 10 frames");
    // No flat reaches saturation: no full well, no linearity error, and a note says why.
    assert_eq!(p.full_well_e, vec![None, None]);
    assert_eq!(p.nonlinearity_pct, vec![None, None]);
    let note = p
        .notes
        .iter()
        .find(|n| n.starts_with("output 0: no flat reaches saturation"))
        .expect("a note");
    assert!(note.contains("from 2 s to 3 s"), "{note}");
    let bytes = std::fs::read(&args.out).unwrap();
    startrack_core::table::CalibTable::parse(&bytes).expect("a valid table");
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(args.report_dir.join("report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(json["full_well_e"], serde_json::json!([null, null]));
    assert_eq!(json["nonlinearity_pct"], serde_json::json!([null, null]));
}

#[test]
fn a_missing_keyword_names_the_file_and_the_keyword() {
    let dir = tempfile::tempdir().unwrap();
    let (set, mut paths) = written(dir.path());
    let (frame, _, _, _) = set.render(0).unwrap();
    let bad = dir.path().join("nokey.fits");
    write_raw_frame(&bad, &frame, &[("EXPTIME", 0.0), ("CCDTEMP", 253.0)]).unwrap();
    write_string_keys(&bad, &[("IMAGETYP", "BIAS")]).unwrap();
    paths.push(bad);
    let s = err(&paths, &set.geometry);
    assert!(
        s.contains("nokey.fits") && s.contains("DATE-OBS") && s.contains("missing"),
        "{s}"
    );
}

#[test]
fn mixed_geometry_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let (set, mut paths) = written(dir.path());
    let bad = dir.path().join("other.fits");
    let frame = RawFrame {
        lines: 10,
        cols: 20,
        data_adu: vec![1000; 200],
    };
    write_raw_frame(&bad, &frame, &[("EXPTIME", 0.0), ("CCDTEMP", 253.0)]).unwrap();
    write_string_keys(
        &bad,
        &[("IMAGETYP", "BIAS"), ("DATE-OBS", "2026-03-01T00:00:00")],
    )
    .unwrap();
    paths.push(bad);
    let s = err(&paths, &set.geometry);
    assert!(
        s.contains("other.fits") && s.contains("mixed geometry"),
        "{s}"
    );
}

#[test]
fn too_few_flats_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (set, paths) = written(dir.path());
    let kept: Vec<PathBuf> = paths
        .into_iter()
        .filter(|p| !p.to_string_lossy().contains("0006_flat"))
        .collect();
    let s = err(&kept, &set.geometry);
    assert!(s.contains("too few flats"), "{s}");
}

#[test]
fn a_saturated_flat_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let (set, paths) = written(dir.path());
    let flat = paths
        .iter()
        .find(|p| p.to_string_lossy().contains("0004_flat"))
        .unwrap()
        .clone();
    let (mut frame, _, t, temp) = set.render(4).unwrap();
    frame.data_adu.iter_mut().for_each(|v| *v = u16::MAX);
    write_raw_frame(&flat, &frame, &[("EXPTIME", t), ("CCDTEMP", temp)]).unwrap();
    write_string_keys(
        &flat,
        &[("IMAGETYP", "FLAT"), ("DATE-OBS", "2026-03-01T00:00:04")],
    )
    .unwrap();
    let s = err(&paths, &set.geometry);
    assert!(
        s.contains("0004_flat.fits") && s.contains("saturated flat"),
        "{s}"
    );
}

#[test]
fn a_geometry_without_covered_pixels_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (set, paths) = written(dir.path());
    let g = ReadoutGeometry {
        covered_px: 0,
        ..set.geometry
    };
    let e = calibrate(&paths, &g, &|| ()).expect_err("must fail");
    assert!(matches!(e, FramesError::Missing(_)));
    assert!(e.to_string().contains("no covered columns"), "{e}");
}

/// Adds a dark of `set`'s first dark frame at `ccdtemp_k` as `name`.
fn add_dark(dir: &Path, set: &LabSet, name: &str, ccdtemp_k: f64, date: &str) -> PathBuf {
    let i = set.plan().iter().position(|p| p.0 == "DARK").unwrap();
    let (frame, _, t, _) = set.render(i).unwrap();
    let p = dir.join(name);
    write_raw_frame(&p, &frame, &[("EXPTIME", t), ("CCDTEMP", ccdtemp_k)]).unwrap();
    write_string_keys(&p, &[("IMAGETYP", "Dark Frame"), ("DATE-OBS", date)]).unwrap();
    p
}

#[test]
fn temperatures_that_chain_past_the_band_name_the_file_and_keyword() {
    let dir = tempfile::tempdir().unwrap();
    let (set, mut paths) = written(dir.path());
    // 263.0 (the set's own dark), then 263.4, 263.8, 264.2: neighbours within 0.5 K, the
    // chain 1.2 K wide: no regulation band holds it.
    for (k, t) in [263.4, 263.8, 264.2].iter().enumerate() {
        paths.push(add_dark(
            dir.path(),
            &set,
            &format!("chain{k}.fits"),
            *t,
            &format!("2026-03-02T00:00:0{k}"),
        ));
    }
    let s = err(&paths, &set.geometry);
    assert!(
        s.contains("CCDTEMP") && s.contains("regulation band") && s.contains(".fits:"),
        "{s}"
    );
    // Darks wandering by hundredths of a kelvin are one temperature.
    let (set, mut paths) = written(&dir.path().join("wander"));
    for (k, t) in [263.02, 262.99, 263.03].iter().enumerate() {
        paths.push(add_dark(
            &dir.path().join("wander"),
            &set,
            &format!("w{k}.fits"),
            *t,
            &format!("2026-03-02T00:00:0{k}"),
        ));
    }
    let p = calibrate(&paths, &set.geometry, &|| ()).expect("grouped");
    assert_eq!(
        p.covered_rates.len(),
        2,
        "263 and 273 K: {:?}",
        p.covered_rates
    );
}

#[test]
fn a_missing_temperature_names_the_file_and_the_keyword() {
    let dir = tempfile::tempdir().unwrap();
    let (set, mut paths) = written(dir.path());
    let (frame, _, _, _) = set.render(0).unwrap();
    let bad = dir.path().join("notemp.fits");
    write_raw_frame(&bad, &frame, &[("EXPOSURE", 0.0)]).unwrap();
    write_string_keys(
        &bad,
        &[
            ("IMAGETYP", "Bias Frame"),
            ("DATE-OBS", "2026-03-01T00:00:00"),
        ],
    )
    .unwrap();
    paths.push(bad);
    let s = err(&paths, &set.geometry);
    assert!(
        s.contains("notemp.fits") && s.contains("CCDTEMP") && s.contains("CCD-TEMP"),
        "{s}"
    );
}

#[test]
fn imagetyp_spellings_of_acquisition_programs() {
    use startrack_lab::calib_frames::FrameKind::{Bias, Dark, Flat, Light};
    use startrack_lab::calib_frames::read::frame_kind;
    for (s, k) in [
        ("BIAS", Bias),
        ("Bias Frame", Bias),
        ("zero", Bias),
        ("OFFSET", Bias),
        ("DARK", Dark),
        ("Dark Frame", Dark),
        ("FLAT", Flat),
        ("Flat Field", Flat),
        ("FLATFIELD", Flat),
        ("flat_frame", Flat),
        ("Light Frame", Light),
        ("LIGHT", Light),
        ("OBJECT", Light),
    ] {
        assert_eq!(frame_kind(s), Some(k), "{s}");
    }
    assert_eq!(frame_kind("Tricolor"), None);
}
