//! Star fields rendered from the catalog at a known attitude: each catalog star in the
//! field projected through the camera model in its own colour (distortion and lateral
//! colour, [`Camera::project_of`]), moved by Gaussian centroid noise, some dropped,
//! some false stars added, and the list sorted by observed brightness (brightest first), the
//! way the tracker reports its stars.

use rand::RngExt;
use rand_distr::{Distribution, Normal};
use startrack_core::attitude::{Camera, Quat};
use startrack_core::catalog::Catalog;
use startrack_core::ident::Measured;

/// Electrons from a star of Hp = 0 in one exposure (sets `flux_e` in written fields; the
/// ordering is what matters).
pub const FLUX_E_AT_MAG0: f64 = 2.0e6;

/// How a field is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldSpec {
    /// The camera.
    pub camera: Camera,
    /// Active columns.
    pub cols: u32,
    /// Active rows.
    pub rows: u32,
    /// Centroid 1-sigma per axis, px.
    pub sigma_px: f64,
    /// Probability that a star is missing.
    pub dropout: f64,
    /// False stars added (uniform over the frame, Hp uniform in 1..6.5).
    pub false_stars: usize,
    /// 1-sigma of the observed magnitude (reorders near-equal stars).
    pub mag_noise: f64,
}

impl FieldSpec {
    /// The CCD47-20 (1024 x 1024) behind a 15 degree field, no distortion.
    pub fn ccd47_15deg(sigma_px: f64) -> Self {
        let f = 512.0 / 7.5f64.to_radians().tan();
        Self {
            camera: Camera::pinhole(f, [511.5, 511.5]),
            cols: 1024,
            rows: 1024,
            sigma_px,
            dropout: 0.0,
            false_stars: 0,
            mag_noise: 0.1,
        }
    }
}

/// One star of a rendered field.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldStar {
    /// Column, px.
    pub x_px: f64,
    /// Row, px.
    pub y_px: f64,
    /// Signal, e-.
    pub flux_e: f64,
    /// The catalog star it is, `None` for a false star.
    pub truth: Option<u16>,
}

/// A uniformly distributed random rotation.
pub fn random_attitude<R: rand::Rng>(rng: &mut R) -> Quat {
    let n = Normal::new(0.0, 1.0).unwrap_or_else(|_| unreachable!());
    loop {
        let q = Quat([n.sample(rng), n.sample(rng), n.sample(rng), n.sample(rng)]);
        if let Some(q) = q.normalized() {
            return q;
        }
    }
}

/// The field seen at attitude `q`, brightest first.
pub fn render<R: rand::Rng>(
    cat: &Catalog<'_>,
    q: Quat,
    spec: &FieldSpec,
    rng: &mut R,
) -> Vec<FieldStar> {
    let noise = Normal::new(0.0, spec.sigma_px.max(0.0)).unwrap_or_else(|_| unreachable!());
    let mag_noise = Normal::new(0.0, spec.mag_noise.max(0.0)).unwrap_or_else(|_| unreachable!());
    let boresight = q.rotate_inv([0.0, 0.0, 1.0]);
    let inside = |p: [f64; 2]| {
        p[0] >= -0.5
            && p[1] >= -0.5
            && p[0] < f64::from(spec.cols) - 0.5
            && p[1] < f64::from(spec.rows) - 0.5
    };
    let mut out: Vec<(f64, FieldStar)> = Vec::new();
    for (idx, dir) in cat.cone(boresight, cat.field_radius_rad() + 0.01) {
        // Each star imaged in its own colour: the camera's lateral colour moves it along the
        // radius by `c (B-V - ref)` times its distance from the principal point.
        let bv_mag = f64::from(cat.star(idx).map_or(0, |s| s.bv_mmag)) / 1000.0;
        let Ok(p) = spec.camera.project_of(q.rotate(dir), bv_mag) else {
            continue;
        };
        if !inside(p) || rng.random::<f64>() < spec.dropout {
            continue;
        }
        let hp = f64::from(cat.star(idx).map_or(6500, |s| s.hp_mmag)) / 1000.0;
        let mag = hp + mag_noise.sample(rng);
        out.push((
            mag,
            FieldStar {
                x_px: p[0] + noise.sample(rng),
                y_px: p[1] + noise.sample(rng),
                flux_e: FLUX_E_AT_MAG0 * 10f64.powf(-0.4 * mag),
                truth: u16::try_from(idx).ok(),
            },
        ));
    }
    for _ in 0..spec.false_stars {
        let mag = 1.0 + 5.5 * rng.random::<f64>();
        out.push((
            mag,
            FieldStar {
                x_px: rng.random::<f64>() * f64::from(spec.cols) - 0.5,
                y_px: rng.random::<f64>() * f64::from(spec.rows) - 0.5,
                flux_e: FLUX_E_AT_MAG0 * 10f64.powf(-0.4 * mag),
                truth: None,
            },
        ));
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out.into_iter().map(|(_, s)| s).collect()
}

/// The measured directions of `stars` through `camera`, each with centroid sigma `sigma_px`.
pub fn measured(stars: &[FieldStar], camera: &Camera, sigma_px: f64) -> Vec<Measured> {
    stars
        .iter()
        .map(|s| {
            let dir = camera.direction(s.x_px, s.y_px);
            // A pixel subtends f / z^2 rad radially and f / z across at an angle acos(z) off
            // the axis: their geometric mean makes the isotropic sigma.
            Measured {
                dir,
                sigma_rad: sigma_px / camera.focal_length_px * dir[2].powf(1.5),
                inst_mag: Measured::inst_mag_of(s.flux_e),
            }
        })
        .collect()
}
