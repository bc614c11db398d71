//! What the per-page checks share: reading the workspace's files and CSVs, parsing a checked
//! table, and comparing a number as the docs write it with the value it comes from (a number
//! written with `d` decimals matches a value when it is that value rounded to `d` decimals,
//! give or take the CSV's own rounding).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The workspace root.
pub(super) fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("host-tests/ has a parent")
        .to_path_buf()
}

/// A file of the workspace, by its path from the root.
pub(super) fn read(rel: &str) -> String {
    let p = root().join(rel);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A CSV: the column names (first line that is not a `#` comment) and the rows.
pub(super) struct Csv {
    pub(super) columns: Vec<String>,
    pub(super) rows: Vec<Vec<String>>,
}

impl Csv {
    pub(super) fn read(rel: &str) -> Self {
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

    pub(super) fn col(&self, name: &str) -> usize {
        self.columns
            .iter()
            .position(|c| c == name)
            .unwrap_or_else(|| panic!("no column {name} in {:?}", self.columns))
    }

    /// The rows as maps from column name to value.
    pub(super) fn records(&self) -> Vec<HashMap<&str, &str>> {
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
    pub(super) fn distinct(&self, name: &str) -> Vec<String> {
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
pub(super) fn num(s: &str) -> f64 {
    let t = s.trim().trim_matches('`').replace(',', "");
    t.parse()
        .unwrap_or_else(|e| panic!("not a number: {s:?} ({e})"))
}

/// Half a unit of the last digit `s` is written with (`1.54` -> 0.005, `4,758` -> 0.5,
/// `1.554882e-1` -> 5e-8).
pub(super) fn half_unit(s: &str) -> f64 {
    let t = s.trim().trim_matches('`').replace(',', "");
    let (mantissa, exp) = match t.split_once(['e', 'E']) {
        Some((m, e)) => (m.to_string(), e.parse::<i32>().expect("exponent")),
        None => (t.clone(), 0),
    };
    let decimals = mantissa.split_once('.').map_or(0, |(_, d)| d.len()) as i32;
    0.5 * 10f64.powi(exp - decimals)
}

/// Whether the docs' `doc` is the CSV's `csv` rounded as written (both roundings allowed).
pub(super) fn matches(doc: &str, csv: &str) -> bool {
    (num(doc) - num(csv)).abs() <= half_unit(doc) + half_unit(csv) + 1e-12
}

/// Whether the docs' `doc` is the exact `value` rounded as written.
pub(super) fn matches_value(doc: &str, value: f64) -> bool {
    (num(doc) - value).abs() <= half_unit(doc) * (1.0 + 1e-9)
}

/// Splits a markdown table line into its trimmed cells.
pub(super) fn cells(line: &str) -> Vec<String> {
    let t = line.trim();
    let t = t.strip_prefix('|').unwrap_or(t);
    let t = t.strip_suffix('|').unwrap_or(t);
    t.split('|').map(|c| c.trim().to_string()).collect()
}

/// The marker that names a checked table.
pub(super) fn marker(name: &str) -> String {
    format!("<!-- checked: {name} -->")
}

/// The table after `<!-- checked: NAME -->` in page `page`: its header cells and body rows.
pub(super) fn table(page: &str, name: &str) -> (Vec<String>, Vec<Vec<String>>) {
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

pub(super) const TRADEOFF: &str = "host-tests/figures/tradeoff.csv";

/// Collapses runs of white space, so that phrases match whatever the line breaks.
pub(super) fn flat(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}
