//! What the command tests share: running a `startrack` binary, and `calib build`'s options
//! for the maps `simulate` writes.

use startrack_host::cli::simulate::SimFiles;
use startrack_lab::table_build::CalibBuildArgs;
use std::path::PathBuf;
use std::process::Command;

/// Runs the binary at `exe` (a test passes `env!("CARGO_BIN_EXE_startrack")`); returns
/// (success, stdout, stderr).
pub fn run(exe: &str, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(exe).args(args).output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `calib build` with every option at its command-line default and no map at all, writing
/// `out` (a test sets the few it needs on top).
pub fn bare_args(out: PathBuf) -> CalibBuildArgs {
    CalibBuildArgs::with_defaults(out)
}

/// `calib build` of every map `simulate` wrote into `f`, with the command's defaults: gains
/// from the maps' keywords, per-pixel maps, the ADC's full range as saturation, no
/// pixel-phase curves.
pub fn build_args(f: &SimFiles, out: PathBuf) -> CalibBuildArgs {
    CalibBuildArgs {
        bias: Some(f.bias.clone()),
        dark: Some(f.dark.clone()),
        flat: Some(f.flat.clone()),
        hot: Some(f.hot.clone()),
        ..bare_args(out)
    }
}
