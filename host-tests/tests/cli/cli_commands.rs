//! The user commands end to end: `startrack simulate` -> `calib build` -> `process` in a
//! temporary folder, checked against the simulator's truth, and every bad-input path of the
//! binary (one-line error, non-zero exit, no panic).

use crate::common_cli;

use common_cli::{build_args, startrack};
use startrack_core::table::CalibTable;
use startrack_core::tracker::CentroidMethod;
use startrack_homes::home::CSV_HEADER;
use startrack_host::cli::process::{ProcessArgs, measure};
use startrack_host::cli::simulate::{SimFiles, SimulateArgs};
use startrack_lab::table_build::{CalibBuildArgs, build};
use startrack_sim::fits::{MapF32, RawFrame, write_map, write_raw_frame};
use startrack_sim::sim::Simulator;
use startrack_sim::sim::truth::TruthSections;
use std::path::{Path, PathBuf};

const SEED: u64 = 5;
const STARS: usize = 40;

fn simulate(dir: &Path, seed: u64, stars: usize) -> SimFiles {
    startrack_host::cli::simulate::run(&SimulateArgs {
        out: dir.to_path_buf(),
        seed,
        stars,
        dark_e: 250.0,
        read_noise_e: 5.0,
        dsnu: 0.1,
        prnu: 0.02,
        psf_a_px: None,
        measured_frames: 0,
        mix: Default::default(),
    })
    .expect("simulate")
}

fn process_args(frame: &Path, table: &Path) -> ProcessArgs {
    ProcessArgs {
        frame: frame.to_path_buf(),
        calib: table.to_path_buf(),
        method: Some(CentroidMethod::GaussFit),
        window: Some(7),
        psf_sigma: Some(0.78),
        psf_a_px: None,
        exposure_s: None,
        temperature_k: None,
        background_stride: None,
        out: None,
    }
}

/// A folder with a simulated frame and a table built from its maps.
fn setup(stars: usize) -> (tempfile::TempDir, SimFiles, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let files = simulate(dir.path(), SEED, stars);
    let table = dir.path().join("table.bin");
    let (bytes, _) = build(&build_args(&files, table.clone())).unwrap();
    std::fs::write(&table, bytes).unwrap();
    (dir, files, table)
}

fn truth(path: &Path) -> Vec<(f64, f64)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x_px,y_px,signal_e,a_px"));
    lines
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            assert_eq!(v.len(), 4);
            (v[0], v[1])
        })
        .collect()
}

#[test]
fn simulate_build_process_finds_the_stars_within_their_sigmas() {
    let (_dir, files, table) = setup(STARS);
    let truth = truth(&files.truth);
    assert_eq!(truth.len(), STARS);
    let result = measure(&process_args(&files.frame, &table)).unwrap();

    // Every simulated star (>= 5000 e-, SNR >= ~50) is found within 2 px, or sits in a
    // detection flagged blended (a close pair); every detection is a star.
    let dist = |r: &startrack_core::tracker::StarRecord, t: (f64, f64)| {
        (f64::from(r.x_px) - t.0).hypot(f64::from(r.y_px) - t.1)
    };
    let (mut found, mut blended, mut chi2, mut k) = (0, 0, 0.0, 0usize);
    for t in &truth {
        let best = result
            .stars
            .iter()
            .min_by(|a, b| dist(a, *t).total_cmp(&dist(b, *t)))
            .expect("some detection");
        if dist(best, *t) < 2.0 && best.flags.is_empty() {
            found += 1;
            let c = best;
            chi2 += ((f64::from(c.x_px) - t.0) / f64::from(c.sigma_x_px)).powi(2)
                + ((f64::from(c.y_px) - t.1) / f64::from(c.sigma_y_px)).powi(2);
            k += 2;
        } else {
            assert!(
                dist(best, *t) < 6.0 && !best.flags.is_empty(),
                "star at {t:?} not found (nearest {best:?})"
            );
            blended += 1;
        }
    }
    for r in &result.stars {
        assert!(
            truth.iter().any(|t| dist(r, *t) < 6.0),
            "false detection {r:?}"
        );
    }
    // Close pairs: with 40 stars on 1024^2 px, the expected number of pairs within 6 px is
    // 40*39/2 * pi 6^2 / 1024^2 = 0.08; allow 2 stars (one pair) in blends.
    assert!(blended <= 2, "{blended} stars in blends, {found} found");
    // Positions: chi^2 of the errors against the reported sigmas, 5-sigma band on k axes.
    let band = 5.0 * (2.0 / k as f64).sqrt();
    let per_dof = chi2 / k as f64;
    eprintln!(
        "simulate -> calib build -> process: {found} of {} found unflagged, {blended} in blends, {} detections, position chi2/dof {per_dof:.3} (band 1 ± {band:.3})",
        truth.len(),
        result.stars.len()
    );
    assert!(
        (1.0 - band..1.0 + band).contains(&per_dof),
        "chi2/dof {per_dof:.3} outside 1 ± {band:.3} ({found} stars)"
    );
}

#[test]
fn calib_build_recovers_the_true_table_to_one_lsb() {
    let dir = tempfile::tempdir().unwrap();
    let files = simulate(dir.path(), 9, 0);
    let (bytes, report) = build(&build_args(&files, dir.path().join("t.bin"))).unwrap();
    assert!(report.notes.iter().any(|n| n.contains("GAIN1/GAIN2")));
    let built = CalibTable::parse(&bytes).unwrap();
    let params = startrack_host::cli::simulate::params(&SimulateArgs {
        out: dir.path().to_path_buf(),
        seed: 9,
        stars: 0,
        dark_e: 250.0,
        read_noise_e: 5.0,
        dsnu: 0.1,
        prnu: 0.02,
        psf_a_px: None,
        measured_frames: 0,
        mix: Default::default(),
    })
    .unwrap();
    let sim = Simulator::new(params, Vec::new());
    let truth_bytes = sim.truth_table(TruthSections::ALL).unwrap();
    let truth = CalibTable::parse(&truth_bytes).unwrap();
    let g = *truth.geometry();
    assert_eq!(built.geometry(), truth.geometry());
    for o in 0..g.outputs {
        let o = startrack_core::geometry::Output(o);
        // f32 keywords: the gain survives to f32 precision (2^-24 relative).
        let (a, b) = (built.gain(o).to_num::<f64>(), truth.gain(o).to_num::<f64>());
        assert!((a - b).abs() <= b * 1e-7, "gain {a} vs {b}");
    }
    // Column bias: the map's offsets above the over-scan median are the simulated column
    // pattern (f32 map: exact to far below the 1/16 ADU step), so at most 1 LSB apart.
    for c in 0..g.line_len() {
        let d = (built.column_bias(c) - truth.column_bias(c))
            .to_bits()
            .abs();
        assert!(d <= 1, "column {c}: {d} LSB");
    }
    for y in 0..g.active_rows {
        for x in 0..g.active_cols {
            let dd = i32::from(built.dark_rel(x, y).to_bits())
                - i32::from(truth.dark_rel(x, y).to_bits());
            let df = i32::from(built.flat_inv(x, y).to_bits())
                - i32::from(truth.flat_inv(x, y).to_bits());
            assert!(
                dd.abs() <= 1 && df.abs() <= 1,
                "({x},{y}): dark {dd}, flat {df} LSB"
            );
        }
    }
}

#[test]
fn missing_maps_give_no_section_and_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    let args = CalibBuildArgs {
        bias: None,
        dark: None,
        flat: None,
        hot: None,
        gains: Some("1.5,1.6".into()),
        ..build_args(&SimFiles::in_dir(dir.path()), dir.path().join("t.bin"))
    };
    let (bytes, report) = build(&args).unwrap();
    let t = CalibTable::parse(&bytes).unwrap();
    assert!(!t.has_column_bias() && t.dark_map().is_none() && t.flat_map().is_none());
    assert!(t.hot_pixels().is_empty());
    for what in [
        "no bias map",
        "no dark map",
        "no flat map",
        "no hot pixel list",
    ] {
        assert!(report.notes.iter().any(|n| n.starts_with(what)), "{what}");
    }
}

#[test]
fn hot_csv_becomes_sorted_active_entries() {
    let dir = tempfile::tempdir().unwrap();
    let hot = dir.path().join("hot.csv");
    // Full-readout columns: 24 is active x = 0; 3 is over-scan (skipped).
    std::fs::write(&hot, "col,row,dark_e\n100,7,500\n24,3,20000\n3,3,50\n").unwrap();
    let args = CalibBuildArgs {
        bias: None,
        dark: None,
        flat: None,
        hot: Some(hot),
        gains: Some("1.5,1.6".into()),
        ..build_args(&SimFiles::in_dir(dir.path()), dir.path().join("t.bin"))
    };
    let (bytes, report) = build(&args).unwrap();
    let t = CalibTable::parse(&bytes).unwrap();
    let h = t.hot_pixels();
    assert_eq!(h.len(), 2);
    let (a, b) = (h.get(0).unwrap(), h.get(1).unwrap());
    assert_eq!(
        (a.x, a.y, a.policy),
        (0, 3, startrack_core::table::HotPolicy::Exclude)
    );
    assert_eq!(
        (b.x, b.y, b.policy),
        (76, 7, startrack_core::table::HotPolicy::Correct)
    );
    assert_eq!(b.rate_e_per_s.to_num::<f64>(), 500.0);
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.contains("1 outside the active area"))
    );
}

/// A failure is one line on standard error, prefixed with the command, no panic.
fn assert_one_line_error(args: &[&str], prefix: &str, contains: &str) {
    let (ok, stdout, stderr) = startrack(args);
    assert!(!ok, "{args:?} succeeded");
    assert!(stdout.is_empty(), "{args:?} printed {stdout}");
    assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
    assert!(stderr.starts_with(prefix), "{args:?}: {stderr}");
    assert!(
        stderr.contains(contains),
        "{args:?}: {stderr} lacks {contains:?}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn process_binary_writes_csv_and_rejects_bad_input_in_one_line() {
    let (dir, files, table) = setup(4);
    let d = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let (frame, table) = (
        files.frame.to_string_lossy().into_owned(),
        table.to_string_lossy().into_owned(),
    );

    // Good input: CSV on stdout, with the documented header, one row per star.
    let (ok, stdout, _) = startrack(&["process", &frame, "--calib", &table, "--method", "cog1"]);
    assert!(ok);
    let mut lines = stdout.lines();
    assert_eq!(lines.next(), Some(CSV_HEADER));
    assert_eq!(lines.count(), 4);
    let out = d("stars.csv");
    let (ok, stdout, _) = startrack(&["process", &frame, "--calib", &table, "--out", &out]);
    assert!(ok && stdout.is_empty());
    assert_eq!(std::fs::read_to_string(&out).unwrap().lines().count(), 5);

    let p = "startrack process: ";
    assert_one_line_error(
        &["process", &d("none.fits"), "--calib", &table],
        p,
        "none.fits",
    );
    assert_one_line_error(
        &["process", &frame, "--calib", &d("none.bin")],
        p,
        "none.bin",
    );
    std::fs::write(d("text.fits"), "not a FITS file\n".repeat(300)).unwrap();
    assert_one_line_error(
        &["process", &d("text.fits"), "--calib", &table],
        p,
        "not a FITS file",
    );
    write_raw_frame(
        &dir.path().join("small.fits"),
        &RawFrame {
            lines: 1024,
            cols: 1024,
            data_adu: vec![1000; 1024 * 1024],
        },
        &[],
    )
    .unwrap();
    assert_one_line_error(
        &["process", &d("small.fits"), "--calib", &table],
        p,
        "wrong shape",
    );
    write_map(
        &dir.path().join("float.fits"),
        &MapF32 {
            rows: 1033,
            cols: 1072,
            data: vec![1000.0; 1033 * 1072],
            keys: vec![],
        },
    )
    .unwrap();
    assert_one_line_error(
        &["process", &d("float.fits"), "--calib", &table],
        p,
        "wrong sample type",
    );
    let mut bytes = std::fs::read(&table).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x10;
    std::fs::write(d("corrupt.bin"), &bytes).unwrap();
    assert_one_line_error(
        &["process", &frame, "--calib", &d("corrupt.bin")],
        p,
        "not a usable calibration table",
    );
    assert_one_line_error(
        &["process", &frame, "--calib", &frame],
        p,
        "not a usable calibration table",
    );
    assert_one_line_error(
        &["process", &frame, "--calib", &table, "--window", "4"],
        p,
        "window 4",
    );
}

#[test]
fn calib_build_and_simulate_binaries_reject_bad_input_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n).to_string_lossy().into_owned();
    let c = "startrack calib build: ";
    let out = d("t.bin");
    assert_one_line_error(&["calib", "build", "--out", &out], c, "no gains");
    assert_one_line_error(
        &["calib", "build", "--out", &out, "--gains", "1.5"],
        c,
        "2 values",
    );
    assert_one_line_error(
        &["calib", "build", "--out", &out, "--gains", "1.5,-1"],
        c,
        "gain -1",
    );
    std::fs::write(d("hot.csv"), "col,row,dark_e\n100,7\n").unwrap();
    assert_one_line_error(
        &[
            "calib",
            "build",
            "--out",
            &out,
            "--gains",
            "1.5,1.6",
            "--hot",
            &d("hot.csv"),
        ],
        c,
        "hot.csv:2",
    );
    write_map(
        &dir.path().join("flat.fits"),
        &MapF32 {
            rows: 1033,
            cols: 1072,
            data: vec![1.0; 1033 * 1072],
            keys: vec![],
        },
    )
    .unwrap();
    assert_one_line_error(
        &[
            "calib",
            "build",
            "--out",
            &out,
            "--gains",
            "1.5,1.6",
            "--flat",
            &d("flat.fits"),
        ],
        c,
        "wrong shape",
    );
    assert_one_line_error(
        &[
            "calib",
            "build",
            "--out",
            &out,
            "--gains",
            "1.5,1.6",
            "--bias",
            &d("none.fits"),
        ],
        c,
        "none.fits",
    );
    assert_one_line_error(
        &["simulate", "--out", &d("sim"), "--dsnu=-1"],
        "startrack simulate: ",
        "--dsnu",
    );
}

/// Every method through `process` on the same simulated frame: each star is measured,
/// inside its pixel's neighbourhood (the worst noise-free bias in the core's method table is
/// the power-1 CoG 5x5's 0.049 px at a = 0.5; 0.5 px leaves room for the faintest stars' noise, whose
/// sigma is below 0.03 px here). Prints RMS error and chi^2/dof per method
/// (`--nocapture`).
#[test]
fn every_method_measures_every_star() {
    let (_dir, files, table) = setup(STARS);
    let truth = truth(&files.truth);
    for method in [
        CentroidMethod::Cog1,
        CentroidMethod::Cog2,
        CentroidMethod::GaussFit,
    ] {
        let result = measure(&ProcessArgs {
            method: Some(method),
            ..process_args(&files.frame, &table)
        })
        .unwrap();
        assert_eq!(result.stars.len(), truth.len(), "{method:?}");
        let (mut sum2, mut chi2, mut k) = (0.0, 0.0, 0usize);
        for t in &truth {
            let c = result
                .stars
                .iter()
                .min_by(|a, b| {
                    let d = |c: &startrack_core::tracker::StarRecord| {
                        (f64::from(c.x_px) - t.0).hypot(f64::from(c.y_px) - t.1)
                    };
                    d(a).total_cmp(&d(b))
                })
                .unwrap();
            let (ex, ey) = (f64::from(c.x_px) - t.0, f64::from(c.y_px) - t.1);
            assert!(
                ex.abs() < 0.5 && ey.abs() < 0.5,
                "{method:?}: star {t:?} measured at ({}, {})",
                c.x_px,
                c.y_px
            );
            sum2 += ex * ex + ey * ey;
            chi2 += (ex / f64::from(c.sigma_x_px)).powi(2) + (ey / f64::from(c.sigma_y_px)).powi(2);
            k += 2;
        }
        eprintln!(
            "{method:?}: RMS error {:.4} px per axis, chi2/dof {:.2} over {} stars",
            (sum2 / k as f64).sqrt(),
            chi2 / k as f64,
            k / 2
        );
    }
}

/// `simulate --measured-frames N` writes dark and flat maps with the calibration noise of N
/// frames: their scatter about the truth matches the shot and read noise of N frames, and the
/// pipeline still finds every star with them.
#[test]
fn measured_maps_carry_the_noise_of_n_frames_and_still_calibrate() {
    const N: u32 = 4;
    let dir = tempfile::tempdir().unwrap();
    let args = SimulateArgs {
        out: dir.path().to_path_buf(),
        seed: 3,
        stars: 20,
        dark_e: 250.0,
        read_noise_e: 5.0,
        dsnu: 0.1,
        prnu: 0.02,
        psf_a_px: None,
        measured_frames: N,
        mix: Default::default(),
    };
    let files = startrack_host::cli::simulate::run(&args).unwrap();
    let sim = Simulator::new(
        startrack_host::cli::simulate::params(&args).unwrap(),
        Vec::new(),
    );
    let g = sim.params.geometry;
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    let x0 = g.first_active_col();
    let dark = startrack_sim::fits::read_map(&files.dark, &[]).unwrap();
    let flat = startrack_sim::fits::read_map(&files.flat, &[]).unwrap();
    let norm = sim.covered_dark_mean();
    // Relative dark: the error of pixel (x, y) is its dark shot noise and read noise over N
    // frames, relative to the covered mean: sqrt(d + r^2) / (mean sqrt N), d = rel * mean.
    let (mut dark_z2, mut flat_z2, mut n) = (0.0f64, 0.0f64, 0usize);
    let (dark_mean_e, read_e) = (sim.params.dark_mean_e, sim.params.read_noise_e);
    for y in (0..rows).step_by(7) {
        for x in (0..cols).step_by(5) {
            let truth_rel = sim.dark_rel(x0 + x, y) / norm;
            let measured = f64::from(dark.data[y * dark.cols + x0 + x]);
            let d_e = truth_rel * dark_mean_e;
            let sd = (d_e + read_e * read_e).sqrt() / (dark_mean_e * f64::from(N).sqrt());
            dark_z2 += ((measured - truth_rel) / sd).powi(2);
            // Flat: shot noise of the flat level plus the dark and read noise, over N frames.
            let level = startrack_host::cli::simulate::FLAT_LEVEL_E * sim.flat(x, y);
            let sf = (level + d_e + read_e * read_e).sqrt()
                / (startrack_host::cli::simulate::FLAT_LEVEL_E * f64::from(N).sqrt());
            let measured_flat = f64::from(flat.data[y * cols + x]);
            flat_z2 += ((measured_flat - sim.flat(x, y)) / sf).powi(2);
            n += 1;
        }
    }
    let (dark_rms_z, flat_rms_z) = ((dark_z2 / n as f64).sqrt(), (flat_z2 / n as f64).sqrt());
    eprintln!(
        "measured maps, N = {N}: dark error / predicted {dark_rms_z:.3}, flat {flat_rms_z:.3} ({n} px)"
    );
    // With n ~ 30 000 samples the RMS of a unit normal is 1 within ~0.4 %; the bounds leave
    // room for the model's approximations (the flat's normalisation to its measured mean,
    // the ADC's quantisation of 1/sqrt(12) ADU, the covered mean's own noise).
    assert!((0.9..1.1).contains(&dark_rms_z), "dark {dark_rms_z}");
    assert!((0.9..1.1).contains(&flat_rms_z), "flat {flat_rms_z}");

    // The pipeline with the measured maps still finds every star, none false.
    let table = dir.path().join("measured.bin");
    let (bytes, _) = build(&build_args(&files, table.clone())).unwrap();
    std::fs::write(&table, bytes).unwrap();
    let result = measure(&process_args(&files.frame, &table)).unwrap();
    let truth = truth(&files.truth);
    for t in &truth {
        assert!(
            result
                .stars
                .iter()
                .any(|r| (f64::from(r.x_px) - t.0).hypot(f64::from(r.y_px) - t.1) < 2.0),
            "star at {t:?} not found with measured maps"
        );
    }
    assert!(result.stars.len() <= truth.len() + 1);
}

/// The removed methods (IWC, the log-parabolic and the parabolic 3-point peaks) are no
/// `--method` value any more: the argument parser refuses them before any file is read,
/// naming the valid values, with a non-zero exit and no panic. (clap's usage error: its
/// first line says what is wrong, the next lists the possible values.)
#[test]
fn removed_methods_are_refused_by_the_parser() {
    for method in ["iwc", "log-quadratic", "quadratic"] {
        let args = [
            "process",
            "none.fits",
            "--calib",
            "none.bin",
            "--method",
            method,
        ];
        let (ok, stdout, stderr) = startrack(&args);
        assert!(!ok, "{args:?} succeeded");
        assert!(stdout.is_empty(), "{args:?} printed {stdout}");
        let first = stderr.lines().next().unwrap_or_default();
        assert!(
            first.starts_with("error: invalid value") && first.contains(method),
            "{stderr}"
        );
        assert!(stderr.contains("cog1, cog2, gauss-fit"), "{stderr}");
        assert!(!stderr.contains("none.fits"), "read a file: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

/// `startrack sil`'s spacecraft options: a velocity as VX,VY,VZ (negative components too)
/// sets the scene's aberration and the clock; bad values are one-line errors.
#[test]
fn sil_velocity_and_time_options_parse_and_refuse_bad_values() {
    use clap::Parser;
    use startrack_host::cli::sil::{SilArgs, config_of};
    #[derive(Parser)]
    struct Wrap {
        #[command(flatten)]
        sil: SilArgs,
    }
    let parse = |args: &[&str]| {
        let w = Wrap::try_parse_from(std::iter::once("sil").chain(args.iter().copied()))
            .expect("parses");
        config_of(&w.sil)
    };
    let c = parse(&["--sky", "--velocity-km-s", "-1.5,30,0"]).expect("valid");
    assert_eq!(c.velocity_m_s, Some([-1500.0, 30_000.0, 0.0]));
    assert_eq!(
        c.spacecraft_epoch_us,
        Some(startrack_homes::sil::SIL_EPOCH_US)
    );
    assert!(c.send_velocity);
    let c = parse(&["--sky", "--velocity-km-s", "0,30,0", "--apparent"]).expect("valid");
    assert!(!c.send_velocity);
    let c = parse(&[
        "--sky",
        "--spacecraft-time-s",
        "2000000000.5",
        "--counter-ppm",
        "-40",
    ])
    .expect("valid");
    assert_eq!(c.spacecraft_epoch_us, Some(2_000_000_000_500_000));
    assert_eq!((c.counter_rate_ppm, c.velocity_m_s), (-40.0, None));
    assert!(parse(&["--sky", "--counter-ppm", "300", "--spacecraft-time-s", "1"]).is_err());
    let s = "startrack sil: ";
    assert_one_line_error(
        &["sil", "--sky", "--velocity-km-s", "0,400,0"],
        s,
        "300 km/s",
    );
    assert_one_line_error(&["sil", "--sky", "--velocity-km-s", "1,2"], s, "VX,VY,VZ");
    assert_one_line_error(&["sil", "--sky", "--spacecraft-time-s", "5e9"], s, "4e9");
}

/// `startrack pil` takes `startrack sil`'s scene options (one flattened set) and compares the
/// firmware with the SIL that `startrack sil` runs on that scene, every other option at its
/// default; only the frame count's default differs (5 against 20).
#[test]
fn pil_runs_the_sils_scene_options() {
    use clap::Parser;
    use startrack_host::cli::pil::PilArgs;
    use startrack_host::cli::sil::{SilArgs, config_of};
    #[derive(Parser)]
    struct Sil {
        #[command(flatten)]
        args: SilArgs,
    }
    #[derive(Parser)]
    struct Pil {
        #[command(flatten)]
        args: PilArgs,
    }
    fn with(frames: Option<&'static str>) -> Vec<&'static str> {
        let mut v = vec!["x", "--sky", "--seed", "7", "--drift-px", "0.5", "0.25"];
        v.extend(frames.map(|f| ["--frames", f]).into_iter().flatten());
        v
    }
    let pil = Pil::try_parse_from(with(Some("3")))
        .expect("pil parses")
        .args;
    let sil = Sil::try_parse_from(with(Some("3")))
        .expect("sil parses")
        .args;
    let of_pil = SilArgs::of_scene(pil.scene).expect("defaults");
    assert_eq!(
        config_of(&of_pil).expect("valid"),
        config_of(&sil).expect("valid")
    );
    let pil = Pil::try_parse_from(with(None)).expect("pil parses").args;
    let sil = Sil::try_parse_from(with(None)).expect("sil parses").args;
    assert_eq!((pil.scene.frames, sil.scene.frames), (5, 20));
}
