//! `startrack accuracy`: the table of every centroid method's RMS error over the Cramer-Rao
//! bound, and of its error estimate over its measured scatter, from the seeded Monte Carlo of
//! [`startrack_analysis::accuracy`], printed as markdown.

use clap::Args;
use startrack_analysis::accuracy::{
    Method, Noise, markdown, run as run_table, width_unknown_csv, width_unknown_markdown,
    width_unknown_methods,
};

/// Options of `startrack accuracy`.
#[derive(Args, Clone, Debug)]
pub struct AccuracyArgs {
    /// Stars per cell (the RMS's relative standard error is 1/sqrt(4 N)).
    #[arg(long, default_value_t = 2000)]
    pub trials: usize,
    /// Seed (reruns with the same seed print the same table).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// PSF widths a (80 %-energy radius), px, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [0.7, 1.0, 1.5, 2.0])]
    pub a: Vec<f64>,
    /// SNRs (eq. 8 in a 5x5 box), comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = [10.0, 30.0, 100.0])]
    pub snr: Vec<f64>,
    /// Background, e- per pixel.
    #[arg(long, default_value_t = 100.0)]
    pub background_e: f64,
    /// Read noise, e- RMS.
    #[arg(long, default_value_t = 5.0)]
    pub read_noise_e: f64,
    /// Instead: the "width unknown" table, the width-free fit (the flight method) and a fit
    /// of an assumed a = 1.2 px on stars of the widths `--a` (default here 0.6, 0.8, 1,
    /// 1.5, 2 when `--a` is not given).
    #[arg(long)]
    pub width_unknown: bool,
    /// With `--width-unknown`: also write its cells as CSV to this file.
    #[arg(long, requires = "width_unknown")]
    pub csv: Option<std::path::PathBuf>,
}

/// Why the table cannot be made.
#[derive(Clone, Debug, PartialEq)]
pub struct AccuracyError(pub String);

impl std::fmt::Display for AccuracyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for AccuracyError {}

/// Runs the Monte Carlo and returns the markdown tables.
pub fn run(args: &AccuracyArgs) -> Result<String, AccuracyError> {
    let usage = |m: &str| Err(AccuracyError(m.into()));
    if args.trials == 0 {
        return usage("--trials must be at least 1");
    }
    if args
        .a
        .iter()
        .any(|a| !(a.is_finite() && *a > 0.1 && *a < 20.0))
    {
        return usage("--a: widths must be in (0.1, 20) px");
    }
    if args.snr.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return usage("--snr: values must be positive");
    }
    let usable = |v: f64| v.is_finite() && v >= 0.0;
    if !(usable(args.background_e) && usable(args.read_noise_e)) {
        return usage("--background-e and --read-noise-e must be finite and not negative");
    }
    let noise = Noise {
        background_e: args.background_e,
        read_noise_e: args.read_noise_e,
        trials: args.trials,
        seed: args.seed,
    };
    if args.width_unknown {
        let default_a = [0.7, 1.0, 1.5, 2.0];
        let widths = if args.a == default_a {
            vec![0.6, 0.8, 1.0, 1.5, 2.0]
        } else {
            args.a.clone()
        };
        let cells = run_table(&width_unknown_methods(), &widths, &args.snr, &noise);
        if let Some(p) = &args.csv {
            std::fs::write(p, width_unknown_csv(&cells))
                .map_err(|e| AccuracyError(format!("{}: {e}", p.display())))?;
        }
        return Ok(width_unknown_markdown(&cells, &args.snr, &noise));
    }
    let methods = Method::all();
    let cells = run_table(&methods, &args.a, &args.snr, &noise);
    Ok(markdown(&cells, &methods, &args.a, &args.snr, &noise))
}
