//! `startrack process FRAME.fits --calib TABLE.bin`: the star list of one raw frame, from
//! the core's tracker application ([`startrack_core::tracker`]) fed the frame's lines: the
//! same code, configuration and output as the board's acquisition frame. The options change
//! only the tracker's configuration.
//!
//! The tracker runs the frame twice, as the board does after start-up: a standby frame that
//! measures the dark scale on the covered columns, then an acquisition frame calibrated with
//! it ([`process_frame`]).
//!
//! The frame's shape must be the table's geometry (lines x line length, 1033 x 1072 for the
//! CCD47-20). Exposure and temperature (for hot pixels' own dark law) come from the options,
//! else from the frame's `EXPTIME` (s) and `CCDTEMP` (K) keywords, else 1 s and the table's
//! hot-pixel reference temperature. The default method fits each star's own PSF width
//! (`gauss-fit-width`, the flight configuration's) and writes it (`psf_a_px`) and the fit's
//! `chi2_dof` to `stars.csv`. A width given by `--psf-a-px` (80 %-energy radius) or
//! `--psf-sigma` makes the fit of that width the default; the width (the `gauss-fit`'s,
//! and which pixel-phase curve a CoG uses) comes from those options, else the frame's
//! `PSFA` keyword (px, written by `startrack simulate`), else the flight configuration's.

use super::{CliError, LabError, read_file};
use clap::builder::TypedValueParser as _;
use startrack_core::table::CalibTable;
use startrack_core::tracker::{CentroidMethod, TrackerConfig};
use startrack_core::units::Kelvin;
use startrack_homes::home::{HOST_CAPACITY, Processed, process_frame, write_csv};
use startrack_sim::fits::{read_keys, read_raw_frame};
use std::path::PathBuf;

/// The acquisition methods `process` offers, by their names.
const METHODS: [CentroidMethod; 4] = [
    CentroidMethod::Cog1,
    CentroidMethod::Cog2,
    CentroidMethod::GaussFit,
    CentroidMethod::GaussFitWidth,
];

/// The `--method` parser: one of [`METHODS`] by name (clap lists them on a bad value).
fn method_parser() -> impl clap::builder::TypedValueParser<Value = CentroidMethod> {
    clap::builder::PossibleValuesParser::new(METHODS.map(CentroidMethod::name)).map(|s| {
        METHODS
            .into_iter()
            .find(|m| m.name() == s)
            .unwrap_or(CentroidMethod::GaussFitWidth)
    })
}

/// Options of `startrack process`.
#[derive(Clone, Debug, clap::Args)]
pub struct ProcessArgs {
    /// Raw frame: FITS, BITPIX 16 with BZERO 32768, lines x columns of the full readout.
    pub frame: PathBuf,
    /// Calibration table (from `startrack calib build` or `startrack table`).
    #[arg(long)]
    pub calib: PathBuf,
    /// Centroid method: gauss-fit-width (the flight configuration's: each star's own PSF
    /// width fitted; the default unless the width is given), gauss-fit (the width given by
    /// --psf-a-px or --psf-sigma: the default when one of them is), cog1 or cog2 (centre of
    /// gravity, power 1 or 2, pixel-phase corrected).
    #[arg(long, value_parser = method_parser())]
    pub method: Option<CentroidMethod>,
    /// Centroid window side, px (odd, 5 to 13); the box is window - 2, the border gives the
    /// background (default: the flight configuration's, 7).
    #[arg(long)]
    pub window: Option<u16>,
    /// PSF Gaussian sigma, px: sqrt(0.31) x the 80 % radius.
    #[arg(long, conflicts_with = "psf_a_px")]
    pub psf_sigma: Option<f32>,
    /// PSF 80 %-energy radius, px: the Gauss fit's width and which pixel-phase curve a CoG
    /// uses.
    #[arg(long)]
    pub psf_a_px: Option<f32>,
    /// Exposure, s (default: the frame's EXPTIME keyword, else 1).
    #[arg(long)]
    pub exposure_s: Option<f64>,
    /// Sensor temperature, K (default: the frame's CCDTEMP keyword, else the table's
    /// hot-pixel reference temperature).
    #[arg(long)]
    pub temperature_k: Option<f64>,
    /// Acquisition background stride, rows (default: the flight configuration's, 16; 1
    /// updates the background on every row).
    #[arg(long)]
    pub background_stride: Option<u16>,
    /// Output CSV (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// The tracker's configuration and the sensor temperature for `args` and the frame's
/// keywords `key`.
pub fn config_of(
    args: &ProcessArgs,
    key: &dyn Fn(&str) -> Option<f64>,
) -> Result<(TrackerConfig, Option<Kelvin>), CliError> {
    let mut config = TrackerConfig {
        max_stars: HOST_CAPACITY as u16,
        ..TrackerConfig::FLIGHT
    };
    // Told the width, the fit of that width; else each star's own (the flight default).
    let told_width = args.psf_sigma.is_some() || args.psf_a_px.is_some();
    match (args.method, told_width) {
        (Some(m), _) => config.acquisition_method = m,
        (None, true) => config.acquisition_method = CentroidMethod::GaussFit,
        (None, false) => {}
    }
    if let Some(w) = args.window {
        config.window_px = w;
    }
    if let Some(s) = args.background_stride {
        config.background_stride = s;
    }
    let exposure_s = args.exposure_s.or(key("EXPTIME")).unwrap_or(1.0);
    if !(0.0..=4.0e6).contains(&exposure_s) {
        return Err(CliError::Usage(format!(
            "exposure {exposure_s} s: must be 0 to 4e6 s"
        )));
    }
    config.exposure_ms = (exposure_s * 1000.0).round() as u32;
    let temperature = args.temperature_k.or(key("CCDTEMP"));
    if let Some(t) = temperature
        && !(1.0..=65535.0).contains(&t)
    {
        return Err(CliError::Usage(format!(
            "temperature {t} K: must be 1 to 65535 K"
        )));
    }
    config.psf_a_px = match (args.psf_sigma, args.psf_a_px) {
        (Some(s), _) => s / 0.31f32.sqrt(),
        (None, Some(a)) => a,
        (None, None) => key("PSFA").map_or(config.psf_a_px, |a| a as f32),
    };
    config
        .validate(HOST_CAPACITY)
        .map_err(|e| CliError::Usage(e.to_string()))?;
    Ok((config, temperature.map(Kelvin::saturating_from_num)))
}

/// Runs the tracker on the frame and returns what it found (nothing written).
pub fn measure(args: &ProcessArgs) -> Result<Processed, CliError> {
    let bytes = read_file(&args.calib)?;
    let table = CalibTable::parse(&bytes).map_err(|err| LabError::Table {
        path: args.calib.clone(),
        err,
    })?;
    let frame = read_raw_frame(&args.frame, table.geometry())?;
    let keys = read_keys(&args.frame, &["EXPTIME", "CCDTEMP", "PSFA"])?;
    let key = |k: &str| keys.iter().find(|(n, _)| n == k).map(|(_, v)| *v);
    let (config, temperature_k) = config_of(args, &key)?;
    process_frame(table, &frame.data_adu, config, temperature_k).map_err(CliError::Usage)
}

/// Runs `startrack process`: the CSV to `--out` or standard output, a one-line summary on
/// standard error.
pub fn run(args: &ProcessArgs) -> Result<(), CliError> {
    let result = measure(args)?;
    let io = |path: PathBuf| {
        move |e: std::io::Error| LabError::Io {
            path,
            msg: e.to_string(),
        }
    };
    match &args.out {
        Some(p) => {
            let mut f = std::io::BufWriter::new(std::fs::File::create(p).map_err(io(p.clone()))?);
            write_csv(&mut f, &result.stars).map_err(io(p.clone()))?;
            std::io::Write::flush(&mut f).map_err(io(p.clone()))?;
        }
        None => {
            let mut out = std::io::stdout().lock();
            write_csv(&mut out, &result.stars).map_err(io("<stdout>".into()))?;
        }
    }
    let c = &result.config;
    let method = c.acquisition_method;
    let pixcorr = match (&result.curve, method) {
        (_, CentroidMethod::GaussFit) => String::new(),
        (_, CentroidMethod::GaussFitWidth) => ", width fitted per star".into(),
        (Some(h), _) => format!(
            ", pixel-phase curve a {:.3} px box {}",
            h.a_px.to_num::<f64>(),
            h.box_side
        ),
        (None, _) => format!(
            ", no pixel-phase curve for box {} and a {} px in the table: uncorrected (flag bit 17)",
            c.box_px(),
            c.psf_a_px
        ),
    };
    let s = &result.summary;
    eprintln!(
        "startrack process: {} stars ({}, window {}, a {} px{pixcorr}), dark scale {:.2} e-, {} candidates lost to a full list, {} windows lost{}",
        s.stars,
        method.name(),
        c.window_px,
        c.psf_a_px,
        s.dark_scale_e.map_or(0.0, |d| d.to_num::<f64>()),
        s.candidates_dropped,
        u32::from(s.ring_lost) + u32::from(s.windows_dropped) + u32::from(s.calib_failed),
        args.out
            .as_ref()
            .map_or(String::new(), |p| format!(", wrote {}", p.display()))
    );
    Ok(())
}
