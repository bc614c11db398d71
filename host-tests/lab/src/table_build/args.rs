//! The options of `startrack calib build` and their validation: the clap arguments, the
//! comma-separated lists (`--gains`, `--psf-a-px`, `--pixcorr-boxes`, `--pixcorr-powers`) and
//! the gains' range. A bad value is a [`LabError::Invalid`] naming the option. Cost: nothing
//! beyond parsing a few numbers.

use crate::LabError;
use fixed::types::U8F8;
use startrack_core::table::DarkLaw;
use startrack_core::table::MAX_TILE_LOG2;
use startrack_core::units::{ERatePerS, GainEPerAdu, Kelvin};
use std::path::PathBuf;

/// Options of `startrack calib build`.
#[derive(Clone, Debug, clap::Args)]
pub struct CalibBuildArgs {
    /// Output table file.
    #[arg(long)]
    pub out: PathBuf,
    /// Bias map, ADU, full readout (lines x line length).
    #[arg(long)]
    pub bias: Option<PathBuf>,
    /// Relative dark map, unitless (covered columns' mean = 1), full readout.
    #[arg(long)]
    pub dark: Option<PathBuf>,
    /// Flat field, unitless relative response, active area.
    #[arg(long)]
    pub flat: Option<PathBuf>,
    /// Gains per output, e-/ADU, "G1,G2" (default: GAIN1/GAIN2 keywords of the maps).
    #[arg(long)]
    pub gains: Option<String>,
    /// Hot pixels: CSV `col,row,dark_e`, full-readout coordinates.
    #[arg(long)]
    pub hot: Option<PathBuf>,
    /// Exposure the hot pixels' `dark_e` was measured in, s.
    #[arg(long, default_value_t = 1.0)]
    pub hot_exposure_s: f64,
    /// Temperature the hot pixels' `dark_e` was measured at, K.
    #[arg(long, default_value_t = 293.0)]
    pub hot_ref_k: f64,
    /// A hot pixel's dark doubles every this many kelvin.
    #[arg(long, default_value_t = 6.0)]
    pub hot_doubling_k: f64,
    /// Hot pixels with more dark than this (e-, in the reference exposure) are excluded.
    #[arg(long, default_value_t = 10_000.0)]
    pub hot_exclude_above_e: f64,
    /// Map tiles of 2^N pixels: 0 is per pixel (full correction, megabytes for the CCD47-20:
    /// external flash); 3 (8x8) fits the firmware's 192 KB table limit.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=i64::from(MAX_TILE_LOG2)))]
    pub tile_log2: u8,
    /// Raw samples at or above this are flagged saturated, ADU.
    #[arg(long, default_value_t = 65535)]
    pub saturation_adu: u16,
    /// PSF 80 %-energy radii, px, "A[,A2..]": adds pixel-phase correction curves for them.
    #[arg(long)]
    pub psf_a_px: Option<String>,
    /// CoG box sides the curves are built for, "5,7" (odd, 3..=29; window = box + 2).
    #[arg(long, default_value = "5,7")]
    pub pixcorr_boxes: String,
    /// CoG powers the curves are built for, "1,2".
    #[arg(long, default_value = "1,2")]
    pub pixcorr_powers: String,
    /// CTI coefficients (JSON from `startrack calib cti` or `calib frames`): adds section 8.
    #[arg(long)]
    pub cti: Option<PathBuf>,
    /// Field PSF model (JSON from `startrack calib psf-model`): adds section 9.
    #[arg(long)]
    pub psf_model: Option<PathBuf>,
    /// Camera model (JSON from `startrack optics fit`): adds the camera-model section.
    #[arg(long)]
    pub camera_model: Option<PathBuf>,
    /// Covered pixels' dark law "RATE,TREF,DOUBLING" (e-/px/s at TREF K, doubling K), or
    /// "RATE,TREF,DOUBLING,LOW,HIGH" with the dark ratio's band (default 0.8,1.25): adds
    /// section 11, which arms the tracker's dark drift check.
    #[arg(long)]
    pub dark_law: Option<String>,
}

impl CalibBuildArgs {
    /// The options with every default as the command line gives them (clap's own defaults,
    /// so they cannot drift from `startrack calib build --help`), writing to `out` and no
    /// maps: what a caller then fills in.
    pub fn with_defaults(out: PathBuf) -> Self {
        #[derive(clap::Parser)]
        struct Command {
            #[command(flatten)]
            args: CalibBuildArgs,
        }
        let out = out.into_os_string();
        <Command as clap::Parser>::parse_from([
            std::ffi::OsString::from("calib-build"),
            "--out".into(),
            out,
        ])
        .args
    }
}

/// The dark law of `--dark-law`: `RATE,TREF,DOUBLING[,LOW,HIGH]`, each in its section-11
/// format and range (rate > 0 e-/px/s, TREF 100..=400 K, doubling 2..=20 K, LOW < HIGH).
pub fn parse_dark_law(s: &str) -> Result<DarkLaw, LabError> {
    let v: Vec<f64> = parse_list("--dark-law", s)?;
    let bad = |why: &str| LabError::Invalid(format!("--dark-law {s}: {why}"));
    let [rate, t_ref, doubling, band @ ..] = v.as_slice() else {
        return Err(bad("need RATE,TREF,DOUBLING[,LOW,HIGH]"));
    };
    let [low, high] = match band {
        [] => DarkLaw::DEFAULT_BAND,
        [lo, hi] => [
            U8F8::checked_from_num(*lo).ok_or_else(|| bad("LOW must be 0 to 255"))?,
            U8F8::checked_from_num(*hi).ok_or_else(|| bad("HIGH must be 0 to 255"))?,
        ],
        _ => return Err(bad("need RATE,TREF,DOUBLING[,LOW,HIGH]")),
    };
    let law = DarkLaw {
        rate_e_per_s: ERatePerS::checked_from_num(*rate)
            .ok_or_else(|| bad("RATE must be 0 to 65535 e-/px/s"))?,
        reference_k: Kelvin::checked_from_num(*t_ref)
            .ok_or_else(|| bad("TREF must be 100 to 400 K"))?,
        doubling_k: U8F8::checked_from_num(*doubling)
            .ok_or_else(|| bad("DOUBLING must be 2 to 20 K"))?,
        band_low: low,
        band_high: high,
    };
    match law.out_of_range_field() {
        None => Ok(law),
        Some(0) => Err(bad("RATE must be above 0 e-/px/s")),
        Some(1) => Err(bad("TREF must be 100 to 400 K")),
        Some(2) => Err(bad("DOUBLING must be 2 to 20 K")),
        Some(_) => Err(bad("the band's LOW must be below its HIGH")),
    }
}

/// A comma-separated list of numbers of option `name`.
pub(super) fn parse_list<T: std::str::FromStr>(name: &str, s: &str) -> Result<Vec<T>, LabError>
where
    T::Err: std::fmt::Display,
{
    s.split(',')
        .map(|v| {
            v.trim()
                .parse::<T>()
                .map_err(|e| LabError::Invalid(format!("{name} {s}: {e}")))
        })
        .collect()
}

/// The gains of `--gains`, one per output.
pub(super) fn parse_gains(s: &str, outputs: usize) -> Result<Vec<f64>, LabError> {
    let g: Vec<f64> = s
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| LabError::Invalid(format!("--gains {s}: {e}")))?;
    if g.len() != outputs {
        return Err(LabError::Invalid(format!(
            "--gains {s}: need {outputs} values, one per output"
        )));
    }
    Ok(g)
}

/// The gains as the table stores them; each must be in (0, 16) e-/ADU.
pub fn encode_gains(g: &[f64]) -> Result<Vec<GainEPerAdu>, LabError> {
    g.iter()
        .map(|&v| {
            if v.is_finite() && v > 0.0 && v < 16.0 {
                Ok(GainEPerAdu::saturating_from_num(v).max(GainEPerAdu::DELTA))
            } else {
                Err(LabError::Invalid(format!(
                    "gain {v} e-/ADU: must be above 0 and below 16"
                )))
            }
        })
        .collect()
}
