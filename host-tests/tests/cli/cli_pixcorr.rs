//! The pixel-phase correction end to end, as a user runs it: `startrack simulate --psf-a-px A`
//! -> `calib build --psf-a-px A` (curves in the table) -> `process --method cog1/cog2` (the
//! curve applied), against the simulator's truth and against the same frame processed with a
//! table without curves (plain CoG, flagged uncorrected).

use crate::common_cli;

use startrack_core::table::CalibTable;
use startrack_core::tracker::CentroidMethod;
use startrack_core::tracker::{StarFlags, StarRecord};
use startrack_homes::home::Processed;
use startrack_host::cli::process::{ProcessArgs, measure};
use startrack_host::cli::simulate::{SimFiles, SimulateArgs};
use startrack_lab::table_build::{CalibBuildArgs, build};
use std::path::{Path, PathBuf};

const SEED: u64 = 11;
const STARS: usize = 60;
/// The simulated PSF's 80 %-energy radius, px: undersampled, so the plain CoG's S-curve
/// (0.035 px at most for power 1 in a 5x5 box, 0.17 px for power 2) stands above the noise.
const A_PX: f64 = 0.6;

/// The simulated pixels clip at a 100 000 e- full well, which on output 2 (1.6 e-/ADU, bias
/// 1100 ADU) is 63 600 ADU, below the ADC's 65 535: flag from 62 000 ADU (97 000 e- there,
/// 91 500 e- on output 1) so that a clipped star (a = 0.6 px puts up to 70 % of 1.9e5 e- in
/// one pixel) is flagged saturated rather than read as a biased centroid.
const SATURATION_ADU: u16 = 62_000;

fn simulate(dir: &Path) -> SimFiles {
    startrack_host::cli::simulate::run(&SimulateArgs {
        out: dir.to_path_buf(),
        seed: SEED,
        stars: STARS,
        dark_e: 250.0,
        read_noise_e: 5.0,
        dsnu: 0.1,
        prnu: 0.02,
        psf_a_px: Some(A_PX),
        measured_frames: 0,
        mix: Default::default(),
    })
    .expect("simulate")
}

fn build_args(f: &SimFiles, out: PathBuf, psf_a_px: Option<String>) -> CalibBuildArgs {
    CalibBuildArgs {
        saturation_adu: SATURATION_ADU,
        psf_a_px,
        ..common_cli::build_args(f, out)
    }
}

fn process(frame: &Path, table: &Path, method: CentroidMethod, psf_a_px: Option<f32>) -> Processed {
    process_window(frame, table, method, psf_a_px, 7)
}

fn process_window(
    frame: &Path,
    table: &Path,
    method: CentroidMethod,
    psf_a_px: Option<f32>,
    window: u16,
) -> Processed {
    measure(&ProcessArgs {
        frame: frame.to_path_buf(),
        calib: table.to_path_buf(),
        method: Some(method),
        window: Some(window),
        psf_sigma: None,
        psf_a_px,
        exposure_s: None,
        temperature_k: None,
        background_stride: None,
        out: None,
    })
    .expect("process")
}

fn truth(path: &Path) -> Vec<(f64, f64, f64)> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (v[0], v[1], v[3])
        })
        .collect()
}

/// A folder with the simulated frame, a table with curves and one without.
struct Setup {
    _dir: tempfile::TempDir,
    files: SimFiles,
    with_curves: PathBuf,
    without: PathBuf,
    notes: Vec<String>,
}

fn setup() -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let files = simulate(dir.path());
    let with_curves = dir.path().join("pixcorr.bin");
    let without = dir.path().join("plain.bin");
    let (bytes, report) = build(&build_args(
        &files,
        with_curves.clone(),
        Some(format!("{A_PX}")),
    ))
    .unwrap();
    std::fs::write(&with_curves, bytes).unwrap();
    let (bytes, _) = build(&build_args(&files, without.clone(), None)).unwrap();
    std::fs::write(&without, bytes).unwrap();
    Setup {
        _dir: dir,
        files,
        with_curves,
        without,
        notes: report.notes,
    }
}

/// Per truth star, the errors (x, y) of the nearest row and its sigmas, for rows within
/// 1 px whose flags (other than [`StarFlags::UNCORRECTED`]) are clear.
fn errors(result: &Processed, truth: &[(f64, f64, f64)]) -> Vec<Option<[f64; 4]>> {
    let d = |r: &StarRecord, t: &(f64, f64, f64)| {
        (f64::from(r.x_px) - t.0).hypot(f64::from(r.y_px) - t.1)
    };
    truth
        .iter()
        .map(|t| {
            let r = result
                .stars
                .iter()
                .min_by(|a, b| d(a, t).total_cmp(&d(b, t)))?;
            // The plain CoG's own flags (uncorrected, so its sigma unreliable) aside.
            let clean = (r.flags - StarFlags::UNCORRECTED - StarFlags::SIGMA_UNRELIABLE).is_empty();
            (d(r, t) < 1.0 && clean).then(|| {
                let c = r;
                [
                    f64::from(c.x_px) - t.0,
                    f64::from(c.y_px) - t.1,
                    f64::from(c.sigma_x_px),
                    f64::from(c.sigma_y_px),
                ]
            })
        })
        .collect()
}

#[test]
fn calib_build_adds_the_curves_and_reports_them() {
    let s = setup();
    let bytes = std::fs::read(&s.with_curves).unwrap();
    let t = CalibTable::parse(&bytes).unwrap();
    // Boxes 5 and 7, powers 1 and 2, one width: four curves, each reported; plus the
    // tracking path's given-background power-1 curves for the same boxes (two).
    assert_eq!(t.pixcorr().len(), 6);
    assert_eq!(
        s.notes
            .iter()
            .filter(|n| n.starts_with("tracking curve (given background): a 0.6 px"))
            .count(),
        2,
        "{:?}",
        s.notes
    );
    for c in t.pixcorr().iter() {
        let a = c.header().a_px.to_num::<f64>();
        assert!((a - A_PX).abs() <= 1.0 / 256.0, "curve a {a}");
    }
    assert_eq!(
        s.notes
            .iter()
            .filter(|n| n.starts_with("pixel-phase curve: a 0.6 px"))
            .count(),
        4,
        "{:?}",
        s.notes
    );
    let plain = std::fs::read(&s.without).unwrap();
    assert!(CalibTable::parse(&plain).unwrap().pixcorr().is_empty());
    // The tracker's CoG with the flight window (power 1, box 5, median perimeter) finds
    // its curve in a table built with the default boxes.
    let fw = t.pixcorr().find(
        startrack_core::table::pixcorr::CogPower::One,
        startrack_core::tracker::TrackerConfig::FLIGHT.box_px(),
        startrack_core::table::pixcorr::PixCorrBackground::PerimeterMedian,
        1.2,
    );
    assert!(fw.is_some());
    // The frame carries the width for `process`.
    let keys = startrack_sim::fits::read_keys(&s.files.frame, &["PSFA"]).unwrap();
    assert_eq!(keys, vec![("PSFA".to_string(), A_PX)]);
}

/// The corrected CoG beats the plain one on the same frame, and its errors agree with its
/// sigmas. Bounds from counts: the mean of the per-axis differences `u^2 - c^2` (plain minus
/// corrected squared error) must exceed 4 standard errors of that mean (same noise in both:
/// the difference is the removed bias); the corrected chi^2 per degree of freedom must be
/// below (1.2)^2 (the required 20 % on sigma) plus 4 standard deviations of a chi^2/dof,
/// 4 sqrt(2 / dof).
#[test]
fn cog_with_the_tables_curve_beats_the_plain_cog_and_matches_its_sigma() {
    let s = setup();
    let truth = truth(&s.files.truth);
    assert!(truth.iter().all(|t| t.2 == A_PX));
    // Window 7 (box 5) is the flight window; window 9 (box 7) the other default curve box.
    for (method, window) in [
        (CentroidMethod::Cog1, 7),
        (CentroidMethod::Cog2, 7),
        (CentroidMethod::Cog1, 9),
    ] {
        // No width option: `process` reads PSFA from the frame.
        let corrected = process_window(&s.files.frame, &s.with_curves, method, None, window);
        let plain = process_window(&s.files.frame, &s.without, method, None, window);
        let h = corrected.curve.expect("a curve was applied");
        assert_eq!(u16::from(h.box_side), window - 2);
        assert!(plain.curve.is_none());
        assert!(
            corrected
                .stars
                .iter()
                .all(|r| !r.flags.contains(StarFlags::UNCORRECTED))
        );
        assert!(
            plain
                .stars
                .iter()
                .all(|r| r.flags.contains(StarFlags::UNCORRECTED)),
            "a plain CoG must be flagged uncorrected"
        );
        assert!(
            plain
                .stars
                .iter()
                .filter(|r| r.is_centroid())
                .all(|r| r.flags.contains(StarFlags::SIGMA_UNRELIABLE)),
            "a plain CoG's sigma (no pixelisation bias in it) must be flagged unreliable"
        );
        let (ec, ep) = (errors(&corrected, &truth), errors(&plain, &truth));
        let (mut diffs, mut chi2, mut sc, mut sp) = (Vec::new(), 0.0, 0.0, 0.0);
        for (c, p) in ec.iter().zip(&ep) {
            let (Some(c), Some(p)) = (c, p) else { continue };
            for axis in 0..2 {
                diffs.push(p[axis] * p[axis] - c[axis] * c[axis]);
                chi2 += (c[axis] / c[axis + 2]).powi(2);
                sc += c[axis] * c[axis];
                sp += p[axis] * p[axis];
            }
        }
        let n = diffs.len() as f64;
        assert!(n >= 2.0 * 0.9 * STARS as f64, "{n} axes measured");
        let mean = diffs.iter().sum::<f64>() / n;
        let var = diffs.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0);
        let se = (var / n).sqrt();
        let per_dof = chi2 / n;
        let band = 1.2f64.powi(2) + 4.0 * (2.0 / n).sqrt();
        eprintln!(
            "{method:?}, a {A_PX} px, window {window}: RMS error {:.4} px corrected, {:.4} px plain over {} axes; mean u^2 - c^2 {mean:.3e} (SE {se:.1e}); corrected chi2/dof {per_dof:.3} (limit {band:.3})",
            (sc / n).sqrt(),
            (sp / n).sqrt(),
            n
        );
        assert!(
            mean > 4.0 * se,
            "{method:?}: correction gains {mean} ± {se}"
        );
        assert!(per_dof < band, "{method:?}: chi2/dof {per_dof} > {band}");
    }
}

/// A width the table has no curve for (beyond the 10 % tolerance) is flagged, never
/// silently left uncorrected; methods without a correction are never flagged.
#[test]
fn no_matching_curve_sets_the_uncorrected_flag() {
    let s = setup();
    let far = process(
        &s.files.frame,
        &s.with_curves,
        CentroidMethod::Cog1,
        Some(0.9),
    );
    assert!(far.curve.is_none());
    assert!(!far.stars.is_empty());
    assert!(
        far.stars
            .iter()
            .all(|r| r.flags.contains(StarFlags::UNCORRECTED))
    );
    let near = process(
        &s.files.frame,
        &s.with_curves,
        CentroidMethod::Cog1,
        Some(0.63),
    );
    assert!(near.curve.is_some());
    let fit = process(
        &s.files.frame,
        &s.with_curves,
        CentroidMethod::GaussFit,
        None,
    );
    assert!(fit.curve.is_none());
    assert!(
        fit.stars
            .iter()
            .all(|r| !r.flags.contains(StarFlags::UNCORRECTED))
    );
}

/// The binary: `calib build --psf-a-px` prints each curve, `process --method cog1` says which
/// curve it used, and an impossible curve is reported, not fatal.
#[test]
fn the_binary_reports_curves_built_and_used() {
    let s = setup();
    let dir = s.with_curves.parent().unwrap();
    let out = dir.join("bin.bin");
    let run = common_cli::startrack;
    let (ok, stdout, stderr) = run(&[
        "calib",
        "build",
        "--out",
        out.to_str().unwrap(),
        "--gains",
        "1.5,1.6",
        "--psf-a-px",
        "1.0,0.5",
        "--pixcorr-boxes",
        "5",
    ]);
    assert!(ok, "{stderr}");
    // a = 0.5 px, power 2: the CoG is not invertible (see core/src/centroid/pixcorr.rs).
    assert!(
        stdout.contains("no pixel-phase curve for a 0.5 px, box 5, power 2"),
        "{stdout}"
    );
    assert_eq!(
        stdout.matches("pixel-phase curve: a ").count(),
        3,
        "{stdout}"
    );
    let (ok, _, stderr) = run(&[
        "process",
        s.files.frame.to_str().unwrap(),
        "--calib",
        s.with_curves.to_str().unwrap(),
        "--method",
        "cog1",
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("pixel-phase curve a 0.602 px box 5"),
        "{stderr}"
    );
    let (ok, _, stderr) = run(&[
        "calib",
        "build",
        "--out",
        out.to_str().unwrap(),
        "--gains",
        "1.5,1.6",
        "--psf-a-px",
        "1,x",
    ]);
    assert!(!ok && stderr.contains("--psf-a-px"), "{stderr}");
    let (ok, _, stderr) = run(&[
        "process",
        s.files.frame.to_str().unwrap(),
        "--calib",
        s.with_curves.to_str().unwrap(),
        "--psf-a-px",
        "0",
    ]);
    assert!(!ok && stderr.lines().count() == 1, "{stderr}");
    assert!(stderr.contains("PSF 80 % radius"), "{stderr}");
}
