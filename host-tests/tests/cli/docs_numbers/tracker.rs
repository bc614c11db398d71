//! `docs/tracker.md` against the code: the flight configuration and the tracker's memory
//! (`size_of` on the 64-bit host).

use super::helpers::table;
use startrack_core::tracker::{Tracker, TrackerBuffers, TrackerConfig};

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

const SIL_RATES: &str = "host-tests/figures/sil-rates.csv";

/// The "At body rate" table of docs/tracker.md is `host-tests/figures/sil-rates.csv`, row
/// for row.
#[test]
fn rate_table_is_the_sil_rates_csv() {
    use super::helpers::{Csv, matches, matches_value, num};
    let csv = Csv::read(SIL_RATES);
    let recs = csv.records();
    let (header, body) = table("docs/tracker.md", "sil-rates");
    assert_eq!(
        header,
        [
            "motion",
            "rate, deg/s",
            "frames",
            "with attitude",
            "with attitude, %",
            "wrong",
            "worst error, arcsec",
            "cross-boresight RMS, arcsec",
            "bound, arcsec",
            "error / bound"
        ]
    );
    assert_eq!(body.len(), recs.len(), "{SIL_RATES}: one row a rate");
    for (row, rec) in body.iter().zip(&recs) {
        assert_eq!(row[0], rec["motion"], "{row:?} vs {rec:?}");
        for (i, col) in [
            (1, "rate_deg_s"),
            (2, "frames"),
            (3, "solved"),
            (5, "wrong"),
            (6, "worst_arcsec"),
            (7, "rms_cross_arcsec"),
            (8, "bound_cross_arcsec"),
            (9, "ratio"),
        ] {
            assert!(matches(&row[i], rec[col]), "{col}: {row:?} vs {rec:?}");
        }
        assert!(
            matches_value(&row[4], 100.0 * num(rec["availability"])),
            "{row:?} vs {rec:?}"
        );
    }
}
