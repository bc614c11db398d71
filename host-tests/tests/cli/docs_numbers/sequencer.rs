//! `docs/sequencer.md`'s readout-plan table against the programs the sequencer compiles.

use super::helpers::table;

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
