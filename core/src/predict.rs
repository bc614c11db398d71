//! The catalog's stars in the next frame: from an attitude, its rate and their covariances,
//! the stars the tracker should look for at the next frame's mid-exposure, where, within what
//! bound and with what trail ([`PredictedStar`], the tracker's input type).
//!
//! What it is for: with an attitude, tracking needs neither the last frame's stars nor a
//! full frame to find stars entering the field. The attitude `q` of the last fix (at its
//! mid-exposure) is propagated by the rate `w` and the acceleration `alpha` over the
//! interval `dt` to the next frame's mid-exposure, `q' = exp(w dt + alpha dt^2 / 2) q` (the
//! convention of [`crate::attitude::RateFilter`]); the
//! catalog stars in the field cone around its boresight (aberrated for the observer's
//! velocity when the attitude is of the ICRF) are projected through the camera model with
//! the focal-length scale identification fitted ([`crate::ident::FocalScale`]) and each
//! star's colour; those whose window fits on the active area are kept, the
//! brightest [`MAX_CANDIDATES`].
//!
//! Choice: a star with a catalog neighbour within [`PredictConfig::blend_px`] that is not
//! at least [`PredictConfig::blend_mag`] fainter is left out (the two would share a window
//! and bias each other); the active area is cut into [`PredictConfig::grid`] x `grid`
//! cells, and the brightest star of each cell is taken first (geometry: the attitude's roll
//! and scale need stars spread over the field), brightest cell first, then the brightest of
//! the rest, up to [`PredictConfig::max_stars`].
//!
//! Bound: the error rotation at the next frame has covariance `P + dt^2 P_w` (the fix's
//! and the rate's; their correlation is left out, the floor covers it); a star's position
//! sigma is the root trace of that covariance mapped through the tangent-plane projection
//! at the star (so roll counts in proportion to the star's distance from the boresight),
//! and its bound is [`PredictConfig::bound_sigmas`] sigmas plus [`PredictConfig::floor_px`]
//! (the centroid's own error, the camera model's, an unmodelled acceleration). The image's
//! velocity is the star's projected path from `dt - T/2` to `dt + T/2` over `T` (the
//! expected exposure; 1 ms when that is shorter), so that the tracker takes the trail over
//! the integration the frame really has; its motion is the projection's change over one
//! more frame interval.
//!
//! Cost: one cone search of the catalog (a binary search and a scan of the field's
//! declination band, a few hundred stars), a rotation and a projection a star in the cone
//! (~100 flops), the blend test of the kept stars against each other (at most
//! `MAX_CANDIDATES^2 / 2` distance tests, a few thousand in a median field), and three more
//! projections and the sigma (~200 flops) for each predicted star. No allocation: about
//! 2.6 KB of candidates on the stack. The M7 count is `cargo m7-bench`'s
//! `predict_catalog_windows_p99` (docs/tracker.md).

use crate::attitude::{Attitude, Camera, Quat, Rate, aberrate};
use crate::catalog::Catalog;
use crate::ident::predicted_sigma;
use crate::tracker::{PredictedStar, predicted_window_side};

/// Most stars predicted a frame (the tracker's windows).
pub const MAX_PREDICTED: usize = crate::tracker::TRACK_WINDOWS;

/// A prediction: at most [`MAX_PREDICTED`] stars.
pub type PredictedStars = heapless::Vec<PredictedStar, MAX_PREDICTED>;

/// Most catalog stars on the active area kept for the choice (the brightest; the densest
/// 15 degree field holds about 160 on the sensor to Hp 6.5).
pub const MAX_CANDIDATES: usize = 128;

/// How the stars are chosen and bounded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PredictConfig {
    /// Most stars predicted (at most [`MAX_PREDICTED`]).
    pub max_stars: usize,
    /// The bound in sigmas of the predicted position.
    pub bound_sigmas: f64,
    /// Added to every bound, px: the centroid's error, the camera model's, what the
    /// constant-rate propagation leaves out.
    pub floor_px: f64,
    /// Cells per side of the grid the stars are spread over.
    pub grid: u8,
    /// A neighbour within this is a blend, px.
    pub blend_px: f64,
    /// ... unless it is fainter by at least this, mag.
    pub blend_mag: f64,
    /// The tracker's centroid window side, px (a star's window must fit on the active
    /// area: [`predicted_window_side`]).
    pub window_px: u16,
    /// Longest interval predicted over, s (beyond it nothing is predicted).
    pub max_interval_s: f64,
}

impl PredictConfig {
    /// The flight choice for the tracker's centroid window `window_px`: 32 stars on a 4 x 4
    /// grid, 5 sigmas plus 1 px, neighbours within 6 px unless 2.5 mag fainter, at most 1 s
    /// ahead.
    pub const fn flight(window_px: u16) -> Self {
        Self {
            max_stars: MAX_PREDICTED,
            bound_sigmas: 5.0,
            floor_px: 1.0,
            grid: 4,
            blend_px: 6.0,
            blend_mag: 2.5,
            window_px,
            max_interval_s: 1.0,
        }
    }
}

/// What a prediction starts from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PredictFrom {
    /// The last fix's attitude (ICRS to camera) and covariance, at its mid-exposure.
    pub attitude: Attitude,
    /// The angular rate and its covariance.
    pub rate: Rate,
    /// The angular acceleration, rad/s^2 (zero when none is measured): the propagation is
    /// `exp(w dt + alpha dt^2 / 2) q`.
    pub accel_rad_s2: [f64; 3],
    /// True focal length over the camera model's ([`crate::ident::FocalScale::value`]).
    pub scale: f64,
    /// From the fix's mid-exposure to the next frame's, s.
    pub interval_s: f64,
    /// The next frame's expected exposure, s: a star is kept only where its window, sized
    /// for the trail over it, fits.
    pub exposure_s: f64,
    /// The frame interval after the next frame, s (for each star's motion).
    pub period_s: f64,
    /// The observer's velocity (ICRF, barycentric, m/s) when the attitude is of the ICRF,
    /// stellar aberration removed ([`crate::solver::Solver::update_at_velocity`]): the
    /// catalog directions are then aberrated ([`crate::attitude::aberrate`]) before they
    /// are projected, so the stars fall where the camera sees them. `None`: the attitude is
    /// of the apparent sky.
    pub velocity_m_s: Option<[f64; 3]>,
}

/// Why nothing was predicted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PredictError {
    /// The attitude, the rate, a covariance, the scale or a time is not finite or out of
    /// range, or the configuration is.
    BadInput,
    /// The interval is longer than [`PredictConfig::max_interval_s`].
    TooOld,
}

impl core::fmt::Display for PredictError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::BadInput => "prediction: attitude, rate, scale, time or setting not valid",
            Self::TooOld => "prediction: the attitude is too old to propagate",
        })
    }
}

impl core::error::Error for PredictError {}

/// A catalog star on the active area.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    index: u16,
    hp_mmag: i16,
    bv_mmag: i16,
    x_px: f32,
    y_px: f32,
    /// Left out of the choice (a blend, or already taken).
    out: bool,
}

/// `q0` turned by the rate `w` (rad/s) and the acceleration `a` (rad/s^2) for `dt` s:
/// `exp(w dt + a dt^2 / 2) q0`.
#[inline(never)]
fn turned(q0: Quat, w: [f64; 3], a: [f64; 3], dt: f64) -> Quat {
    let h = 0.5 * dt * dt;
    let mut v = [0.0; 3];
    for ((o, wi), ai) in v.iter_mut().zip(w).zip(a) {
        *o = wi * dt + ai * h;
    }
    Quat::from_rotation_vector(v) * q0
}

/// The pixel position of the catalog direction `dir` of colour `bv_mmag` at attitude `q`
/// (one copy of the projection for the four uses, to keep the flash image small).
#[inline(never)]
fn project(cam: &Camera, q: Quat, dir: [f64; 3], bv_mmag: i16) -> Option<[f64; 2]> {
    cam.project_of(q.rotate(dir), f64::from(bv_mmag) / 1000.0)
        .ok()
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|c| c.is_finite())
}

fn finite33(m: &[[f64; 3]; 3]) -> bool {
    m.iter().all(finite3)
}

/// The catalog stars `from` predicts on an active area of `active_px` (columns, rows)
/// through `camera`, chosen by `cfg`, into `out` (cleared first); returns how many. An empty
/// cone or a field with no star whose window fits gives none (`Ok(0)`).
#[inline(never)]
pub fn predict(
    cat: &Catalog<'_>,
    camera: &Camera,
    from: &PredictFrom,
    active_px: [u16; 2],
    cfg: &PredictConfig,
    out: &mut PredictedStars,
) -> Result<usize, PredictError> {
    out.clear();
    let ok = finite33(&from.attitude.cov_rad2)
        && finite33(&from.rate.cov_rad2_s2)
        && finite3(&from.rate.w_rad_s)
        && finite3(&from.accel_rad_s2)
        && from.scale.is_finite()
        && (0.9..=1.1).contains(&from.scale)
        && from.interval_s.is_finite()
        && from.interval_s >= 0.0
        && from.exposure_s.is_finite()
        && from.exposure_s >= 0.0
        && from.period_s.is_finite()
        && from.period_s >= 0.0
        && from.velocity_m_s.is_none_or(|v| finite3(&v))
        && cfg.bound_sigmas.is_finite()
        && cfg.floor_px.is_finite()
        && cfg.floor_px > 0.0
        && cfg.blend_px.is_finite()
        && cfg.blend_mag.is_finite()
        && cfg.grid > 0
        && camera.focal_length_px.is_finite()
        && camera.focal_length_px > 0.0;
    let q0 = from.attitude.q.normalized().filter(|_| ok);
    let Some(q0) = q0 else {
        return Err(PredictError::BadInput);
    };
    if from.interval_s > cfg.max_interval_s {
        return Err(PredictError::TooOld);
    }
    let (w, a) = (from.rate.w_rad_s, from.accel_rad_s2);
    let turn = |dt: f64| turned(q0, w, a, dt);
    let q = turn(from.interval_s);
    let cam = Camera {
        focal_length_px: camera.focal_length_px * from.scale,
        ..*camera
    };
    let dt2 = from.interval_s * from.interval_s;
    let mut cov = from.attitude.cov_rad2;
    for (row, rrow) in cov.iter_mut().zip(from.rate.cov_rad2_s2.iter()) {
        for (c, r) in row.iter_mut().zip(rrow) {
            *c += dt2 * r;
        }
    }

    let [cols, rows] = active_px.map(f64::from);
    let mut cands: heapless::Vec<Candidate, MAX_CANDIDATES> = heapless::Vec::new();
    let boresight = q.rotate_inv([0.0, 0.0, 1.0]);
    let seen = |dir: [f64; 3]| match from.velocity_m_s {
        Some(v) => aberrate(dir, v),
        None => dir,
    };
    for (idx, dir) in cat.cone(boresight, cat.field_radius_rad()) {
        let dir = seen(dir);
        let (Some(star), Ok(index)) = (cat.star(idx), u16::try_from(idx)) else {
            continue;
        };
        let Some(p) = project(&cam, q, dir, star.bv_mmag) else {
            continue;
        };
        // The still window must fit: a star entering the field joins once it does.
        let half = f64::from(cfg.window_px / 2 + 1);
        if !(p[0] >= half && p[1] >= half && p[0] <= cols - 1.0 - half && p[1] <= rows - 1.0 - half)
        {
            continue;
        }
        let c = Candidate {
            index,
            hp_mmag: star.hp_mmag,
            bv_mmag: star.bv_mmag,
            x_px: p[0] as f32,
            y_px: p[1] as f32,
            out: false,
        };
        if cands.push(c).is_err()
            && let Some(faintest) = cands.iter_mut().max_by_key(|c| c.hp_mmag)
            && faintest.hp_mmag > c.hp_mmag
        {
            *faintest = c;
        }
    }
    // Blends: a neighbour within blend_px not blend_mag fainter.
    let blend2 = (cfg.blend_px * cfg.blend_px) as f32;
    let blend_mmag = (cfg.blend_mag * 1000.0) as i32;
    for i in 0..cands.len() {
        let Some(&a) = cands.get(i) else { continue };
        let blended = cands.iter().enumerate().any(|(j, b)| {
            let (dx, dy) = (b.x_px - a.x_px, b.y_px - a.y_px);
            j != i
                && dx * dx + dy * dy < blend2
                && i32::from(b.hp_mmag) - i32::from(a.hp_mmag) < blend_mmag
        });
        if let Some(c) = cands.get_mut(i) {
            c.out = blended;
        }
    }
    // The brightest of each cell first, brightest cell first; then the brightest of the rest.
    let grid = usize::from(cfg.grid);
    let cell_of = |c: &Candidate| {
        let gx = ((f64::from(c.x_px) / cols * grid as f64) as usize).min(grid - 1);
        let gy = ((f64::from(c.y_px) / rows * grid as f64) as usize).min(grid - 1);
        gy * grid + gx
    };
    let max = cfg.max_stars.min(MAX_PREDICTED);
    // The span the image's velocity is taken over: the exposure, at least 1 ms.
    let span_s = from.exposure_s.max(1e-3);
    let half_t = 0.5 * span_s;
    let (q_start, q_end, q_next) = (
        turn(from.interval_s - half_t),
        turn(from.interval_s + half_t),
        turn(from.interval_s + from.period_s),
    );
    // The rotation's covariance with no scale term, for identification's own mapping.
    let mut cov4 = [[0.0f64; 4]; 4];
    for (r4, r3) in cov4.iter_mut().zip(cov.iter()) {
        for (c4, c3) in r4.iter_mut().zip(r3) {
            *c4 = *c3;
        }
    }
    // A candidate's prediction, if its window (bound and trail) fits on the active area.
    let make = |c: &Candidate| -> Option<PredictedStar> {
        let dir = seen(cat.dir(usize::from(c.index))?);
        let at = |qq: Quat| project(&cam, qq, dir, c.bv_mmag);
        let (ps, pe, pn) = (at(q_start)?, at(q_end)?, at(q_next)?);
        let sigma_px = camera.focal_length_px * predicted_sigma(q.rotate(dir), &cov4, from.scale);
        let p = PredictedStar {
            catalog: c.index,
            x_px: c.x_px,
            y_px: c.y_px,
            bound_px: (cfg.bound_sigmas * sigma_px + cfg.floor_px) as f32,
            rate_px_s: (
                ((pe[0] - ps[0]) / span_s) as f32,
                ((pe[1] - ps[1]) / span_s) as f32,
            ),
            motion_px: (
                (pn[0] - f64::from(c.x_px)) as f32,
                (pn[1] - f64::from(c.y_px)) as f32,
            ),
        };
        let trail = p.trail_px(from.exposure_s as f32);
        let half = f32::from(predicted_window_side(cfg.window_px, p.bound_px, trail) / 2);
        let inside = p.x_px >= half
            && p.y_px >= half
            && p.x_px <= cols as f32 - 1.0 - half
            && p.y_px <= rows as f32 - 1.0 - half;
        (p.is_valid() && inside).then_some(p)
    };
    // The brightest candidate left, in a cell with no star yet when `spread`.
    let mut cell_taken = [false; 64];
    let spread_first = grid * grid <= cell_taken.len();
    let mut spread = spread_first;
    while out.len() < max {
        let best = cands
            .iter()
            .enumerate()
            .filter(|(_, c)| !c.out)
            .filter(|(_, c)| !spread || !cell_taken.get(cell_of(c)).copied().unwrap_or(true))
            .min_by_key(|(_, c)| c.hp_mmag)
            .map(|(i, _)| i);
        let Some(c) = best.and_then(|i| cands.get_mut(i)) else {
            if spread {
                spread = false;
                continue;
            }
            break;
        };
        c.out = true;
        let c = *c;
        if let Some(p) = make(&c) {
            if let Some(t) = cell_taken.get_mut(cell_of(&c)) {
                *t = true;
            }
            let _ = out.push(p);
        }
    }
    Ok(out.len())
}
