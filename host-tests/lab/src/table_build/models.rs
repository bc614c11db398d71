//! The model sections of `calib build`: `--cti FILE` (the CTI coefficients as JSON, written by
//! `startrack calib cti` or `calib frames`) becomes section 8, and `--psf-model FILE` (the
//! field PSF model as JSON, written by `startrack calib psf-model`) section 9. A file that
//! does not parse, or values out of the table's range, is a [`LabError::Invalid`] naming the
//! file. Cost: reading two small files.

use crate::LabError;
use crate::cti::CtiCoeffsJson;
use crate::psf_model::PsfModelFit;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{CtiCoeffs, PsfModel};
use std::path::Path;

fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, LabError> {
    let text = std::fs::read_to_string(path).map_err(|e| LabError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    serde_json::from_str(&text).map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))
}

/// The CTI coefficients of `path` for geometry `g`, and the note for the report.
pub fn cti_from_json(g: &ReadoutGeometry, path: &Path) -> Result<(CtiCoeffs, String), LabError> {
    let j: CtiCoeffsJson = read_json(path)?;
    let c = j
        .to_coeffs(g.outputs)
        .map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))?;
    let note = format!(
        "CTI: alpha {:.3}, F_0 {} e-, per transfer at {} e-: {}",
        j.alpha,
        j.flux_offset_e,
        j.reference_flux_e,
        j.outputs
            .iter()
            .enumerate()
            .map(|(o, v)| format!(
                "output {o} parallel {:.3e} px, serial {:.3e} px",
                v.parallel_px_per_transfer, v.serial_px_per_transfer
            ))
            .collect::<Vec<_>>()
            .join("; ")
    );
    Ok((c, note))
}

/// The field PSF model of `path` for geometry `g`, and the note for the report. The model
/// must have been fitted on the same active area (its coordinates are normalised by it).
pub fn psf_model_from_json(
    g: &ReadoutGeometry,
    path: &Path,
) -> Result<(PsfModel, String), LabError> {
    let m: PsfModelFit = read_json(path)?;
    if (m.active_cols, m.active_rows) != (g.active_cols, g.active_rows) {
        return Err(LabError::Invalid(format!(
            "{}: fitted on a {} x {} active area, the table's is {} x {}",
            path.display(),
            m.active_cols,
            m.active_rows,
            g.active_cols,
            g.active_rows
        )));
    }
    let t = m
        .to_table()
        .map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))?;
    let note = format!(
        "field PSF model: degree {}, {} stars, scatter {:.3} px, a = {:.3} px at the centre, {:.3} px in the corner (0, 0)",
        m.degree,
        m.stars,
        m.scatter_px,
        m.a_px(
            f64::from(g.active_cols) / 2.0 - 0.5,
            f64::from(g.active_rows) / 2.0 - 0.5
        ),
        m.a_px(0.0, 0.0)
    );
    Ok((t, note))
}
