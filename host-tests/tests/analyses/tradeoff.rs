//! `startrack tradeoff`'s logic: the Pareto frontier on hand-made points, the M7 cost table
//! and its mapping to the methods, the run's determinism, and the command's bad inputs.

use crate::common_cli;

use common_cli::startrack;
use startrack_analysis::accuracy::{Method, Noise};
use startrack_analysis::figures::Written;
use startrack_analysis::tradeoff::cost::{M7Table, m7_cost};
use startrack_analysis::tradeoff::failures::{self, MapSpec, Perturb};
use startrack_analysis::tradeoff::pareto::frontier;
use startrack_analysis::tradeoff::{chart, write_chart, write_failures};
use startrack_core::table::pixcorr::CogPower;

#[test]
fn pareto_keeps_exactly_the_undominated_points() {
    // (cost, error): b is cheaper and better than c; d costs more than a with the same error.
    let pts = [
        (1.0, 5.0),           // a: cheapest
        (2.0, 2.0),           // b
        (3.0, 3.0),           // c: dominated by b
        (4.0, 5.0),           // d: dominated by a and b
        (5.0, 1.0),           // e: most accurate
        (5.0, 1.0),           // f: equal to e, neither dominates the other
        (f64::NAN, 0.1),      // no cost: never on it, dominates nothing
        (0.5, f64::INFINITY), // no error: never on it
    ];
    assert_eq!(
        frontier(&pts),
        vec![true, true, false, false, true, true, false, false]
    );
    assert!(frontier(&[]).is_empty());
    assert_eq!(frontier(&[(3.0, 3.0)]), vec![true]);
    // Equal cost, worse error: dominated.
    assert_eq!(frontier(&[(1.0, 1.0), (1.0, 2.0)]), vec![true, false]);
}

fn table() -> M7Table {
    M7Table::parse(
        "# calibration comment\nstage,unit,instructions_per_unit\n\
         centroid_cog1_5x5,star,1000\ncentroid_cog1_7x7,star,1960\n\
         centroid_cog2_5x5,star,1100\ncentroid_cog2_7x7,star,2100\n\
         centroid_cog1_given_bg_5x5,star,500\ncentroid_cog1_given_bg_7x7,star,980\n\
         centroid_gauss_fit_5x5,star,50000\ncentroid_gauss_fit_7x7,star,90000\n",
    )
    .unwrap()
}

#[test]
fn m7_costs_map_measured_extrapolated_and_estimated_stages() {
    let t = table();
    let cog = |power, box_side, corrected| Method::Cog {
        power,
        box_side,
        corrected,
    };
    let (c, basis) = m7_cost(&cog(CogPower::One, 5, false), &t).unwrap();
    assert_eq!((c, basis.as_str()), (500.0, "measured"));
    // Linear in the pixel count: 500 + (980 - 500) / 24 * (9 - 25) = 180.
    let (c, basis) = m7_cost(&cog(CogPower::One, 3, false), &t).unwrap();
    assert!((c - 180.0).abs() < 1e-9, "{c}");
    assert_eq!(basis, "extrapolated");
    // Power 2 given: cog1_given_bg + (cog2 - cog1) = 980 + 140.
    let (c, _) = m7_cost(&cog(CogPower::Two, 7, false), &t).unwrap();
    assert!((c - 1120.0).abs() < 1e-9, "{c}");
    // The correction is not counted: same as uncorrected, and said so.
    let (c, basis) = m7_cost(&cog(CogPower::One, 5, true), &t).unwrap();
    assert_eq!(c, 500.0);
    assert_eq!(basis, "measured; correction not counted");
    assert_eq!(
        m7_cost(&Method::GaussFit { window: 7 }, &t).unwrap().0,
        90000.0
    );
    // A method whose stages the table lacks (the Gauss fit without its 7x7 stage) gives no
    // cost, and the chart's cost column says so.
    let partial = M7Table::parse("centroid_gauss_fit_5x5,star,50000\n").unwrap();
    let fit = Method::GaussFit { window: 5 };
    assert!(m7_cost(&fit, &partial).is_none());
    let costs = chart::costs(&[fit], &partial, 0);
    assert_eq!(costs[0].0, None);
    assert_eq!(costs[0].1, "not in the M7 table");
}

#[test]
fn gauss_fit_cost_prefers_the_given_background_stage() {
    // With the Monte Carlo's stage (background given and held) in the CSV, that stage is the
    // cost, measured; the perimeter stage (background fitted) is only the fallback above.
    let text = "centroid_gauss_fit_5x5,star,50000\ncentroid_gauss_fit_7x7,star,90000\n\
                centroid_gauss_fit_given_bg_5x5,star,3000\n\
                centroid_gauss_fit_given_bg_7x7,star,4200\n";
    let t = M7Table::parse(text).unwrap();
    for (window, want) in [(5u8, 3000.0), (7, 4200.0)] {
        let (c, basis) = m7_cost(&Method::GaussFit { window }, &t).unwrap();
        assert_eq!((c, basis.as_str()), (want, "measured"), "window {window}");
    }
    // Other windows: linear in the pixel count through the given-background stages.
    let (c, basis) = m7_cost(&Method::GaussFit { window: 9 }, &t).unwrap();
    assert!((c - (4200.0 + 1200.0 / 24.0 * 32.0)).abs() < 1e-9, "{c}");
    assert_eq!(basis, "extrapolated");
    // Without them: the perimeter stage, labelled as the upper bound it is.
    let (c, basis) = m7_cost(&Method::GaussFit { window: 5 }, &table()).unwrap();
    assert_eq!(
        (c, basis.as_str()),
        (50000.0, "perimeter bg + background fitted")
    );
}

#[test]
fn m7_parse_rejects_malformed_rows() {
    assert!(M7Table::parse("").is_err());
    assert!(M7Table::parse("stage,unit,instructions_per_unit\n").is_err());
    let e = M7Table::parse("stage,unit,instructions_per_unit\na,star,12\nb,star\n").unwrap_err();
    assert_eq!(e.line, 3);
    assert!(M7Table::parse("a,star,abc\n").is_err());
    assert!(M7Table::parse("a,star,-1\n").is_err());
    assert!(M7Table::parse("a,star,NaN\n").is_err());
}

#[test]
fn committed_m7_costs_cover_every_method() {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/m7-costs.csv"))
        .expect("host-tests/m7-costs.csv (cargo m7-bench > host-tests/m7-costs.csv)");
    let t = M7Table::parse(&text).unwrap();
    for m in startrack_analysis::tradeoff::methods() {
        let (c, _) = m7_cost(&m, &t).unwrap_or_else(|| panic!("{} has no M7 cost", m.name()));
        assert!(c > 0.0, "{}: {c}", m.name());
    }
    // A CoG costs more in a bigger box, and the pixel-phase correction adds to it.
    let cog = |power, box_side, corrected| {
        m7_cost(
            &Method::Cog {
                power,
                box_side,
                corrected,
            },
            &t,
        )
        .unwrap()
        .0
    };
    for power in [CogPower::One, CogPower::Two] {
        for corrected in [false, true] {
            let (c3, c5, c7) = (
                cog(power, 3, corrected),
                cog(power, 5, corrected),
                cog(power, 7, corrected),
            );
            assert!(c3 < c5 && c5 < c7, "{c3} {c5} {c7}");
        }
        for side in [3, 5, 7] {
            assert!(cog(power, side, true) > cog(power, side, false));
        }
    }
    // The Gauss fit costs more than the power-1 CoGs of the same box (no longer more than
    // the power-2 ones: its held-background path is cheaper than a corrected power-2 7x7).
    let fit = m7_cost(&Method::GaussFit { window: 7 }, &t).unwrap().0;
    assert!(fit > cog(CogPower::One, 7, true) && fit > cog(CogPower::One, 7, false));
}

/// A small run of both outputs into `dir`.
fn small_run(dir: &std::path::Path) {
    let methods = vec![
        Method::Cog {
            power: CogPower::One,
            box_side: 5,
            corrected: true,
        },
        Method::Cog {
            power: CogPower::Two,
            box_side: 3,
            corrected: false,
        },
        Method::GaussFit { window: 5 },
    ];
    let noise = Noise {
        trials: 60,
        ..Noise::default()
    };
    let costs = chart::costs(&methods, &table(), 0);
    let rows = chart::rows(&methods, &costs, &noise, || {});
    let mut w = Written::default();
    write_chart(dir, &rows, &methods, &noise, "test table", &mut w).unwrap();
    let spec = MapSpec {
        grid_snr: vec![3.0, 30.0],
        grid_a_px: vec![0.5, 1.5],
        sweeps: vec![
            Perturb::Dsnu(0.2),
            Perturb::HotPixel(300.0),
            Perturb::Telegraph(300.0),
            Perturb::Saturation(2.0),
            Perturb::Edge(0),
            Perturb::Pair(2.0),
        ],
        trials: 40,
        ..MapSpec::new(true)
    };
    let cells = failures::run(&methods, &spec, || {});
    write_failures(dir, &methods, &spec, &cells, &mut w).unwrap();
}

#[test]
fn two_runs_write_identical_csvs() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    small_run(a.path());
    small_run(b.path());
    for name in ["tradeoff.csv", "failures.csv"] {
        let x = std::fs::read_to_string(a.path().join(name)).unwrap();
        let y = std::fs::read_to_string(b.path().join(name)).unwrap();
        assert_eq!(x, y, "{name} differs between two runs");
        // Every scene and method has a row: 12 chart cells x 3 methods; 10 scenes x 3.
        let rows = x.lines().filter(|l| !l.starts_with('#')).count() - 1;
        assert_eq!(rows, if name == "tradeoff.csv" { 36 } else { 30 }, "{name}");
        // No field holds a comma: every line has as many fields as the column names.
        let mut lines = x.lines().filter(|l| !l.starts_with('#'));
        let fields = lines.next().unwrap().split(',').count();
        for l in lines {
            assert_eq!(l.split(',').count(), fields, "{name}: {l}");
        }
    }
    // Without host timing the host_ns column is empty.
    let t = std::fs::read_to_string(a.path().join("tradeoff.csv")).unwrap();
    assert!(
        t.lines()
            .any(|l| l.starts_with("gauss fit 5x5,5,1,30,50000,perimeter bg + background fitted,,"))
    );
}

#[test]
fn bad_m7_file_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(
        &bad,
        "stage,unit,instructions_per_unit\ncentroid_x,star,many\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    for m7 in [bad.clone(), dir.path().join("missing.csv")] {
        let (ok, stdout, stderr) = startrack(&[
            "tradeoff",
            "--out",
            out.to_str().unwrap(),
            "--m7",
            m7.to_str().unwrap(),
        ]);
        assert!(!ok);
        assert!(stdout.is_empty(), "{stdout}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(stderr.starts_with("startrack tradeoff: "), "{stderr}");
    }
    assert!(!out.exists(), "nothing is written on a bad M7 file");
}

#[test]
fn corrected_power_1_cog_costs_the_cheaper_of_the_fused_and_general_paths() {
    // The fused raw path (calibration included) against the CoG on a calibrated window plus
    // the correction (cog1c_7x7 - cog1_7x7 = 1000 here): 7x7 fused 1640 < 980 + 1000; 5x5
    // fused 1520 > 500 + 1000.
    let text = "centroid_cog1_5x5,star,1000\ncentroid_cog1_7x7,star,1960\n\
                centroid_cog2_5x5,star,1100\ncentroid_cog2_7x7,star,2100\n\
                centroid_cog1_given_bg_5x5,star,500\ncentroid_cog1_given_bg_7x7,star,980\n\
                centroid_cog1c_7x7,star,2960\n\
                centroid_cog1c_raw_5x5,star,1520\ncentroid_cog1c_raw_7x7,star,1640\n";
    let t = M7Table::parse(text).unwrap();
    let cog = |power, box_side, corrected| Method::Cog {
        power,
        box_side,
        corrected,
    };
    let (c, basis) = m7_cost(&cog(CogPower::One, 7, true), &t).unwrap();
    assert_eq!(
        (c, basis.as_str()),
        (1640.0, "fused raw path (calibration included)")
    );
    let (c, basis) = m7_cost(&cog(CogPower::One, 5, true), &t).unwrap();
    assert_eq!(
        (c, basis.as_str()),
        (1500.0, "measured; correction added (7x7 measurement)")
    );
    // 3x3: both extrapolated linearly in the pixel count; fused 1520 - 120 / 24 * 16 = 1440
    // against 500 - 480 / 24 * 16 + 1000 = 1180.
    let (c, basis) = m7_cost(&cog(CogPower::One, 3, true), &t).unwrap();
    assert!((c - 1180.0).abs() < 1e-9, "{c}");
    assert_eq!(basis, "extrapolated; correction added (7x7 measurement)");
    // The uncorrected and power-2 CoGs never take the fused path.
    assert_eq!(m7_cost(&cog(CogPower::One, 7, false), &t).unwrap().0, 980.0);
    let (c, _) = m7_cost(&cog(CogPower::Two, 7, true), &t).unwrap();
    assert!((c - (980.0 + 140.0 + 1000.0)).abs() < 1e-9, "{c}");
}

#[test]
fn psf_shapes_flag_writes_only_the_shapes_csv_the_same_twice() {
    let dir = tempfile::tempdir().unwrap();
    let mut texts = Vec::new();
    for run in ["a", "b"] {
        let out = dir.path().join(run);
        let (ok, stdout, stderr) = startrack(&[
            "tradeoff",
            "--psf-shapes",
            "--quick",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{stderr}");
        assert_eq!(stdout.lines().count(), 1, "{stdout}");
        let names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["psf-shapes.csv"]);
        texts.push(std::fs::read_to_string(out.join("psf-shapes.csv")).unwrap());
    }
    assert_eq!(texts[0], texts[1], "two runs differ");
    // Every method that applies at a = 1 px on each of the 6 shapes; no field holds a comma.
    let mut lines = texts[0].lines().filter(|l| !l.starts_with('#'));
    let fields = lines.next().unwrap().split(',').count();
    let rows: Vec<&str> = lines.collect();
    assert_eq!(
        rows.len(),
        6 * startrack_analysis::tradeoff::methods().len()
    );
    for l in rows {
        assert_eq!(l.split(',').count(), fields, "{l}");
    }
}
