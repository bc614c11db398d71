//! Lost in space while the spacecraft turns ([`startrack_analysis::acquisition_rates`]):
//! acquisition frames only, each identified from nothing, on the SIL's sky turning during
//! each exposure; trailed stars fitted with their trail unknown, at mid-exposure.

use startrack_analysis::acquisition_rates::{self, ACQ_CASES, AcqCase};

/// The committed table (docs/tracker.md, "Lost in space at body rate").
pub const ACQ_CSV: &str = "host-tests/figures/acquisition-rates.csv";

#[test]
#[ignore = "exploration"]
fn explore() {
    let runs: u64 = std::env::var("RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    for c in ACQ_CASES {
        let r = acquisition_rates::run_case(&c, 300, runs).unwrap();
        eprintln!("{c:?}: {r:?}");
    }
    let _: Option<AcqCase> = None;
}
