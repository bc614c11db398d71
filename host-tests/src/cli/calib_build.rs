//! `startrack calib build`: the calibration table from measured maps
//! ([`startrack_lab::table_build`], where each input and its conversion are described), written
//! to `--out`, with one line per input saying what became of it.

use super::{CliError, write_file};
use startrack_lab::table_build::{BuildReport, CalibBuildArgs, build};

/// Runs `startrack calib build`: writes the table and prints what each input became.
pub fn run(args: &CalibBuildArgs) -> Result<BuildReport, CliError> {
    let (bytes, report) = build(args)?;
    write_file(&args.out, &bytes)?;
    for n in &report.notes {
        println!("{n}");
    }
    println!("wrote {} ({} bytes)", args.out.display(), report.bytes);
    Ok(report)
}
