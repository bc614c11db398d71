//! `startrack process FRAME.fits --calib TABLE.bin`: the star list of one raw frame, through
//! the host pipeline ([`crate::pipeline`]): the same core code as the firmware.
//!
//! The frame's shape must be the table's geometry (lines x line length, 1033 x 1072 for the
//! CCD47-20). Exposure and temperature (for hot pixels' own dark law) come from the options,
//! else from the frame's `EXPTIME` (s) and `CCDTEMP` (K) keywords, else 1 s and 293 K.
//! The PSF width (Gauss-fit model, and which pixel-phase curve `cog1`/`cog2`
//! use) comes from `--psf-a-px` (80 %-energy radius) or `--psf-sigma`, else the frame's
//! `PSFA` keyword (px, written by `startrack simulate`), else sigma 0.8 px (a = 1.44 px).

use super::{CliError, read_file};
use crate::fits::{read_keys, read_raw_frame};
use crate::pipeline::{self, FrameResult, Method, PipelineConfig};
use startrack_core::table::CalibTable;
use std::path::PathBuf;

/// Options of `startrack process`.
#[derive(Clone, Debug, clap::Args)]
pub struct ProcessArgs {
    /// Raw frame: FITS, BITPIX 16 with BZERO 32768, lines x columns of the full readout.
    pub frame: PathBuf,
    /// Calibration table (from `startrack calib build` or `startrack table`).
    #[arg(long)]
    pub calib: PathBuf,
    /// Centroid method.
    #[arg(long, value_enum, default_value = "gauss-fit")]
    pub method: Method,
    /// Window side, px (odd, 3 to 31); box methods use window - 2 inside it.
    #[arg(long, default_value_t = pipeline::DEFAULT_WINDOW_PX)]
    pub window: u16,
    /// PSF Gaussian sigma, px (Gauss-fit model): sqrt(0.31) x the 80 % radius
    /// (default: from --psf-a-px, else the frame's PSFA keyword, else 0.8).
    #[arg(long, conflicts_with = "psf_a_px")]
    pub psf_sigma: Option<f32>,
    /// PSF 80 %-energy radius, px: picks the table's pixel-phase curve for cog1/cog2 and
    /// sets the sigma of gauss-fit (sigma = sqrt(0.31) a).
    #[arg(long)]
    pub psf_a_px: Option<f32>,
    /// Exposure, s (default: the frame's EXPTIME keyword, else 1).
    #[arg(long)]
    pub exposure_s: Option<f64>,
    /// Sensor temperature, K (default: the frame's CCDTEMP keyword, else 293).
    #[arg(long)]
    pub temperature_k: Option<f64>,
    /// Output CSV (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// PSF sigma when neither an option nor the frame gives one, px.
pub const DEFAULT_PSF_SIGMA_PX: f32 = 0.8;

/// Runs the pipeline on the frame and returns what it found (nothing written).
pub fn measure(args: &ProcessArgs) -> Result<FrameResult, CliError> {
    let bytes = read_file(&args.calib)?;
    let table = CalibTable::parse(&bytes).map_err(|err| CliError::Table {
        path: args.calib.clone(),
        err,
    })?;
    let frame = read_raw_frame(&args.frame, table.geometry())?;
    let keys = read_keys(&args.frame, &["EXPTIME", "CCDTEMP", "PSFA"])?;
    let key = |k: &str| keys.iter().find(|(n, _)| n == k).map(|(_, v)| *v);
    let exposure_s = args.exposure_s.or(key("EXPTIME")).unwrap_or(1.0);
    let temperature_k = args.temperature_k.or(key("CCDTEMP")).unwrap_or(293.0);
    if !(0.0..=4.0e6).contains(&exposure_s) {
        return Err(CliError::Usage(format!(
            "exposure {exposure_s} s: must be 0 to 4e6 s"
        )));
    }
    if !(1.0..=65535.0).contains(&temperature_k) {
        return Err(CliError::Usage(format!(
            "temperature {temperature_k} K: must be 1 to 65535 K"
        )));
    }
    let psf_sigma_px = match (args.psf_sigma, args.psf_a_px) {
        (Some(s), _) => s,
        (None, Some(a)) => pipeline::sigma_of_a(a),
        (None, None) => {
            key("PSFA").map_or(DEFAULT_PSF_SIGMA_PX, |a| pipeline::sigma_of_a(a as f32))
        }
    };
    if !(psf_sigma_px.is_finite() && (0.05..=50.0).contains(&psf_sigma_px)) {
        return Err(CliError::Usage(format!(
            "PSF sigma {psf_sigma_px} px: must be 0.05 to 50 px"
        )));
    }
    let config = PipelineConfig {
        method: args.method,
        window_px: args.window,
        psf_sigma_px,
        exposure_ms: (exposure_s * 1000.0).round() as u32,
        temperature_k,
        ..PipelineConfig::default()
    };
    Ok(pipeline::process(table, &frame.data_adu, &config)?)
}

/// Runs `startrack process`: the CSV to `--out` or standard output, a one-line summary on
/// standard error.
pub fn run(args: &ProcessArgs) -> Result<(), CliError> {
    let result = measure(args)?;
    let io = |path: PathBuf| {
        move |e: std::io::Error| CliError::Io {
            path,
            msg: e.to_string(),
        }
    };
    match &args.out {
        Some(p) => {
            let mut f = std::io::BufWriter::new(std::fs::File::create(p).map_err(io(p.clone()))?);
            pipeline::write_csv(&mut f, &result.stars).map_err(io(p.clone()))?;
            std::io::Write::flush(&mut f).map_err(io(p.clone()))?;
        }
        None => {
            let mut out = std::io::stdout().lock();
            pipeline::write_csv(&mut out, &result.stars).map_err(io("<stdout>".into()))?;
        }
    }
    let pixcorr = match (
        &result.pixcorr,
        pipeline::corrected_cog(args.method, args.window),
    ) {
        (Some(h), _) => format!(
            ", pixel-phase curve a {:.3} px box {}",
            h.a_px.to_num::<f64>(),
            h.box_side
        ),
        (None, Some((_, b))) => format!(
            ", no pixel-phase curve for box {b} and this PSF width in the table: uncorrected (flag bit {})",
            pipeline::UNCORRECTED_BIT
        ),
        (None, None) => String::new(),
    };
    eprintln!(
        "startrack process: {} stars ({:?}, window {}{pixcorr}), dark scale {:.2} e-, {} candidates lost to a full list{}",
        result.stars.len(),
        args.method,
        args.window,
        result.conditions.dark_scale_e.to_num::<f64>(),
        result.dropped,
        args.out
            .as_ref()
            .map_or(String::new(), |p| format!(", wrote {}", p.display()))
    );
    Ok(())
}
