//! docs/attitude.md: the identification table against tetra3rs (the focal length told
//! wrong and sparse fields) against `host-tests/data/ident-tetra3rs.csv`, which
//! `host-tests/scripts/tetra3rs_scale_sparse.py` writes, and the real-sky comparison with
//! tetra3rs against its committed CSV.

use super::helpers::{Csv, flat, matches, read, table};

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

const REALSKY: &str = "host-tests/figures/realsky-tetra3rs.csv";

/// The "Real night-sky images" table is `host-tests/figures/realsky-tetra3rs.csv` row for
/// row, and the prose's largest differences are the CSV's.
#[test]
fn realsky_table_is_its_csv() {
    let csv = Csv::read(REALSKY);
    let recs = csv.records();
    assert_eq!(recs.len(), 8, "{REALSKY}: the eight shared frames");
    let (header, body) = table("docs/attitude.md", "realsky-tetra3rs");
    assert_eq!(header.len(), 8);
    assert_eq!(body.len(), recs.len(), "one row per frame");
    let (mut b_max, mut r_max) = (0.0f64, 0.0f64);
    for (row, r) in body.iter().zip(&recs) {
        let name = r["image"]
            .trim_start_matches("2019-07-29T204726_")
            .trim_end_matches("_Try1");
        assert_eq!(row[0], name);
        assert!(matches(&row[1], r["st_ra_deg"]), "{row:?}");
        assert!(matches(&row[2], r["st_dec_deg"]), "{row:?}");
        assert!(matches(&row[3], r["st_roll_deg"]), "{row:?}");
        assert_eq!(row[4], format!("{} ({})", r["st_matched"], r["t3_matched"]));
        assert_eq!(
            row[5],
            format!("{} ({})", r["st_rmse_arcsec"], r["t3_rmse_arcsec"])
        );
        assert!(matches(&row[6], r["boresight_diff_arcsec"]), "{row:?}");
        assert!(matches(&row[7], r["roll_diff_arcsec"]), "{row:?}");
        b_max = b_max.max(r["boresight_diff_arcsec"].parse::<f64>().unwrap());
        r_max = r_max.max(r["roll_diff_arcsec"].parse::<f64>().unwrap().abs());
    }
    let page = flat(&read("docs/attitude.md"));
    let phrase = format!(
        "The boresights agree within {b_max:.2} arcsec (0.05 px at 40 arcsec a pixel) and the rolls within {r_max:.1} arcsec"
    );
    assert!(page.contains(&phrase), "docs/attitude.md lacks {phrase:?}");
}
