//! The software-in-the-loop scene from the sky: the catalog's stars seen by the CCD47-20
//! behind the 15 degree camera at an attitude that turns at a constant rate, as the simulated
//! sensor's stars, with the true attitude of each frame beside them.
//!
//! Frame `k`'s attitude is `q_k = exp(k w) q_0`: `q_0` takes ICRS to the camera at frame 0
//! and `w` is the turn per frame in the camera frame (x, y across the boresight, z roll).
//! Every catalog star within the field (plus a margin of [`EDGE_MARGIN_PX`], so stars at the
//! edges are rendered cut) becomes a simulator star at its projected position with
//! `flux_e_at_mag0 10^(-0.4 Hp)` electrons. Positions are exact: the tracker's error is what
//! the run measures.
//!
//! Cost: one cone search of the catalog (a few hundred stars) and a projection each a frame,
//! microseconds beside the frame's rendering.

use crate::sim::Star;
use crate::sky::field::FLUX_E_AT_MAG0;
use startrack_core::attitude::{Camera, Quat};
use startrack_core::catalog::Catalog;

/// Stars projected up to this far outside the active area are still rendered, px.
pub const EDGE_MARGIN_PX: f64 = 8.0;

/// A scene from the sky.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkyScene {
    /// ICRS to camera at frame 0.
    pub attitude0: Quat,
    /// Turn per frame, camera frame, rad (x, y across the boresight, z roll).
    pub rate_rad_per_frame: [f64; 3],
    /// The camera that images the sky on the active area.
    pub camera: Camera,
    /// Electrons from a star of Hp = 0.
    pub flux_e_at_mag0: f64,
    /// Active columns and rows.
    pub active_px: [u16; 2],
}

impl SkyScene {
    /// The CCD47-20 (1024 x 1024 active) behind the 15 degree camera of
    /// [`crate::sky::field::FieldSpec::ccd47_15deg`], at `attitude0`, turning by
    /// `rate_rad_per_frame`; [`FLUX_E_AT_MAG0`] electrons at Hp = 0 (Hp 6.5: 5,000 e-).
    pub fn ccd47_15deg(attitude0: Quat, rate_rad_per_frame: [f64; 3]) -> Self {
        Self {
            attitude0,
            rate_rad_per_frame,
            camera: crate::sky::field::FieldSpec::ccd47_15deg(0.0).camera,
            flux_e_at_mag0: FLUX_E_AT_MAG0,
            active_px: [1024, 1024],
        }
    }

    /// The true attitude at frame `frame`.
    pub fn attitude(&self, frame: u32) -> Quat {
        let k = f64::from(frame);
        let w = self.rate_rad_per_frame;
        Quat::from_rotation_vector([w[0] * k, w[1] * k, w[2] * k]) * self.attitude0
    }

    /// The stars of frame `frame`, each with the PSF width `a_px`.
    pub fn stars(&self, catalog: &Catalog<'_>, frame: u32, a_px: f64) -> Vec<Star> {
        let q = self.attitude(frame);
        let boresight = q.rotate_inv([0.0, 0.0, 1.0]);
        let [cols, rows] = self.active_px.map(f64::from);
        let m = EDGE_MARGIN_PX;
        catalog
            .cone(boresight, catalog.field_radius_rad() + 0.02)
            .filter_map(|(idx, dir)| {
                let p = self.camera.project(q.rotate(dir))?;
                let inside =
                    p[0] >= -m && p[1] >= -m && p[0] <= cols - 1.0 + m && p[1] <= rows - 1.0 + m;
                let hp = f64::from(catalog.star(idx)?.hp_mmag) / 1000.0;
                inside.then(|| Star {
                    x_px: p[0],
                    y_px: p[1],
                    signal_e: self.flux_e_at_mag0 * 10f64.powf(-0.4 * hp),
                    a_px,
                })
            })
            .collect()
    }
}

/// The on-board catalog the repo carries (`host-tests/data/catalog-15deg.bin`, the build of
/// the repo's star list that `startrack catalog build` makes; a test keeps them equal).
pub fn committed_catalog() -> Result<Vec<u8>, String> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/catalog-15deg.bin");
    std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))
}
