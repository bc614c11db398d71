//! `startrack calib build`: a calibration table (core/src/table) from maps a ground
//! calibration measured, given as FITS images, and a hot-pixel CSV.
//!
//! # Inputs and how each becomes a table section
//! - Gains, e-/ADU per output: `--gains G1,G2`, else the `GAIN1`/`GAIN2` keywords of the
//!   first map given (bias, dark, flat). Required: without gains there is no table.
//! - Bias (`--bias`, ADU, full readout: lines x line length, e.g. a mean of bias frames) ->
//!   **column bias** (I12F4 ADU per raw column). The core subtracts, on every line, the
//!   level it measures on that line's over-scan (median of the output's over-scan elements),
//!   then the table's column bias. So the column bias must be each column's offset *above the
//!   over-scan level of its own line*, not the bias map itself: for each line of the bias map
//!   take the same over-scan median per output as the core, subtract it from the line, and
//!   average the differences over lines. Bias drift (per line or per frame) moves over-scan
//!   and columns together and cancels; over-scan columns get 0 (the core never applies
//!   column bias to them). Values beyond ±2048 ADU are clamped and counted.
//! - Dark (`--dark`, relative, full readout) -> **relative dark map** (U2F6) of the active
//!   area. The core scales it by the frame's covered-column mean, so the map is divided by
//!   the mean of its own covered columns (a map already relative to them is unchanged; a
//!   dark frame in e- or ADU above bias works too). Values are averaged over the table's
//!   tiles and clamped to 0..4.
//! - Flat (`--flat`, relative response, active area rows x columns) -> **inverse flat**
//!   (U2F14): 1/flat averaged over each tile, clamped to (0, 4); a flat at or below 0.25
//!   (dead pixel) is clamped and counted.
//! - Hot pixels (`--hot`, CSV `col,row,dark_e` in full-readout coordinates, an optional
//!   header line) -> **hot pixel** entries: `dark_e` is the pixel's dark signal in
//!   `--hot-exposure-s` at `--hot-ref-k` (the rate is their ratio), doubling every
//!   `--hot-doubling-k`; pixels with more than `--hot-exclude-above-e` are excluded rather
//!   than corrected (their shot noise outweighs the correction). Pixels outside the active
//!   area are skipped and counted (the table lists active pixels only).
//!
//! - Pixel-phase correction (`--psf-a-px A[,A2..]`, the PSF's 80 %-energy radius) ->
//!   **pixel-phase curves** (section 7, [`crate::pixcorr`]): one 33-knot curve per width,
//!   per CoG box in `--pixcorr-boxes` (default 5 and 7: `startrack process`'s default 7 px
//!   window and the firmware's 9 px one) and per power in `--pixcorr-powers` (default 1,2),
//!   all for the median-perimeter background both use. A combination the builder refuses
//!   (CoG not invertible, or the wings reach the perimeter) is reported and skipped; at
//!   most 16 curves fit the section. Then, while the section has room, one power-1 curve
//!   per width and box up to 9 for a *given* background: the firmware's tracking path
//!   (`centroid::raw_cog`, background carried from the star's last measurement) uses it.
//!
//! A missing map gives no section and is reported ("no dark map: no dark correction").
//! Geometry: the CCD47-20 read through both outputs.

use super::{CliError, write_file};
use crate::fits::{MapF32, read_map_shaped};
use crate::pixcorr::{Curve, CurveSpec, build_curve, write_table_with_curves};
use fixed::types::U8F8;
use startrack_core::centroid::cog::CogPower;
use startrack_core::centroid::pixcorr::PixCorrBackground;
use startrack_core::geometry::{Output, ReadoutGeometry, Segment};
use startrack_core::table::{HotPixel, HotPolicy, MAX_TILE_LOG2, MapSpec, TableSpec, write_table};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu, Kelvin};
use std::path::{Path, PathBuf};

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
    /// Map tiles of 2^N pixels: 0 is per pixel (full correction, 2 MB for the CCD47-20,
    /// external flash); 3 (8x8) fits the firmware's 128 KB CALIB sector.
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
}

/// Knots per pixel-phase curve (74 bytes each).
pub const PIXCORR_KNOTS: u8 = 33;

/// Most curves the pixel-phase section holds.
pub const MAX_CURVES: usize = 16;

/// A comma-separated list of numbers of option `name`.
fn parse_list<T: std::str::FromStr>(name: &str, s: &str) -> Result<Vec<T>, CliError>
where
    T::Err: std::fmt::Display,
{
    s.split(',')
        .map(|v| {
            v.trim()
                .parse::<T>()
                .map_err(|e| CliError::Usage(format!("{name} {s}: {e}")))
        })
        .collect()
}

/// The pixel-phase curves of `args` (empty without `--psf-a-px`) and one note per curve
/// built or refused.
pub fn curves_from_args(args: &CalibBuildArgs) -> Result<(Vec<Curve>, Vec<String>), CliError> {
    let Some(list) = &args.psf_a_px else {
        return Ok((
            Vec::new(),
            vec![
                "no --psf-a-px: no pixel-phase correction (cog1/cog2 are flagged uncorrected)"
                    .into(),
            ],
        ));
    };
    let widths: Vec<f64> = parse_list("--psf-a-px", list)?;
    if let Some(a) = widths
        .iter()
        .find(|a| !(a.is_finite() && (0.1..=50.0).contains(*a)))
    {
        return Err(CliError::Usage(format!(
            "--psf-a-px {a}: must be 0.1 to 50 px"
        )));
    }
    let boxes: Vec<u8> = parse_list("--pixcorr-boxes", &args.pixcorr_boxes)?;
    if let Some(b) = boxes
        .iter()
        .find(|b| !(3..=29).contains(*b) || b.is_multiple_of(2))
    {
        return Err(CliError::Usage(format!(
            "--pixcorr-boxes: box {b} must be odd, 3 to 29"
        )));
    }
    let powers = parse_list::<u8>("--pixcorr-powers", &args.pixcorr_powers)?
        .into_iter()
        .map(|p| match p {
            1 => Ok(CogPower::One),
            2 => Ok(CogPower::Two),
            _ => Err(CliError::Usage(format!(
                "--pixcorr-powers: power {p} must be 1 or 2"
            ))),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut curves = Vec::new();
    let mut notes = Vec::new();
    for &a_px in &widths {
        for &box_side in &boxes {
            for &power in &powers {
                let spec = CurveSpec {
                    a_px,
                    box_side,
                    power,
                    background: PixCorrBackground::PerimeterMedian,
                    knots: PIXCORR_KNOTS,
                };
                let p = if power == CogPower::One { 1 } else { 2 };
                match build_curve(&spec) {
                    Ok(c) => {
                        notes.push(format!(
                            "pixel-phase curve: a {a_px} px, box {box_side}, power {p}, median perimeter background (largest correction {:.4} px)",
                            c.knots_px.iter().fold(0.0f64, |m, k| m.max(k.abs()))
                        ));
                        curves.push(c);
                    }
                    Err(e) => notes.push(format!(
                        "no pixel-phase curve for a {a_px} px, box {box_side}, power {p}: {e}"
                    )),
                }
            }
        }
    }
    // The firmware's tracking path (core `centroid::raw_cog`: power 1, a given background
    // carried from the star's last measurement) needs curves made for a given background:
    // one per width for each box the fused path takes (side <= 9), while the section has
    // room (a note says when it had not).
    for &a_px in &widths {
        for &box_side in boxes.iter().filter(|b| **b <= 9) {
            let spec = CurveSpec {
                a_px,
                box_side,
                power: CogPower::One,
                background: PixCorrBackground::Given,
                knots: PIXCORR_KNOTS,
            };
            if curves.len() >= MAX_CURVES {
                notes.push(format!(
                    "no tracking curve (given background) for a {a_px} px, box {box_side}: the section is full"
                ));
                continue;
            }
            match build_curve(&spec) {
                Ok(c) => {
                    notes.push(format!(
                        "tracking curve (given background): a {a_px} px, box {box_side}, power 1 (largest correction {:.4} px)",
                        c.knots_px.iter().fold(0.0f64, |m, k| m.max(k.abs()))
                    ));
                    curves.push(c);
                }
                Err(e) => notes.push(format!(
                    "no tracking curve (given background) for a {a_px} px, box {box_side}: {e}"
                )),
            }
        }
    }
    if curves.len() > MAX_CURVES {
        return Err(CliError::Usage(format!(
            "{} pixel-phase curves: the table holds at most {MAX_CURVES} (fewer widths, boxes or powers)",
            curves.len()
        )));
    }
    Ok((curves, notes))
}

/// What `calib build` did, for the report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildReport {
    /// Bytes written.
    pub bytes: usize,
    /// One line per input: what became of it.
    pub notes: Vec<String>,
}

const GAIN_KEYS: [&str; 2] = ["GAIN1", "GAIN2"];

fn parse_gains(s: &str, outputs: usize) -> Result<Vec<f64>, CliError> {
    let g: Vec<f64> = s
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| CliError::Usage(format!("--gains {s}: {e}")))?;
    if g.len() != outputs {
        return Err(CliError::Usage(format!(
            "--gains {s}: need {outputs} values, one per output"
        )));
    }
    Ok(g)
}

/// The gains as the table stores them; each must be in (0, 16) e-/ADU.
fn encode_gains(g: &[f64]) -> Result<Vec<GainEPerAdu>, CliError> {
    g.iter()
        .map(|&v| {
            if v.is_finite() && v > 0.0 && v < 16.0 {
                Ok(GainEPerAdu::saturating_from_num(v).max(GainEPerAdu::DELTA))
            } else {
                Err(CliError::Usage(format!(
                    "gain {v} e-/ADU: must be above 0 and below 16"
                )))
            }
        })
        .collect()
}

/// The median of `v` (mean of the two middle values for an even count), as the core's
/// over-scan level.
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match (v.get(n.wrapping_sub(1) / 2), v.get(n / 2)) {
        (Some(a), Some(b)) => 0.5 * (a + b),
        _ => 0.0,
    }
}

/// Column bias from a full-readout bias map: each column's mean offset above its line's
/// over-scan level (see the module docs). Returns the values and how many were clamped.
pub fn column_bias_from_map(g: &ReadoutGeometry, bias: &MapF32) -> (Vec<ColumnBiasAdu>, usize) {
    let len = g.line_len();
    let mut sum = vec![0.0f64; len];
    let mut lines = 0usize;
    for line in bias.data.chunks_exact(len) {
        let mut level = [0.0f64; 2];
        for (o, l) in level.iter_mut().enumerate().take(usize::from(g.outputs)) {
            let strips = [
                Some(g.overscan_cols(Output(o as u8))),
                g.overscan_cols_extra(),
            ];
            let mut v: Vec<f64> = strips
                .into_iter()
                .flatten()
                .flat_map(|(s, e)| line.get(s..e).unwrap_or(&[]).iter())
                .map(|&x| f64::from(x))
                .collect();
            *l = median(&mut v);
        }
        for (c, (s, &x)) in sum.iter_mut().zip(line).enumerate() {
            let out = usize::from(g.output_of_col(c).0);
            *s += f64::from(x) - level.get(out).copied().unwrap_or(0.0);
        }
        lines += 1;
    }
    let mut clamped = 0;
    let cb = sum
        .iter()
        .enumerate()
        .map(|(c, s)| {
            if g.segment(c) == Some(Segment::OverScan) || lines == 0 {
                return ColumnBiasAdu::ZERO;
            }
            let v = s / lines as f64;
            if v < ColumnBiasAdu::MIN.to_num::<f64>() || v > ColumnBiasAdu::MAX.to_num::<f64>() {
                clamped += 1;
            }
            ColumnBiasAdu::saturating_from_num(v)
        })
        .collect();
    (cb, clamped)
}

/// Relative dark tiles from a full-readout dark map, normalised to its covered columns'
/// mean. Returns the tiles, the covered mean found, and how many tiles were clamped.
pub fn dark_from_map(
    g: &ReadoutGeometry,
    dark: &MapF32,
    tile_log2: u8,
    path: &Path,
) -> Result<(Vec<DarkRel>, f64, usize), CliError> {
    let (mut sum, mut n) = (0.0, 0usize);
    for line in 0..usize::from(g.lines) {
        for (s, e) in g.covered_cols() {
            for col in s..e {
                sum += f64::from(dark.get(line, col).unwrap_or(0.0));
                n += 1;
            }
        }
    }
    let mean = if n == 0 { 1.0 } else { sum / n as f64 };
    if !(mean.is_finite() && mean > 0.0) {
        return Err(CliError::Usage(format!(
            "{}: the covered columns' mean is {mean}: a relative dark map needs a positive one",
            path.display()
        )));
    }
    let f = |x: usize, y: usize| {
        f64::from(
            dark.get(g.raw_line_of_y(y), g.raw_col_of_x(x))
                .unwrap_or(0.0),
        ) / mean
    };
    let mut clamped = 0;
    let tiles = crate::sim::truth::tile_means(g, tile_log2, &f)
        .into_iter()
        .map(|v| {
            if !(0.0..=DarkRel::MAX.to_num::<f64>()).contains(&v) {
                clamped += 1;
            }
            DarkRel::saturating_from_num(v)
        })
        .collect();
    Ok((tiles, mean, clamped))
}

/// Inverse flat tiles from an active-area flat. Returns the tiles and how many pixels or
/// tiles were clamped.
pub fn flat_from_map(g: &ReadoutGeometry, flat: &MapF32, tile_log2: u8) -> (Vec<FlatInv>, usize) {
    let limit = FlatInv::MAX.to_num::<f64>();
    let mut clamped = 0;
    for v in &flat.data {
        if f64::from(*v) <= 1.0 / limit {
            clamped += 1;
        }
    }
    let f = |x: usize, y: usize| {
        let v = f64::from(flat.get(y, x).unwrap_or(1.0));
        if v <= 1.0 / limit { limit } else { 1.0 / v }
    };
    let tiles = crate::sim::truth::tile_means(g, tile_log2, &f)
        .into_iter()
        .map(|v| FlatInv::saturating_from_num(v).max(FlatInv::DELTA))
        .collect();
    (tiles, clamped)
}

/// Hot pixels from the CSV; returns the sorted list and the number outside the active area.
pub fn hot_from_csv(
    g: &ReadoutGeometry,
    path: &Path,
    args: &CalibBuildArgs,
) -> Result<(Vec<HotPixel>, usize), CliError> {
    let text = std::fs::read_to_string(path).map_err(|e| CliError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    let bad = |line: usize, msg: String| CliError::Csv {
        path: path.to_path_buf(),
        line,
        msg,
    };
    if !(args.hot_exposure_s.is_finite() && args.hot_exposure_s > 0.0) {
        return Err(CliError::Usage(format!(
            "--hot-exposure-s {}: must be positive",
            args.hot_exposure_s
        )));
    }
    let doubling = U8F8::checked_from_num(args.hot_doubling_k)
        .filter(|d| *d > U8F8::ZERO)
        .ok_or_else(|| {
            CliError::Usage(format!(
                "--hot-doubling-k {}: must be above 0 and below 256",
                args.hot_doubling_k
            ))
        })?;
    let mut hot = Vec::new();
    let mut outside = 0;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if i == 0 && fields.first().is_some_and(|f| f.parse::<f64>().is_err()) {
            continue; // header
        }
        let [col, row, dark] = fields[..] else {
            return Err(bad(n, format!("expected col,row,dark_e, got {line:?}")));
        };
        let col: usize = col
            .parse()
            .map_err(|e| bad(n, format!("col {col:?}: {e}")))?;
        let row: usize = row
            .parse()
            .map_err(|e| bad(n, format!("row {row:?}: {e}")))?;
        let dark_e: f64 = dark
            .parse()
            .map_err(|e| bad(n, format!("dark_e {dark:?}: {e}")))?;
        if !(dark_e.is_finite() && dark_e >= 0.0) {
            return Err(bad(n, format!("dark_e {dark_e}: must be 0 or more")));
        }
        let active = g.segment(col) == Some(Segment::Active) && row < usize::from(g.active_rows);
        if !active {
            outside += 1;
            continue;
        }
        let rate = dark_e / args.hot_exposure_s;
        hot.push(HotPixel {
            x: (col - g.first_active_col()) as u16,
            y: row as u16,
            rate_e_per_s: ERatePerS::saturating_from_num(rate),
            doubling_k: doubling,
            policy: if dark_e > args.hot_exclude_above_e {
                HotPolicy::Exclude
            } else {
                HotPolicy::Correct
            },
        });
    }
    hot.sort_by_key(|h| (h.y, h.x));
    if let Some(w) = hot
        .windows(2)
        .find(|w| (w[0].y, w[0].x) == (w[1].y, w[1].x))
    {
        return Err(CliError::Csv {
            path: path.to_path_buf(),
            line: 0,
            msg: format!(
                "hot pixel col {}, row {} listed twice",
                usize::from(w[0].x) + g.first_active_col(),
                w[0].y
            ),
        });
    }
    Ok((hot, outside))
}

/// Builds the table bytes and the report (nothing written).
pub fn build(args: &CalibBuildArgs) -> Result<(Vec<u8>, BuildReport), CliError> {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let (lines, len) = (usize::from(g.lines), g.line_len());
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    let mut notes = Vec::new();
    let bias = args
        .bias
        .as_deref()
        .map(|p| read_map_shaped(p, lines, len, &GAIN_KEYS))
        .transpose()?;
    let dark = args
        .dark
        .as_deref()
        .map(|p| read_map_shaped(p, lines, len, &GAIN_KEYS))
        .transpose()?;
    let flat = args
        .flat
        .as_deref()
        .map(|p| read_map_shaped(p, rows, cols, &GAIN_KEYS))
        .transpose()?;

    let outputs = usize::from(g.outputs);
    let gains = match &args.gains {
        Some(s) => {
            notes.push(format!("gains {s} e-/ADU (--gains)"));
            parse_gains(s, outputs)?
        }
        None => {
            let from_keys = [
                (&args.bias, &bias),
                (&args.dark, &dark),
                (&args.flat, &flat),
            ]
            .into_iter()
            .find_map(|(p, m)| {
                let m = m.as_ref()?;
                let g: Option<Vec<f64>> =
                    GAIN_KEYS.iter().take(outputs).map(|k| m.key(k)).collect();
                Some((p.clone()?, g?))
            });
            let Some((p, g)) = from_keys else {
                return Err(CliError::Usage(
                    "no gains: give --gains G1,G2 or GAIN1/GAIN2 keywords in a map".into(),
                ));
            };
            notes.push(format!(
                "gains {g:?} e-/ADU (GAIN1/GAIN2 of {})",
                p.display()
            ));
            g
        }
    };
    let gains = encode_gains(&gains)?;

    let column_bias = bias.as_ref().map(|m| column_bias_from_map(&g, m));
    match &column_bias {
        Some((_, clamped)) => notes.push(format!(
            "column bias from {} (offset above each line's over-scan level){}",
            args.bias
                .as_deref()
                .map_or(String::new(), |p| p.display().to_string()),
            if *clamped > 0 {
                format!(", {clamped} columns clamped to ±2048 ADU")
            } else {
                String::new()
            }
        )),
        None => notes.push("no bias map: no column bias correction (over-scan level only)".into()),
    }
    let dark_rel = match (&dark, &args.dark) {
        (Some(m), Some(p)) => {
            let (tiles, mean, clamped) = dark_from_map(&g, m, args.tile_log2, p)?;
            notes.push(format!(
                "relative dark from {} (covered mean {mean:.4}, normalised to 1){}",
                p.display(),
                if clamped > 0 {
                    format!(", {clamped} tiles clamped to 0..4")
                } else {
                    String::new()
                }
            ));
            Some(tiles)
        }
        _ => {
            notes
                .push("no dark map: no dark correction (covered mean subtracted uniformly)".into());
            None
        }
    };
    let flat_inv = match (&flat, &args.flat) {
        (Some(m), Some(p)) => {
            let (tiles, clamped) = flat_from_map(&g, m, args.tile_log2);
            notes.push(format!(
                "inverse flat from {}{}",
                p.display(),
                if clamped > 0 {
                    format!(", {clamped} pixels at or below 0.25 clamped")
                } else {
                    String::new()
                }
            ));
            Some(tiles)
        }
        _ => {
            notes.push("no flat map: no flat correction".into());
            None
        }
    };
    let hot = match &args.hot {
        Some(p) => {
            let (hot, outside) = hot_from_csv(&g, p, args)?;
            notes.push(format!(
                "{} hot pixels from {} ({} excluded){}",
                hot.len(),
                p.display(),
                hot.iter()
                    .filter(|h| h.policy == HotPolicy::Exclude)
                    .count(),
                if outside > 0 {
                    format!(", {outside} outside the active area skipped")
                } else {
                    String::new()
                }
            ));
            hot
        }
        None => {
            notes.push("no hot pixel list: no hot pixel correction".into());
            Vec::new()
        }
    };
    if args.tile_log2 > 0 && (dark_rel.is_some() || flat_inv.is_some()) {
        notes.push(format!(
            "maps averaged over {0}x{0} tiles",
            1u32 << args.tile_log2
        ));
    }
    let hot_ref_k = Kelvin::checked_from_num(args.hot_ref_k).ok_or_else(|| {
        CliError::Usage(format!(
            "--hot-ref-k {}: must be 0 to 65535",
            args.hot_ref_k
        ))
    })?;
    let spec = TableSpec {
        geometry: g,
        saturation_adu: args.saturation_adu,
        gains: &gains,
        column_bias: column_bias.as_ref().map(|(c, _)| &c[..]),
        dark_rel: dark_rel.as_deref().map(|tiles| MapSpec {
            tile_log2: args.tile_log2,
            tiles,
        }),
        flat_inv: flat_inv.as_deref().map(|tiles| MapSpec {
            tile_log2: args.tile_log2,
            tiles,
        }),
        hot_ref_k,
        hot: &hot,
        telegraph: &[],
    };
    let (curves, curve_notes) = curves_from_args(args)?;
    notes.extend(curve_notes);
    let buf = if curves.is_empty() {
        let mut buf = vec![0u8; spec.encoded_len()];
        let n = write_table(&spec, &mut buf).map_err(CliError::TableWrite)?;
        buf.truncate(n);
        buf
    } else {
        write_table_with_curves(&spec, &curves).map_err(CliError::TableWrite)?
    };
    let n = buf.len();
    Ok((buf, BuildReport { bytes: n, notes }))
}

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
