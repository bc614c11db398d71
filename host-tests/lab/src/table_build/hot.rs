//! The hot-pixel list of `calib build --hot`: a CSV of `col,row,dark_e` in full-readout
//! coordinates (an optional header line, `#` comments) becomes the table's sorted hot-pixel
//! entries, each corrected by its own dark law or excluded above `--hot-exclude-above-e`.
//! A malformed line is a [`LabError::Csv`] with its line number. Cost: one pass over the
//! file and a sort of the list.

use super::args::CalibBuildArgs;
use crate::LabError;
use fixed::types::U8F8;
use startrack_core::geometry::{ReadoutGeometry, Segment};
use startrack_core::table::{HotPixel, HotPolicy};
use startrack_core::units::ERatePerS;
use std::path::Path;

/// Hot pixels from the CSV; returns the sorted list and the number outside the active area.
pub fn hot_from_csv(
    g: &ReadoutGeometry,
    path: &Path,
    args: &CalibBuildArgs,
) -> Result<(Vec<HotPixel>, usize), LabError> {
    let text = std::fs::read_to_string(path).map_err(|e| LabError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    let bad = |line: usize, msg: String| LabError::Csv {
        path: path.to_path_buf(),
        line,
        msg,
    };
    if !(args.hot_exposure_s.is_finite() && args.hot_exposure_s > 0.0) {
        return Err(LabError::Invalid(format!(
            "--hot-exposure-s {}: must be positive",
            args.hot_exposure_s
        )));
    }
    let doubling = U8F8::checked_from_num(args.hot_doubling_k)
        .filter(|d| *d > U8F8::ZERO)
        .ok_or_else(|| {
            LabError::Invalid(format!(
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
        return Err(LabError::Csv {
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
