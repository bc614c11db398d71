//! From an image's stars to an attitude when the field of view is known only roughly: the
//! core's lost-in-space identification tried over a ladder of focal lengths, then every
//! measured star matched and the attitude and focal length refit from all of them.
//!
//! - Camera: a pinhole about the image centre with the focal length from the horizontal
//!   field of view, or a given model (focal length, principal point, distortion: a table's
//!   camera section or `optics fit`'s file), whose directions the identification uses.
//! - Scale search: the nominal focal length `f0` (from the horizontal field of view, or
//!   given) is known to a relative error `E`. Lost in space is tried at `f0 (1 + k s)`,
//!   `k = 0, +1, -1, +2, ...` within `+-E`, with `s` = [`SCALE_STEP`] (1 %), the pair
//!   tolerance widened by the separation error half a step leaves on the longest side
//!   (14 degrees: the shared frames' diagonal) and the match radius by what it leaves at the
//!   field's corner. The first trial that verifies is kept; each trial's false-match bound is
//!   the core's 1e-9, so the bound of the whole search is the trials tried times that, and
//!   is reported so.
//! - Refinement: with the identified attitude every measured star (not only the 32 the core
//!   looks at) is matched to the nearest catalog star within the match radius (a catalog
//!   star taken once, by its nearest measured star), the attitude solved by the core's
//!   q-method from every match, the focal length fitted by least squares to the matched
//!   pixels (principal point and distortion held), and again, three rounds; a match
//!   whose residual exceeds 5 of its sigmas is dropped. A refined attitude more than 0.1
//!   degree from the identified one, or a focal length outside `f0 (1 +- E)`, is no
//!   solution (never a wrong attitude).
//!
//! Cost: a failed trial is up to 5,000 hypotheses (tens of ms on x86); the refinement a
//! cone search per star and a 4 x 4 eigenproblem a round.

use super::stars::ImageStar;
use startrack_core::attitude::{self, Attitude, Camera, Observation, Quat, angle_between};
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig, IdentError, Measured};

/// Relative step of the focal-length ladder.
pub const SCALE_STEP: f64 = 0.01;
/// Longest star separation the scale slack is sized for, rad (14 degrees).
const LONGEST_SIDE_RAD: f64 = 14.0 * std::f64::consts::PI / 180.0;
/// Refinement rounds.
const ROUNDS: usize = 3;
/// A refined attitude this far from the identified one is rejected, rad (0.1 degree).
const MAX_REFINE_MOVE_RAD: f64 = 0.1 * std::f64::consts::PI / 180.0;
/// Residual cut of a match, its own sigmas.
pub(crate) const CUT_SIGMAS: f64 = 5.0;
/// Fewest matches of a solution.
const MIN_MATCHED: usize = 4;

/// What the solver is told about the camera and the centroids.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveSpec {
    /// Image columns and rows.
    pub size_px: [usize; 2],
    /// The camera model believed; its focal length is the nominal one, known to
    /// [`Self::focal_length_error`] (the colour terms are not used: the colours are not
    /// known before identification).
    pub camera: Camera,
    /// The focal length's relative uncertainty (0.1: 10 %).
    pub focal_length_error: f64,
    /// Smallest centroid sigma believed, px (systematic errors: optics, catalog): each
    /// star's sigma is its fit's or this, whichever is larger; saturated stars get twice it.
    pub sigma_floor_px: f64,
}

/// One measured star matched to a catalog star.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StarMatch {
    /// Index in the image's star list.
    pub star: usize,
    /// Catalog index.
    pub catalog: usize,
    /// Angle between the measured direction and the catalog star through the attitude, rad.
    pub residual_rad: f64,
}

/// A solved image.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageSolution {
    /// Attitude (ICRS to camera) with its covariance.
    pub attitude: Attitude,
    /// Fitted focal length, px.
    pub focal_length_px: f64,
    /// The camera with that focal length.
    pub camera: Camera,
    /// Every matched star.
    pub matches: Vec<StarMatch>,
    /// RMS of the match residuals, rad.
    pub rmse_rad: f64,
    /// Focal lengths tried before one verified (1: the nominal).
    pub trials: usize,
    /// Bound on the false-match probability of the search: trials times the core's bound
    /// of the trial that verified.
    pub false_probability: f64,
}

/// Why an image was not solved.
#[derive(Clone, Debug, PartialEq)]
pub enum ImageSolveError {
    /// Fewer than four stars were found.
    TooFewStars(usize),
    /// No trial verified.
    NoMatch {
        /// Focal lengths tried.
        trials: usize,
        /// Hypotheses verified over all of them.
        hypotheses: u32,
    },
    /// The refinement did not confirm the identification.
    Unconfirmed(String),
    /// The inputs are out of range.
    BadSpec(String),
}

impl std::fmt::Display for ImageSolveError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFewStars(n) => write!(f, "not solved: {n} stars found, at least 4 needed"),
            Self::NoMatch { trials, hypotheses } => write!(
                f,
                "not solved: no identification at {trials} focal lengths ({hypotheses} hypotheses verified)"
            ),
            Self::Unconfirmed(m) => write!(f, "not solved: {m}"),
            Self::BadSpec(m) => f.write_str(m),
        }
    }
}

impl SolveSpec {
    /// A pinhole of focal length `focal_length_px` about the image centre.
    pub fn pinhole(
        size_px: [usize; 2],
        focal_length_px: f64,
        focal_length_error: f64,
        sigma_floor_px: f64,
    ) -> Self {
        Self {
            size_px,
            camera: Camera::pinhole(focal_length_px, centre(size_px)),
            focal_length_error,
            sigma_floor_px,
        }
    }

    /// The model at focal length `f_px`, the rest as given.
    fn camera_at(&self, f_px: f64) -> Camera {
        Camera {
            focal_length_px: f_px,
            ..self.camera
        }
    }

    /// Checks the spec: a positive focal length, its error in 0..0.5, a positive sigma
    /// floor, the principal point inside the image and the model invertible over it.
    fn check(&self) -> Result<(), ImageSolveError> {
        let bad = |m: &str| Err(ImageSolveError::BadSpec(m.into()));
        let c = &self.camera;
        let ok = c.focal_length_px.is_finite()
            && c.focal_length_px > 0.0
            && (0.0..0.5).contains(&self.focal_length_error)
            && self.sigma_floor_px > 0.0
            && self.sigma_floor_px.is_finite();
        if !ok {
            return bad(
                "focal length must be positive, its error in 0..0.5, the sigma floor positive",
            );
        }
        let [w, h] = self.size_px.map(|v| v as f64);
        let [cx, cy] = c.principal_point_px;
        if !((-0.5..w - 0.5).contains(&cx) && (-0.5..h - 0.5).contains(&cy)) {
            return bad(&format!(
                "principal point ({cx}, {cy}) is outside the {w} x {h} px image"
            ));
        }
        let (Ok(cols), Ok(rows)) = (
            u16::try_from(self.size_px[0]),
            u16::try_from(self.size_px[1]),
        ) else {
            return bad("image too large");
        };
        let bv = c.colour_ref_bv_mag;
        c.check_over(cols, rows, [bv, bv])
            .or_else(|e| bad(&format!("camera model unusable over the image: {e}")))
    }
}

/// The image centre, px: the principal point of a pinhole with nothing better known.
pub fn centre(size_px: [usize; 2]) -> [f64; 2] {
    [
        (size_px[0] as f64 - 1.0) / 2.0,
        (size_px[1] as f64 - 1.0) / 2.0,
    ]
}

fn sigma_px(s: &ImageStar, spec: &SolveSpec) -> f64 {
    star_sigma_px(s, spec.sigma_floor_px)
}

/// A star's 1-sigma per axis with a floor of `floor_px`, px: its fit's sigma or the floor,
/// whichever is larger; at least twice the floor for a saturated star.
pub fn star_sigma_px(s: &ImageStar, floor_px: f64) -> f64 {
    let base = if s.sigma_px.is_finite() {
        s.sigma_px.max(floor_px)
    } else {
        floor_px
    };
    if s.saturated() {
        base.max(2.0 * floor_px)
    } else {
        base
    }
}

fn measured(stars: &[ImageStar], camera: &Camera, spec: &SolveSpec) -> Vec<Measured> {
    stars
        .iter()
        .map(|s| {
            let dir = camera.direction(s.x_px, s.y_px);
            Measured {
                dir,
                sigma_rad: sigma_px(s, spec) / camera.focal_length_px * dir[2].powf(1.5),
                // A saturated star's flux is a lower bound: no magnitude.
                inst_mag: if s.saturated() {
                    None
                } else {
                    Measured::inst_mag_of(s.flux_e)
                },
            }
        })
        .collect()
}

/// The ladder of focal lengths: nominal first, then alternately longer and shorter.
pub fn ladder(spec: &SolveSpec) -> Vec<f64> {
    let f0 = spec.camera.focal_length_px;
    let k_max = (spec.focal_length_error / SCALE_STEP).floor() as i64;
    let mut out = vec![f0];
    for k in 1..=k_max {
        for s in [1.0, -1.0] {
            out.push(f0 * (1.0 + s * k as f64 * SCALE_STEP));
        }
    }
    // The ladder's ends reach the error bound itself.
    if spec.focal_length_error > k_max as f64 * SCALE_STEP + 1e-12 {
        out.push(f0 * (1.0 + spec.focal_length_error));
        out.push(f0 * (1.0 - spec.focal_length_error));
    }
    out
}

/// The distance from the principal point to the farthest corner of the image, px.
fn corner_px(spec: &SolveSpec) -> f64 {
    let [cx, cy] = spec.camera.principal_point_px;
    let [w, h] = spec.size_px.map(|v| v as f64 - 1.0);
    [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
        .iter()
        .map(|(x, y)| (x - cx).hypot(y - cy))
        .fold(0.0, f64::max)
}

/// Identifies and refines (see the module docs). `stars` brightest first.
pub fn solve(
    cat: &Catalog<'_>,
    stars: &[ImageStar],
    spec: &SolveSpec,
) -> Result<ImageSolution, ImageSolveError> {
    spec.check()?;
    if stars.len() < MIN_MATCHED {
        return Err(ImageSolveError::TooFewStars(stars.len()));
    }
    let corner_px = corner_px(spec);
    let mut hypotheses = 0u32;
    let ladder = ladder(spec);
    for (trial, &f) in ladder.iter().enumerate() {
        let camera = spec.camera_at(f);
        let meas = measured(stars, &camera, spec);
        let half_step = if spec.focal_length_error > 0.0 {
            SCALE_STEP / 2.0
        } else {
            0.0
        };
        let base = IdentConfig::for_camera(f, spec.sigma_floor_px);
        let cfg = IdentConfig {
            pair_tolerance_rad: base.pair_tolerance_rad + half_step * LONGEST_SIDE_RAD,
            match_radius_rad: base.match_radius_rad + half_step * corner_px / f,
            ..base
        };
        let n = meas.len().min(ident::MAX_STARS);
        match ident::lost_in_space(cat, &meas[..n], &cfg) {
            Ok(sol) => {
                let bound = (trial + 1) as f64 * sol.false_probability;
                return refine(cat, stars, spec, sol.attitude.q, f, trial + 1, bound);
            }
            Err(IdentError::NoMatch { hypotheses: h }) => hypotheses += h,
            Err(IdentError::TooFewStars) => return Err(ImageSolveError::TooFewStars(n)),
            Err(IdentError::BadInput) => {
                return Err(ImageSolveError::BadSpec(
                    "identification refused the stars or its settings".into(),
                ));
            }
            Err(e) => return Err(ImageSolveError::Unconfirmed(e.to_string())),
        }
    }
    Err(ImageSolveError::NoMatch {
        trials: ladder.len(),
        hypotheses,
    })
}

/// Matches every star to the catalog through `q` and `camera`: each star to its nearest
/// catalog star within `radius_px`, a catalog star kept for its nearest star only.
pub(crate) fn match_all(
    cat: &Catalog<'_>,
    stars: &[ImageStar],
    q: Quat,
    camera: &Camera,
    radius_px: f64,
) -> Vec<StarMatch> {
    let radius = radius_px / camera.focal_length_px;
    let mut best: std::collections::HashMap<usize, StarMatch> = std::collections::HashMap::new();
    for (i, s) in stars.iter().enumerate() {
        let dir = camera.direction(s.x_px, s.y_px);
        let sky = q.rotate_inv(dir);
        let mut nearest: Option<(usize, f64)> = None;
        for (idx, d) in cat.cone(sky, radius) {
            let a = angle_between(sky, d);
            if nearest.is_none_or(|(_, b)| a < b) {
                nearest = Some((idx, a));
            }
        }
        let Some((idx, a)) = nearest else { continue };
        let m = StarMatch {
            star: i,
            catalog: idx,
            residual_rad: a,
        };
        match best.get(&idx) {
            Some(o) if o.residual_rad <= a => {}
            _ => {
                best.insert(idx, m);
            }
        }
    }
    let mut out: Vec<StarMatch> = best.into_values().collect();
    out.sort_by_key(|m| m.star);
    out
}

fn refine(
    cat: &Catalog<'_>,
    stars: &[ImageStar],
    spec: &SolveSpec,
    q_ident: Quat,
    f_ident: f64,
    trials: usize,
    false_probability: f64,
) -> Result<ImageSolution, ImageSolveError> {
    let pp = spec.camera.principal_point_px;
    let radius_px = 5.0 * spec.sigma_floor_px + 1.0;
    let mut q = q_ident;
    let mut f = f_ident;
    let mut result = None;
    for _ in 0..ROUNDS {
        let camera = spec.camera_at(f);
        let mut matches = match_all(cat, stars, q, &camera, radius_px + SCALE_STEP);
        // Drop a match beyond its own 5 sigmas.
        matches.retain(|m| {
            let s = sigma_px(&stars[m.star], spec) / f;
            m.residual_rad <= CUT_SIGMAS * s
        });
        if matches.len() < MIN_MATCHED {
            return Err(ImageSolveError::Unconfirmed(format!(
                "{} stars matched after refinement",
                matches.len()
            )));
        }
        let obs: Vec<Observation> = matches
            .iter()
            .filter_map(|m| {
                let s = &stars[m.star];
                let dir = camera.direction(s.x_px, s.y_px);
                Some(Observation {
                    camera: dir,
                    icrs: cat.dir(m.catalog)?,
                    sigma_rad: sigma_px(s, spec) / f * dir[2].powf(1.5),
                })
            })
            .collect();
        let att = attitude::solve(&obs)
            .map_err(|e| ImageSolveError::Unconfirmed(format!("attitude: {e}")))?;
        q = att.q;
        // Focal length by least squares on the matched pixels, principal point and
        // distortion held: the pixel is pp + f (x_d, y_d).
        let (mut num, mut den) = (0.0, 0.0);
        for m in &matches {
            let (Some(icrs), s) = (cat.dir(m.catalog), &stars[m.star]) else {
                continue;
            };
            let c = q.rotate(icrs);
            if c[2] <= 0.0 {
                continue;
            }
            let [u, v] = camera.distort(c[0] / c[2], c[1] / c[2]);
            num += (s.x_px - pp[0]) * u + (s.y_px - pp[1]) * v;
            den += u * u + v * v;
        }
        if den > 0.0 {
            f = num / den;
        }
        result = Some((att, matches));
    }
    let Some((att, _)) = result else {
        return Err(ImageSolveError::Unconfirmed("no refinement round".into()));
    };
    let f0 = spec.camera.focal_length_px;
    let lo = f0 * (1.0 - spec.focal_length_error - SCALE_STEP);
    let hi = f0 * (1.0 + spec.focal_length_error + SCALE_STEP);
    if !(lo..=hi).contains(&f) {
        return Err(ImageSolveError::Unconfirmed(format!(
            "fitted focal length {f:.1} px outside {lo:.1}..{hi:.1}"
        )));
    }
    let moved = angle_between(
        q_ident.rotate_inv([0.0, 0.0, 1.0]),
        att.q.rotate_inv([0.0, 0.0, 1.0]),
    );
    if moved > MAX_REFINE_MOVE_RAD {
        return Err(ImageSolveError::Unconfirmed(format!(
            "refinement moved the boresight {:.3} deg",
            moved.to_degrees()
        )));
    }
    // Final residuals through the final attitude and focal length.
    let camera = spec.camera_at(f);
    let mut matches = Vec::new();
    let mut sum2 = 0.0;
    for m in match_all(cat, stars, att.q, &camera, radius_px) {
        let s = &stars[m.star];
        if m.residual_rad <= CUT_SIGMAS * sigma_px(s, spec) / f {
            sum2 += m.residual_rad * m.residual_rad;
            matches.push(m);
        }
    }
    if matches.len() < MIN_MATCHED {
        return Err(ImageSolveError::Unconfirmed(format!(
            "{} stars matched at the fitted focal length",
            matches.len()
        )));
    }
    let rmse_rad = (sum2 / matches.len() as f64).sqrt();
    Ok(ImageSolution {
        attitude: att,
        focal_length_px: f,
        camera,
        matches,
        rmse_rad,
        trials,
        false_probability,
    })
}

/// The attitude of the frame whose boresight is the image centre's direction, the
/// reference of RA, Dec and roll ([`roll_tetra3_deg`]): `q` followed by the smallest
/// rotation taking the centre's camera-frame direction to +z; `q` itself when the principal
/// point is the image centre.
pub fn centre_attitude(q: Quat, camera: &Camera, size_px: [usize; 2]) -> Quat {
    let [x, y] = centre(size_px);
    let d = camera.direction(x, y);
    // d x z = (d_y, -d_x, 0), of length sin(angle).
    let s = d[0].hypot(d[1]);
    if s == 0.0 {
        return q;
    }
    let angle = s.atan2(d[2]);
    Quat::from_rotation_vector([d[1] / s * angle, -d[0] / s * angle, 0.0]) * q
}

/// Right ascension and declination of a unit vector, deg (RA in 0..360).
pub fn ra_dec_deg(v: [f64; 3]) -> (f64, f64) {
    let ra = v[1].atan2(v[0]).to_degrees().rem_euclid(360.0);
    let dec = v[2].clamp(-1.0, 1.0).asin().to_degrees();
    (ra, dec)
}

/// Roll as tetra3 defines it, deg in 0..360: tetra3's image frame is `(i, j, k)` = (the
/// boresight, towards decreasing column, towards decreasing row), its rotation matrix `R`
/// takes ICRS vectors to that frame, and roll = `atan2(R[1][2], R[2][2])`: the angle of the
/// north celestial pole's projection from the image's up (decreasing row), positive towards
/// the left (decreasing column). In this camera frame (+x increasing column, +y increasing
/// row) that is `atan2(-x_icrs.z, -y_icrs.z)` with `x_icrs`, `y_icrs` the camera's x and y
/// axes in ICRS.
pub fn roll_tetra3_deg(q: Quat) -> f64 {
    let x = q.rotate_inv([1.0, 0.0, 0.0]);
    let y = q.rotate_inv([0.0, 1.0, 0.0]);
    (-x[2]).atan2(-y[2]).to_degrees().rem_euclid(360.0)
}

/// Horizontal field of view of `width_px` columns at focal length `f_px` (tetra3's FOV), deg.
pub fn fov_deg(width_px: usize, f_px: f64) -> f64 {
    2.0 * (width_px as f64 / 2.0 / f_px).atan().to_degrees()
}

/// Focal length for a horizontal field of view, px.
pub fn focal_length_px(width_px: usize, fov_deg: f64) -> f64 {
    width_px as f64 / 2.0 / (fov_deg.to_radians() / 2.0).tan()
}
