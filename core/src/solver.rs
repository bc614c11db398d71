//! The attitude stage of the frame loop: a frame's star list in, an identified attitude with
//! its covariance out, and the prior it keeps from one frame to the next.
//!
//! Each frame, the usable stars ([`StarRecord::is_centroid`], not saturated, their trail
//! not unknown ([`StarFlags::TRAIL_UNKNOWN`]), with a finite
//! positive sigma) are turned into camera-frame directions by the [`Camera`], at most
//! [`ident::MAX_STARS`], those the fitted PSF describes first (no [`StarFlags::POOR_FIT`]),
//! then the brightest; with [`CLEAN_ENOUGH`] of those, the `POOR_FIT` ones are left out. With a prior no older than
//! [`SolverConfig::max_prior_age_us`], [`ident::track`] identifies them near it; without one,
//! or when tracking fails, [`ident::lost_in_space`] does. A solution replaces the prior; a
//! frame with none leaves the prior to age out, so one bad frame does not send the next
//! frames to lost in space.
//!
//! The focal-length scale identification fits with each attitude ([`ident::FocalScale`]:
//! lost in space finds it within 2 % of the camera model's) is kept with the prior, and
//! tracking starts from it, so a slow drift of the focal length (thermal) is followed from
//! frame to frame; [`Solver::scale`] reports it. The camera model itself is never changed
//! here: a corrected model reaches the table only by command.
//!
//! A star's angular sigma is its pixel sigma (the larger axis) scaled by the camera at its
//! position: a pixel subtends `z^2 / f` rad radially and `z / f` across at `acos(z)` off the
//! axis, and their geometric mean `z^1.5 / f` makes the isotropic sigma the identification and
//! the q-method take.
//!
//! Cost: what identification costs (docs/attitude.md: on the Cortex-M7 tracking and attitude
//! about 0.67 M instructions a frame, lost in space 3.4 M median and 15.8 M at the 99th
//! percentile) plus a sort of at most 32 stars; no allocation, about 1 KB of state beyond
//! identification's stack.

use crate::attitude::{self, Attitude, AttitudeError, Camera, Observation, Quat, aberrate};
use crate::catalog::Catalog;
use crate::ident::{self, FocalScale, IdentConfig, IdentError, Measured};
use crate::tracker::{StarFlags, StarRecord};

/// How the attitude stage identifies and when it trusts its prior.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverConfig {
    /// The camera model that turns pixels into directions.
    pub camera: Camera,
    /// Identification settings.
    pub ident: IdentConfig,
    /// How far the prior may be off when tracking, rad (any axis; below 0.2).
    pub prior_error_rad: f64,
    /// A prior older than this is not used, us.
    pub max_prior_age_us: u64,
}

impl SolverConfig {
    /// Settings for `camera` with centroid 1-sigma `sigma_px`: identification as
    /// [`IdentConfig::for_camera`], tracking from a prior up to 2 degrees off and at most 2 s
    /// old.
    pub fn for_camera(camera: Camera, sigma_px: f64) -> Self {
        Self {
            camera,
            ident: IdentConfig::for_camera(camera.focal_length_px, sigma_px),
            prior_error_rad: 2.0f64.to_radians(),
            max_prior_age_us: 2_000_000,
        }
    }
}

/// How a frame's attitude was identified.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SolveMode {
    /// From the prior attitude.
    Tracking,
    /// With no prior (none, too old, or tracking failed).
    LostInSpace,
}

/// A frame's attitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fix {
    /// The attitude (ICRS to camera) and its covariance.
    pub attitude: Attitude,
    /// How it was identified.
    pub mode: SolveMode,
    /// Stars used for identification (usable stars of the list, at most 32).
    pub used: u8,
    /// Stars identified and used in the attitude.
    pub matched: u8,
    /// Upper bound on the probability that the identification is false.
    pub false_probability: f64,
    /// Time of the frame, us.
    pub time_us: u64,
}

/// Why a frame has no attitude.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SolveError {
    /// Fewer usable stars than identification needs (`MIN_MATCHES`, 4).
    TooFewStars {
        /// Usable stars in the list.
        usable: u8,
    },
    /// Identification found no solution (after tracking, lost in space).
    Ident {
        /// Usable stars given to identification.
        usable: u8,
        /// Lost in space's reason.
        error: IdentError,
    },
}

impl core::fmt::Display for SolveError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooFewStars { usable } => {
                write!(
                    f,
                    "attitude: {usable} usable stars, {} needed",
                    ident::MIN_MATCHES
                )
            }
            Self::Ident { usable, error } => write!(f, "attitude from {usable} stars: {error}"),
        }
    }
}

impl core::error::Error for SolveError {}

/// The attitude stage: the catalog, the camera, and the prior of the last solved frame.
pub struct Solver<'c> {
    catalog: Catalog<'c>,
    config: SolverConfig,
    prior: Option<(Quat, u64)>,
    scale: Option<FocalScale>,
}

impl<'c> Solver<'c> {
    /// A stage with no prior (its first frame is lost in space).
    pub fn new(catalog: Catalog<'c>, config: SolverConfig) -> Self {
        Self {
            catalog,
            config,
            prior: None,
            scale: None,
        }
    }

    /// The focal-length scale of the last solved frame (true focal length over the camera
    /// model's, with its 1-sigma); kept when the prior ages out, forgotten with it by
    /// [`Solver::forget`].
    pub fn scale(&self) -> Option<FocalScale> {
        self.scale
    }

    /// The attitude of the last solved frame and its time, us.
    pub fn prior(&self) -> Option<(Quat, u64)> {
        self.prior
    }

    /// Forgets the prior (the next frame is lost in space).
    pub fn forget(&mut self) {
        self.prior = None;
        self.scale = None;
    }

    /// The attitude of the frame at `time_us` whose tracker reported `stars`, of the apparent
    /// directions (no aberration correction).
    pub fn update(&mut self, stars: &[StarRecord], time_us: u64) -> Result<Fix, SolveError> {
        self.update_at_velocity(stars, time_us, None).0
    }

    /// [`Self::update`] for an observer moving at `velocity_m_s` (ICRF, barycentric, m/s):
    /// once identified, the attitude is refitted with each matched catalog direction moved
    /// by [`aberrate`], so the quaternion takes the ICRF (not the
    /// apparent sky) to the camera. Identification itself runs on the catalog as it is (the
    /// aberration, at most 0.001 c, is well inside its tolerances). The `bool` says whether
    /// the correction was applied (`false` without a velocity, or when the refit failed and
    /// the apparent attitude is given). Cost: one aberration a matched star and a q-method.
    pub fn update_at_velocity(
        &mut self,
        stars: &[StarRecord],
        time_us: u64,
        velocity_m_s: Option<[f64; 3]>,
    ) -> (Result<Fix, SolveError>, bool) {
        let mut applied = false;
        let result = self.identify(stars, time_us, velocity_m_s, &mut applied);
        (result, applied)
    }

    fn identify(
        &mut self,
        stars: &[StarRecord],
        time_us: u64,
        velocity_m_s: Option<[f64; 3]>,
        applied: &mut bool,
    ) -> Result<Fix, SolveError> {
        // Ranked as the star list ranks: a window the PSF describes (no `POOR_FIT`: a
        // particle hit is bright and fits badly) before one it does not, then the brighter.
        let rank = |s: &StarRecord| (!s.flags.contains(StarFlags::POOR_FIT), s.flux_e);
        let above = |a: &(bool, f32), b: &(bool, f32)| (a.0, a.1) > (b.0, b.1);
        let mut measured: heapless::Vec<((bool, f32), Measured), { ident::MAX_STARS }> =
            heapless::Vec::new();
        for s in stars.iter().filter(|s| usable(s)) {
            // A position the camera model cannot invert (a fold) is not used.
            let Some(m) = self.measure(s) else { continue };
            if measured.len() < ident::MAX_STARS {
                let _ = measured.push((rank(s), m));
            } else if let Some(lowest) = measured
                .iter_mut()
                .min_by(|a, b| a.0.0.cmp(&b.0.0).then(a.0.1.total_cmp(&b.0.1)))
                .filter(|d| above(&rank(s), &d.0))
            {
                *lowest = (rank(s), m);
            }
        }
        crate::small_sort::sort_by(&mut measured, |a, b| {
            b.0.0.cmp(&a.0.0).then(b.0.1.total_cmp(&a.0.1))
        });
        // With enough stars the PSF describes, those it does not are left out: their
        // positions and sigmas are not clean (a proton hit inside a tracked star's window
        // moves its fit by up to pixels while its sigma stays the star's).
        let clean = measured.iter().filter(|m| m.0.0).count();
        if clean >= CLEAN_ENOUGH {
            measured.truncate(clean);
        }
        let mut dirs: heapless::Vec<Measured, { ident::MAX_STARS }> = heapless::Vec::new();
        for (_, m) in &measured {
            let _ = dirs.push(*m);
        }
        let used = dirs.len() as u8;
        if dirs.len() < ident::MIN_MATCHES {
            return Err(SolveError::TooFewStars { usable: used });
        }
        let cfg = &self.config;
        let fresh = self
            .prior
            .filter(|&(_, t)| time_us >= t && time_us - t <= cfg.max_prior_age_us);
        let prior_scale = self.scale.map_or(1.0, |s| s.value);
        let tracked = fresh.and_then(|(q, _)| {
            ident::track_scaled(
                &self.catalog,
                &dirs,
                q,
                prior_scale,
                cfg.prior_error_rad,
                &cfg.ident,
            )
            .ok()
        });
        let (solution, mode) = match tracked {
            Some(s) => (s, SolveMode::Tracking),
            None => (
                ident::lost_in_space(&self.catalog, &dirs, &cfg.ident).map_err(|error| {
                    SolveError::Ident {
                        usable: used,
                        error,
                    }
                })?,
                SolveMode::LostInSpace,
            ),
        };
        let mut attitude = solution.attitude;
        if let Some(v) = velocity_m_s
            && let Ok(a) = self.aberrated(&dirs, &solution, v)
        {
            attitude = a;
            *applied = true;
        }
        self.prior = Some((attitude.q, time_us));
        self.scale = Some(solution.scale);
        Ok(Fix {
            attitude,
            mode,
            used,
            matched: solution.matches.len() as u8,
            false_probability: solution.false_probability,
            time_us,
        })
    }

    /// The attitude of `solution`'s matches refitted with their catalog directions aberrated
    /// for `v_m_s`.
    fn aberrated(
        &self,
        dirs: &[Measured],
        solution: &ident::Solution,
        v_m_s: [f64; 3],
    ) -> Result<Attitude, AttitudeError> {
        // The directions of the focal length the identification fitted (as its attitude's).
        let k = 1.0 / solution.scale.value;
        let mut obs: heapless::Vec<Observation, { ident::MAX_STARS }> = heapless::Vec::new();
        for m in &solution.matches {
            let (Some(s), Some(r)) = (
                dirs.get(usize::from(m.star)),
                self.catalog.dir(usize::from(m.catalog)),
            ) else {
                continue;
            };
            let o = Observation {
                camera: ident::rescale_dir(s.dir, k),
                icrs: aberrate(r, v_m_s),
                sigma_rad: s.sigma_rad * k,
            };
            if obs.push(o).is_err() {
                break;
            }
        }
        attitude::solve(&obs)
    }

    /// The direction of a star (at the camera's reference colour: colours are known only
    /// once identified) and its isotropic angular sigma; `None` where the camera model has
    /// no inverse.
    fn measure(&self, s: &StarRecord) -> Option<Measured> {
        let cam = &self.config.camera;
        let dir = cam
            .direction_of(f64::from(s.x_px), f64::from(s.y_px), cam.colour_ref_bv_mag)
            .ok()?;
        let z = dir[2].clamp(0.0, 1.0);
        let sigma_px = f64::from(s.sigma_x_px.max(s.sigma_y_px));
        Some(Measured {
            dir,
            sigma_rad: sigma_px * z * libm::sqrt(z) / cam.focal_length_px,
        })
    }
}

/// Stars the fitted PSF describes (no [`StarFlags::POOR_FIT`]) from which the others are
/// left out of identification.
pub const CLEAN_ENOUGH: usize = 6;

/// A star whose position identification may use: a centroid, not saturated, its trail not
/// unknown, with a finite position and a finite positive sigma.
fn usable(s: &StarRecord) -> bool {
    s.is_centroid()
        && !s.flags.intersects(
            StarFlags::SATURATED | StarFlags::DETECT_SATURATED | StarFlags::TRAIL_UNKNOWN,
        )
        && s.x_px.is_finite()
        && s.y_px.is_finite()
        && s.flux_e.is_finite()
        && s.sigma_x_px.is_finite()
        && s.sigma_y_px.is_finite()
        && s.sigma_x_px > 0.0
        && s.sigma_y_px > 0.0
}
