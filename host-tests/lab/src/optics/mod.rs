//! The camera-model fit: focal length, principal point, radial (`k1`, `k2`) and tangential
//! (`p1`, `p2`) distortion and the lateral colour scale, measured from identified stars over
//! many frames together with each frame's attitude (`startrack optics fit`).
//!
//! Each frame's stars are identified with the core's lost-in-space identification through
//! the current camera model; every identified star gives two residuals, its measured pixel
//! position less the model's projection of its catalog direction in its own colour
//! ([`Camera::project_of`]) through the frame's attitude. Levenberg-Marquardt in f64
//! minimises their sum of squares over the 8 camera parameters and 3 small rotations a frame
//! (the attitude starts from the identification's). The normal equations are accumulated
//! star by star (each star touches 11 unknowns) and solved by Cholesky (`nalgebra`);
//! the Jacobian is by central differences. Cost per iteration: 45 projections a star and one
//! dense `(8 + 3 N)`-square Cholesky solve (`N` frames; 120 frames: 368 unknowns, 17 M
//! flops); a fit converges in 7 or 8 iterations, and `optics fit` of 120 frames, both
//! identification passes included, takes about 6 s on a shared two-core machine.
//! Identification and fit run twice: the first pass identifies through the nominal pinhole
//! (wider match radius, since the distortion is not yet known), the second through the
//! first fit, which brings in the stars at the field's edge.
//!
//! What is not determined well: the principal point trades against the frames' attitudes
//! (a shift of `(cx, cy)` looks like a small rotation except for second-order terms) and
//! against `p1`, `p2`; the fit reports formal 1-sigma errors from its covariance, and the
//! model's error in the image, which is what a star's direction depends on, is measured
//! against the truth in simulations with [`model_error`] (best rotation removed).

mod model_file;
pub mod sky;

pub use model_file::{CameraModelJson, read_camera_file, read_camera_model};

use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use startrack_core::attitude::{self, Camera, Observation, Quat};
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig, Measured};
use startrack_sim::sky::field::{self, FieldSpec, FieldStar};

/// Camera parameters the fit estimates, in this order in [`Fit::sigma`].
pub const PARAM_NAMES: [&str; 8] = [
    "focal_length_px",
    "cx_px",
    "cy_px",
    "k1",
    "k2",
    "p1",
    "p2",
    "colour_scale_per_mag",
];

/// Model error allowed for in the first identification, through the nominal camera, px:
/// enough for the stars within two thirds of the field's radius whatever a percent-level
/// distortion does at the edge (the second pass, through the first fit, brings those in);
/// wider slack costs hypotheses (3 px: ten times the time).
pub const FIRST_PASS_SLACK_PX: f64 = 1.0;

/// Central-difference steps of the camera parameters (about 1e-3 px of image motion each).
const STEP: [f64; 8] = [1e-3, 1e-3, 1e-3, 1e-5, 1e-4, 1e-7, 1e-7, 1e-7];
/// Central-difference step of a frame's rotation, rad.
const STEP_ROT: f64 = 1e-7;

/// An identified star.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IdStar {
    /// Measured column, px.
    pub x_px: f64,
    /// Measured row, px.
    pub y_px: f64,
    /// Catalog direction, ICRS unit vector.
    pub icrs: [f64; 3],
    /// Catalog B-V, mag.
    pub bv_mag: f64,
    /// Catalog index.
    pub catalog: u16,
    /// The position's 1-sigma per axis, px: the star's residuals are weighted by its inverse
    /// square.
    pub sigma_px: f64,
}

/// One frame's identified stars and its attitude from the identification.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// Index of the field it was identified in.
    pub field: usize,
    /// ICRS to camera.
    pub attitude: Quat,
    /// Identified stars.
    pub stars: Vec<IdStar>,
}

/// Identifies each field (pixel positions, brightest first) through `camera` with centroid
/// 1-sigma `sigma_px` and `slack_px` of model error allowed (taken as a 1-sigma of
/// `slack_px / 2`); fields that do not solve are left out.
pub fn identify(
    cat: &Catalog<'_>,
    fields: &[Vec<[f64; 2]>],
    camera: &Camera,
    sigma_px: f64,
    slack_px: f64,
) -> Vec<Frame> {
    identify_from(cat, fields, camera, sigma_px, slack_px, &[])
}

/// As [`identify`]; a field with a prior attitude in `priors` (by field index, within
/// 0.1 degree) is identified by tracking from it instead of lost in space.
pub fn identify_from(
    cat: &Catalog<'_>,
    fields: &[Vec<[f64; 2]>],
    camera: &Camera,
    sigma_px: f64,
    slack_px: f64,
    priors: &[(usize, Quat)],
) -> Vec<Frame> {
    // The model's error counts as noise: the identification's tolerances, its match radius
    // and its final 5-sigma cut all grow with it.
    let sigma_px = sigma_px.hypot(slack_px / 2.0);
    let cfg = IdentConfig::for_camera(camera.focal_length_px, sigma_px);
    let mut out = Vec::new();
    for (field, stars) in fields.iter().enumerate() {
        let meas: Vec<Measured> = stars
            .iter()
            .map(|p| {
                let dir = camera.direction(p[0], p[1]);
                Measured {
                    dir,
                    sigma_rad: sigma_px / camera.focal_length_px * dir[2].powf(1.5),
                    inst_mag: None,
                }
            })
            .collect();
        let prior = priors.iter().find(|p| p.0 == field).map(|p| p.1);
        let sol = match prior {
            Some(q) => ident::track(cat, &meas, q, 0.1f64.to_radians(), &cfg),
            None => ident::lost_in_space(cat, &meas, &cfg),
        };
        let Ok(sol) = sol else {
            continue;
        };
        let ids = sol
            .matches
            .iter()
            .filter_map(|m| {
                let p = stars.get(usize::from(m.star))?;
                let s = cat.star(usize::from(m.catalog))?;
                Some(IdStar {
                    x_px: p[0],
                    y_px: p[1],
                    icrs: s.dir,
                    bv_mag: f64::from(s.bv_mmag) / 1000.0,
                    catalog: m.catalog,
                    sigma_px,
                })
            })
            .collect();
        out.push(Frame {
            field,
            attitude: sol.attitude.q,
            stars: ids,
        });
    }
    out
}

/// What the fit estimates; a parameter not fitted is held at the start value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FitOptions {
    /// Fit the focal length.
    pub focal_length: bool,
    /// Fit the principal point.
    pub principal_point: bool,
    /// Fit `k1`.
    pub k1: bool,
    /// Fit `k2`.
    pub k2: bool,
    /// Fit the tangential distortion `p1`, `p2`.
    pub tangential: bool,
    /// Fit the lateral colour scale.
    pub colour: bool,
    /// Most Levenberg-Marquardt iterations.
    pub max_iterations: usize,
}

impl Default for FitOptions {
    /// Every parameter fitted.
    fn default() -> Self {
        Self {
            focal_length: true,
            principal_point: true,
            k1: true,
            k2: true,
            tangential: true,
            colour: true,
            max_iterations: 60,
        }
    }
}

impl FitOptions {
    /// Only the frames' attitudes fitted, the camera held (a model tested on other frames).
    pub fn attitudes_only() -> Self {
        Self {
            focal_length: false,
            principal_point: false,
            k1: false,
            k2: false,
            tangential: false,
            colour: false,
            ..Self::default()
        }
    }

    /// Which of [`PARAM_NAMES`] are fitted.
    pub fn free(&self) -> [bool; 8] {
        [
            self.focal_length,
            self.principal_point,
            self.principal_point,
            self.k1,
            self.k2,
            self.tangential,
            self.tangential,
            self.colour,
        ]
    }
}

/// A fitted camera model.
#[derive(Clone, Debug, PartialEq)]
pub struct Fit {
    /// The model.
    pub camera: Camera,
    /// Formal 1-sigma of each parameter of [`PARAM_NAMES`] (0 when held): from the normal
    /// equations' inverse, scaled by the chi-square per degree of freedom.
    pub sigma: [f64; 8],
    /// Their covariance, in the order of [`PARAM_NAMES`] (0 for a held parameter).
    pub covariance: [[f64; 8]; 8],
    /// Each frame's fitted attitude.
    pub attitudes: Vec<Quat>,
    /// RMS of the residuals per axis, px (unweighted).
    pub residual_rms_px: f64,
    /// The weighted residuals' chi-square per degree of freedom (1 when every star's sigma
    /// is right).
    pub chi2_per_dof: f64,
    /// Identified stars used.
    pub stars: usize,
    /// Iterations taken.
    pub iterations: usize,
}

/// Why the fit failed.
#[derive(Clone, Debug, PartialEq)]
pub enum FitError {
    /// Fewer stars than unknowns.
    TooFewStars,
    /// The starting model cannot project the stars.
    BadStart,
    /// The normal equations are singular (a parameter the stars do not constrain).
    Singular,
}

impl std::fmt::Display for FitError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::TooFewStars => "optics fit: fewer identified stars than unknowns",
            Self::BadStart => "optics fit: the starting model cannot project the stars",
            Self::Singular => "optics fit: the stars do not constrain every parameter",
        })
    }
}

impl std::error::Error for FitError {}

fn camera_of(p: &[f64; 8], colour_ref_bv_mag: f64) -> Camera {
    Camera {
        focal_length_px: p[0],
        principal_point_px: [p[1], p[2]],
        k1: p[3],
        k2: p[4],
        p1: p[5],
        p2: p[6],
        colour_scale_per_mag: p[7],
        colour_ref_bv_mag,
    }
}

/// The parameters of `c` in the order of [`PARAM_NAMES`].
pub fn params_of(c: &Camera) -> [f64; 8] {
    [
        c.focal_length_px,
        c.principal_point_px[0],
        c.principal_point_px[1],
        c.k1,
        c.k2,
        c.p1,
        c.p2,
        c.colour_scale_per_mag,
    ]
}

/// The residual (model less measured, px) of `s` seen through `cam` at attitude `q` turned
/// by the small rotation `rot`.
fn residual(cam: &Camera, q: Quat, rot: [f64; 3], s: &IdStar) -> Option<[f64; 2]> {
    let v = Quat::from_rotation_vector(rot).rotate(q.rotate(s.icrs));
    let p = cam.project_of(v, s.bv_mag).ok()?;
    Some([p[0] - s.x_px, p[1] - s.y_px])
}

struct State {
    params: [f64; 8],
    rots: Vec<[f64; 3]>,
}

/// The weight of a star's residuals: its inverse variance (1 for a sigma that is not
/// positive and finite).
fn weight(s: &IdStar) -> f64 {
    if s.sigma_px.is_finite() && s.sigma_px > 0.0 {
        1.0 / (s.sigma_px * s.sigma_px)
    } else {
        1.0
    }
}

/// The weighted sum of squares (chi-square) and the plain one, px^2.
fn cost(frames: &[Frame], st: &State, colour_ref: f64) -> Option<(f64, f64)> {
    let cam = camera_of(&st.params, colour_ref);
    let (mut chi2, mut sum) = (0.0, 0.0);
    for (f, rot) in frames.iter().zip(&st.rots) {
        for s in &f.stars {
            let r = residual(&cam, f.attitude, *rot, s)?;
            let r2 = r[0] * r[0] + r[1] * r[1];
            chi2 += weight(s) * r2;
            sum += r2;
        }
    }
    Some((chi2, sum))
}

/// Fits the camera model to `frames`, starting from `start` (its colour reference is kept):
/// weighted least squares, each star's residuals by its inverse variance.
pub fn fit(frames: &[Frame], start: &Camera, opts: FitOptions) -> Result<Fit, FitError> {
    let n_frames = frames.len();
    let n = 8 + 3 * n_frames;
    let n_stars: usize = frames.iter().map(|f| f.stars.len()).sum();
    let free = opts.free();
    let held = free.iter().filter(|f| !**f).count();
    if 2 * n_stars <= n - held + 1 {
        return Err(FitError::TooFewStars);
    }
    let colour_ref = start.colour_ref_bv_mag;
    let mut st = State {
        params: params_of(start),
        rots: vec![[0.0; 3]; n_frames],
    };
    let (mut c0, mut sum0) = cost(frames, &st, colour_ref).ok_or(FitError::BadStart)?;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut jtj = DMatrix::<f64>::zeros(n, n);
    for _ in 0..opts.max_iterations {
        iterations += 1;
        let (a, g) = normal_equations(frames, &st, colour_ref, &free);
        jtj = a.clone();
        let mut improved = false;
        while lambda < 1e12 {
            let mut m = a.clone();
            for i in 0..n {
                m[(i, i)] += lambda * a[(i, i)].max(1e-30);
            }
            let Some(ch) = m.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let step = ch.solve(&(-&g));
            let mut trial = State {
                params: st.params,
                rots: st.rots.clone(),
            };
            for (k, p) in trial.params.iter_mut().enumerate() {
                *p += step[k];
            }
            for (j, r) in trial.rots.iter_mut().enumerate() {
                for (a, v) in r.iter_mut().enumerate() {
                    *v += step[8 + 3 * j + a];
                }
            }
            match cost(frames, &trial, colour_ref) {
                Some((c, sum)) if c < c0 => {
                    let rel = (c0 - c) / c0.max(1e-300);
                    st = trial;
                    c0 = c;
                    sum0 = sum;
                    lambda = (lambda / 10.0).max(1e-12);
                    improved = rel > 1e-12;
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        if !improved {
            break;
        }
    }
    // Formal covariance: (J^T W J)^-1 over the free parameters, scaled by the chi-square
    // per degree of freedom (so that a sigma too small or too large for every star cancels).
    let dof = (2 * n_stars).saturating_sub(n - held);
    let chi2_per_dof = c0 / dof.max(1) as f64;
    let cov = jtj.cholesky().ok_or(FitError::Singular)?.inverse();
    let mut sigma = [0.0; 8];
    let mut covariance = [[0.0; 8]; 8];
    for k in 0..8 {
        if !free[k] {
            continue;
        }
        sigma[k] = (chi2_per_dof * cov[(k, k)]).sqrt();
        for l in 0..8 {
            if free[l] {
                covariance[k][l] = chi2_per_dof * cov[(k, l)];
            }
        }
    }
    let attitudes = frames
        .iter()
        .zip(&st.rots)
        .map(|(f, r)| Quat::from_rotation_vector(*r) * f.attitude)
        .collect();
    Ok(Fit {
        camera: camera_of(&st.params, colour_ref),
        sigma,
        covariance,
        attitudes,
        residual_rms_px: (sum0 / (2 * n_stars) as f64).sqrt(),
        chi2_per_dof,
        stars: n_stars,
        iterations,
    })
}

/// `J^T W J` and `J^T W r` at `st`; a held parameter gets an identity row and no gradient.
fn normal_equations(
    frames: &[Frame],
    st: &State,
    colour_ref: f64,
    free: &[bool; 8],
) -> (DMatrix<f64>, DVector<f64>) {
    let n = 8 + 3 * frames.len();
    let mut a = DMatrix::<f64>::zeros(n, n);
    let mut g = DVector::<f64>::zeros(n);
    let cam = camera_of(&st.params, colour_ref);
    let shifted: Vec<[Camera; 2]> = (0..8)
        .map(|k| {
            let mut lo = st.params;
            let mut hi = st.params;
            lo[k] -= STEP[k];
            hi[k] += STEP[k];
            [camera_of(&lo, colour_ref), camera_of(&hi, colour_ref)]
        })
        .collect();
    for (j, (f, rot)) in frames.iter().zip(&st.rots).enumerate() {
        for s in &f.stars {
            let Some(r) = residual(&cam, f.attitude, *rot, s) else {
                continue;
            };
            let w = weight(s);
            // 11 columns: the 8 camera parameters, then this frame's 3 rotations.
            let mut cols = [[0.0f64; 2]; 11];
            let mut idx = [0usize; 11];
            for (k, pair) in shifted.iter().enumerate() {
                idx[k] = k;
                if !free[k] {
                    continue;
                }
                let lo = residual(&pair[0], f.attitude, *rot, s).unwrap_or(r);
                let hi = residual(&pair[1], f.attitude, *rot, s).unwrap_or(r);
                cols[k] = [
                    (hi[0] - lo[0]) / (2.0 * STEP[k]),
                    (hi[1] - lo[1]) / (2.0 * STEP[k]),
                ];
            }
            for ax in 0..3 {
                let (mut lo, mut hi) = (*rot, *rot);
                lo[ax] -= STEP_ROT;
                hi[ax] += STEP_ROT;
                let rl = residual(&cam, f.attitude, lo, s).unwrap_or(r);
                let rh = residual(&cam, f.attitude, hi, s).unwrap_or(r);
                idx[8 + ax] = 8 + 3 * j + ax;
                cols[8 + ax] = [
                    (rh[0] - rl[0]) / (2.0 * STEP_ROT),
                    (rh[1] - rl[1]) / (2.0 * STEP_ROT),
                ];
            }
            for p in 0..11 {
                g[idx[p]] += w * (cols[p][0] * r[0] + cols[p][1] * r[1]);
                for q in 0..11 {
                    a[(idx[p], idx[q])] += w * (cols[p][0] * cols[q][0] + cols[p][1] * cols[q][1]);
                }
            }
        }
    }
    for (k, f) in free.iter().enumerate() {
        if !f {
            for i in 0..n {
                a[(k, i)] = 0.0;
                a[(i, k)] = 0.0;
            }
            a[(k, k)] = 1.0;
            g[k] = 0.0;
        }
    }
    (a, g)
}

/// How far a fitted model images directions from the truth, px: on a 17 x 17 grid over the
/// frame, the fitted model's direction of each truth-imaged point, after the one rotation
/// that best aligns the two models' directions is removed (the frames' attitudes absorb any
/// common rotation), converted to px at the truth's focal length; at the reference colour.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelError {
    /// RMS over the grid, px.
    pub rms_px: f64,
    /// Largest, px.
    pub max_px: f64,
}

/// The image-plane error of `fitted` against `truth` over a `cols` x `rows` frame.
pub fn model_error(fitted: &Camera, truth: &Camera, cols: u32, rows: u32) -> ModelError {
    let mut pts = Vec::new();
    for i in 0..17 {
        for j in 0..17 {
            let x = f64::from(cols) * f64::from(i) / 16.0 - 0.5;
            let y = f64::from(rows) * f64::from(j) / 16.0 - 0.5;
            if let (Ok(t), Ok(f)) = (
                truth.direction_of(x, y, truth.colour_ref_bv_mag),
                fitted.direction_of(x, y, truth.colour_ref_bv_mag),
            ) {
                pts.push((t, f));
            }
        }
    }
    // The rotation taking the truth's directions to the fitted ones.
    let obs: Vec<Observation> = pts
        .iter()
        .map(|(t, f)| Observation {
            camera: *f,
            icrs: *t,
            sigma_rad: 1e-5,
        })
        .collect();
    let rot = attitude::solve(&obs).map_or(Quat::IDENTITY, |a| a.q);
    let errs: Vec<f64> = pts
        .iter()
        .map(|(t, f)| attitude::angle_between(rot.rotate(*t), *f) * truth.focal_length_px)
        .collect();
    let n = errs.len().max(1) as f64;
    ModelError {
        rms_px: (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        max_px: errs.iter().copied().fold(0.0, f64::max),
    }
}

/// The lateral colour of the stars, before and after correction, px.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColourError {
    /// RMS of the true colour shifts (what an uncorrected model leaves), px.
    pub uncorrected_rms_px: f64,
    /// Largest true colour shift, px.
    pub uncorrected_max_px: f64,
    /// RMS over the stars of the true colour shift less the fitted model's, px.
    pub residual_rms_px: f64,
    /// Largest such residual, px.
    pub residual_max_px: f64,
}

/// The colour shift (position in the star's colour less at the reference colour) of each
/// identified star of `frames` under `truth`, against the same shift under `fitted`, each
/// at its field's true attitude (`truth_attitudes`, indexed by [`Frame::field`]).
pub fn colour_error(
    frames: &[Frame],
    truth_attitudes: &[Quat],
    fitted: &Camera,
    truth: &Camera,
) -> ColourError {
    let shift = |cam: &Camera, v: [f64; 3], bv: f64| -> Option<[f64; 2]> {
        let a = cam.project_of(v, bv).ok()?;
        let b = cam.project_of(v, cam.colour_ref_bv_mag).ok()?;
        Some([a[0] - b[0], a[1] - b[1]])
    };
    let (mut u, mut r) = (Vec::new(), Vec::new());
    for f in frames {
        let Some(q) = truth_attitudes.get(f.field) else {
            continue;
        };
        for s in &f.stars {
            let v = q.rotate(s.icrs);
            if let (Some(t), Some(m)) = (shift(truth, v, s.bv_mag), shift(fitted, v, s.bv_mag)) {
                u.push(t[0].hypot(t[1]));
                r.push((t[0] - m[0]).hypot(t[1] - m[1]));
            }
        }
    }
    let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    ColourError {
        uncorrected_rms_px: rms(&u),
        uncorrected_max_px: max(&u),
        residual_rms_px: rms(&r),
        residual_max_px: max(&r),
    }
}

/// The simulated optics: the CCD47-20 behind a 15 degree field with percent-level barrel
/// distortion (2.5 px at the corner), decentring of a few hundredths of a px, the principal
/// point 3.8 and -3.4 px off the centre, and lateral colour of 2.5e-4 per magnitude
/// (0.18 px at the corner for one magnitude of B-V from the reference 0.6).
pub fn simulated_truth() -> Camera {
    let f = 512.0 / 7.5f64.to_radians().tan();
    Camera {
        k1: 0.1,
        k2: -0.3,
        p1: 1.5e-4,
        p2: -1.0e-4,
        colour_scale_per_mag: 2.5e-4,
        colour_ref_bv_mag: 0.6,
        ..Camera::pinhole(f * 1.002, [515.3, 508.1])
    }
}

/// The nominal camera a fit starts from: the design's pinhole, centred, no distortion.
pub fn nominal() -> Camera {
    FieldSpec::ccd47_15deg(0.0).camera
}

/// Simulated frames: `n` fields at random attitudes (seeded) through `truth`, centroid noise
/// `sigma_px`, 10 % of the stars dropped and 2 false stars a field. Returns the true
/// attitudes and the fields' pixel positions, brightest first.
pub fn simulate(
    cat: &Catalog<'_>,
    truth: &Camera,
    n: usize,
    seed: u64,
    sigma_px: f64,
) -> (Vec<Quat>, Vec<Vec<FieldStar>>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let spec = FieldSpec {
        camera: *truth,
        dropout: 0.1,
        false_stars: 2,
        ..FieldSpec::ccd47_15deg(sigma_px)
    };
    (0..n)
        .map(|_| {
            let q = field::random_attitude(&mut rng);
            (q, field::render(cat, q, &spec, &mut rng))
        })
        .unzip()
}

/// The whole measurement: identify through `start` lost in space (with
/// [`FIRST_PASS_SLACK_PX`] of slack), fit,
/// identify again through the fit by tracking from the fitted attitudes, fit again. Returns the frames of the second pass and its fit.
pub fn identify_and_fit(
    cat: &Catalog<'_>,
    fields: &[Vec<[f64; 2]>],
    start: &Camera,
    sigma_px: f64,
    opts: FitOptions,
) -> Result<(Vec<Frame>, Fit), FitError> {
    let frames = identify(cat, fields, start, sigma_px, FIRST_PASS_SLACK_PX);
    let first = fit(&frames, start, opts)?;
    let priors: Vec<(usize, Quat)> = frames
        .iter()
        .zip(&first.attitudes)
        .map(|(f, q)| (f.field, *q))
        .collect();
    let frames = identify_from(cat, fields, &first.camera, sigma_px, 0.0, &priors);
    let second = fit(&frames, &first.camera, opts)?;
    Ok((frames, second))
}
