//! `docs/speed.md` against `host-tests/m7-costs.csv` (the M7 stage costs in instructions and
//! their targets) and `host-tests/figures/tradeoff.csv` (the speed-accuracy frontier).

use super::helpers::{Csv, TRADEOFF, half_unit, matches, matches_value, num, table};
use std::collections::{BTreeSet, HashMap};

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
