//! The attitude stage of the frame loop: a frame's star list in, an identified attitude with
//! its covariance out, and the prior it keeps from one frame to the next.
//!
//! Each frame, the usable stars ([`StarRecord::is_centroid`], not saturated, their trail
//! neither unknown nor clipped ([`StarFlags::TRAIL_UNKNOWN`], [`StarFlags::TRAIL_CLIPPED`]),
//! with a finite positive sigma) are turned into camera-frame directions by the [`Camera`],
//! at most [`ident::MAX_STARS`], those the fitted PSF describes first (no
//! [`StarFlags::POOR_FIT`]), then the brightest; with [`CLEAN_ENOUGH`] of those, the
//! `POOR_FIT` ones are left out. With a prior no older than
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
//! the q-method take. The identified attitude is then refined with each star's whole 2x2
//! position covariance ([`attitude::refine`]: `sigma_x_px`, `sigma_y_px` and `cov_xy_px2`
//! through the pinhole's Jacobian): a trailed star is known worse along its trail than
//! across it, and one sigma a star (the larger) would give the attitude a bound too wide about
//! the axis its trails do not cross (1.3 times the error at 3 deg/s across the boresight).
//!
//! Cost: what identification costs (docs/attitude.md: on the Cortex-M7 tracking and attitude
//! about 0.67 M instructions a frame, lost in space 3.3 M median and 15.7 M at the 99th
//! percentile) plus a sort of at most 32 stars and the refinement (~19,000 instructions
//! for 30 stars, in `cargo m7-bench`'s `ident_confirm_p99`); no allocation, about 1 KB of
//! state beyond identification's stack.

use crate::attitude::{
    self, Attitude, AttitudeError, Camera, ImageObservation, Observation, Quat, Rate, aberrate,
};
use crate::catalog::Catalog;
use crate::ident::{self, FocalScale, IdentConfig, IdentError, Measured};
use crate::predict::{self, PredictConfig, PredictError, PredictFrom};
use crate::tracker::{PredictedStar, StarFlags, StarRecord};

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
    prior: Option<(Attitude, u64)>,
    scale: Option<FocalScale>,
    /// Stars of the last fix identified by their predicted identities (0: searched).
    identified: u8,
    /// The velocity the last fix's aberration was removed for (its attitude is then of the
    /// ICRF), m/s.
    prior_velocity: Option<[f64; 3]>,
}

impl<'c> Solver<'c> {
    /// A stage with no prior (its first frame is lost in space).
    pub fn new(catalog: Catalog<'c>, config: SolverConfig) -> Self {
        Self {
            catalog,
            config,
            prior: None,
            scale: None,
            identified: 0,
            prior_velocity: None,
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
        self.prior.map(|(a, t)| (a.q, t))
    }

    /// How many stars of the last fix were identified by the identities the catalog
    /// predicted for them ([`Self::update_with_identities`]): 0 when the fix was searched
    /// (tracking's triangles, lost in space) or there was none.
    pub fn identified(&self) -> u8 {
        self.identified
    }

    /// The catalog stars of the next frame ([`predict::predict`]): the last fix (its
    /// attitude, covariance and focal-length scale, at its time, and the velocity its
    /// aberration was removed for) propagated by `rate` and `accel_rad_s2` (rad/s^2) to
    /// `next_mid_us`, the next frame's mid-exposure, its stars trailed over `exposure_s` and
    /// moving over `period_s` after it, on an active area of `active_px` (columns, rows),
    /// into `out`. No fix, a fix after `next_mid_us` or older than the configuration allows
    /// is an error, as are bad inputs.
    #[allow(
        clippy::too_many_arguments,
        reason = "the prediction's inputs, each plain"
    )]
    pub fn predict(
        &self,
        rate: &Rate,
        accel_rad_s2: [f64; 3],
        next_mid_us: u64,
        exposure_s: f64,
        period_s: f64,
        active_px: [u16; 2],
        cfg: &PredictConfig,
        out: &mut predict::PredictedStars,
    ) -> Result<usize, PredictError> {
        out.clear();
        let (attitude, t) = self.prior.ok_or(PredictError::TooOld)?;
        if next_mid_us < t {
            return Err(PredictError::BadInput);
        }
        let from = PredictFrom {
            attitude,
            rate: *rate,
            accel_rad_s2,
            scale: self.scale.map_or(1.0, |s| s.value),
            interval_s: (next_mid_us - t) as f64 * 1e-6,
            exposure_s,
            period_s,
            velocity_m_s: self.prior_velocity,
        };
        predict::predict(
            &self.catalog,
            &self.config.camera,
            &from,
            active_px,
            cfg,
            out,
        )
    }

    /// The camera model that turns pixels into directions.
    pub fn camera(&self) -> &Camera {
        &self.config.camera
    }

    /// Forgets the prior (the next frame is lost in space).
    pub fn forget(&mut self) {
        self.prior = None;
        self.scale = None;
        self.identified = 0;
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
        self.update_with_identities(stars, core::iter::empty(), time_us, velocity_m_s)
    }

    /// [`Self::update_at_velocity`] for stars measured in windows the catalog predicted:
    /// `identities` gives each star of `stars`, in order, the prediction it was measured for
    /// (the tracker's [`crate::tracker::Tracker::identities`]; `None`, or a shorter
    /// iterator, for a star found otherwise). A usable star within its prediction's bound
    /// ([`PredictedStar::matches`]) keeps its catalog identity; with a fresh prior and at
    /// least four such stars, [`ident::confirm`] verifies them (a star off its prediction,
    /// or inconsistent with the others' attitude, is dropped, so a false star cannot enter
    /// the attitude), and only when that fails does identification search (tracking's
    /// triangles, then lost in space) on every usable star. Cost: the joint fit of the
    /// identified stars, a few thousand flops, instead of the search.
    pub fn update_with_identities<'p>(
        &mut self,
        stars: &[StarRecord],
        identities: impl IntoIterator<Item = Option<&'p PredictedStar>>,
        time_us: u64,
        velocity_m_s: Option<[f64; 3]>,
    ) -> (Result<Fix, SolveError>, bool) {
        let mut applied = false;
        let mut ids = identities.into_iter();
        let result = self.identify(
            stars,
            &mut |_| ids.next().flatten().copied(),
            time_us,
            velocity_m_s,
            &mut applied,
        );
        (result, applied)
    }

    fn identify(
        &mut self,
        stars: &[StarRecord],
        identity: &mut dyn FnMut(usize) -> Option<PredictedStar>,
        time_us: u64,
        velocity_m_s: Option<[f64; 3]>,
        applied: &mut bool,
    ) -> Result<Fix, SolveError> {
        self.identified = 0;
        // Ranked as the star list ranks: a window the PSF describes (no `POOR_FIT`: a
        // particle hit is bright and fits badly) before one it does not, then the brighter;
        // each with its direction and the catalog star it was predicted to be (when it lies
        // within its prediction's bound).
        let rank = |s: &StarRecord| (s.fit_is_clean(), s.flux_e);
        let above = |a: &(bool, f32), b: &(bool, f32)| (a.0, a.1) > (b.0, b.1);
        let mut measured: heapless::Vec<Ranked, { ident::MAX_STARS }> = heapless::Vec::new();
        for (k, s) in stars.iter().enumerate() {
            let id = identity(k)
                .filter(|p| p.matches(s.x_px, s.y_px))
                .map(|p| p.catalog);
            if !usable(s) {
                continue;
            }
            // A position the camera model cannot invert (a fold) is not used.
            let Some(m) = self.measure(s) else { continue };
            let cov = PixelCov::of(s);
            if measured.len() < ident::MAX_STARS {
                let _ = measured.push((rank(s), m, id, cov));
            } else if let Some(lowest) = measured
                .iter_mut()
                .min_by(|a, b| a.0.0.cmp(&b.0.0).then(a.0.1.total_cmp(&b.0.1)))
                .filter(|d| above(&rank(s), &d.0))
            {
                *lowest = (rank(s), m, id, cov);
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
        let mut dirs_cov: heapless::Vec<PixelCov, { ident::MAX_STARS }> = heapless::Vec::new();
        let mut known: heapless::Vec<Measured, { ident::MAX_STARS }> = heapless::Vec::new();
        let mut known_cov: heapless::Vec<PixelCov, { ident::MAX_STARS }> = heapless::Vec::new();
        let mut known_ids: heapless::Vec<u16, { ident::MAX_STARS }> = heapless::Vec::new();
        for (_, m, id, cov) in &measured {
            let _ = dirs.push(*m);
            let _ = dirs_cov.push(*cov);
            if let Some(c) = id {
                let _ = known.push(*m);
                let _ = known_cov.push(*cov);
                let _ = known_ids.push(*c);
            }
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
        let confirmed = fresh
            .filter(|_| known.len() >= ident::MIN_MATCHES)
            .and_then(|(a, _)| {
                ident::confirm(
                    &self.catalog,
                    &known,
                    &known_ids,
                    a.q,
                    prior_scale,
                    &cfg.ident,
                )
                .ok()
            });
        let tracked = || {
            fresh.and_then(|(a, _)| {
                ident::track_scaled(
                    &self.catalog,
                    &dirs,
                    a.q,
                    prior_scale,
                    cfg.prior_error_rad,
                    &cfg.ident,
                )
                .ok()
            })
        };
        let (solution, mode, (basis, basis_cov)) = match confirmed {
            Some(s) => {
                self.identified = s.matches.len() as u8;
                (s, SolveMode::Tracking, (&known, &known_cov))
            }
            None => match tracked() {
                Some(s) => (s, SolveMode::Tracking, (&dirs, &dirs_cov)),
                None => (
                    ident::lost_in_space(&self.catalog, &dirs, &cfg.ident).map_err(|error| {
                        SolveError::Ident {
                            usable: used,
                            error,
                        }
                    })?,
                    SolveMode::LostInSpace,
                    (&dirs, &dirs_cov),
                ),
            },
        };
        let mut attitude = solution.attitude;
        self.prior_velocity = None;
        if let Some(v) = velocity_m_s
            && let Ok(a) = self.aberrated(basis, &solution, v)
        {
            attitude = a;
            *applied = true;
            self.prior_velocity = Some(v);
        }
        // Each star's whole image-plane covariance (a trailed star's along and across its
        // trail), where identification and the q-method take one sigma a star.
        if let Ok(a) = self.refined(basis, basis_cov, &solution, attitude.q) {
            attitude = a;
        }
        self.prior = Some((attitude, time_us));
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

    /// `start` refined with the image-plane covariance of each of `solution`'s matches
    /// ([`attitude::refine`]), the catalog directions aberrated for the velocity the prior
    /// holds (the one [`Self::aberrated`] applied, if any). A star's pixel covariance is
    /// scaled to the direction by `z k / f` (`k` the inverse of the fitted focal-length scale).
    #[inline(never)]
    fn refined(
        &self,
        dirs: &[Measured],
        covs: &[PixelCov],
        solution: &ident::Solution,
        start: Quat,
    ) -> Result<Attitude, AttitudeError> {
        let k = 1.0 / solution.scale.value;
        let f = self.config.camera.focal_length_px;
        let mut obs: heapless::Vec<ImageObservation, { ident::MAX_STARS }> = heapless::Vec::new();
        for m in &solution.matches {
            let i = usize::from(m.star);
            let (Some(s), Some(c), Some(r)) = (
                dirs.get(i),
                covs.get(i),
                self.catalog.dir(usize::from(m.catalog)),
            ) else {
                continue;
            };
            let camera = ident::rescale_dir(s.dir, k);
            let scale = camera[2] * k / f;
            let o = ImageObservation {
                camera,
                icrs: self.prior_velocity.map_or(r, |v| aberrate(r, v)),
                cov_rad2: c.0.map(|v| v * scale * scale),
            };
            if obs.push(o).is_err() {
                break;
            }
        }
        attitude::refine(start, &obs)
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
            inst_mag: Measured::inst_mag_of(f64::from(s.flux_e)),
        })
    }
}

/// A usable star as identification takes it: its rank (clean fit, flux), its direction,
/// the catalog identity it was predicted to have, its position covariance.
type Ranked = ((bool, f32), Measured, Option<u16>, PixelCov);

/// A star's position covariance, px^2: `[xx, yy, xy]` from its record's sigmas and
/// covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PixelCov([f64; 3]);

impl PixelCov {
    fn of(s: &StarRecord) -> Self {
        let (sx, sy) = (f64::from(s.sigma_x_px), f64::from(s.sigma_y_px));
        // A correlation within +-0.999: the record's covariance is bounded by its sigmas,
        // and a singular 2x2 would give a direction no weight's inverse.
        let m = 0.999 * sx * sy;
        let c = f64::from(s.cov_xy_px2);
        Self([
            sx * sx,
            sy * sy,
            if c.is_finite() {
                crate::clamp::clamp(c, -m, m)
            } else {
                0.0
            },
        ])
    }
}

/// Stars the fitted PSF describes (no [`StarFlags::POOR_FIT`]) from which the others are
/// left out of identification.
pub const CLEAN_ENOUGH: usize = 6;

/// A star whose position identification may use: a centroid, not saturated, its trail
/// neither unknown nor clipped, with a finite position and a finite positive sigma.
fn usable(s: &StarRecord) -> bool {
    s.is_centroid()
        && !s.flags.intersects(
            StarFlags::SATURATED
                | StarFlags::DETECT_SATURATED
                | StarFlags::TRAIL_UNKNOWN
                | StarFlags::TRAIL_CLIPPED,
        )
        && s.x_px.is_finite()
        && s.y_px.is_finite()
        && s.flux_e.is_finite()
        && s.sigma_x_px.is_finite()
        && s.sigma_y_px.is_finite()
        && s.sigma_x_px > 0.0
        && s.sigma_y_px > 0.0
}
