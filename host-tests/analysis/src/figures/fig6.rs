//! Figure 6: detection probability (measured SNR > 3) against DSNU, from the same trials as
//! Figure 5 (power 1; the detection does not depend on the power).

use super::fig5::{Fig5Result, dsnu_series, header};
use super::{FigureError, FigureFiles, Written, plot};
use std::path::Path;

/// Writes fig6.csv and fig6.png.
pub fn write(out: &Path, res: &Fig5Result, written: &mut Written) -> Result<(), FigureError> {
    let pts: Vec<_> = res.points.iter().filter(|q| q.power == 1).collect();
    let lines: Vec<String> = pts
        .iter()
        .map(|q| {
            format!(
                "{},{:.3},{},{:.6}",
                q.snr0,
                q.dsnu,
                q.method.name(),
                q.detect_rate
            )
        })
        .collect();
    let mut h = header(&res.params);
    h.insert(
        0,
        "Figure 6: detection probability against dark non-uniformity".into(),
    );
    FigureFiles {
        number: 6,
        header: h,
        columns: "snr0,dsnu,method,detect_rate",
        rows: lines,
        chart: plot::Chart {
            title: "Fig. 6: detection probability vs DSNU".into(),
            x_label: "DSNU (dark sigma / mean)".into(),
            y_label: "P(measured SNR > 3)".into(),
            log_x: false,
            log_y: false,
        },
        series: dsnu_series(res, &[1], |q| q.detect_rate),
    }
    .write(out, written)
}
