//! The command line end to end and the documents' numbers against the outputs they come from.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod cli_commands;
mod cli_models;
mod cli_optics_sky;
mod cli_pil_faults;
mod cli_pixcorr;
mod cli_sil_motion;
mod cli_solve_image;
mod docs_numbers;

/// The command-line helpers, with `startrack` running this package's binary.
mod common_cli {
    pub use startrack_test_support::cli::*;

    /// Runs the `startrack` binary with `args`: (success, stdout, stderr).
    pub fn startrack(args: &[&str]) -> (bool, String, String) {
        run(env!("CARGO_BIN_EXE_startrack"), args)
    }
}
