//! `docs/accuracy.md` against the accuracy CSVs in `host-tests/figures/`: RMS over the
//! Cramer-Rao bound (`tradeoff.csv`), the failure maps and low-SNR detection (`failures.csv`),
//! the width-unknown and PSF-shape tables, and the end-to-end frame tables, cell for cell; a
//! few numbers in running text as the exact phrase the CSV gives.

use super::helpers::{Csv, TRADEOFF, cells, flat, matches, matches_value, num, read, table};
use std::collections::{BTreeSet, HashMap};

/// A column header `a 0.7 SNR 10` as (a, SNR).
fn scene(col: &str) -> (f64, f64) {
    let w: Vec<&str> = col.split_whitespace().collect();
    assert!(
        w.len() == 4 && w[0] == "a" && w[2] == "SNR",
        "not a scene column: {col:?}"
    );
    (num(w[1]), num(w[3]))
}

/// The tradeoff.csv rows of `method` (or of every method) at scene (a, snr).
fn at<'a>(
    recs: &'a [HashMap<&'a str, &'a str>],
    method: Option<&str>,
    (a, snr): (f64, f64),
) -> Vec<&'a HashMap<&'a str, &'a str>> {
    recs.iter()
        .filter(|x| method.is_none_or(|m| x["method"] == m))
        .filter(|x| num(x["a_px"]) == a && num(x["snr"]) == snr)
        .collect()
}

#[test]
fn accuracy_table_is_the_tradeoff_csv() {
    let csv = Csv::read(TRADEOFF);
    let recs = csv.records();
    let (header, body) = table("docs/accuracy.md", "accuracy-rms-crlb");
    assert_eq!(header[0], "method");
    let scenes: Vec<(f64, f64)> = header[1..].iter().map(|c| scene(c)).collect();
    let csv_scenes: BTreeSet<(u64, u64)> = recs
        .iter()
        .map(|x| (num(x["a_px"]).to_bits(), num(x["snr"]).to_bits()))
        .collect();
    assert_eq!(
        scenes
            .iter()
            .map(|(a, s)| (a.to_bits(), s.to_bits()))
            .collect::<BTreeSet<_>>(),
        csv_scenes,
        "the table's scenes are the CSV's"
    );
    let mut listed = Vec::new();
    for r in &body {
        let m = r[0].as_str();
        for (cell, &sc) in r[1..].iter().zip(&scenes) {
            let rows = at(&recs, Some(m), sc);
            let what = format!("docs/accuracy.md: {m} at a {} SNR {}", sc.0, sc.1);
            if cell == "-" {
                assert!(
                    rows.iter().all(|x| x["rms_over_crlb"].is_empty()),
                    "{what}: `-` but {TRADEOFF} has a value"
                );
                continue;
            }
            assert_eq!(rows.len(), 1, "{what}: {} rows in {TRADEOFF}", rows.len());
            let x = rows[0];
            let (value, failed) = match cell.split_once(" (") {
                Some((v, f)) => (
                    v,
                    f.strip_suffix(" failed)")
                        .unwrap_or_else(|| panic!("{what}: {cell:?}")),
                ),
                None => (cell.as_str(), "0"),
            };
            assert!(
                matches(value, x["rms_over_crlb"]),
                "{what}: {value} in the docs, {} in {TRADEOFF}",
                x["rms_over_crlb"]
            );
            assert_eq!(failed, x["failed"], "{what}: failed results");
        }
        listed.push(m.to_string());
    }
    assert_eq!(
        listed,
        csv.distinct("method"),
        "every method, in the CSV's order"
    );

    // The CRLB row: `startrack accuracy` prints the first method's cell of each scene.
    let (header, body) = table("docs/accuracy.md", "accuracy-crlb");
    assert_eq!(body.len(), 1);
    assert_eq!(body[0][0], "CRLB");
    let first = csv.distinct("method").remove(0);
    for (cell, col) in body[0][1..].iter().zip(&header[1..]) {
        let sc = scene(col);
        let x = at(&recs, Some(&first), sc)[0];
        assert!(
            matches(cell, x["crlb_px"]),
            "docs/accuracy.md CRLB at {col}: {cell}, {} in {TRADEOFF}",
            x["crlb_px"]
        );
    }
}

const FAILURES: &str = "host-tests/figures/failures.csv";

/// Sweeps of the failure maps: CSV name and whether a larger value is the harder one.
const SWEEPS: [(&str, bool); 6] = [
    ("dsnu", true),
    ("hot_e", true),
    ("telegraph_e", true),
    ("saturation", true),
    ("edge_px", false),
    ("pair_px", false),
];

/// The value up to which every step of `sweep` passes for `method`, from the mildest, or
/// `fails` when the mildest already fails.
fn passing_up_to(
    recs: &[HashMap<&str, &str>],
    method: &str,
    sweep: &str,
    harder_up: bool,
) -> String {
    let mut steps: Vec<(f64, &str, &str)> = recs
        .iter()
        .filter(|x| x["method"] == method && x["sweep"] == sweep)
        .map(|x| (num(x["value"]), x["value"], x["fail"]))
        .collect();
    assert!(!steps.is_empty(), "{method}: no {sweep} sweep");
    steps.sort_by(|a, b| a.0.total_cmp(&b.0));
    if !harder_up {
        steps.reverse();
    }
    let mut last = "fails".to_string();
    for (_, v, fail) in steps {
        if fail != "pass" {
            break;
        }
        last = v.to_string();
    }
    last
}

/// The PSF-width mismatch sweep: the contiguous range of true widths around the configured one
/// (the rows' `a_px`) over which every step passes, `lo-hi`, or `fails` when the configured
/// width itself fails.
fn true_width_range(recs: &[HashMap<&str, &str>], method: &str) -> String {
    let mut steps: Vec<(f64, &str, &str, f64)> = recs
        .iter()
        .filter(|x| x["method"] == method && x["sweep"] == "true_a_px")
        .map(|x| (num(x["value"]), x["value"], x["fail"], num(x["a_px"])))
        .collect();
    steps.sort_by(|a, b| a.0.total_cmp(&b.0));
    let Some(i) = steps.iter().position(|s| s.0 == s.3) else {
        panic!("{method}: the true_a_px sweep lacks the configured width");
    };
    if steps[i].2 != "pass" {
        return "fails".into();
    }
    let (mut lo, mut hi) = (i, i);
    while lo > 0 && steps[lo - 1].2 == "pass" {
        lo -= 1;
    }
    while hi + 1 < steps.len() && steps[hi + 1].2 == "pass" {
        hi += 1;
    }
    format!("{}-{}", steps[lo].1, steps[hi].1)
}

#[test]
fn failure_map_table_is_the_failures_csv() {
    let csv = Csv::read(FAILURES);
    let recs = csv.records();
    let (header, body) = table("docs/accuracy.md", "failure-maps");
    // The sweeps, then the width mismatch's passing range of true widths.
    assert_eq!(header.len(), 2 + SWEEPS.len() + 1);
    let mut listed = Vec::new();
    for r in &body {
        let m = r[0].as_str();
        let grid: Vec<_> = recs
            .iter()
            .filter(|x| x["method"] == m && x["sweep"] == "grid")
            .collect();
        let pass = grid.iter().filter(|x| x["fail"] == "pass").count();
        let n_cells = grid.iter().filter(|x| x["fail"] != "n/a").count();
        assert_eq!(
            r[1],
            format!("{pass} of {n_cells}"),
            "docs/accuracy.md: {m}'s grid cells passing"
        );
        for ((sweep, up), cell) in SWEEPS.iter().zip(&r[2..]) {
            let want = passing_up_to(&recs, m, sweep, *up);
            let same = if want == "fails" || cell == "fails" {
                *cell == want
            } else {
                num(cell) == num(&want)
            };
            assert!(
                same,
                "docs/accuracy.md: {m}, {sweep}: {cell} in the docs, {want} in {FAILURES}"
            );
        }
        let want = true_width_range(&recs, m);
        assert_eq!(
            r[2 + SWEEPS.len()],
            want,
            "docs/accuracy.md: {m}, true a passing: {FAILURES} says {want}"
        );
        listed.push(m.to_string());
    }
    assert_eq!(
        listed,
        csv.distinct("method"),
        "every method, in the CSV's order"
    );
}

#[test]
fn low_snr_detection_table_is_the_failures_csv() {
    let csv = Csv::read(FAILURES);
    let recs = csv.records();
    let grid: Vec<_> = recs.iter().filter(|x| x["sweep"] == "grid").collect();
    let mut snrs: Vec<&str> = Vec::new();
    for x in &grid {
        if !snrs.contains(&x["snr"]) {
            snrs.push(x["snr"]);
        }
    }
    snrs.sort_by(|a, b| num(a).total_cmp(&num(b)));
    let best = |snr: &str| {
        grid.iter()
            .filter(|x| x["snr"] == snr && !x["detect_rate"].is_empty())
            .map(|x| num(x["detect_rate"]))
            .fold(0.0, f64::max)
    };
    let (_, body) = table("docs/accuracy.md", "low-snr-detection");
    // The grid's lowest SNRs, in order, up to the first at which a method detects 90 %.
    for (i, r) in body.iter().enumerate() {
        assert!(
            matches(&r[0], snrs[i]),
            "row {i}: SNR {} against {}",
            r[0],
            snrs[i]
        );
        let d = best(snrs[i]);
        assert!(
            matches_value(&r[1], d),
            "SNR {}: {} in the docs, {d}",
            snrs[i],
            r[1]
        );
        assert_eq!(
            d >= 0.9,
            i == body.len() - 1,
            "SNR {}: detected {d}",
            snrs[i]
        );
    }
    let page = flat(&read("docs/accuracy.md"));
    let last = num(snrs[body.len() - 1]);
    let phrase = format!("{last:.1} is the lowest grid SNR at which a method detects 90 %");
    assert!(
        page.contains(&phrase),
        "docs/accuracy.md should say {phrase:?}"
    );
}

#[test]
fn failure_map_bullets_are_the_failures_csv() {
    let csv = Csv::read(FAILURES);
    let recs = csv.records();
    let grid: Vec<_> = recs.iter().filter(|x| x["sweep"] == "grid").collect();
    let page = flat(&read("docs/accuracy.md"));
    let has = |phrase: String| {
        assert!(
            page.contains(&phrase),
            "docs/accuracy.md should say {phrase:?}"
        );
    };
    let a_values = {
        let mut v: Vec<f64> = grid.iter().map(|x| num(x["a_px"])).collect();
        v.sort_by(f64::total_cmp);
        v.dedup();
        v
    };

    // The plain power-2 CoG's systematic error at SNR 100 below 1 px.
    let plain_cog2 = |x: &&&HashMap<&str, &str>| {
        x["method"].starts_with("cog2") && !x["method"].ends_with("corrected")
    };
    let small: Vec<_> = grid
        .iter()
        .filter(plain_cog2)
        .filter(|x| num(x["snr"]) == 100.0 && num(x["a_px"]) < 1.0)
        .collect();
    let bias: Vec<f64> = small.iter().map(|x| num(x["bias_px"])).collect();
    let amax = small.iter().map(|x| num(x["a_px"])).fold(0.0, f64::max);
    has(format!(
        "at SNR 100 its systematic error is {:.2}-{:.2} px at a <= {amax:.2} px",
        bias.iter().copied().fold(f64::INFINITY, f64::min),
        bias.iter().copied().fold(0.0, f64::max)
    ));

    // The corrected power-1 CoG's systematic error over the whole grid.
    let worst = grid
        .iter()
        .filter(|x| x["method"].starts_with("cog1") && x["method"].ends_with("corrected"))
        .map(|x| num(x["bias_px"]))
        .fold(0.0, f64::max);
    assert!(
        worst < 0.01,
        "corrected power-1 CoG: systematic error {worst} px"
    );
    has(format!(
        "stays under 0.01 px down to a = {} px",
        a_values[0]
    ));

    // Where a plain power-1 CoG in a 5x5 or 7x7 box passes.
    let passing_a = |m: &str| {
        let a: Vec<f64> = grid
            .iter()
            .filter(|x| x["method"] == m && x["fail"] == "pass")
            .map(|x| num(x["a_px"]))
            .collect();
        (
            a.iter().copied().fold(f64::INFINITY, f64::min),
            a.iter().copied().fold(0.0, f64::max),
        )
    };
    let (l5, h5) = passing_a("cog1 5x5");
    let (l7, h7) = passing_a("cog1 7x7");
    has(format!(
        "(a = {l5:.2}-{h5:.2} px for 5x5, {l7:.2}-{h7:.2} px for 7x7)"
    ));

    // The Gauss fit told the width: never biased nor above 2x the bound at SNR >= 3.5; at the
    // smallest a it often does not converge.
    let fit: Vec<_> = grid
        .iter()
        .filter(|x| x["method"].starts_with("gauss fit") && !x["method"].contains("width-free"))
        .collect();
    for x in fit.iter().filter(|x| num(x["snr"]) >= 3.5) {
        assert!(
            !x["fail"].contains("bias") && !x["fail"].contains("rms"),
            "{} a {} SNR {}: {}",
            x["method"],
            x["a_px"],
            x["snr"],
            x["fail"]
        );
    }
    has(format!(
        "at every SNR >= 3.5 over the whole grid (a = {}-{} px)",
        a_values[0],
        a_values[a_values.len() - 1]
    ));
    let rates: Vec<f64> = fit
        .iter()
        .filter(|x| num(x["a_px"]) == a_values[0] && num(x["snr"]) >= 5.0)
        .map(|x| num(x["detect_rate"]))
        .collect();
    has(format!(
        "({:.0}-{:.0} % detected at SNR >= 5)",
        100.0 * rates.iter().copied().fold(f64::INFINITY, f64::min),
        100.0 * rates.iter().copied().fold(0.0, f64::max)
    ));

    // The width-free fit 7x7: the lowest grid SNR from which every cell of a >= 0.5 px passes,
    // and its systematic error at the smallest a (below its width floor).
    let free: Vec<_> = grid
        .iter()
        .filter(|x| x["method"] == "gauss fit width-free 7x7")
        .collect();
    let mut snrs: Vec<f64> = free.iter().map(|x| num(x["snr"])).collect();
    snrs.sort_by(f64::total_cmp);
    snrs.dedup();
    let passes_from = |s: f64| {
        free.iter()
            .filter(|x| num(x["snr"]) >= s && num(x["a_px"]) >= 0.5)
            .all(|x| x["fail"] == "pass")
    };
    let lowest = snrs
        .iter()
        .copied()
        .find(|&s| passes_from(s))
        .expect("the width-free fit passes at the top of the grid");
    has(format!(
        "passes every cell of a = 0.5-{} px from SNR {lowest:.1} up",
        a_values[a_values.len() - 1]
    ));
    let b0: Vec<f64> = free
        .iter()
        .filter(|x| num(x["a_px"]) == a_values[0])
        .map(|x| num(x["bias_px"]))
        .collect();
    has(format!(
        "its systematic error at a = {} px is {:.3}-{:.3} px",
        a_values[0],
        b0.iter().copied().fold(f64::INFINITY, f64::min),
        b0.iter().copied().fold(0.0, f64::max)
    ));
}

/// `host-tests/figures/accuracy-width.csv` (`startrack accuracy --width-unknown --csv`)
/// as (method, a, SNR) -> row.
fn accuracy_width_csv() -> HashMap<(String, String, String), HashMap<String, String>> {
    let text = read("host-tests/figures/accuracy-width.csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    lines
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            let row: HashMap<String, String> = header
                .iter()
                .zip(&v)
                .map(|(h, x)| (h.to_string(), x.to_string()))
                .collect();
            (
                (
                    row["method"].clone(),
                    row["a_px"].clone(),
                    row["snr"].clone(),
                ),
                row,
            )
        })
        .collect()
}

#[test]
fn width_unknown_table_is_its_csv() {
    let csv = accuracy_width_csv();
    let (header, body) = table("docs/accuracy.md", "accuracy-width-unknown");
    assert_eq!(header[..2], ["method", "a"]);
    let snrs: Vec<String> = header[2..]
        .iter()
        .map(|h| h.strip_prefix("SNR ").expect("SNR column").to_string())
        .collect();
    let mut seen = 0;
    for r in &body {
        for (cell, snr) in r[2..].iter().zip(&snrs) {
            let key = (r[0].clone(), r[1].clone(), snr.clone());
            let row = csv
                .get(&key)
                .unwrap_or_else(|| panic!("docs/accuracy.md: {key:?} is not in the CSV"));
            let what = format!("docs/accuracy.md width unknown {key:?}");
            // "R / R_free / pull P[, S % flagged (P_clean)][ (N failed)]" or "R[ (N failed)]".
            let parts: Vec<&str> = cell.split(" / ").collect();
            let first = |s: &str| s.split_whitespace().next().unwrap_or("").to_string();
            assert!(
                matches(&first(parts[0]), &row["rms_over_crlb"]),
                "{what}: {cell}"
            );
            if parts.len() == 3 {
                assert!(
                    matches(&first(parts[1]), &row["rms_over_crlb_width_free"]),
                    "{what}: {cell}"
                );
                let pull = parts[2].trim_start_matches("pull ");
                let pull = pull.split([',', ' ']).next().unwrap_or("");
                assert!(matches(pull, &row["pull_rms"]), "{what}: {cell}");
            }
            let failed = cell
                .rsplit_once(" (")
                .and_then(|(_, t)| t.strip_suffix(" failed)"))
                .unwrap_or("0");
            assert_eq!(failed, row["failures"], "{what}: failures");
            seen += 1;
        }
    }
    assert_eq!(seen, csv.len(), "every CSV row in the table");
}

const SHAPES: &str = "host-tests/figures/psf-shapes.csv";

#[test]
fn psf_shape_table_is_its_csv() {
    let csv = Csv::read(SHAPES);
    let recs = csv.records();
    let (header, body) = table("docs/accuracy.md", "psf-shapes");
    assert_eq!(header[0], "method");
    // Columns: `gaussian`, or `defocus|coma SIZE px`.
    let shapes: Vec<(String, f64)> = header[1..]
        .iter()
        .map(|h| match h.split_whitespace().collect::<Vec<_>>()[..] {
            [name] => (name.to_string(), 0.0),
            [name, size, "px"] => (name.to_string(), num(size)),
            _ => panic!("docs/accuracy.md psf-shapes: column {h:?}"),
        })
        .collect();
    let mut listed = Vec::new();
    for r in &body {
        let m = r[0].as_str();
        for (cell, (name, size)) in r[1..].iter().zip(&shapes) {
            let x = recs
                .iter()
                .find(|x| x["method"] == m && x["shape"] == name && num(x["size_px"]) == *size)
                .unwrap_or_else(|| panic!("{SHAPES}: no {m} on {name} {size}"));
            let what = format!("docs/accuracy.md psf-shapes: {m} on {name} {size}");
            if cell == "not converged" {
                assert_eq!(x["failed"], x["trials"], "{what}");
                continue;
            }
            let (rest, failed) = match cell.split_once(" (") {
                Some((v, f)) => (v, f.strip_suffix(" failed)").expect("(N failed)")),
                None => (cell.as_str(), "0"),
            };
            assert_eq!(failed, x["failed"], "{what}: failed");
            let (rest, poor) = match rest.split_once(" [") {
                Some((v, p)) => (v, p.strip_suffix(" % POOR_FIT]").expect("[P % POOR_FIT]")),
                None => (rest, "0"),
            };
            assert!(
                matches_value(poor, 100.0 * num(x["poor_fit_rate"])),
                "{what}: POOR_FIT {poor} %, {} in {SHAPES}",
                x["poor_fit_rate"]
            );
            let (mean, rms) = rest.split_once(" / ").expect("MEAN / RMS");
            assert!(
                matches(mean, x["mean_err_x_px"]),
                "{what}: mean x error {mean}, {} in {SHAPES}",
                x["mean_err_x_px"]
            );
            assert!(
                matches(rms, x["rms_px"]),
                "{what}: RMS {rms}, {} in {SHAPES}",
                x["rms_px"]
            );
        }
        listed.push(m.to_string());
    }
    assert_eq!(
        listed,
        csv.distinct("method"),
        "every method, in the CSV's order"
    );
}

/// docs/accuracy.md's end-to-end table is `startrack accuracy-frames`' markdown of
/// `host-tests/figures/accuracy-frames.csv` (its `--csv`), cell for cell.
#[test]
fn frames_table_is_its_csv() {
    use startrack_host::cli::accuracy_frames::monte_carlo::{from_csv, markdown};
    let bins = from_csv(&read("host-tests/figures/accuracy-frames.csv"))
        .expect("host-tests/figures/accuracy-frames.csv: rows of accuracy-frames --csv");
    assert_eq!(bins.len(), 30, "two configurations, 5 widths, 3 SNR bins");
    let (header, body) = table("docs/accuracy.md", "accuracy-frames");
    let want: Vec<Vec<String>> = markdown(&bins).lines().map(cells).collect();
    assert_eq!(header, want[0], "docs/accuracy.md accuracy-frames header");
    assert_eq!(
        body,
        want[2..],
        "docs/accuracy.md accuracy-frames: not the CSV's table"
    );
}

/// docs/accuracy.md's smooth-field table is `startrack accuracy-frames --field-a 0.6,2`'s
/// markdown of `host-tests/figures/accuracy-frames-field.csv` (its `--csv`), cell for cell.
#[test]
fn field_frames_table_is_its_csv() {
    use startrack_host::cli::accuracy_frames::monte_carlo::{from_csv, markdown};
    let bins = from_csv(&read("host-tests/figures/accuracy-frames-field.csv")).expect(
        "host-tests/figures/accuracy-frames-field.csv: rows of accuracy-frames --field-a --csv",
    );
    assert_eq!(bins.len(), 30, "two configurations, 5 widths, 3 SNR bins");
    let (header, body) = table("docs/accuracy.md", "accuracy-frames-field");
    let want: Vec<Vec<String>> = markdown(&bins).lines().map(cells).collect();
    assert_eq!(
        header, want[0],
        "docs/accuracy.md accuracy-frames-field header"
    );
    assert_eq!(
        body,
        want[2..],
        "docs/accuracy.md accuracy-frames-field: not the CSV's table"
    );
}

const TRAIL_BOUND: &str = "host-tests/figures/trail-bound.csv";

/// The "Trailed stars" table of docs/accuracy.md is
/// `host-tests/figures/trail-bound.csv`, row for row.
#[test]
fn trail_bound_table_is_the_trail_bound_csv() {
    let csv = Csv::read(TRAIL_BOUND);
    let recs = csv.records();
    let (_, body) = table("docs/accuracy.md", "trail-bound");
    assert_eq!(
        body.len(),
        recs.len(),
        "{TRAIL_BOUND}: one row a trail length"
    );
    for (row, rec) in body.iter().zip(&recs) {
        assert!(matches(&row[0], rec["trail_px"]), "{row:?} vs {rec:?}");
        assert!(matches(&row[1], rec["along_px"]), "{row:?} vs {rec:?}");
        assert!(matches(&row[2], rec["across_px"]), "{row:?} vs {rec:?}");
    }
}

const TRAIL_RATES: &str = "host-tests/figures/trail-rates.csv";

/// The accuracy-against-rate table of docs/accuracy.md ("Trailed stars") is
/// `host-tests/figures/trail-rates.csv`, row for row (a method's NaN written `-`).
#[test]
fn trail_rates_table_is_the_trail_rates_csv() {
    let csv = Csv::read(TRAIL_RATES);
    let recs = csv.records();
    let (header, body) = table("docs/accuracy.md", "trail-rates");
    assert_eq!(
        header,
        [
            "rate, deg/s",
            "trail, px",
            "method",
            "flagged",
            "RMS, px",
            "bound, px",
            "RMS / bound",
            "pull"
        ]
    );
    assert_eq!(
        body.len(),
        recs.len(),
        "{TRAIL_RATES}: one row a rate and method"
    );
    for (row, rec) in body.iter().zip(&recs) {
        assert_eq!(row[2].replace('`', ""), rec["method"], "{row:?} vs {rec:?}");
        let flagged = format!("{}/{}", rec["flagged"], rec["stars"]);
        assert_eq!(row[3], flagged, "{row:?} vs {rec:?}");
        for (i, col) in [
            (0, "rate_deg_s"),
            (1, "trail_px"),
            (4, "rms_px"),
            (5, "bound_px"),
            (6, "ratio"),
            (7, "pull"),
        ] {
            let (d, c) = (&row[i], rec[col]);
            let same = if c == "NaN" { d == "-" } else { matches(d, c) };
            assert!(same, "{col}: {row:?} vs {rec:?}");
        }
    }
}
