//! Software in the loop: the core's tracker application run live on the simulated
//! CCD47-20, frame after frame, over a scene whose stars drift (a slow attitude rate). The
//! sensor renders only what the tracker's request reads (whole lines while acquiring, the
//! windows' rows while tracking: [`crate::home::SimLines`]), the telemetry port records every
//! star, summary and event, and the truth of each frame is kept beside it.
//!
//! [`run`] gives a [`SilReport`]: per frame the mode, the stars matched to the truth and the
//! stars in the field that were not reported, and over the run the chi^2 per degree of
//! freedom of the positions against the reported sigmas. `startrack sil` writes it as CSV;
//! the host test `sil` pins it.
//!
//! With a sky scene ([`SilConfig::sky`]: the catalog's stars at a turning attitude,
//! [`startrack_sim::sky::scene`]) each frame's star list also goes through the core's attitude stage
//! ([`startrack_core::solver`]: identification, tracking from the last frame's attitude, and
//! the q-method), and the report holds each frame's attitude error against the truth
//! ([`SilReport::attitude_summary`]).
//!
//! Cost: a full frame (acquisition) renders 1.1 M samples, a tracking frame about 40 lines'
//! over-scan and covered columns plus its windows per star; ~1 s and ~0.02 s in release
//! (`time startrack sil --frames N` for a few N measures both).

use crate::home::{FrameTiming, ReadoutClock, Recorder, SimLines, block_on, host_health};
use rand::{RngExt, SeedableRng};
use startrack_core::attitude::Quat;
use startrack_core::catalog::Catalog;
use startrack_core::cycle::{CyclePorts, FrameCycle};
use startrack_core::link::telemetry::{AttitudeReport, Housekeeping};
use startrack_core::link::{LinkService, NoWindows};
use startrack_core::safe::Health;
use startrack_core::solver::{Fix, SolveError, SolveMode, Solver, SolverConfig};
use startrack_core::table::CalibTable;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::PixCorrBackground;
use startrack_core::tracker::{
    Event, FixedTable, FixedTemperature, FrameSummary, Integration, Mode, StarRecord, Tracker,
    TrackerBuffers, TrackerConfig,
};
use startrack_sim::pixcorr::{CurveSpec, build_curves};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator, Star};
use startrack_sim::sky::bright::BrightSky;
use startrack_sim::sky::scene::{REFERENCE_EXPOSURE_S, SkyScene, committed_catalog};

/// Stars a frame the SIL's tracker keeps: the board's capacity.
pub const SIL_CAPACITY: usize = 32;

/// The centroid 1-sigma the SIL's identification settings assume, px (its tolerances add
/// 1 px of model error to it).
pub const SOLVER_SIGMA_PX: f64 = 0.2;

/// A star is "in the field" when its true position is at least this far from the active
/// area's edges, px (a whole tracking window fits around it).
pub const FIELD_MARGIN_PX: f64 = 8.0;

/// A reported star within this distance of a true star is that star, px.
pub const MATCH_PX: f64 = 1.5;

/// What the SIL runs.
#[derive(Clone, Debug, PartialEq)]
pub struct SilConfig {
    /// Frames to run.
    pub frames: u32,
    /// Seed of the scene and of the sensor's noise and fixed patterns.
    pub seed: u64,
    /// Stars in the scene.
    pub stars: usize,
    /// Motion of every star per frame (x, y), px: a slow attitude rate across the boresight.
    pub drift_px: (f64, f64),
    /// The tracker's configuration (its `psf_a_px` is also the scene's PSF width).
    pub tracker: TrackerConfig,
    /// Frame period, us (the home clock's step).
    pub period_us: u64,
    /// The table also holds the pixel-phase curves of the tracker's CoG box for its PSF
    /// width (power 1; border-median and given background: the CoG methods' and the fused
    /// CoG's), as `calib build --psf-a-px` writes them.
    pub pixcorr_curves: bool,
    /// Stars from the sky at a turning attitude instead of the random drifting scene
    /// (`stars` and `drift_px` are then not used); every frame is then also identified and
    /// its attitude checked against the truth.
    pub sky: Option<SkyScene>,
    /// The spacecraft's time at the tracker's counter 0, us since the CUC epoch: the SIL
    /// then runs the PPS line ([`crate::pps::PpsModel`]) and, before its first frame, sends
    /// the time-set command of its next pulse through the link, so the attitude reports are
    /// on spacecraft time (`None`: no time set, the reports say so).
    pub spacecraft_epoch_us: Option<u64>,
    /// The tracker's counter's frequency error against spacecraft time, ppm.
    pub counter_rate_ppm: f64,
    /// The spacecraft's velocity, ICRF, m/s: a sky scene's stars are then seen aberrated
    /// ([`aberrated_sky_stars`]).
    pub velocity_m_s: Option<[f64; 3]>,
    /// With `velocity_m_s` and a spacecraft clock: the SIL sends the velocity command (at the
    /// time of its first pulse) before its first frame, so the attitude stage removes the
    /// aberration; `false` leaves the attitude apparent (for comparison).
    pub send_velocity: bool,
    /// Point sources in no catalog, still, rendered besides the scene's stars in every
    /// frame from `false_stars_from`: false stars, or with a narrow PSF (`a_px` 0.3) a hot
    /// pixel's or a cosmic ray's spike. They are not in the frames' truth.
    pub false_stars: Vec<Star>,
    /// The first frame with the false stars.
    pub false_stars_from: u32,
    /// With a sky scene: the Moon, the Earth, the Sun's stray light, planets and proton hits
    /// ([`startrack_sim::sky::bright`]); empty by default.
    pub bright: BrightSky,
    /// Frame `k`'s integration on the tracker's clock where the `k`-th entry is `Some`,
    /// instead of the one [`frame_timing`] gives: another run's instants (the PIL's
    /// firmware's), so that the two runs' rates and predictions are the same to the bit.
    /// Empty by default.
    pub integrations: Vec<Option<Integration>>,
    /// The platform's largest angular acceleration, rad/s^2, told to the attitude stage
    /// ([`FrameCycle::set_max_acceleration`]); the cycle's default,
    /// [`startrack_core::cycle::DEFAULT_MAX_ACCEL_RAD_S2`] (1 deg/s^2), by default.
    pub max_accel_rad_s2: f64,
}

/// The spacecraft time the SIL's commands take at counter 0 (`--spacecraft-time`'s
/// default): 2,100,000,000.25 s after 1958-01-01 TAI (2024-07-18).
pub const SIL_EPOCH_US: u64 = 2_100_000_000_250_000;

impl Default for SilConfig {
    fn default() -> Self {
        Self {
            frames: 20,
            seed: 1,
            stars: 20,
            drift_px: (0.3, -0.2),
            tracker: TrackerConfig::FLIGHT,
            period_us: 100_000,
            pixcorr_curves: false,
            sky: None,
            spacecraft_epoch_us: None,
            counter_rate_ppm: 0.0,
            velocity_m_s: None,
            send_velocity: true,
            false_stars: Vec::new(),
            false_stars_from: 0,
            bright: BrightSky::default(),
            integrations: Vec::new(),
            max_accel_rad_s2: startrack_core::cycle::DEFAULT_MAX_ACCEL_RAD_S2,
        }
    }
}

/// The scene's stars at frame 0: seeded positions clear of the edges by 20 px plus the
/// drift of the whole run (so they stay in the field; a run too long for that lets them
/// leave), signals from 3,000 to 100,000 e- (SNR ~20 to ~600 on the default sensor), every
/// PSF of width `config.tracker.psf_a_px`.
pub fn scene(config: &SilConfig, params: &SensorParams) -> Vec<Star> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(config.seed ^ 0x5349_4c00);
    let g = params.geometry;
    let run = f64::from(config.frames);
    let span = |drift: f64, n: u16| {
        let half = f64::from(n) / 2.0;
        let m = (20.0 + drift.abs() * run).min(half - 1.0);
        m..f64::from(n) - m
    };
    let (sx, sy) = (
        span(config.drift_px.0, g.active_cols),
        span(config.drift_px.1, g.active_rows),
    );
    (0..config.stars)
        .map(|_| Star {
            x_px: r.random_range(sx.clone()),
            y_px: r.random_range(sy.clone()),
            signal_e: 10f64.powf(r.random_range(3.5..5.0)),
            a_px: f64::from(config.tracker.psf_a_px),
        })
        .collect()
}

/// The stars of `base` at frame `frame`.
pub fn stars_at(base: &[Star], drift_px: (f64, f64), frame: u32) -> Vec<Star> {
    let k = f64::from(frame);
    base.iter()
        .map(|s| Star {
            x_px: s.x_px + drift_px.0 * k,
            y_px: s.y_px + drift_px.1 * k,
            ..*s
        })
        .collect()
}

/// A reported star and the true star it matched, if any.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Matched {
    /// As reported.
    pub star: StarRecord,
    /// The true star within [`MATCH_PX`], nearest.
    pub truth: Option<Star>,
}

/// One frame of the run.
#[derive(Clone, Debug, PartialEq)]
pub struct SilFrame {
    /// The tracker's summary.
    pub summary: FrameSummary,
    /// The true stars of the frame.
    pub truth: Vec<Star>,
    /// Its reported stars, matched.
    pub stars: Vec<Matched>,
    /// True stars in the field (see [`FIELD_MARGIN_PX`]) that no usable centroid matched.
    pub missed: Vec<Star>,
    /// Samples the sensor rendered for it.
    pub samples_read: u64,
    /// Its windows the attitude stage predicted from the catalog (0: none; the tracker's
    /// own windows, or a full frame).
    pub predicted_windows: usize,
    /// The attitude stage's result and the truth (sky scenes only).
    pub attitude: Option<AttitudeCheck>,
    /// In-field true stars clear of the bright scene ([`unaffected`]); `None` without one.
    pub unaffected: Option<usize>,
    /// The Moon or the Earth is on the active area ([`object_in_field`]); `None` without a
    /// bright scene.
    pub object_in_field: Option<bool>,
    /// What of the bright scene is in the frame ([`causes`]); `None` without one.
    pub causes: Option<Causes>,
}

/// The truth of a frame's bright scene that its [`startrack_core::tracker::Obstructions`]
/// bits name.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Causes {
    /// Columns of the active area the Moon's lit disc spans, px (0: not on the area).
    pub moon_cols: f64,
    /// The Earth is on the active area.
    pub earth: bool,
    /// The Sun's stray light at the active area's centre, e- a pixel in the exposure (0:
    /// none).
    pub stray_e: f64,
    /// The proton environment (`None`: no protons rendered).
    pub protons: Option<startrack_sim::sim::protons::ProtonEnv>,
}

/// What of the bright scene `bright` is in `sim`'s frame.
pub fn causes(sim: &Simulator, bright: &BrightSky) -> Causes {
    let Some(b) = sim.bright.as_ref() else {
        return Causes::default();
    };
    let g = sim.params.geometry;
    let (cols, rows) = (f64::from(g.active_cols), f64::from(g.active_rows));
    let moon_cols = b.moon.map_or(0.0, |m| {
        let on_rows =
            m.centre_px[1] + m.radius_px >= -0.5 && m.centre_px[1] - m.radius_px <= rows - 0.5;
        if m.surface_e <= 0.0 || !on_rows {
            return 0.0;
        }
        let lo = (m.centre_px[0] - m.radius_px).max(-0.5);
        let hi = (m.centre_px[0] + m.radius_px).min(cols - 0.5);
        (hi - lo).max(0.0)
    });
    Causes {
        moon_cols,
        earth: earth_in_field(sim),
        stray_e: b.stray.map_or(0.0, |s| s.centre_e),
        protons: bright.protons,
    }
}

/// A frame's attitude against the truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeCheck {
    /// The frame's mid-exposure, s from the run's start ([`SkyScene::mid_exposure_s`]).
    pub t_mid_s: f64,
    /// The true attitude at mid-exposure (ICRS to camera).
    pub truth: Quat,
    /// The true rate at mid-exposure, camera frame, rad/s ([`SkyScene::rate_rad_s`]).
    pub true_rate_rad_s: [f64; 3],
    /// What the attitude stage gave.
    pub fix: Result<Fix, SolveError>,
    /// The report the link carried (time, rate, flags; `None` outside the frame cycle).
    pub report: Option<AttitudeReport>,
    /// The true spacecraft time at mid-exposure, s since the CUC epoch (`None` without a
    /// spacecraft clock).
    pub true_time_s: Option<f64>,
    /// Stars of the fix identified by their predicted identities (0: searched, or none).
    pub identified: u8,
}

impl AttitudeCheck {
    /// The error rotation vector of the fix against the truth, camera frame, rad (x, y across
    /// the boresight, z roll); `None` without a fix.
    pub fn error_rad(&self) -> Option<[f64; 3]> {
        self.fix
            .as_ref()
            .ok()
            .map(|f| f.attitude.q.error_vector(self.truth))
    }
}

/// A run's attitude results (sky scenes).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AttitudeSummary {
    /// Frames.
    pub frames: usize,
    /// Frames with an attitude.
    pub solved: usize,
    /// ... of them lost in space.
    pub lost_in_space: usize,
    /// Solved frames whose error exceeds [`WRONG_ATTITUDE_RAD`]: a wrong identification.
    pub wrong: usize,
    /// RMS cross-boresight error of the solved frames (not wrong), arcsec.
    pub rms_boresight_arcsec: f64,
    /// RMS roll error, arcsec.
    pub rms_roll_arcsec: f64,
    /// RMS of the reported 1-sigma cross-boresight bound, arcsec.
    pub bound_boresight_arcsec: f64,
    /// RMS of the reported 1-sigma roll bound, arcsec.
    pub bound_roll_arcsec: f64,
    /// Mean normalised error squared (3 when the covariance is consistent).
    pub mean_nees: f64,
}

/// A fix farther than this from the truth is a wrong identification, rad (0.1 degree: two
/// orders above any centroid-limited error).
pub const WRONG_ATTITUDE_RAD: f64 = 1.745e-3;

const ARCSEC_PER_RAD: f64 = 206_264.806;

/// What a SIL run gave.
#[derive(Clone, Debug, PartialEq)]
pub struct SilReport {
    /// Per frame.
    pub frames: Vec<SilFrame>,
    /// Every event, in order.
    pub events: Vec<Event>,
    /// The frame cycle's housekeeping after the last frame.
    pub health: Health,
    /// The link's housekeeping report after the last frame.
    pub housekeeping: Housekeeping,
}

impl SilReport {
    /// Sum over matched usable centroids of frames in `mode` (all modes for `None`) and both
    /// axes of (error / reported sigma)^2, and the number of terms.
    pub fn chi2(&self, mode: Option<Mode>) -> (f64, usize) {
        let mut sum = 0.0;
        let mut n = 0;
        for f in &self.frames {
            if mode.is_some_and(|m| m != f.summary.mode) {
                continue;
            }
            for m in &f.stars {
                let Some(t) = m.truth else { continue };
                let s = &m.star;
                if !s.is_centroid() {
                    continue;
                }
                let ex = f64::from(s.x_px) - t.x_px;
                let ey = f64::from(s.y_px) - t.y_px;
                sum +=
                    (ex / f64::from(s.sigma_x_px)).powi(2) + (ey / f64::from(s.sigma_y_px)).powi(2);
                n += 2;
            }
        }
        (sum, n)
    }

    /// chi^2 per degree of freedom of [`Self::chi2`] (0 with no star).
    pub fn chi2_per_dof(&self, mode: Option<Mode>) -> f64 {
        let (s, n) = self.chi2(mode);
        if n == 0 { 0.0 } else { s / n as f64 }
    }

    /// The attitude results of a sky run (`None` for a random scene).
    pub fn attitude_summary(&self) -> Option<AttitudeSummary> {
        let checks: Vec<&AttitudeCheck> = self
            .frames
            .iter()
            .filter_map(|f| f.attitude.as_ref())
            .collect();
        if checks.is_empty() {
            return None;
        }
        let mut s = AttitudeSummary {
            frames: checks.len(),
            ..AttitudeSummary::default()
        };
        let (mut eb, mut er, mut bb, mut br, mut nees, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0);
        for c in checks {
            let (Ok(fix), Some(e)) = (c.fix.as_ref(), c.error_rad()) else {
                continue;
            };
            s.solved += 1;
            s.lost_in_space += usize::from(fix.mode == SolveMode::LostInSpace);
            if e.iter().map(|v| v * v).sum::<f64>().sqrt() > WRONG_ATTITUDE_RAD {
                s.wrong += 1;
                continue;
            }
            let a = &fix.attitude;
            eb += e[0] * e[0] + e[1] * e[1];
            er += e[2] * e[2];
            bb += a.boresight_sigma_rad().powi(2);
            br += a.roll_sigma_rad().powi(2);
            nees += a.nees(e).unwrap_or(f64::INFINITY);
            n += 1;
        }
        if n > 0 {
            let rms = |v: f64| (v / n as f64).sqrt() * ARCSEC_PER_RAD;
            s.rms_boresight_arcsec = rms(eb);
            s.rms_roll_arcsec = rms(er);
            s.bound_boresight_arcsec = rms(bb);
            s.bound_roll_arcsec = rms(br);
            s.mean_nees = nees / n as f64;
        }
        Some(s)
    }

    /// RMS position error per axis over matched usable centroids, px.
    pub fn rms_error_px(&self) -> f64 {
        let (mut sum, mut n) = (0.0, 0usize);
        for m in self.frames.iter().flat_map(|f| &f.stars) {
            if let Some(t) = m.truth.filter(|_| m.star.is_centroid()) {
                sum += (f64::from(m.star.x_px) - t.x_px).powi(2)
                    + (f64::from(m.star.y_px) - t.y_px).powi(2);
                n += 2;
            }
        }
        if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
    }
}

/// Whether a true star is in the field (clear of the edges by [`FIELD_MARGIN_PX`]).
pub fn in_field(s: &Star, params: &SensorParams) -> bool {
    let g = params.geometry;
    s.x_px >= FIELD_MARGIN_PX
        && s.y_px >= FIELD_MARGIN_PX
        && s.x_px <= f64::from(g.active_cols) - 1.0 - FIELD_MARGIN_PX
        && s.y_px <= f64::from(g.active_rows) - 1.0 - FIELD_MARGIN_PX
}

/// Runs the tracker for `config.frames` frames on the default sensor (seeded) with its true
/// calibration table.
pub fn run(config: &SilConfig) -> Result<SilReport, String> {
    let params = SensorParams {
        seed: config.seed,
        ..SensorParams::default()
    };
    run_with_table(config, &truth_table(config, &params)?)
}

/// [`run`] with `table_bytes` as the calibration table instead of the true per-pixel one
/// (the PIL's comparison runs the SIL with the table the firmware has in flash).
pub fn run_with_table(config: &SilConfig, table_bytes: &[u8]) -> Result<SilReport, String> {
    let params = SensorParams {
        seed: config.seed,
        ..SensorParams::default()
    };
    let base = scene(config, &params);
    let catalog_bytes = match config.sky {
        Some(_) => committed_catalog()?,
        None => Vec::new(),
    };
    let sky = match config.sky {
        Some(sky) => Some((
            sky,
            Catalog::parse(&catalog_bytes).map_err(|e| format!("catalog: {e}"))?,
        )),
        None => None,
    };
    let catalog = sky.as_ref().map(|(_, c)| c);
    let stars_of = |frame: u32| frame_stars(config, &base, catalog, frame);
    let period_s = config.period_us as f64 * 1e-6;
    if let Some(m) = config.sky.as_ref().and_then(|s| s.motion)
        && (m.period_s - period_s).abs() > 1e-9
    {
        return Err(format!(
            "the scene's frame period ({} s) is not the SIL's ({period_s} s)",
            m.period_s
        ));
    }
    let solver = sky.as_ref().map(|(scene, cat)| sky_solver(scene, *cat));
    let table = CalibTable::parse(table_bytes).map_err(|e| e.to_string())?;
    let mut buffers = Box::new(TrackerBuffers::new());
    let tracker = Tracker::<SIL_CAPACITY>::new(config.tracker, params.geometry, &mut buffers)
        .map_err(|e| e.to_string())?;
    let mut link = Box::new(LinkService::new());
    let mut cycle = Box::new(FrameCycle::new(tracker, &mut link, solver, host_health()));
    cycle.set_max_acceleration(config.max_accel_rad_s2);
    let mut source = SimLines::new(|frame| frame_simulator(config, &params, &base, catalog, frame))
        .with_timing(frame_timing(config))
        .with_integrations(config.integrations.clone());
    let mut recorder = Recorder::default();
    let mut tables = FixedTable(Some(table));
    let mut thermometer = FixedTemperature(None);
    let mut frames = Vec::new();
    let mut pps = config
        .spacecraft_epoch_us
        .map(|epoch| crate::pps::PpsModel::new(epoch, config.counter_rate_ppm, config.seed));
    if let Some(line) = pps.as_ref() {
        // The spacecraft's time-set command for its next pulse, through the link as the
        // ground sends it.
        let (tc, _) = startrack_ground::frame_telecommand(
            startrack_core::link::protocol::TC_TIME_SET,
            &line.next_pulse_time().with_p_field(),
            0,
        );
        let mut store = crate::memory_tables::MemoryTables::new(params.geometry, None);
        cycle.receive(&tc, &mut store, &mut NoWindows);
        if let (Some(v), true) = (config.velocity_m_s, config.send_velocity) {
            let (tc, _) = startrack_ground::frame_telecommand(
                startrack_core::link::protocol::TC_VELOCITY,
                &velocity_command(v, line.next_pulse_time()),
                1,
            );
            cycle.receive(&tc, &mut store, &mut NoWindows);
        }
        let _ = cycle.transmit(&mut [0u8; 256]);
    }
    for k in 0..config.frames {
        // The frame's start reads the frame's instant; its report, after its lines, that
        // instant plus the board's readout of what it read.
        source.readout_done_us.set(0);
        let mut clock = ReadoutClock {
            frame: k,
            period_us: config.period_us,
            readout_done_us: source.readout_done_us.clone(),
        };
        if let Some(line) = pps.as_mut() {
            line.advance_to(u64::from(k) * config.period_us);
            cycle.sync(line);
        }
        let mut ports = CyclePorts {
            clock: &mut clock,
            thermometer: &mut thermometer,
            tables: &mut tables,
            table_in_force: None,
            telemetry: &mut recorder,
        };
        let before = source.samples_rendered;
        let predicted_windows = cycle.predicted();
        let Ok(outcome) = block_on(cycle.run_frame(&mut source, &mut ports));
        let summary = outcome.summary;
        let truth = stars_of(summary.frame);
        let mut frame = match_frame(
            summary,
            truth,
            cycle.tracker().stars(),
            &params,
            source.samples_rendered - before,
        );
        frame.predicted_windows = if summary.mode == Mode::Tracking {
            predicted_windows
        } else {
            0
        };
        if config.sky.is_some() && !config.bright.is_empty() {
            let sim = frame_simulator(config, &params, &base, catalog, summary.frame);
            frame.unaffected = Some(
                frame
                    .truth
                    .iter()
                    .filter(|t| in_field(t, &params) && unaffected(&sim, t))
                    .count(),
            );
            frame.object_in_field = Some(object_in_field(&sim));
            frame.causes = Some(causes(&sim, &config.bright));
        }
        if let (Some(fix), Some((scene, _))) = (outcome.attitude, sky.as_ref()) {
            let mid_us = outcome.report.map_or(0, |r| r.mid_exposure_us);
            frame.attitude = Some(AttitudeCheck {
                t_mid_s: scene.mid_exposure_s(summary.frame, period_s),
                truth: scene.attitude(summary.frame),
                true_rate_rad_s: scene.rate_rad_s(summary.frame, period_s),
                fix,
                report: outcome.report,
                true_time_s: pps
                    .as_ref()
                    .map(|l| l.spacecraft_us_at(mid_us as f64) * 1e-6),
                identified: cycle.solver().map_or(0, |s| s.identified()),
            });
        }
        frames.push(frame);
    }
    Ok(SilReport {
        frames,
        events: recorder.events,
        health: *cycle.health(),
        housekeeping: cycle.housekeeping(None),
    })
}

/// When the SIL's frames are taken: one every `period_us`, each integrating from its start
/// for the exposure the simulator renders: a sky scene's motion's when it has one
/// ([`SkyScene::motion`]), else the tracker's configured exposure.
pub fn frame_timing(config: &SilConfig) -> FrameTiming {
    let motion_us = config
        .sky
        .as_ref()
        .and_then(|s| s.motion.as_ref())
        .map(|m| (m.exposure_s * 1e6).round() as u64);
    FrameTiming {
        period_us: config.period_us,
        exposure_us: motion_us.unwrap_or(u64::from(config.tracker.exposure_ms) * 1000),
    }
}

/// The true stars (at mid-exposure) of frame `frame` of `config`'s scene: the sky's when it has one and its
/// `catalog` is given, else those of the drifting random scene `base` ([`scene`]).
pub fn frame_stars(
    config: &SilConfig,
    base: &[Star],
    catalog: Option<&Catalog<'_>>,
    frame: u32,
) -> Vec<Star> {
    match (&config.sky, catalog) {
        (Some(sky), Some(cat)) => match config.velocity_m_s {
            Some(v) => aberrated_sky_stars(sky, cat, frame, f64::from(config.tracker.psf_a_px), v),
            None => sky.stars(cat, frame, f64::from(config.tracker.psf_a_px)),
        },
        _ => stars_at(base, config.drift_px, frame),
    }
}

/// The simulated sensor of frame `frame`: [`frame_stars`] still, or with a sky scene that
/// turns during the exposure its stars along their paths ([`SkyScene::trails`]); and the
/// configuration's false stars.
pub fn frame_simulator(
    config: &SilConfig,
    params: &SensorParams,
    base: &[Star],
    catalog: Option<&Catalog<'_>>,
    frame: u32,
) -> Simulator {
    let mut sim = if let (Some(sky), Some(cat)) = (&config.sky, catalog)
        && sky.motion.is_some()
    {
        Simulator {
            frame,
            trails: sky.trails(cat, frame, f64::from(config.tracker.psf_a_px)),
            ..Simulator::new(params.clone(), false_stars(config, frame))
        }
    } else {
        let mut stars = frame_stars(config, base, catalog, frame);
        stars.extend(false_stars(config, frame));
        Simulator {
            frame,
            ..Simulator::new(params.clone(), stars)
        }
    };
    if let Some(sky) = config.sky.as_ref().filter(|_| !config.bright.is_empty()) {
        let exposure_s = sky.motion.map_or(REFERENCE_EXPOSURE_S, |m| m.exposure_s);
        let (bright, planets) = config.bright.frame(
            sky,
            frame,
            exposure_s,
            f64::from(config.tracker.psf_a_px),
            config.seed,
        );
        sim.stars.extend(planets);
        sim.bright = Some(std::sync::Arc::new(bright));
    }
    sim
}

/// Whether `sim`'s frame has the Moon's disc or the Earth on the active area (false without
/// a bright scene).
pub fn object_in_field(sim: &Simulator) -> bool {
    let Some(b) = sim.bright.as_ref() else {
        return false;
    };
    let g = sim.params.geometry;
    let (cols, rows) = (f64::from(g.active_cols), f64::from(g.active_rows));
    let moon = b.moon.is_some_and(|m| {
        m.surface_e > 0.0
            && m.centre_px[0] + m.radius_px >= -0.5
            && m.centre_px[0] - m.radius_px <= cols - 0.5
            && m.centre_px[1] + m.radius_px >= -0.5
            && m.centre_px[1] - m.radius_px <= rows - 0.5
    });
    moon || earth_in_field(sim)
}

/// Whether the Earth is on `sim`'s active area: its region is convex and large, so on the
/// area when a corner is in it.
fn earth_in_field(sim: &Simulator) -> bool {
    let Some(b) = sim.bright.as_ref() else {
        return false;
    };
    let g = sim.params.geometry;
    let (cols, rows) = (f64::from(g.active_cols), f64::from(g.active_rows));
    b.earth.is_some_and(|e| {
        [
            (0.0, 0.0),
            (cols - 1.0, 0.0),
            (0.0, rows - 1.0),
            (cols - 1.0, rows - 1.0),
        ]
        .iter()
        .any(|&(x, y)| e.inside_px(x, y) > -0.5)
    })
}

/// Half the side of the box around a true star that an object must stay out of for the
/// star to be unaffected, px (the 11 px tracking window and a pixel).
pub const UNAFFECTED_HALF_PX: i64 = 6;

/// A proton deposit above this in a star's box affects it, e- (about 3 sigma of the
/// SIL sensor's dark and read noise in a pixel).
pub const UNAFFECTED_HIT_E: f64 = 50.0;

/// Whether true star `s` of `sim`'s frame is clear of its bright scene: no bloomed or
/// saturated column, no light of the Moon or the Earth and no proton charge above
/// [`UNAFFECTED_HIT_E`] within [`UNAFFECTED_HALF_PX`] of it (stray light, a smooth
/// background, leaves it unaffected). Every star is without a bright scene.
pub fn unaffected(sim: &Simulator, s: &Star) -> bool {
    let Some(b) = sim.bright.as_ref() else {
        return true;
    };
    let g = sim.params.geometry;
    let (cx, cy) = (s.x_px.round() as i64, s.y_px.round() as i64);
    let bloomed = sim.bloomed();
    for y in (cy - UNAFFECTED_HALF_PX)..=(cy + UNAFFECTED_HALF_PX) {
        for x in (cx - UNAFFECTED_HALF_PX)..=(cx + UNAFFECTED_HALF_PX) {
            if x < 0 || y < 0 || x >= i64::from(g.active_cols) || y >= i64::from(g.active_rows) {
                continue;
            }
            let (x, y) = (x as usize, y as usize);
            let (xf, yf) = (x as f64, y as f64);
            let lit = b.moon.is_some_and(|m| m.at(xf, yf) > 0.0)
                || b.earth.is_some_and(|e| e.at(xf, yf) > 0.0);
            let bloom = bloomed
                .get(&x)
                .is_some_and(|c| c.at(y).is_none_or(|spill| spill > 0.0));
            if lit || bloom || b.proton_e(x, y) > UNAFFECTED_HIT_E {
                return false;
            }
        }
    }
    true
}

/// The false stars of frame `frame` ([`SilConfig::false_stars`]).
fn false_stars(config: &SilConfig, frame: u32) -> Vec<Star> {
    if frame >= config.false_stars_from {
        config.false_stars.clone()
    } else {
        Vec::new()
    }
}

/// The velocity command's data (`TC[134,1]`): `v_m_s` as f32 and the time it holds at.
pub fn velocity_command(v_m_s: [f64; 3], at: startrack_core::time::Cuc) -> Vec<u8> {
    let mut d = Vec::with_capacity(18);
    for c in v_m_s {
        d.extend_from_slice(&(c as f32).to_be_bytes());
    }
    d.extend_from_slice(&at.t_field());
    d
}

/// The stars of `sky`'s frame `frame` seen by an observer moving at `v_m_s` (ICRF, m/s):
/// [`SkyScene::stars`] with each catalog direction moved by
/// [`startrack_core::attitude::aberrate`] before it is projected.
pub fn aberrated_sky_stars(
    sky: &SkyScene,
    catalog: &Catalog<'_>,
    frame: u32,
    a_px: f64,
    v_m_s: [f64; 3],
) -> Vec<Star> {
    sky.stars_seen(catalog, frame, a_px, |dir| {
        startrack_core::attitude::aberrate(dir, v_m_s)
    })
}

/// The attitude stage the SIL runs after each frame of a sky scene: the core's solver over
/// `catalog` (the on-board catalog, [`committed_catalog`]) with the scene's camera and
/// [`SOLVER_SIGMA_PX`]. [`run`] and the served SIL ([`crate::link_home::serve`]) both use it.
pub fn sky_solver<'c>(scene: &SkyScene, catalog: Catalog<'c>) -> Solver<'c> {
    Solver::new(
        catalog,
        SolverConfig::for_camera(scene.camera, SOLVER_SIGMA_PX),
    )
}

/// The sensor's true calibration table (per pixel) as the SIL starts with it, with the
/// pixel-phase curves `config` asks for.
pub fn truth_table(config: &SilConfig, params: &SensorParams) -> Result<Vec<u8>, String> {
    truth_table_tiled(config, params, 0)
}

/// [`truth_table`] with its maps averaged over square tiles of `2^tile_log2` pixels (the
/// form that fits a flash slot).
pub fn truth_table_tiled(
    config: &SilConfig,
    params: &SensorParams,
    tile_log2: u8,
) -> Result<Vec<u8>, String> {
    let curves = if config.pixcorr_curves {
        let spec = |background| CurveSpec {
            a_px: f64::from(config.tracker.psf_a_px),
            box_side: config.tracker.box_px(),
            power: CogPower::One,
            background,
            knots: 33,
        };
        build_curves(&[
            spec(PixCorrBackground::PerimeterMedian),
            spec(PixCorrBackground::Given),
        ])
        .map_err(|(i, e)| format!("pixel-phase curve {i}: {e:?}"))?
    } else {
        Vec::new()
    };
    Simulator::new(params.clone(), Vec::new())
        .truth_table_with_curves(TruthSections::ALL, tile_log2, &curves)
        .map_err(|e| e.to_string())
}

/// Matches a frame's reported stars to its truth.
fn match_frame(
    summary: FrameSummary,
    truth: Vec<Star>,
    reported: &[StarRecord],
    params: &SensorParams,
    samples_read: u64,
) -> SilFrame {
    let nearest = |s: &StarRecord| {
        truth
            .iter()
            .map(|t| {
                (
                    t,
                    (f64::from(s.x_px) - t.x_px).hypot(f64::from(s.y_px) - t.y_px),
                )
            })
            .filter(|(_, d)| *d < MATCH_PX)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(t, _)| *t)
    };
    let stars: Vec<Matched> = reported
        .iter()
        .map(|s| Matched {
            star: *s,
            truth: nearest(s),
        })
        .collect();
    let missed = truth
        .iter()
        .filter(|t| in_field(t, params))
        .filter(|t| {
            !stars
                .iter()
                .any(|m| m.star.is_centroid() && m.truth.is_some_and(|u| u == **t))
        })
        .copied()
        .collect();
    SilFrame {
        summary,
        truth,
        stars,
        missed,
        samples_read,
        predicted_windows: 0,
        attitude: None,
        unaffected: None,
        object_in_field: None,
        causes: None,
    }
}
