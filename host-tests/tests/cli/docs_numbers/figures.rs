//! `docs/figures.md` against the CSVs its figures are drawn from (`host-tests/figures/fig*.csv`).

use super::helpers::{Csv, matches, matches_value, num, table};
use std::collections::HashMap;

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
