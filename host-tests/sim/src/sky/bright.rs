//! Bright objects in the SIL's sky: the Moon, the Earth's limb, the Sun's stray light,
//! planets brighter than any star, and proton hits, each placed at frame 0 and then fixed in
//! the sky (ICRS) as the scene's attitude turns, each frame rendered on the pixels
//! ([`crate::sim::bright::BrightFrame`]) through the scene's photometric model
//! ([`SkyScene::flux_e_at_hp`]: 2.0e7 e-/s at Hp 0, its source in [`super::scene`]; Hp is
//! taken for V, within ~0.1 mag for the Moon's and the Earth's colours).
//!
//! Constants and their sources:
//! - the Moon: mean radius 1,737.4 km at the mean distance 384,400 km, an angular radius of
//!   0.2590 deg ([`MOON_RADIUS_DEG`]; NASA's Moon fact sheet), 17.6 px on the 15 degree camera;
//!   its V magnitude at phase angle `a` (deg), `-12.73 + 0.026 |a| + 4.0e-9 a^4` (Allen's
//!   Astrophysical Quantities), spread evenly over its lit part (the full Moon shows almost
//!   no limb darkening), the terminator an ellipse, the bright limb towards +x;
//! - the Earth: radius 6,371 km seen from [`EARTH_ALTITUDE_KM`] (an angular radius of 68 deg),
//!   its sunlit surface as bright as a Lambertian surface of the Earth's Bond albedo 0.306
//!   (NASA's Earth fact sheet), that is the full Moon's surface brightness times
//!   0.306 / 0.12 (the Moon's geometric albedo), its limb a sharp edge (the airglow layer and
//!   the optics' scattered halo are not modelled);
//! - the Sun: V -26.74; the stray light at the detector is the Sun's irradiance at the
//!   aperture times the baffle's point-source transmittance ([`pst`]): 1e-9 beyond 45 deg
//!   (attenuation of the order of 1e9 beyond a two-stage baffle's exclusion angle:
//!   Haghshenas and Johari, Proc. SPIE 9264, 2014), rising a decade every 5 deg to 1e-6 at
//!   the 30 deg exclusion angle (the HE-5AS's Sun exclusion), that rise an assumption; the
//!   aperture (1,390 mm^2) is the photometric model's; across the field it falls linearly
//!   away from the Sun's azimuth, +-30 % at the corners (an assumption: the shape of scattered
//!   light, not a measured map);
//! - planets: point sources of the scene's PSF at their magnitude (Venus reaches -4.6,
//!   Jupiter -2.9, Mars -2.9: brighter than Sirius's -1.46).
//!
//! Cost: see [`crate::sim::bright`] and [`crate::sim::protons`]; placing them is a few
//! projections a frame.

use super::scene::SkyScene;
use crate::sim::Star;
use crate::sim::bright::{BrightFrame, EarthDisc, MoonDisc, StrayLight};
use crate::sim::protons::{ProtonEnv, ProtonHits};
use startrack_core::attitude::Quat;

/// The Moon's mean angular radius, deg.
pub const MOON_RADIUS_DEG: f64 = 0.2590;
/// The full Moon's V magnitude.
pub const MOON_FULL_V: f64 = -12.73;
/// The Moon's geometric albedo.
pub const MOON_ALBEDO: f64 = 0.12;
/// The Earth's Bond albedo.
pub const EARTH_ALBEDO: f64 = 0.306;
/// The Earth's mean radius, km.
pub const EARTH_RADIUS_KM: f64 = 6371.0;
/// The orbit's altitude, km.
pub const EARTH_ALTITUDE_KM: f64 = 500.0;
/// The Sun's V magnitude.
pub const SUN_V: f64 = -26.74;
/// The baffle's Sun exclusion angle, deg.
pub const SUN_EXCLUSION_DEG: f64 = 30.0;
/// The camera's aperture, mm^2 (the photometric model's: 50.5 mm at f/1.2).
pub const APERTURE_MM2: f64 = 1390.0;
/// The CCD47-20's pixel, mm.
pub const PIXEL_MM: f64 = 0.013;
/// The stray light's change from the field's centre to its corners, fraction.
pub const STRAY_GRADIENT: f64 = 0.3;

/// The baffle's point-source transmittance at a Sun angle of `angle_deg` from the boresight.
pub fn pst(angle_deg: f64) -> f64 {
    if angle_deg >= 45.0 {
        1e-9
    } else {
        1e-9 * 10f64.powf((45.0 - angle_deg) / 5.0)
    }
}

/// The Moon's V magnitude at phase angle `phase_deg`.
pub fn moon_v(phase_deg: f64) -> f64 {
    let a = phase_deg.abs();
    MOON_FULL_V + 0.026 * a + 4.0e-9 * a.powi(4)
}

/// The Moon, placed at frame 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoonSpec {
    /// Its centre at frame 0, active px.
    pub at_px: [f64; 2],
    /// Phase angle, deg (0 full, 180 new).
    pub phase_deg: f64,
}

/// The Earth, placed at frame 0 by where its limb crosses a corner.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EarthSpec {
    /// The corner: 0 (0, 0), 1 (last column, 0), 2 (0, last row), 3 (last column, last row).
    pub corner: u8,
    /// How far the limb reaches into the field along the corner's diagonal, px.
    pub depth_px: f64,
}

/// The Sun outside the field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunSpec {
    /// Its angle from the boresight, deg (at least [`SUN_EXCLUSION_DEG`]).
    pub angle_deg: f64,
    /// Its azimuth about the boresight on the image, deg from +x towards +y.
    pub azimuth_deg: f64,
}

/// A planet, placed at frame 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlanetSpec {
    /// Its position at frame 0, active px.
    pub at_px: [f64; 2],
    /// Its magnitude (Hp taken for V).
    pub mag: f64,
}

/// What the SIL's sky holds beyond its stars.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BrightSky {
    /// The Moon.
    pub moon: Option<MoonSpec>,
    /// The Earth.
    pub earth: Option<EarthSpec>,
    /// The Sun.
    pub sun: Option<SunSpec>,
    /// Planets.
    pub planets: Vec<PlanetSpec>,
    /// Proton hits.
    pub protons: Option<ProtonEnv>,
}

/// A direction fixed in the sky from a pixel at frame 0.
fn sky_dir(scene: &SkyScene, px: [f64; 2]) -> [f64; 3] {
    scene
        .attitude(0)
        .rotate_inv(scene.camera.direction(px[0], px[1]))
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| c / n)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

impl BrightSky {
    /// True when it holds nothing.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// The Earth's centre in the sky (ICRS) and its angular radius, rad.
    fn earth_centre(&self, scene: &SkyScene, e: &EarthSpec) -> ([f64; 3], f64) {
        let [cols, rows] = scene.active_px.map(f64::from);
        let corner = match e.corner {
            0 => [0.0, 0.0],
            1 => [cols - 1.0, 0.0],
            2 => [0.0, rows - 1.0],
            _ => [cols - 1.0, rows - 1.0],
        };
        let centre = [(cols - 1.0) / 2.0, (rows - 1.0) / 2.0];
        let (dx, dy) = (centre[0] - corner[0], centre[1] - corner[1]);
        let n = dx.hypot(dy);
        let limb = [
            corner[0] + e.depth_px * dx / n,
            corner[1] + e.depth_px * dy / n,
        ];
        let outward = [corner[0] - 50.0 * dx / n, corner[1] - 50.0 * dy / n];
        let cam = &scene.camera;
        let (dp, dc) = (
            cam.direction(limb[0], limb[1]),
            cam.direction(outward[0], outward[1]),
        );
        let radius = (EARTH_RADIUS_KM / (EARTH_RADIUS_KM + EARTH_ALTITUDE_KM)).asin();
        let k = unit(cross(dp, dc));
        let kxp = cross(k, dp);
        let c = [0, 1, 2].map(|i| dp[i] * radius.cos() + kxp[i] * radius.sin());
        (scene.attitude(0).rotate_inv(c), radius)
    }

    /// Frame `frame` of `scene` on the pixels, for an exposure of `exposure_s`, the planets
    /// as stars of PSF width `a_px`; `seed` draws the proton hits.
    pub fn frame(
        &self,
        scene: &SkyScene,
        frame: u32,
        exposure_s: f64,
        a_px: f64,
        seed: u64,
    ) -> (BrightFrame, Vec<Star>) {
        let q: Quat = scene.attitude(frame);
        let cam = &scene.camera;
        let f = cam.focal_length_px;
        let scale = exposure_s / super::scene::REFERENCE_EXPOSURE_S;
        let e_at = |mag: f64| scene.flux_e_at_mag0 * scale * 10f64.powf(-0.4 * mag);
        let radius_px = f * MOON_RADIUS_DEG.to_radians().tan();
        let disc_px2 = std::f64::consts::PI * radius_px * radius_px;
        let full_moon_sb = e_at(MOON_FULL_V) / disc_px2;
        let moon = self.moon.and_then(|m| {
            let p = cam.project(q.rotate(sky_dir(scene, m.at_px)))?;
            let lit = (1.0 + m.phase_deg.to_radians().cos()) / 2.0;
            Some(MoonDisc {
                centre_px: p,
                radius_px,
                phase_deg: m.phase_deg,
                sun_direction_rad: 0.0,
                surface_e: if lit > 1e-6 {
                    e_at(moon_v(m.phase_deg)) / (lit * disc_px2)
                } else {
                    0.0
                },
            })
        });
        let earth = self.earth.map(|e| {
            let (c, radius) = self.earth_centre(scene, &e);
            EarthDisc {
                centre_cam: q.rotate(c),
                radius_rad: radius,
                focal_px: f,
                principal_px: cam.principal_point_px,
                surface_e: full_moon_sb * EARTH_ALBEDO / MOON_ALBEDO,
            }
        });
        let [cols, rows] = scene.active_px;
        let stray = self.sun.map(|s| {
            let per_px_at_pst_1 = e_at(SUN_V) * PIXEL_MM * PIXEL_MM / APERTURE_MM2;
            let level = per_px_at_pst_1 * pst(s.angle_deg);
            let half_diag = f64::from(cols).hypot(f64::from(rows)) / 2.0;
            let az = s.azimuth_deg.to_radians();
            let g = STRAY_GRADIENT * level / half_diag;
            StrayLight {
                centre_e: level,
                gradient_e_per_px: [g * az.cos(), g * az.sin()],
                centre_px: [(f64::from(cols) - 1.0) / 2.0, (f64::from(rows) - 1.0) / 2.0],
            }
        });
        let planets = self
            .planets
            .iter()
            .filter_map(|p| {
                let at = cam.project(q.rotate(sky_dir(scene, p.at_px)))?;
                Some(Star {
                    x_px: at[0],
                    y_px: at[1],
                    signal_e: e_at(p.mag),
                    a_px,
                })
            })
            .collect();
        let protons = self
            .protons
            .map(|env| ProtonHits::draw(env, seed, frame, cols, rows, exposure_s));
        (
            BrightFrame {
                moon,
                earth,
                stray,
                protons,
                bloom: true,
            },
            planets,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_moon_and_the_sun_give_their_stated_levels() {
        let scene = SkyScene::ccd47_15deg(Quat::IDENTITY, [0.0; 3]);
        let sky = BrightSky {
            moon: Some(MoonSpec {
                at_px: [300.0, 400.0],
                phase_deg: 0.0,
            }),
            earth: Some(EarthSpec {
                corner: 3,
                depth_px: 100.0,
            }),
            sun: Some(SunSpec {
                angle_deg: 30.0,
                azimuth_deg: 0.0,
            }),
            planets: Vec::new(),
            protons: None,
        };
        let (b, _) = sky.frame(&scene, 0, 0.1, 1.2, 1);
        let m = b.moon.unwrap();
        assert!((m.centre_px[0] - 300.0).abs() < 1e-6 && (m.radius_px - 17.6).abs() < 0.1);
        // The full Moon: 2.0e6 x 10^(0.4 x 12.73) e- over 973 px in 100 ms: 2.5e8 e-/px.
        assert!((m.surface_e / 2.5e8 - 1.0).abs() < 0.05, "{}", m.surface_e);
        // The Sun at the exclusion angle: 1e-6 of 1.2e11 e-/px/s, 100 ms.
        let s = b.stray.unwrap();
        assert!((s.centre_e / 1.21e4 - 1.0).abs() < 0.05, "{}", s.centre_e);
        // The limb 100 px into the last corner along its diagonal.
        let e = b.earth.unwrap();
        let d = 100.0 / 2f64.sqrt();
        assert!(e.inside_px(1023.0 - d, 1023.0 - d).abs() < 1.0);
        assert!(e.at(1023.0, 1023.0) > 1e8 && e.at(500.0, 500.0) == 0.0);
    }
}
