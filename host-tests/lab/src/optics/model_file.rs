//! The camera-model file (JSON): the model `optics fit` measures and `calib build
//! --camera-model` and `solve-image --camera` read, with how well the fit knows each parameter.

use super::PARAM_NAMES;
use crate::{LabError, read_file};
use serde::{Deserialize, Serialize};
use startrack_core::attitude::Camera;
use std::path::Path;

/// The camera-model file: the model and, from a fit, how well it is known.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraModelJson {
    /// Focal length, px.
    pub focal_length_px: f64,
    /// Principal point (column, row), px.
    pub principal_point_px: [f64; 2],
    /// Radial distortion, `r^2` term.
    #[serde(default)]
    pub k1: f64,
    /// Radial distortion, `r^4` term.
    #[serde(default)]
    pub k2: f64,
    /// Tangential distortion.
    #[serde(default)]
    pub p1: f64,
    /// Tangential distortion.
    #[serde(default)]
    pub p2: f64,
    /// Lateral colour, relative scale per mag of B-V.
    #[serde(default)]
    pub colour_scale_per_mag: f64,
    /// Reference B-V of the colour scale, mag.
    #[serde(default = "default_ref_bv")]
    pub colour_ref_bv_mag: f64,
    /// Formal 1-sigma of the fitted parameters, in the order of `sigma_names`.
    #[serde(default)]
    pub sigma: Vec<f64>,
    /// Names of `sigma`'s entries.
    #[serde(default)]
    pub sigma_names: Vec<String>,
    /// RMS of the fit's residuals per axis, px.
    #[serde(default)]
    pub residual_rms_px: Option<f64>,
    /// Identified stars the fit used.
    #[serde(default)]
    pub stars: Option<usize>,
    /// Frames the fit used.
    #[serde(default)]
    pub frames: Option<usize>,
    /// Covariance of the fitted parameters, in the order of `sigma_names` (0 for a held
    /// one).
    #[serde(default)]
    pub covariance: Vec<Vec<f64>>,
}

fn default_ref_bv() -> f64 {
    Camera::pinhole(1.0, [0.0, 0.0]).colour_ref_bv_mag
}

impl CameraModelJson {
    /// The file of a bare model.
    pub fn of(c: &Camera) -> Self {
        Self {
            focal_length_px: c.focal_length_px,
            principal_point_px: c.principal_point_px,
            k1: c.k1,
            k2: c.k2,
            p1: c.p1,
            p2: c.p2,
            colour_scale_per_mag: c.colour_scale_per_mag,
            colour_ref_bv_mag: c.colour_ref_bv_mag,
            sigma: Vec::new(),
            sigma_names: Vec::new(),
            residual_rms_px: None,
            stars: None,
            frames: None,
            covariance: Vec::new(),
        }
    }

    /// The file of a fit over `frames` frames.
    pub fn of_fit(f: &super::Fit, frames: usize) -> Self {
        Self {
            sigma: f.sigma.to_vec(),
            sigma_names: PARAM_NAMES.iter().map(|s| (*s).to_string()).collect(),
            residual_rms_px: Some(f.residual_rms_px),
            stars: Some(f.stars),
            frames: Some(frames),
            covariance: f.covariance.iter().map(|r| r.to_vec()).collect(),
            ..Self::of(&f.camera)
        }
    }

    /// The model.
    pub fn camera(&self) -> Camera {
        Camera {
            focal_length_px: self.focal_length_px,
            principal_point_px: self.principal_point_px,
            k1: self.k1,
            k2: self.k2,
            p1: self.p1,
            p2: self.p2,
            colour_scale_per_mag: self.colour_scale_per_mag,
            colour_ref_bv_mag: self.colour_ref_bv_mag,
        }
    }
}

/// Reads a camera model from a calibration table's camera section or from the JSON `optics
/// fit` writes (a file whose first non-blank byte is `{`), unchecked: the caller checks it
/// over its own frame.
pub fn read_camera_file(path: &Path) -> Result<Camera, LabError> {
    let bytes = read_file(path)?;
    if bytes.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{') {
        let m: CameraModelJson = serde_json::from_slice(&bytes)
            .map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))?;
        return Ok(m.camera());
    }
    let table =
        startrack_core::table::CalibTable::parse(&bytes).map_err(|err| LabError::Table {
            path: path.to_path_buf(),
            err,
        })?;
    table.camera_model().ok_or_else(|| {
        LabError::Invalid(format!(
            "{}: the calibration table has no camera section",
            path.display()
        ))
    })
}

/// Reads a camera-model file (as `optics fit` writes) and checks that the model is usable over
/// the CCD47-20's frame.
pub fn read_camera_model(path: &Path) -> Result<Camera, LabError> {
    let bytes = read_file(path)?;
    let m: CameraModelJson = serde_json::from_slice(&bytes)
        .map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))?;
    let cam = m.camera();
    cam.check_over(
        1024,
        1024,
        startrack_core::table::camera::COLOUR_RANGE_BV_MAG,
    )
    .map_err(|e| LabError::Invalid(format!("{}: {e}", path.display())))?;
    Ok(cam)
}
