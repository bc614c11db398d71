//! The report directory of `calib frames`:
//!
//! | file | contents |
//! |---|---|
//! | `report.json` | `gain_e_per_adu`, `read_noise_e`, `full_well_e` (where the mean stops rising), `full_well_adu`, `nonlinearity_pct` (EMVA 1288 linearity error over 5 to 95 % of the full well), one per output and `null` when no flat pair reaches saturation (a note says so); photon transfer points, covered dark rate per temperature, `covered_dark_law` (the law fitted over them as the table's section 11 stores it: `rate_e_per_s` at `reference_k`, `doubling_k`, `band`; `null` without one), counts, `groups` (each group of frames found and what it served), notes |
//! | `hot.csv` | `col,row,rate_e_per_s_at_293k,doubling_k,rate_sigma_e_per_s,doubling_sigma_k` (raw readout coordinates; each law's standard errors from its fit) |
//! | `rts.csv` | `col,row` (raw readout coordinates) |
//! | `cti_traps.json`, `cti.json` | the trap law measured by EPER, and the table's CTI coefficients from it (`calib build --cti`, `calib cti --traps`); written when EPER measured one |
//! | `master_bias.fits`, `dark_rel.fits`, `flat.fits` | the maps for DS9 (full readout, full readout, active area) |
//! | `ptc.png`, `dark_temperature.png` | photon transfer per output with its full well marked (where the mean stops rising) and its linearity error (LE) in the legend; dark rate against temperature (covered pixels and hot pixels) |
//!
//! The PNGs are drawn by the figures' chart code ([`startrack_analysis::figures::plot`]); without a font
//! they are skipped with a reason. Cost: writing the maps, a few kilobytes else.

use super::Products;
use crate::{LabError, write_file};
use startrack_analysis::figures::Written;
use startrack_analysis::figures::plot::{Chart, Series, lines};
use startrack_sim::fits::write_map;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The JSON report.
pub fn json(p: &Products) -> serde_json::Value {
    serde_json::json!({
        "gain_e_per_adu": p.gain_e_per_adu,
        "read_noise_e": p.read_noise_e,
        "full_well_e": p.full_well_e,
        "full_well_adu": p.full_well_adu,
        "nonlinearity_pct": p.nonlinearity_pct,
        "bias_variance_adu2": p.bias_var_adu2,
        "frames": { "bias": p.frames.0, "flat": p.frames.1, "dark": p.frames.2 },
        "ptc": p.ptc.iter().map(|q| serde_json::json!({
            "output": q.output, "exptime_s": q.exptime_s,
            "mean_adu": q.mean_adu, "variance_adu2": q.var_adu2, "pixels": q.pixels,
        })).collect::<Vec<_>>(),
        "covered_dark_e_per_s": p.covered_rates.iter()
            .map(|(t, r)| serde_json::json!({ "ccdtemp_k": t, "rate_e_per_s": r }))
            .collect::<Vec<_>>(),
        "covered_dark_law": p.dark_law().map(|l| serde_json::json!({
            "rate_e_per_s": l.rate_e_per_s.to_num::<f64>(),
            "reference_k": l.reference_k.to_num::<f64>(),
            "doubling_k": l.doubling_k.to_num::<f64>(),
            "band": [l.band_low.to_num::<f64>(), l.band_high.to_num::<f64>()],
        })),
        "hot_pixels": p.hot.len(),
        "hot_without_law": p.hot_unfitted,
        "telegraph_pixels": p.rts.len(),
        "telegraph_series": p.rts_series.map(|(t, k, n)| serde_json::json!({
            "exptime_s": t, "ccdtemp_k": k, "frames": n })),
        "cti_eper": p.eper.as_ref().map(|e| serde_json::json!({
            "traps": e.traps, "serial_measured": e.serial_measured, "mean_delay_px": e.mean_delay,
        })),
        "groups": p.groups,
        "notes": p.notes,
    })
}

/// Writes every file of the report into `dir` (created if needed); returns what was written
/// and the PNGs skipped.
pub fn write(p: &Products, dir: &Path) -> Result<Written, LabError> {
    std::fs::create_dir_all(dir).map_err(|e| LabError::Io {
        path: dir.to_path_buf(),
        msg: e.to_string(),
    })?;
    let mut w = Written::default();
    let put = |name: &str, bytes: &[u8], w: &mut Written| -> Result<(), LabError> {
        let path = dir.join(name);
        write_file(&path, bytes)?;
        w.files.push(path);
        Ok(())
    };
    let text =
        serde_json::to_string_pretty(&json(p)).map_err(|e| LabError::Invalid(e.to_string()))?;
    put("report.json", text.as_bytes(), &mut w)?;
    let mut hot = String::from(
        "col,row,rate_e_per_s_at_293k,doubling_k,rate_sigma_e_per_s,doubling_sigma_k\n",
    );
    for h in &p.hot {
        let _ = writeln!(
            hot,
            "{},{},{:.4},{:.4},{:.4},{:.4}",
            h.col,
            h.row,
            h.rate_e_per_s_at_293k,
            h.doubling_k,
            h.rate_sigma_e_per_s,
            h.doubling_sigma_k
        );
    }
    put("hot.csv", hot.as_bytes(), &mut w)?;
    let mut rts = String::from("col,row\n");
    for (c, r) in &p.rts {
        let _ = writeln!(rts, "{c},{r}");
    }
    put("rts.csv", rts.as_bytes(), &mut w)?;
    if let Some(e) = &p.eper {
        let t =
            serde_json::to_string_pretty(&e.traps).map_err(|e| LabError::Invalid(e.to_string()))?;
        put("cti_traps.json", t.as_bytes(), &mut w)?;
        if let Some(c) = p.cti_coeffs() {
            let j = crate::cti::CtiCoeffsJson::from_coeffs(&c, p.geometry.outputs);
            let t =
                serde_json::to_string_pretty(&j).map_err(|e| LabError::Invalid(e.to_string()))?;
            put("cti.json", t.as_bytes(), &mut w)?;
        }
    }
    for (name, map) in [
        ("master_bias.fits", &p.master_bias),
        ("dark_rel.fits", &p.dark_rel),
        ("flat.fits", &p.flat),
    ] {
        let path: PathBuf = dir.join(name);
        write_map(&path, map)?;
        w.files.push(path);
    }
    figures(p, dir, &mut w)?;
    Ok(w)
}

/// The report's PNGs.
fn figures(p: &Products, dir: &Path, w: &mut Written) -> Result<(), LabError> {
    let fig = |e: startrack_analysis::figures::FigureError| LabError::Io {
        path: e.path,
        msg: e.message,
    };
    let outputs = p.gain_e_per_adu.len();
    let mut series = Vec::new();
    for o in 0..outputs {
        let pts: Vec<(f64, f64)> = p
            .ptc
            .iter()
            .filter(|q| usize::from(q.output) == o)
            .map(|q| (q.mean_adu / 1e3, q.var_adu2 / 1e3))
            .collect();
        let bv = p.bias_var_adu2.get(o).copied().unwrap_or(0.0);
        let g = p.gain_e_per_adu.get(o).copied().unwrap_or(1.0);
        let top = pts.iter().map(|q| q.0).fold(0.0, f64::max);
        let var_top = pts.iter().map(|q| q.1).fold(0.0, f64::max);
        // The fit over the linear range, not past it.
        let fit_top = p
            .full_well_adu
            .get(o)
            .copied()
            .flatten()
            .map_or(top, |fw| top.min(fw / 1e3));
        let le = p
            .nonlinearity_pct
            .get(o)
            .copied()
            .flatten()
            .map_or(String::new(), |l| format!(", LE {l:.3} %"));
        series.push(Series::solid(format!("output {o}: measured{le}"), pts, o));
        series.push(Series {
            label: format!("output {o}: fit, gain {g:.4} e-/ADU"),
            points: vec![(0.0, bv / 1e3), (fit_top, (bv + 1e3 * fit_top / g) / 1e3)],
            color: o,
            dashed: true,
        });
        if let (Some(Some(fw_adu)), Some(Some(fw_e))) =
            (p.full_well_adu.get(o), p.full_well_e.get(o))
        {
            series.push(Series {
                label: format!("output {o}: full well {fw_e:.0} e-"),
                points: vec![(fw_adu / 1e3, 0.0), (fw_adu / 1e3, var_top)],
                color: o,
                dashed: true,
            });
        }
    }
    lines(
        dir,
        "ptc.png",
        &Chart {
            title: "Photon transfer (LE: EMVA 1288 linearity error)".into(),
            x_label: "mean signal above bias, kADU".into(),
            y_label: "var(A - B) / 2, thousand ADU^2".into(),
            log_x: false,
            log_y: false,
        },
        &series,
        w,
    )
    .map_err(fig)?;
    let mut series = vec![Series::solid(
        "covered pixels (regular dark)".into(),
        p.covered_rates.clone(),
        0,
    )];
    let temps: Vec<f64> = p.covered_rates.iter().map(|c| c.0).collect();
    let mut hot: Vec<_> = p.hot.clone();
    hot.sort_by(|a, b| b.rate_e_per_s_at_293k.total_cmp(&a.rate_e_per_s_at_293k));
    for (i, h) in hot
        .iter()
        .step_by((hot.len() / 4).max(1))
        .take(4)
        .enumerate()
    {
        let pts = temps
            .iter()
            .map(|t| {
                (
                    *t,
                    h.rate_e_per_s_at_293k
                        * 2f64.powf((t - super::dark::HOT_REFERENCE_K) / h.doubling_k),
                )
            })
            .collect();
        series.push(Series::solid(
            format!(
                "hot ({}, {}), fitted law: doubling {:.2} K",
                h.col, h.row, h.doubling_k
            ),
            pts,
            i + 1,
        ));
    }
    lines(
        dir,
        "dark_temperature.png",
        &Chart {
            title: "Dark rate against temperature".into(),
            x_label: "CCDTEMP, K".into(),
            y_label: "dark rate, e-/s".into(),
            log_x: false,
            log_y: true,
        },
        &series,
        w,
    )
    .map_err(fig)
}
