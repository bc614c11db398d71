//! The numbers of `README.md` and `docs/*.md` against the committed outputs they come from,
//! so that a regenerated CSV that changes them fails here until the page follows.
//!
//! A table the docs mark with `<!-- checked: NAME -->` on the line before it is parsed and
//! each of its cells compared with the CSV it comes from (`host-tests/m7-costs.csv`,
//! `host-tests/figures/*.csv`) or with the code (`StarFlags`). A number written
//! with `d` decimals matches a value when it is that value rounded to `d` decimals, give or
//! take the CSV's own rounding. A few numbers in running text are checked as the exact
//! phrase the CSV gives. Also: every marker is one this file checks, every relative link
//! and anchor of the pages resolves, the pages speak of the product only, and the README
//! stays short.

use startrack_core::tracker::{Provenance, StarFlags, Tracker, TrackerBuffers, TrackerConfig};
use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// The workspace root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host-tests/ has a parent")
        .to_path_buf()
}

/// A file of the workspace, by its path from the root.
fn read(rel: &str) -> String {
    let p = root().join(rel);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The pages: the README and every `docs/*.md`, as (path from the root, text).
fn pages() -> Vec<(String, String)> {
    let mut names: Vec<String> = std::fs::read_dir(root().join("docs"))
        .expect("docs/")
        .map(|e| {
            e.expect("docs/ entry")
                .file_name()
                .to_string_lossy()
                .into_owned()
        })
        .filter(|n| n.ends_with(".md"))
        .map(|n| format!("docs/{n}"))
        .collect();
    names.sort();
    names.insert(0, "README.md".into());
    names.into_iter().map(|n| (n.clone(), read(&n))).collect()
}

/// A CSV: the column names (first line that is not a `#` comment) and the rows.
struct Csv {
    columns: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Csv {
    fn read(rel: &str) -> Self {
        let text = read(rel);
        let mut lines = text
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty());
        let columns = lines
            .next()
            .unwrap_or_else(|| panic!("{rel}: no column names"))
            .split(',')
            .map(str::to_string)
            .collect::<Vec<_>>();
        let rows = lines
            .map(|l| l.split(',').map(str::to_string).collect::<Vec<_>>())
            .collect::<Vec<_>>();
        for r in &rows {
            assert_eq!(r.len(), columns.len(), "{rel}: {r:?}");
        }
        Csv { columns, rows }
    }

    fn col(&self, name: &str) -> usize {
        self.columns
            .iter()
            .position(|c| c == name)
            .unwrap_or_else(|| panic!("no column {name} in {:?}", self.columns))
    }

    /// The rows as maps from column name to value.
    fn records(&self) -> Vec<HashMap<&str, &str>> {
        self.rows
            .iter()
            .map(|r| {
                self.columns
                    .iter()
                    .map(String::as_str)
                    .zip(r.iter().map(String::as_str))
                    .collect()
            })
            .collect()
    }

    /// The distinct values of a column, in file order.
    fn distinct(&self, name: &str) -> Vec<String> {
        let c = self.col(name);
        let mut out: Vec<String> = Vec::new();
        for r in &self.rows {
            if !out.contains(&r[c]) {
                out.push(r[c].clone());
            }
        }
        out
    }
}

/// Parses a number as the docs or a CSV write it: thousands commas allowed.
fn num(s: &str) -> f64 {
    let t = s.trim().trim_matches('`').replace(',', "");
    t.parse()
        .unwrap_or_else(|e| panic!("not a number: {s:?} ({e})"))
}

/// Half a unit of the last digit `s` is written with (`1.54` -> 0.005, `4,758` -> 0.5,
/// `1.554882e-1` -> 5e-8).
fn half_unit(s: &str) -> f64 {
    let t = s.trim().trim_matches('`').replace(',', "");
    let (mantissa, exp) = match t.split_once(['e', 'E']) {
        Some((m, e)) => (m.to_string(), e.parse::<i32>().expect("exponent")),
        None => (t.clone(), 0),
    };
    let decimals = mantissa.split_once('.').map_or(0, |(_, d)| d.len()) as i32;
    0.5 * 10f64.powi(exp - decimals)
}

/// Whether the docs' `doc` is the CSV's `csv` rounded as written (both roundings allowed).
fn matches(doc: &str, csv: &str) -> bool {
    (num(doc) - num(csv)).abs() <= half_unit(doc) + half_unit(csv) + 1e-12
}

/// Whether the docs' `doc` is the exact `value` rounded as written.
fn matches_value(doc: &str, value: f64) -> bool {
    (num(doc) - value).abs() <= half_unit(doc) * (1.0 + 1e-9)
}

/// Splits a markdown table line into its trimmed cells.
fn cells(line: &str) -> Vec<String> {
    let t = line.trim();
    let t = t.strip_prefix('|').unwrap_or(t);
    let t = t.strip_suffix('|').unwrap_or(t);
    t.split('|').map(|c| c.trim().to_string()).collect()
}

/// The marker that names a checked table.
fn marker(name: &str) -> String {
    format!("<!-- checked: {name} -->")
}

/// The table after `<!-- checked: NAME -->` in page `page`: its header cells and body rows.
fn table(page: &str, name: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let text = read(page);
    let m = marker(name);
    let mut lines = text.lines().skip_while(|l| l.trim() != m);
    assert!(lines.next().is_some(), "{page}: no {m}");
    let rows: Vec<Vec<String>> = lines
        .skip_while(|l| l.trim().is_empty())
        .take_while(|l| l.trim_start().starts_with('|'))
        .map(cells)
        .collect();
    assert!(rows.len() >= 3, "{page}: {m} is not followed by a table");
    assert!(
        rows[1]
            .iter()
            .all(|c| c.chars().all(|ch| ch == '-' || ch == ':')),
        "{page}: {m}: second line is not a separator"
    );
    let header = rows[0].clone();
    let body = rows[2..].to_vec();
    for r in &body {
        assert_eq!(r.len(), header.len(), "{page}: {m}: {r:?}");
    }
    (header, body)
}

/// The checked tables, by marker name.
const CHECKED: [&str; 18] = [
    "m7-costs",
    "m7-targets",
    "frontier",
    "accuracy-rms-crlb",
    "accuracy-crlb",
    "failure-maps",
    "low-snr-detection",
    "fig-minima",
    "fig5-fig6",
    "star-flags",
    "star-provenance",
    "tracker-config",
    "tracker-memory",
    "readout-plan",
    "accuracy-width-unknown",
    "psf-shapes",
    "accuracy-frames",
    "accuracy-frames-field",
];

#[test]
fn every_marker_is_checked_and_every_check_has_its_marker() {
    let mut seen = Vec::new();
    for (page, text) in pages() {
        for l in text.lines() {
            if let Some(rest) = l.trim().strip_prefix("<!-- checked: ") {
                let name = rest.strip_suffix(" -->").expect("marker ends with -->");
                assert!(
                    CHECKED.contains(&name),
                    "{page}: marker {name:?} is not checked by docs_numbers.rs"
                );
                seen.push(name.to_string());
            }
        }
    }
    for name in CHECKED {
        let n = seen.iter().filter(|s| s.as_str() == name).count();
        assert_eq!(n, 1, "marker {name:?} appears {n} times in the pages");
    }
}

const M7: &str = "host-tests/m7-costs.csv";

/// `host-tests/m7-costs.csv` as stage -> (unit, instructions as written).
fn m7_costs() -> HashMap<String, (String, String)> {
    let csv = Csv::read(M7);
    csv.records()
        .iter()
        .map(|r| {
            (
                r["stage"].to_string(),
                (
                    r["unit"].to_string(),
                    r["instructions_per_unit"].to_string(),
                ),
            )
        })
        .collect()
}

#[test]
fn speed_stage_table_is_the_m7_costs_csv() {
    let costs = m7_costs();
    let (header, body) = table("docs/speed.md", "m7-costs");
    assert_eq!(header, ["stage", "unit", "what it runs", "instructions"]);
    let mut listed = BTreeSet::new();
    for r in &body {
        let stage = r[0].trim_matches('`');
        let (unit, instr) = costs
            .get(stage)
            .unwrap_or_else(|| panic!("docs/speed.md: stage {stage} is not in {M7}"));
        assert_eq!(
            r[1].trim_matches('`'),
            unit,
            "docs/speed.md: unit of {stage}"
        );
        assert!(
            matches(&r[3], instr),
            "docs/speed.md: {stage} is {} in the docs, {instr} in {M7}",
            r[3]
        );
        assert!(listed.insert(stage.to_string()), "{stage} listed twice");
    }
    let all: BTreeSet<String> = costs.keys().cloned().collect();
    assert_eq!(
        listed, all,
        "docs/speed.md must list every stage of {M7} (cargo m7-bench > {M7})"
    );
}

#[test]
fn speed_targets_are_the_m7_costs_csv() {
    let costs = m7_costs();
    let (header, body) = table("docs/speed.md", "m7-targets");
    assert_eq!(
        header,
        [
            "target",
            "stage",
            "instructions",
            "target",
            "measured / target"
        ]
    );
    for r in &body {
        let stage = r[1].trim_matches('`');
        let (_, instr) = &costs[stage];
        assert!(
            matches(&r[2], instr),
            "docs/speed.md targets: {stage} is {}, {instr} in {M7}",
            r[2]
        );
        let ratio = num(instr) / num(&r[3]);
        assert!(
            matches_value(&r[4], ratio),
            "docs/speed.md targets: {stage}: {} / {} = {ratio:.3}, the docs say {}",
            instr,
            r[3],
            r[4]
        );
    }
}

const TRADEOFF: &str = "host-tests/figures/tradeoff.csv";

#[test]
fn speed_frontier_table_is_the_tradeoff_csv() {
    let csv = Csv::read(TRADEOFF);
    let recs = csv.records();
    let (header, body) = table("docs/speed.md", "frontier");
    assert_eq!(
        header,
        [
            "method",
            "window",
            "M7 instructions",
            "RMS / CRLB",
            "M7 frontier scenes",
            "host ns",
            "host frontier scenes"
        ]
    );
    let mut listed = Vec::new();
    for r in &body {
        let m = r[0].as_str();
        let rows: Vec<_> = recs.iter().filter(|x| x["method"] == m).collect();
        assert!(!rows.is_empty(), "docs/speed.md: {m} is not in {TRADEOFF}");
        // One window, one M7 cost and one host time per method, whatever the scene.
        for col in ["window", "m7_instructions", "host_ns"] {
            let v: BTreeSet<&str> = rows.iter().map(|x| x[col]).collect();
            assert_eq!(v.len(), 1, "{m}: {col} varies by scene: {v:?}");
        }
        assert_eq!(r[1], rows[0]["window"], "{m}: window");
        assert!(
            matches(&r[2], rows[0]["m7_instructions"]),
            "{m}: M7 {} in the docs, {} in {TRADEOFF}",
            r[2],
            rows[0]["m7_instructions"]
        );
        let q: Vec<f64> = rows.iter().map(|x| num(x["rms_over_crlb"])).collect();
        let (lo, hi) = r[3].split_once('-').expect("RMS / CRLB as lo-hi");
        let min = q.iter().copied().fold(f64::INFINITY, f64::min);
        let max = q.iter().copied().fold(0.0, f64::max);
        // The CSV's 3 decimals: half a unit of slack on top of the docs' rounding.
        assert!(
            matches_value(lo, min) || (num(lo) - min).abs() <= half_unit(lo) + 5e-4,
            "{m}: lowest RMS / CRLB {min} against {lo}"
        );
        assert!(
            matches_value(hi, max) || (num(hi) - max).abs() <= half_unit(hi) + 5e-4,
            "{m}: highest RMS / CRLB {max} against {hi}"
        );
        let count = |col: &str| rows.iter().filter(|x| x[col] == "1").count().to_string();
        assert_eq!(r[4], count("pareto_m7"), "{m}: scenes on the M7 frontier");
        assert_eq!(r[5], rows[0]["host_ns"], "{m}: host ns");
        assert_eq!(
            r[6],
            count("pareto_host"),
            "{m}: scenes on the host frontier"
        );
        listed.push(m.to_string());
    }
    assert_eq!(
        listed,
        csv.distinct("method"),
        "every method, in the CSV's order"
    );
}

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

/// Collapses runs of white space, so that phrases match whatever the line breaks.
fn flat(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
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

#[test]
fn figure_minima_are_the_fig1_and_fig4_csvs() {
    let (header, body) = table("docs/figures.md", "fig-minima");
    assert_eq!(header.len(), 5);
    for r in &body {
        let (file, power) = match r[0].as_str() {
            "1" => ("host-tests/figures/fig1.csv", "1"),
            "4" => ("host-tests/figures/fig4.csv", "2"),
            f => panic!("docs/figures.md: figure {f} has no minima"),
        };
        assert_eq!(r[1], power, "figure {}: CoG power", r[0]);
        let window = r[2].split_once('x').expect("box as NxN").0;
        let csv = Csv::read(file);
        let (a, rms) = csv
            .records()
            .iter()
            .filter(|x| x["window"] == window)
            .map(|x| (num(x["a_px"]), num(x["rms_px"])))
            .min_by(|p, q| p.1.total_cmp(&q.1))
            .expect("rows of the window");
        assert!(
            matches_value(&r[3], rms),
            "{file} {}: smallest RMS {rms}, the docs say {}",
            r[2],
            r[3]
        );
        assert!(
            matches_value(&r[4], a),
            "{file} {}: minimum at a = {a}, the docs say {}",
            r[2],
            r[4]
        );
    }
}

#[test]
fn figure_5_and_6_table_is_their_csvs() {
    let fig5 = Csv::read("host-tests/figures/fig5.csv");
    let fig6 = Csv::read("host-tests/figures/fig6.csv");
    let (r5, r6) = (fig5.records(), fig6.records());
    let (header, body) = table("docs/figures.md", "fig5-fig6");
    assert_eq!(
        header,
        [
            "SNR",
            "DSNU",
            "background",
            "RMS power 1, px",
            "RMS power 2, px",
            "detected"
        ]
    );
    for r in &body {
        let (snr, dsnu, method) = (num(&r[0]), num(&r[1]), r[2].as_str());
        let key = |x: &&HashMap<&str, &str>| {
            num(x["snr0"]) == snr && num(x["dsnu"]) == dsnu && x["method"] == method
        };
        for (power, cell) in [("1", &r[3]), ("2", &r[4])] {
            let x = r5
                .iter()
                .find(|x| key(x) && x["power"] == power)
                .unwrap_or_else(|| panic!("fig5.csv: no {r:?}"));
            assert!(
                matches(cell, x["rms_px"]),
                "fig5 SNR {snr} DSNU {dsnu} {method} power {power}: {cell} against {}",
                x["rms_px"]
            );
        }
        let x = r6
            .iter()
            .find(key)
            .unwrap_or_else(|| panic!("fig6.csv: no {r:?}"));
        assert!(
            matches(&r[5], x["detect_rate"]),
            "fig6 SNR {snr} DSNU {dsnu} {method}: {} against {}",
            r[5],
            x["detect_rate"]
        );
    }
}

/// The bit table under `marker` in docs/formats.md against `bits` (name, value), in order:
/// one row each, its bit, value and name.
fn check_bit_table(marker: &str, columns: &[&str], bits: &[(&str, u32)]) {
    let (header, body) = table("docs/formats.md", marker);
    assert_eq!(header, columns, "{marker}: columns");
    assert_eq!(body.len(), bits.len(), "{marker}: one row per bit");
    for (r, (name, value)) in body.iter().zip(bits) {
        let bit = value.trailing_zeros();
        assert_eq!(r[0], bit.to_string(), "{name}'s bit");
        assert_eq!(r[1], value.to_string(), "{name}'s value");
        assert_eq!(r[2].replace('`', ""), *name, "bit {bit}'s name");
    }
}

#[test]
fn star_flag_table_is_star_flags() {
    let flags: Vec<(&str, u32)> = StarFlags::all()
        .iter_names()
        .map(|(n, f)| (n, f.bits()))
        .collect();
    check_bit_table(
        "star-flags",
        &["bit", "value", "flag", "from", "meaning"],
        &flags,
    );
}

#[test]
fn star_provenance_table_is_the_provenance_bits() {
    let bits: Vec<(&str, u32)> = Provenance::all()
        .iter_names()
        .map(|(n, f)| (n, u32::from(f.bits())))
        .collect();
    check_bit_table(
        "star-provenance",
        &["bit", "value", "flag", "meaning"],
        &bits,
    );
}

#[test]
fn tracker_config_table_is_the_flight_configuration() {
    let (header, body) = table("docs/tracker.md", "tracker-config");
    assert_eq!(header, ["field", "unit", "flight", "meaning"]);
    let f = TrackerConfig::FLIGHT;
    let expected: Vec<(&str, String)> = vec![
        ("acquisition_method", format!("{:?}", f.acquisition_method)),
        ("tracking_method", format!("{:?}", f.tracking_method)),
        ("window_px", f.window_px.to_string()),
        ("track_margin_px", f.track_margin_px.to_string()),
        ("psf_a_px", f.psf_a_px.to_string()),
        ("pixcorr_tolerance", f.pixcorr_tolerance.to_string()),
        ("background_stride", f.background_stride.to_string()),
        (
            "background_warmup_rows",
            f.background_warmup_rows.to_string(),
        ),
        ("max_stars", f.max_stars.to_string()),
        ("max_tracked", f.max_tracked.to_string()),
        ("min_track_stars", f.min_track_stars.to_string()),
        ("reacquire_every", f.reacquire_every.to_string()),
        ("exposure_ms", f.exposure_ms.to_string()),
        ("line_summary_every", f.line_summary_every.to_string()),
    ];
    assert_eq!(body.len(), expected.len(), "one row per field");
    for (r, (field, value)) in body.iter().zip(&expected) {
        assert_eq!(r[0].replace('`', ""), *field);
        assert_eq!(r[2].replace('`', ""), *value, "{field}");
    }
}

#[test]
fn tracker_memory_table_is_size_of() {
    use startrack_core::centroid::raw_cog::RawCogPlan;
    use startrack_core::detect::ScanDetector;
    use startrack_core::tracker::{Capture, Ring};
    use std::mem::size_of;
    let (header, body) = table("docs/tracker.md", "tracker-memory");
    assert_eq!(header, ["component", "bytes (64-bit host)", "what"]);
    let sizes = [
        ("Ring", size_of::<Ring>()),
        ("Capture", size_of::<Capture>()),
        ("RawCogPlan x 32", 32 * size_of::<RawCogPlan>()),
        ("TrackerBuffers", size_of::<TrackerBuffers>()),
        ("ScanDetector<32>", size_of::<ScanDetector<'static, 32>>()),
        ("Tracker<32>", size_of::<Tracker<'static, 'static, 32>>()),
    ];
    assert_eq!(body.len(), sizes.len());
    for (r, (name, size)) in body.iter().zip(sizes) {
        assert_eq!(r[0].replace('`', ""), name);
        assert_eq!(r[1], size.to_string(), "{name}");
    }
}

/// GitHub's anchor of a heading: lower case, punctuation but `-` and `_` dropped, spaces as
/// `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

/// The lines of a page outside fenced code blocks.
fn prose(text: &str) -> Vec<&str> {
    let mut fenced = false;
    text.lines()
        .filter(|l| {
            if l.trim_start().starts_with("```") {
                fenced = !fenced;
                return false;
            }
            !fenced
        })
        .collect()
}

/// The anchors of a page's headings.
fn anchors(text: &str) -> BTreeSet<String> {
    prose(text)
        .iter()
        .filter_map(|l| {
            let t = l.trim_start_matches('#');
            (l.starts_with('#') && t.starts_with(' ')).then(|| slug(t))
        })
        .collect()
}

/// The targets of a line's markdown links and images, `[text](target)`.
fn link_targets(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        match after.find(')') {
            Some(j) => {
                out.push(after[..j].to_string());
                rest = &after[j + 1..];
            }
            None => break,
        }
    }
    out
}

#[test]
fn every_relative_link_resolves() {
    let mut checked = 0;
    for (page, text) in pages() {
        let dir = root().join(&page).parent().unwrap().to_path_buf();
        for line in prose(&text) {
            for target in link_targets(line) {
                if target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                let (path, anchor) = match target.split_once('#') {
                    Some((p, a)) => (p, Some(a)),
                    None => (target.as_str(), None),
                };
                let file = if path.is_empty() {
                    root().join(&page)
                } else {
                    dir.join(path)
                };
                assert!(
                    file.exists(),
                    "{page}: link {target} -> {} does not exist",
                    file.display()
                );
                if let Some(a) = anchor {
                    let text = std::fs::read_to_string(&file).expect("a linked page");
                    assert!(
                        anchors(&text).contains(a),
                        "{page}: link {target}: no heading #{a} in {}",
                        file.display()
                    );
                }
                checked += 1;
            }
        }
    }
    assert!(
        checked > 20,
        "only {checked} links found: is the parser broken?"
    );
}

#[test]
fn pages_speak_of_the_product() {
    for (page, text) in pages() {
        let lower = text.to_lowercase();
        // Phrases of a development log, not of the product ("at the time of" is followed by
        // "writing": split so that this file does not read as one).
        let dated = ["at the time of", " writing"].concat();
        for word in ["session", dated.as_str()] {
            assert!(!lower.contains(word), "{page}: {word:?}");
        }
        for (i, _) in lower.match_indices("issue") {
            let next = lower[i + 5..].trim_start_matches([' ', '\'', 's']);
            assert!(
                !next.starts_with(|c: char| c.is_ascii_digit()),
                "{page}: an issue number: {:?}",
                &text[i..(i + 12).min(text.len())]
            );
        }
    }
}

#[test]
fn readme_stays_short() {
    // The README says what the project is and links the reference pages in docs/, which hold
    // the rest.
    let n = read("README.md").lines().count();
    assert!(
        n <= 150,
        "README.md has {n} lines: move reference material to docs/"
    );
}

/// docs/sequencer.md's readout-plan table: each row recompiled with `startrack readout-plan`'s
/// code (both outputs, binning 1, 11-pixel windows, seed 1) and compared cell by cell.
#[test]
fn readout_plan_table_is_the_compiled_programs() {
    use startrack_host::cli::readout_plan::{Mode, ReadoutPlanArgs, plan_cost};
    let (header, body) = table("docs/sequencer.md", "readout-plan");
    assert_eq!(
        header.join(","),
        startrack_host::cli::readout_plan::HEADER,
        "docs/sequencer.md: readout-plan header"
    );
    assert!(body.len() >= 12);
    for row in body {
        let mode = match row[0].as_str() {
            "full" => Mode::Full,
            "windows" => Mode::Windows,
            m => panic!("docs/sequencer.md: mode {m:?}"),
        };
        let args = ReadoutPlanArgs {
            mode,
            pixel_rate_hz: row[1].parse().expect("pixel rate"),
            windows: row[3].parse().expect("windows"),
            window_px: 11,
            outputs: row[2].parse().expect("outputs"),
            binning: 1,
            exposure_us: 0,
            seed: 1,
            breakdown: false,
        };
        let got = plan_cost(&args).expect("plan compiles").row;
        let got = got.split(',').collect::<Vec<_>>();
        // A full-frame row prints 0 windows whatever --windows says.
        assert_eq!(row, got, "docs/sequencer.md: readout-plan row");
    }
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
    use startrack_host::frame_accuracy::{from_csv, markdown};
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
    use startrack_host::frame_accuracy::{from_csv, markdown};
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
