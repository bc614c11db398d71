//! The software-in-the-loop scene from the sky: the catalog's stars seen by the CCD47-20
//! behind the 15 degree camera at an attitude that turns at a constant rate, as the simulated
//! sensor's stars, with the true attitude of each frame beside them.
//!
//! Frame `k`'s attitude is `q_k = exp(k w) q_0`: `q_0` takes ICRS to the camera at frame 0
//! and `w` is the turn per frame in the camera frame (x, y across the boresight, z roll).
//! Every catalog star within the field (plus a margin of [`EDGE_MARGIN_PX`], so stars at the
//! edges are rendered cut) becomes a simulator star at its projected position with
//! `flux_e_at_mag0 10^(-0.4 Hp)` electrons in a [`REFERENCE_EXPOSURE_S`] exposure, scaled by
//! the motion's exposure over it when the scene has one (a still scene's exposures are the
//! reference's). The photometric model: 2.0e7 e-/s at Hp = 0 (2.0e6 e- in 100 ms). For
//! scale: the figure usually quoted from Liebe (IEEE AES Magazine 10(6), 1995), about 19,100
//! photons s^-1 mm^-2 from a magnitude 0 G2 star, through the 15 degree camera's 50.5 mm
//! lens at f/1.2 (about 1,390 mm^2) with 0.75 for optics and quantum efficiency gives 2.0e7 e-/s
//! (the aperture and the efficiency are this model's assumptions, not a lens's data). Positions are exact: the tracker's error is what
//! the run measures.
//!
//! With a motion during the exposure ([`SkyScene::motion`], [`super::motion`]) the attitude
//! follows the rate profile in time instead, the frame's truth (attitude, rate, star
//! positions) is at mid-exposure, and each star is rendered along its path over the exposure
//! ([`SkyScene::trails`]): its direction projected at the midpoints of equal time steps, one
//! step per [`crate::trail::PATH_STEP_PX`] of the path (a roll's trail is curved, a slew's
//! accelerating), integrated by [`TrailedImage`].
//!
//! Cost: one cone search of the catalog (a few hundred stars) and a projection each a frame,
//! microseconds beside the frame's rendering; with a motion, a projection per path step and
//! the trailed image's `width + height` erf differences and `width x height` products per step
//! (a 20 px trail: 1,000 steps, ~36 x 16 px, ~0.6 M products a star).

use crate::sim::Star;
use crate::sky::field::FLUX_E_AT_MAG0;
use crate::sky::motion::ExposureMotion;
use crate::trail::{TrailedImage, path_steps};
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
    /// Electrons from a star of Hp = 0 in a [`REFERENCE_EXPOSURE_S`] exposure.
    pub flux_e_at_mag0: f64,
    /// Active columns and rows.
    pub active_px: [u16; 2],
    /// The turn during the exposure (then `rate_rad_per_frame` is not used); `None`: the
    /// attitude steps between frames and stands still during each (instantaneous) exposure.
    pub motion: Option<ExposureMotion>,
}

/// The exposure [`SkyScene::flux_e_at_mag0`] is given for, s (the SIL's 100 ms frame).
pub const REFERENCE_EXPOSURE_S: f64 = 0.1;

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
            motion: None,
        }
    }

    /// [`Self::ccd47_15deg`] at `attitude0` (at `t = 0`) turning by `motion` during the
    /// exposures.
    pub fn ccd47_15deg_moving(attitude0: Quat, motion: ExposureMotion) -> Self {
        Self {
            motion: Some(motion),
            ..Self::ccd47_15deg(attitude0, [0.0; 3])
        }
    }

    /// Electrons in one exposure from a star of Hp `hp`: the reference exposure's, scaled by
    /// the motion's exposure when there is one.
    pub fn flux_e_at_hp(&self, hp: f64) -> f64 {
        let scale = self
            .motion
            .as_ref()
            .map_or(1.0, |m| m.exposure_s / REFERENCE_EXPOSURE_S);
        self.flux_e_at_mag0 * scale * 10f64.powf(-0.4 * hp)
    }

    /// Frame `frame`'s mid-exposure, s: with a motion its own timing, else the frame's
    /// instant `frame period_s`.
    pub fn mid_exposure_s(&self, frame: u32, period_s: f64) -> f64 {
        match &self.motion {
            Some(m) => m.mid_s(frame),
            None => f64::from(frame) * period_s,
        }
    }

    /// The true rate at frame `frame`'s mid-exposure, camera frame, rad/s (the convention
    /// of [`super::motion`]): with a motion its profile's; else the mean rate between
    /// frames `period_s` apart (the exposure itself sees none).
    pub fn rate_rad_s(&self, frame: u32, period_s: f64) -> [f64; 3] {
        match &self.motion {
            Some(m) => m.profile.rate_at(m.mid_s(frame)),
            None if period_s > 0.0 => self.rate_rad_per_frame.map(|c| -c / period_s),
            None => [0.0; 3],
        }
    }

    /// The true attitude at frame `frame` (at mid-exposure with a motion).
    pub fn attitude(&self, frame: u32) -> Quat {
        if let Some(m) = &self.motion {
            return m.profile.attitude(self.attitude0, m.mid_s(frame));
        }
        let k = f64::from(frame);
        let w = self.rate_rad_per_frame;
        Quat::from_rotation_vector([w[0] * k, w[1] * k, w[2] * k]) * self.attitude0
    }

    /// Frame `frame`'s stars as the sensor integrates them over the exposure along their
    /// paths, PSF width `a_px` (empty without a motion: [`Self::stars`] are then still).
    /// A star is rendered when any point of its path is within [`EDGE_MARGIN_PX`] of the
    /// active area.
    pub fn trails(&self, catalog: &Catalog<'_>, frame: u32, a_px: f64) -> Vec<TrailedImage> {
        let Some(m) = &self.motion else {
            return Vec::new();
        };
        let q_at = |t: f64| m.profile.attitude(self.attitude0, t);
        let (qs, qm, qe) = (
            q_at(m.start_s(frame)),
            q_at(m.mid_s(frame)),
            q_at(m.end_s(frame)),
        );
        let boresight = qm.rotate_inv([0.0, 0.0, 1.0]);
        // The cone holds every star that crosses the field during the exposure.
        let turned = qs
            .error_vector(qe)
            .iter()
            .map(|c| c * c)
            .sum::<f64>()
            .sqrt();
        let [cols, rows] = self.active_px.map(f64::from);
        let margin = EDGE_MARGIN_PX;
        let inside = |p: &[f64; 2]| {
            p[0] >= -margin
                && p[1] >= -margin
                && p[0] <= cols - 1.0 + margin
                && p[1] <= rows - 1.0 + margin
        };
        let sigma = crate::sim::psf::sigma_of_a(a_px);
        let active = self.active_px.map(usize::from);
        catalog
            .cone(boresight, catalog.field_radius_rad() + 0.02 + turned)
            .filter_map(|(idx, dir)| {
                let at = |q: Quat| self.camera.project(q.rotate(dir));
                let (ps, pm, pe) = (at(qs)?, at(qm)?, at(qe)?);
                let length =
                    (pm[0] - ps[0]).hypot(pm[1] - ps[1]) + (pe[0] - pm[0]).hypot(pe[1] - pm[1]);
                let path: Option<Vec<[f64; 2]>> = m
                    .step_times_s(frame, path_steps(length))
                    .map(|t| at(q_at(t)))
                    .collect();
                let path = path?;
                if !path.iter().any(inside) {
                    return None;
                }
                let hp = f64::from(catalog.star(idx)?.hp_mmag) / 1000.0;
                TrailedImage::along(&path, self.flux_e_at_hp(hp), sigma, active)
            })
            .collect()
    }

    /// The stars of frame `frame` (at mid-exposure with a motion), each with the PSF width
    /// `a_px`.
    pub fn stars(&self, catalog: &Catalog<'_>, frame: u32, a_px: f64) -> Vec<Star> {
        self.stars_seen(catalog, frame, a_px, |dir| dir)
    }

    /// [`Self::stars`] with each catalog direction moved by `seen` before it is projected
    /// (an observer's aberration, say).
    pub fn stars_seen(
        &self,
        catalog: &Catalog<'_>,
        frame: u32,
        a_px: f64,
        seen: impl Fn([f64; 3]) -> [f64; 3],
    ) -> Vec<Star> {
        let q = self.attitude(frame);
        let boresight = q.rotate_inv([0.0, 0.0, 1.0]);
        let [cols, rows] = self.active_px.map(f64::from);
        let m = EDGE_MARGIN_PX;
        catalog
            .cone(boresight, catalog.field_radius_rad() + 0.02)
            .filter_map(|(idx, dir)| {
                let p = self.camera.project(q.rotate(seen(dir)))?;
                let inside =
                    p[0] >= -m && p[1] >= -m && p[0] <= cols - 1.0 + m && p[1] <= rows - 1.0 + m;
                let hp = f64::from(catalog.star(idx)?.hp_mmag) / 1000.0;
                inside.then(|| Star {
                    x_px: p[0],
                    y_px: p[1],
                    signal_e: self.flux_e_at_hp(hp),
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
