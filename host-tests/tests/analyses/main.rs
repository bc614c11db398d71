//! Analyses and figures: the accuracy tables and their frame Monte Carlo, the paper's figures,
//! and the trade-off.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod accuracy;
mod accuracy_frames;
mod accuracy_width;
mod figures_dark;
mod figures_pixelisation;
mod tradeoff;
mod tradeoff_failures;
mod tradeoff_shapes;
mod trail_chart;

/// The command-line helpers, with `startrack` running this package's binary.
mod common_cli {
    pub use startrack_test_support::cli::*;

    /// Runs the `startrack` binary with `args`: (success, stdout, stderr).
    pub fn startrack(args: &[&str]) -> (bool, String, String) {
        run(env!("CARGO_BIN_EXE_startrack"), args)
    }
}
