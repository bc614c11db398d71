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

const OPTICS: &str = "host-tests/figures/realsky-optics.csv";

/// The camera model fitted to the shared frames: docs/attitude.md's two tables are
/// `host-tests/figures/realsky-optics.csv` (which `cli_optics_sky` checks against a fresh
/// `optics fit --images`).
#[test]
fn realsky_optics_tables_are_their_csv() {
    let csv = Csv::read(OPTICS);
    let recs = csv.records();
    let get = |q: &str| -> (&str, &str) {
        let r = recs
            .iter()
            .find(|r| r["quantity"] == q)
            .unwrap_or_else(|| panic!("{OPTICS}: no {q}"));
        (r["value"], r["sigma"])
    };
    const PARAMS: [(&str, &str); 6] = [
        ("focal length, px", "focal_length_px"),
        ("principal point column, px", "cx_px"),
        ("principal point row, px", "cy_px"),
        ("`k1`", "k1"),
        ("`k2`", "k2"),
        ("`p1`, `p2`", "p1"),
    ];
    let (_, body) = table("docs/attitude.md", "realsky-optics");
    assert_eq!(body.len(), PARAMS.len());
    for (row, (name, q)) in body.iter().zip(PARAMS) {
        assert_eq!(row[0], name);
        let (v, s) = get(q);
        if s == "held" {
            assert!(matches(&row[1], v), "{row:?}");
            assert_eq!(row[2], "held", "{row:?}");
        } else {
            assert!(matches(&row[1], v), "{row:?}: {v}");
            assert!(matches(&row[2], s), "{row:?}: {s}");
        }
    }
    let (_, body) = table("docs/attitude.md", "realsky-optics-residuals");
    let rows = [
        ("stars", "rms_pinhole_px", "rms_model_px"),
        (
            "holdout1_stars",
            "holdout1_rms_pinhole_px",
            "holdout1_rms_model_px",
        ),
        (
            "holdout2_stars",
            "holdout2_rms_pinhole_px",
            "holdout2_rms_model_px",
        ),
    ];
    assert_eq!(body.len(), rows.len());
    for (row, (n, a, b)) in body.iter().zip(rows) {
        assert_eq!(row[1], get(n).0, "{row:?}");
        assert!(matches(&row[2], get(a).0), "{row:?}");
        assert!(matches(&row[3], get(b).0), "{row:?}");
    }
}

/// The prose's figures of the variants (`k2` held, the tangential terms and the colour
/// scale fitted) are their committed CSVs'.
#[test]
fn realsky_optics_variants_are_their_csvs() {
    let value = |rel: &str, q: &str| -> (f64, String) {
        let csv = Csv::read(rel);
        let recs = csv.records();
        let r = recs
            .iter()
            .find(|r| r["quantity"] == q)
            .unwrap_or_else(|| panic!("{rel}: no {q}"));
        (r["value"].parse().unwrap(), r["sigma"].to_string())
    };
    let f = |rel: &str, q: &str| value(rel, q).0;
    let s = |rel: &str, q: &str| value(rel, q).1.parse::<f64>().unwrap();
    let no_k2 = "host-tests/figures/realsky-optics-no-k2.csv";
    let tan = "host-tests/figures/realsky-optics-tangential.csv";
    let col = "host-tests/figures/realsky-optics-colour.csv";
    let page = flat(&read("docs/attitude.md"));
    let phrases = [
        format!(
            "Without `k2` the holdout residuals are {:.4} and {:.4} px",
            f(no_k2, "holdout1_rms_model_px"),
            f(no_k2, "holdout2_rms_model_px")
        ),
        format!(
            "(fitted: `p1` {:.1e} +- {:.1e}, `p2` {:.1e} +- {:.1e}) make both holdouts worse ({:.4} and {:.4} px) and the principal point's sigma grows from {:.1} to {:.1} px",
            f(tan, "p1"),
            s(tan, "p1"),
            f(tan, "p2"),
            s(tan, "p2"),
            f(tan, "holdout1_rms_model_px"),
            f(tan, "holdout2_rms_model_px"),
            s(OPTICS, "cx_px"),
            s(tan, "cx_px"),
        ),
        format!(
            "The lateral colour scale fits to {:.1e} +- {:.1e} per mag",
            f(col, "colour_scale_per_mag"),
            s(col, "colour_scale_per_mag")
        ),
    ];
    for p in &phrases {
        assert!(page.contains(p.as_str()), "docs/attitude.md lacks {p:?}");
    }
    // The chosen model beats each variant on both holdouts or is within 0.001 px of it.
    for v in [no_k2, tan, col] {
        for h in ["holdout1_rms_model_px", "holdout2_rms_model_px"] {
            assert!(f(OPTICS, h) <= f(v, h) + 0.001, "{v}: {h}");
        }
    }
}

/// The release timing of `solve-image`: the docs' range and median are the committed run's.
#[test]
fn realsky_time_per_image_is_its_csv() {
    let csv = Csv::read("host-tests/figures/realsky-solve-release.csv");
    let c = csv.col("time_ms");
    let mut t: Vec<f64> = csv.rows.iter().map(|r| r[c].parse().unwrap()).collect();
    assert_eq!(t.len(), 8);
    t.sort_by(f64::total_cmp);
    let median = (t[3] + t[4]) / 2.0;
    let phrase = format!("was {:.1} to {:.1} ms, median {median:.1} ms", t[0], t[7]);
    let page = flat(&read("docs/attitude.md"));
    assert!(page.contains(&phrase), "docs/attitude.md lacks {phrase:?}");
}

/// What the prose derives from the fit (the holdout's gain, the principal point's offset from
/// the centre of the 1024 x 768 frames, the terms' significance, the distortion at the
/// farthest corner) is computed from `realsky-optics.csv`.
#[test]
fn realsky_optics_prose_is_its_csv() {
    let csv = Csv::read(OPTICS);
    let recs = csv.records();
    let get = |q: &str, col: &str| -> f64 {
        recs.iter()
            .find(|r| r["quantity"] == q)
            .unwrap_or_else(|| panic!("{OPTICS}: no {q}"))[col]
            .parse()
            .unwrap()
    };
    let v = |q: &str| get(q, "value");
    let s = |q: &str| get(q, "sigma");
    let gain = |n: u8| {
        100.0
            * (1.0
                - v(&format!("holdout{n}_rms_model_px")) / v(&format!("holdout{n}_rms_pinhole_px")))
    };
    let (dx, dy) = (v("cx_px") - 511.5, v("cy_px") - 383.5);
    // The corner farthest from the principal point, and the distortion's radial shift there.
    let (cx, cy, f) = (v("cx_px"), v("cy_px"), v("focal_length_px"));
    let r = [(0.0, 0.0), (1023.0, 0.0), (0.0, 767.0), (1023.0, 767.0)]
        .iter()
        .map(|(x, y): &(f64, f64)| (x - cx).hypot(y - cy))
        .fold(0.0, f64::max);
    let rn2 = (r / f).powi(2);
    let corner_px = r * (v("k1") * rn2 + v("k2") * rn2 * rn2);
    let phrase = format!(
        "The model takes {:.0} % and {:.0} % of the residual off frames it was not fitted to. The principal point is {dx:.1} px right of and {dy:.1} px below the image centre ({:.1} and {:.1} sigma); `k1` is {:.1} sigma and `k2` {:.1}: together a pincushion of {corner_px:.1} px at the farthest corner.",
        gain(1),
        gain(2),
        dx / s("cx_px"),
        dy / s("cy_px"),
        v("k1") / s("k1"),
        v("k2").abs() / s("k2"),
    );
    let page = flat(&read("docs/attitude.md"));
    assert!(page.contains(&phrase), "docs/attitude.md lacks {phrase:?}");
}

const MORE: &str = "host-tests/figures/realsky-more.csv";

/// The rows of the "More skies" table: each a set, the images' folder and the nominal field.
const MORE_GROUPS: [(&str, &str, &str); 9] = [
    (
        "openstartracker",
        "tests/science_cam_may8_0.1sec_gain40/samples",
        "6.1",
    ),
    (
        "openstartracker",
        "tests/science_cam_may8_0.05sec_gain40/samples",
        "6.1",
    ),
    (
        "openstartracker",
        "tests/science_cam_may8_0.04sec_gain40/samples",
        "6.1",
    ),
    (
        "openstartracker",
        "tests/science_cam_may8_0.03sec_gain40/samples",
        "6.1",
    ),
    (
        "openstartracker",
        "tests/science_cam_may8_0.1sec_gain12/samples",
        "6.1",
    ),
    ("cedar-solve", "examples/data/medium_fov", "11"),
    ("cedar-solve", "examples/data/medium_fov", "10"),
    ("cedar-solve", "examples/data/medium_fov", "15"),
    ("cedar-solve", "examples/data/medium_fov", "20"),
];

/// The "More skies" table is `host-tests/figures/realsky-more.csv` summed per set, folder
/// and field, and the prose's totals and largest differences are the CSV's.
#[test]
fn realsky_more_table_is_its_csv() {
    let csv = Csv::read(MORE);
    let recs = csv.records();
    let (header, body) = table("docs/attitude.md", "realsky-more");
    assert_eq!(header.len(), 10);
    assert_eq!(body.len(), MORE_GROUPS.len());
    let others = ["t3rs", "t3st", "cs"];
    let (mut b_all, mut r_all) = (0.0f64, 0.0f64);
    let mut in_groups = 0;
    for (row, (set, folder, fov)) in body.iter().zip(MORE_GROUPS) {
        let rs: Vec<_> = recs
            .iter()
            .filter(|r| {
                r["set"] == set
                    && r["nominal_fov_deg"] == fov
                    && r["image"].rsplit_once('/').map(|(d, _)| d) == Some(folder)
            })
            .collect();
        in_groups += rs.len();
        let solved = |k: &str| {
            rs.iter()
                .filter(|r| r[format!("{k}_solved").as_str()] == "1")
                .count()
        };
        assert_eq!(row[1], fov, "{row:?}");
        assert_eq!(row[2], rs.len().to_string(), "{row:?}");
        assert_eq!(row[3], solved("st").to_string(), "{row:?}");
        assert_eq!(row[4], solved("t3rs").to_string(), "{row:?}");
        assert_eq!(row[5], solved("t3st").to_string(), "{row:?}");
        if rs.iter().all(|r| r["cs_run"] == "0") {
            assert_eq!(row[6], "not run", "{row:?}");
        } else {
            assert_eq!(row[6], solved("cs").to_string(), "{row:?}");
        }
        let col = |name: String| -> Vec<f64> {
            rs.iter()
                .filter_map(|r| r.get(name.as_str()).filter(|v| !v.is_empty()))
                .map(|v| v.parse::<f64>().unwrap().abs())
                .collect()
        };
        let b: Vec<f64> = others
            .iter()
            .flat_map(|k| col(format!("{k}_boresight_diff_arcsec")))
            .collect();
        let r: Vec<f64> = others
            .iter()
            .flat_map(|k| col(format!("{k}_roll_diff_arcsec")))
            .collect();
        let w = col("st_wcs_rms_px".into());
        if b.is_empty() {
            assert!(
                row[7].is_empty() && row[8].is_empty() && row[9].is_empty(),
                "{row:?}"
            );
            continue;
        }
        let max = |v: &[f64]| v.iter().copied().fold(0.0f64, f64::max);
        let min = |v: &[f64]| v.iter().copied().fold(f64::MAX, f64::min);
        assert!(matches(&row[7], &format!("{:.2}", max(&b))), "{row:?}");
        assert!(matches(&row[8], &format!("{:.1}", max(&r))), "{row:?}");
        let wcs = match row[9].split_once(" to ") {
            Some((lo, hi)) => {
                matches(lo, &format!("{:.3}", min(&w))) && matches(hi, &format!("{:.3}", max(&w)))
            }
            None => matches(&row[9], &format!("{:.3}", max(&w))) && min(&w) == max(&w),
        };
        assert!(wcs, "{row:?}: {w:?}");
        b_all = b_all.max(max(&b));
        r_all = r_all.max(max(&r));
    }
    assert_eq!(in_groups, recs.len(), "every image in a row of the table");
    let total = |k: &str| {
        recs.iter()
            .filter(|r| r[format!("{k}_solved").as_str()] == "1")
            .count()
    };
    let page = flat(&read("docs/attitude.md"));
    for phrase in [
        format!("every attitude `solve-image` gives is within {b_all:.2} arcsec"),
        format!("its roll within {r_all:.1} arcsec"),
        format!(
            "Of the {} images `solve-image` solves {}, tetra3rs {} end to end and {} from `solve-image`'s own stars, cedar-solve {} of the {} it was run on",
            recs.len(),
            total("st"),
            total("t3rs"),
            total("t3st"),
            total("cs"),
            recs.iter().filter(|r| r["cs_run"] == "1").count()
        ),
        format!(
            "it gives no attitude on the {} frames it does not solve",
            recs.len() - total("st")
        ),
    ] {
        assert!(page.contains(&phrase), "docs/attitude.md lacks {phrase:?}");
    }
}
