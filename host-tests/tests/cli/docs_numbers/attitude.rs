//! docs/attitude.md: the identification table against tetra3rs (the focal length told
//! wrong and sparse fields) against `host-tests/data/ident-tetra3rs.csv`, which
//! `host-tests/scripts/tetra3rs_scale_sparse.py` writes.

use super::helpers::{Csv, matches, table};

/// The docs' name of each case of the CSV.
const CASES: [(&str, &str); 4] = [
    ("as written", "nominal"),
    ("focal length 1 % long", "focal_plus_1pct"),
    ("focal length 2 % short", "focal_minus_2pct"),
    ("sparse, Hp <= 5.5", "sparse_hp5.5"),
];

#[test]
fn tetra3rs_table_is_its_csv() {
    let csv = Csv::read("host-tests/data/ident-tetra3rs.csv");
    let records = csv.records();
    let (header, body) = table("docs/attitude.md", "ident-tetra3rs");
    assert_eq!(header[0], "case");
    assert_eq!(body.len(), records.len(), "one row per CSV row");
    for row in &body {
        let case = CASES
            .iter()
            .find(|c| c.0 == row[0])
            .unwrap_or_else(|| panic!("unknown case {:?}", row[0]))
            .1;
        let r = records
            .iter()
            .find(|r| r["case"] == case && r["solver"] == row[1])
            .unwrap_or_else(|| panic!("no CSV row for {case} {}", row[1]));
        assert_eq!(r["fields"], "1000", "{row:?}");
        assert_eq!(row[2], r["solved"], "{row:?}");
        assert_eq!(row[3], r["wrong"], "{row:?}");
        assert!(matches(&row[4], r["boresight_rms_arcsec"]), "{row:?}");
    }
}
