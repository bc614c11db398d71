//! Loading the maps and turning each into its table section: the FITS bias, dark and flat
//! maps are read and checked for shape, the gains taken from `--gains` or the maps'
//! `GAIN1`/`GAIN2` keywords, and each map converted as the module docs of
//! [`super`] say (column bias above each line's over-scan level, dark relative to its covered
//! columns, inverse flat), with one note per input. Cost: one pass over each map (1033 x 1072
//! samples for the full-readout bias and dark, 1024 x 1024 for the flat), plus a median of
//! each line's over-scan elements per output for the bias.

use super::args::{CalibBuildArgs, encode_gains, parse_gains};
use super::hot::hot_from_csv;
use crate::LabError;
use startrack_core::geometry::{Output, ReadoutGeometry, Segment};
use startrack_core::table::{HotPixel, HotPolicy};
use startrack_core::units::{ColumnBiasAdu, DarkRel, FlatInv, GainEPerAdu};
use startrack_sim::fits::{MapF32, read_map_shaped};
use std::path::Path;

const GAIN_KEYS: [&str; 2] = ["GAIN1", "GAIN2"];

/// The table's sections from the inputs, before encoding; `None` for a map not given.
pub(super) struct Sections {
    pub gains: Vec<GainEPerAdu>,
    /// The column bias and how many columns were clamped.
    pub column_bias: Option<(Vec<ColumnBiasAdu>, usize)>,
    pub dark_rel: Option<Vec<DarkRel>>,
    pub flat_inv: Option<Vec<FlatInv>>,
    pub hot: Vec<HotPixel>,
}

/// Reads every input `args` names and converts it for geometry `g`, pushing one note per
/// input (and one for the tiling) onto `notes`.
pub(super) fn load_sections(
    g: &ReadoutGeometry,
    args: &CalibBuildArgs,
    notes: &mut Vec<String>,
) -> Result<Sections, LabError> {
    let (lines, len) = (usize::from(g.lines), g.line_len());
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
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
                return Err(LabError::Invalid(
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

    let column_bias = bias.as_ref().map(|m| column_bias_from_map(g, m));
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
            let (tiles, mean, clamped) = dark_from_map(g, m, args.tile_log2, p)?;
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
            let (tiles, clamped) = flat_from_map(g, m, args.tile_log2);
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
            let (hot, outside) = hot_from_csv(g, p, args)?;
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
    Ok(Sections {
        gains,
        column_bias,
        dark_rel,
        flat_inv,
        hot,
    })
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
) -> Result<(Vec<DarkRel>, f64, usize), LabError> {
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
        return Err(LabError::Invalid(format!(
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
    let tiles = startrack_sim::sim::truth::tile_means(g, tile_log2, &f)
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
    let tiles = startrack_sim::sim::truth::tile_means(g, tile_log2, &f)
        .into_iter()
        .map(|v| FlatInv::saturating_from_num(v).max(FlatInv::DELTA))
        .collect();
    (tiles, clamped)
}
