//! The board's routing of the tracker's requests to the sequencer, on the host: the tables
//! the firmware sets aside for a frame (two of them, `firmware/src/sequencer.rs`) hold every
//! plan the board compiles at its pixel rate.

use startrack_host::cli::readout_plan::{Mode, ReadoutPlanArgs, plan_cost};

/// `firmware/src/sequencer.rs`'s `MAX_WORDS` and `MAX_STEPS` (the firmware crate does not
/// build for the host; keep them equal).
const BOARD_MAX_WORDS: usize = 1024;
const BOARD_MAX_STEPS: usize = 4096;

/// Every plan the board compiles (1 MHz, both outputs, binning 1: a full frame, or up to the
/// plan's 64 windows of 11 x 11) fits one of the board's table buffers.
#[test]
fn board_plans_fit_the_board_tables() {
    let (mut words, mut steps) = (0, 0);
    for (mode, n) in [
        (Mode::Full, 0),
        (Mode::Windows, 10),
        (Mode::Windows, 30),
        (Mode::Windows, 60),
        (Mode::Windows, 64),
    ] {
        let a = ReadoutPlanArgs {
            mode,
            pixel_rate_hz: 1_000_000,
            windows: n,
            window_px: 11,
            outputs: 2,
            binning: 1,
            exposure_us: 1_000_000,
            seed: 1,
            breakdown: false,
        };
        let c = plan_cost(&a);
        assert!(c.is_ok(), "{c:?}");
        let Ok(c) = c else { return };
        words = words.max(c.words);
        steps = steps.max(c.steps);
    }
    println!(
        "largest board plan: {words} words (of {BOARD_MAX_WORDS}), {steps} steps (of {BOARD_MAX_STEPS})"
    );
    assert!(words <= BOARD_MAX_WORDS && steps <= BOARD_MAX_STEPS);
}
