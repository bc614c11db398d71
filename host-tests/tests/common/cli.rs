//! What the command tests share: running the `startrack` binary, and `calib build`'s options
//! for the maps `simulate` writes.
#![allow(dead_code)]

use startrack_host::cli::calib_build::CalibBuildArgs;
use startrack_host::cli::simulate::SimFiles;
use std::path::PathBuf;
use std::process::Command;

/// Runs the binary; returns (success, stdout, stderr).
pub fn startrack(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_startrack"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// `calib build` with every option at its command-line default and no map at all, writing
/// `out` (a test sets the few it needs on top).
pub fn bare_args(out: PathBuf) -> CalibBuildArgs {
    CalibBuildArgs {
        out,
        bias: None,
        dark: None,
        flat: None,
        gains: None,
        hot: None,
        hot_exposure_s: 1.0,
        hot_ref_k: 293.0,
        hot_doubling_k: 6.0,
        hot_exclude_above_e: 10_000.0,
        tile_log2: 0,
        saturation_adu: 65535,
        psf_a_px: None,
        pixcorr_boxes: "5,7".into(),
        pixcorr_powers: "1,2".into(),
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    }
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
