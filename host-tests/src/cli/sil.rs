//! `startrack sil`: the tracker application live on the simulated CCD47-20 ([`startrack_homes::sil`]),
//! frame after frame over a drifting scene. Writes the telemetry (one row per star per
//! frame) and the truth (one row per true star per frame) as CSV, the mode changes and a
//! closing summary on standard error.
//!
//! - `--telemetry FILE`: `frame,mode,x_px,y_px,flux_e,snr,sigma_x_px,sigma_y_px,flags,provenance,psf_a_px,chi2_dof`
//!   (`flags`: the `StarFlags` bits, docs/formats.md);
//! - `--truth FILE`: `frame,x_px,y_px,signal_e,a_px`;
//! - with `--sky`, `--attitude FILE`: one row per frame,
//!   `frame,solved,solve_mode,used,matched,qw,qx,qy,qz,error_boresight_arcsec,error_roll_arcsec,sigma_boresight_arcsec,sigma_roll_arcsec,false_probability,t_mid_s,true_qw,true_qx,true_qy,true_qz,true_wx_deg_s,true_wy_deg_s,true_wz_deg_s`
//!   (the quaternions take ICRS to the camera, scalar first; errors against the truth; the
//!   truth at mid-exposure, its rate the camera's angular velocity in the camera frame).
//! - with `--sky`, `--rate-deg-s WX,WY,WZ`, `--exposure-ms MS` and `--slew-accel-deg-s2 A`:
//!   the camera turns during each exposure ([`startrack_sim::sky::motion`]) and the stars
//!   trail.
//!   then `cuc_mid_s,true_cuc_mid_s,flags,wx_deg_s,wy_deg_s,wz_deg_s,sigma_wx_deg_s,sigma_wy_deg_s,sigma_wz_deg_s`
//!   (the report's mid-exposure in spacecraft time, CUC seconds, and the truth, both empty
//!   without `--spacecraft-time-s`; the report's validity flags joined by `+`; its rate and
//!   1-sigma, camera frame, deg/s).
//!
//! With `--port P` it serves the link instead ([`startrack_homes::link_home::serve`]); with `--sky` too,
//! each frame's attitude report (`TM[134,2]`) is sent as the board sends it.

use super::{CliError, LabError};
use startrack_core::tracker::{Event, Mode, TrackerConfig};
use startrack_homes::home::csv_row;
use startrack_homes::sil::{self, SilConfig, SilReport};
use startrack_sim::sky::bright::BrightSky;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The scene options `startrack sil` and `startrack pil` share (each flattens them into its
/// own options; `pil` runs 5 frames by default).
#[derive(Clone, Debug, clap::Args)]
pub struct SceneArgs {
    /// Frames to run.
    #[arg(long, default_value_t = 20)]
    pub frames: u32,
    /// Seed of the scene and the sensor.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Stars in the scene (without `--sky`).
    #[arg(long, default_value_t = 20)]
    pub stars: usize,
    /// Motion of the scene per frame, px: X,Y (a slow attitude rate).
    #[arg(long, value_delimiter = ',', num_args = 2, default_values_t = [0.3, -0.2])]
    pub drift_px: Vec<f64>,
    /// The scene from the sky: the catalog's stars at a seeded random attitude turning by
    /// `--drift-px` a frame across the boresight, every frame identified and its attitude
    /// checked against the truth (instead of `--stars` random stars).
    #[arg(long)]
    pub sky: bool,
}

/// Options of `startrack sil`.
#[derive(Clone, Debug, clap::Args)]
pub struct SilArgs {
    /// The scene.
    #[command(flatten)]
    pub scene: SceneArgs,
    /// PSF 80 %-energy radius of the scene and the tracker, px.
    #[arg(long)]
    pub psf_a_px: Option<f32>,
    /// Telemetry CSV (one row per reported star per frame).
    #[arg(long)]
    pub telemetry: Option<PathBuf>,
    /// Truth CSV (one row per true star per frame).
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// With `--sky`: attitude CSV (one row per frame).
    #[arg(long, requires = "sky")]
    pub attitude: Option<PathBuf>,
    /// With `--sky`: the camera's angular velocity during the exposures, camera frame,
    /// deg/s: WX,WY,WZ (x, y across the boresight, z roll), each within -10 to 10; the stars
    /// trail (instead of `--drift-px`'s steps between still exposures).
    #[arg(
        long,
        requires = "sky",
        conflicts_with = "drift_px",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub rate_deg_s: Option<Vec<f64>>,
    /// With `--sky`: the exposure, ms (0 to 10,000; default the 100 ms frame period); a
    /// longer exposure lengthens the period to it. Alone it gives a still sky (rate 0) with
    /// this timing.
    #[arg(long, requires = "sky")]
    pub exposure_ms: Option<f64>,
    /// With `--rate-deg-s`: reach the rate from rest at the start of the run with this
    /// acceleration, deg/s^2 (above 0; default: at the rate from the start).
    #[arg(long, requires = "rate_deg_s")]
    pub slew_accel_deg_s2: Option<f64>,
    /// The platform's largest angular acceleration told to the attitude stage, deg/s^2 (0 to
    /// 100; default 1): until the rate filter measures the acceleration, the attitude's
    /// and the rate's covariances carry what this much could do.
    #[arg(long, value_name = "DEG_S2")]
    pub max_accel_deg_s2: Option<f64>,
    /// The spacecraft time at the tracker's counter 0, CUC seconds (1958 TAI epoch): the SIL
    /// runs the PPS line and sends the time-set command for its next pulse before the first
    /// frame, so the attitude reports are on spacecraft time. Without it they flag the time
    /// not synchronised.
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    pub spacecraft_time_s: Option<f64>,
    /// With `--spacecraft-time-s`: the tracker counter's frequency error, ppm (within the
    /// clock model's 200).
    #[arg(
        long,
        default_value_t = 0.0,
        allow_negative_numbers = true,
        requires = "spacecraft_time_s"
    )]
    pub counter_ppm: f64,
    /// With `--sky`: the spacecraft's velocity, ICRF, km/s: VX,VY,VZ (at most 300 km/s). The
    /// scene's stars are seen aberrated, and the SIL sends the velocity command (and, without
    /// `--spacecraft-time-s`, the time from 2,100,000,000.25 s) so the attitude is of the
    /// ICRF. Not with `--rate-deg-s` or `--exposure-ms` (the trailed scene is not aberrated).
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        requires = "sky",
        conflicts_with_all = ["rate_deg_s", "exposure_ms"]
    )]
    pub velocity_km_s: Option<Vec<f64>>,
    /// With `--velocity-km-s`: do not send the velocity command (the attitude stays apparent,
    /// its aberration uncorrected).
    #[arg(long, requires = "velocity_km_s")]
    pub apparent: bool,
    /// With `--sky`: the Moon, its centre at frame 0 X,Y (active px) and its phase angle
    /// (deg, 0 full to 180 new; default 0), fixed in the sky as the field turns: `X,Y[,PHASE]`.
    #[arg(
        long,
        requires = "sky",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub moon: Option<Vec<f64>>,
    /// With `--sky`: the sunlit Earth seen from 500 km, its limb across a corner of the
    /// field at frame 0: CORNER,DEPTH (corner 0 at (0, 0), 1 last column, 2 last row, 3 both;
    /// DEPTH px into the field along the corner's diagonal).
    #[arg(long, requires = "sky", value_delimiter = ',')]
    pub earth_limb: Option<Vec<f64>>,
    /// With `--sky`: the Sun's stray light, the Sun A deg from the boresight (30, the
    /// baffle's exclusion, to 180) at azimuth AZ on the image (deg from +x towards +y;
    /// default 0): `A[,AZ]`.
    #[arg(
        long,
        requires = "sky",
        value_delimiter = ',',
        allow_hyphen_values = true
    )]
    pub sun_angle_deg: Option<Vec<f64>>,
    /// With `--sky`: a planet at X,Y (active px, frame 0) of magnitude MAG (-5 to 6), fixed
    /// in the sky: X,Y,MAG; repeat for more.
    #[arg(long, requires = "sky", allow_hyphen_values = true)]
    pub planet: Vec<String>,
    /// With `--sky`: proton hits at the rate and spectrum of a quiet orbit, the South
    /// Atlantic Anomaly or a solar flare (docs/cli.md states them).
    #[arg(long, requires = "sky", value_parser = ["quiet", "saa", "flare"])]
    pub protons: Option<String>,
    /// Serve the tracker's command and telemetry link on TCP 127.0.0.1:PORT (standing in
    /// for the UART) and run until stopped; `--frames`, `--telemetry` and `--truth` are then
    /// not used (drive it with `startrack gse --port PORT`). With `--sky` the attitude stage
    /// runs after every frame, as on the board, and its report goes out on the link
    /// (`startrack gse --port PORT attitude`).
    #[arg(long)]
    pub port: Option<u16>,
    /// With `--port`: probability that a received byte has a bit flipped (seeded).
    #[arg(long, default_value_t = 0.0)]
    pub link_noise: f64,
    /// With `--port`: keep the tables in the flash store over the flash model held in FILE
    /// (created erased, with the SIL's table, if absent); restarting with the same FILE is a
    /// reboot.
    #[arg(long, value_name = "FILE")]
    pub flash: Option<PathBuf>,
    /// With `--flash`: cut the power during the N-th flash step (unit program or sector
    /// erase) after start-up, N from 1; the SIL then exits with code
    /// [`POWER_CUT_EXIT_CODE`], FILE holding the flash as cut.
    #[arg(long, value_name = "N", requires = "flash")]
    pub power_cut_at_write: Option<u64>,
}

/// Exit code of `startrack sil --power-cut-at-write N` when the cut happened.
pub const POWER_CUT_EXIT_CODE: u8 = 4;

impl SilArgs {
    /// `startrack sil`'s options as given on their own (each at its default) over `scene`:
    /// the SIL `startrack pil` compares the firmware with.
    pub fn of_scene(scene: SceneArgs) -> Result<Self, CliError> {
        use clap::{Args, FromArgMatches};
        let usage = |e: clap::Error| CliError::Usage(e.to_string());
        let matches = Self::augment_args(clap::Command::new("sil"))
            .try_get_matches_from(["sil"])
            .map_err(usage)?;
        let args = Self::from_arg_matches(&matches).map_err(usage)?;
        Ok(Self { scene, ..args })
    }
}

/// The SIL configuration of `args`.
pub fn config_of(args: &SilArgs) -> Result<SilConfig, CliError> {
    let scene = &args.scene;
    let [dx, dy] = scene.drift_px[..] else {
        return Err(CliError::Usage("--drift-px takes X,Y".into()));
    };
    if !(dx.is_finite() && dy.is_finite() && dx.abs() <= 5.0 && dy.abs() <= 5.0) {
        return Err(CliError::Usage(
            "--drift-px: each component within -5 to 5 px a frame".into(),
        ));
    }
    let mut tracker = TrackerConfig::FLIGHT;
    if let Some(a) = args.psf_a_px {
        tracker.psf_a_px = a;
    }
    tracker
        .validate(sil::SIL_CAPACITY)
        .map_err(|e| CliError::Usage(e.to_string()))?;
    let sky = scene.sky.then(|| {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(scene.seed ^ 0x534b_5900);
        let q0 = startrack_sim::sky::field::random_attitude(&mut rng);
        let f = startrack_sim::sky::field::FieldSpec::ccd47_15deg(0.0)
            .camera
            .focal_length_px;
        // A turn about +y moves the field along +x, about +x along -y.
        startrack_sim::sky::scene::SkyScene::ccd47_15deg(q0, [-dy / f, dx / f, 0.0])
    });
    let spacecraft_epoch_us = match args.spacecraft_time_s {
        None => None,
        Some(t) if t.is_finite() && (0.0..4.0e9).contains(&t) => Some((t * 1e6).round() as u64),
        Some(_) => {
            return Err(CliError::Usage(
                "--spacecraft-time-s: 0 to 4e9 s after 1958".into(),
            ));
        }
    };
    if !(args.counter_ppm.is_finite() && args.counter_ppm.abs() <= 150.0) {
        return Err(CliError::Usage("--counter-ppm: within -150 to 150".into()));
    }
    let velocity_m_s = match args.velocity_km_s.as_deref() {
        None => None,
        Some(&[x, y, z]) => {
            let v = [x, y, z].map(|c| c * 1000.0);
            let speed = v.iter().map(|c| c * c).sum::<f64>().sqrt();
            if !(speed.is_finite() && speed <= startrack_core::link::protocol::MAX_SPEED_M_S) {
                return Err(CliError::Usage(
                    "--velocity-km-s: VX,VY,VZ, at most 300 km/s".into(),
                ));
            }
            Some(v)
        }
        Some(_) => {
            return Err(CliError::Usage("--velocity-km-s takes VX,VY,VZ".into()));
        }
    };
    let spacecraft_epoch_us = spacecraft_epoch_us.or(velocity_m_s.map(|_| sil::SIL_EPOCH_US));
    let bright = bright_of(args)?;
    let mut config = SilConfig {
        velocity_m_s,
        send_velocity: !args.apparent,
        spacecraft_epoch_us,
        counter_rate_ppm: args.counter_ppm,
        frames: scene.frames,
        seed: scene.seed,
        stars: scene.stars,
        drift_px: (dx, dy),
        tracker,
        sky,
        bright,
        ..SilConfig::default()
    };
    match args.max_accel_deg_s2 {
        None => {}
        Some(a) if a.is_finite() && (0.0..=100.0).contains(&a) => {
            config.max_accel_rad_s2 = a.to_radians();
        }
        Some(_) => {
            return Err(CliError::Usage(
                "--max-accel-deg-s2: 0 to 100 deg/s^2".into(),
            ));
        }
    }
    if let (Some(sky), Some(motion)) = (config.sky.as_mut(), motion_of(args, config.period_us)?) {
        config.period_us = (motion.period_s * 1e6).round() as u64;
        // The tracker is told the exposure it runs with (its mid-exposure tags follow it).
        config.tracker.exposure_ms = (motion.exposure_s * 1e3).round().max(1.0) as u32;
        sky.motion = Some(motion);
        sky.rate_rad_per_frame = [0.0; 3];
    }
    Ok(config)
}

/// The bright objects and protons of `args` (`--moon`, `--earth-limb`, `--sun-angle-deg`,
/// `--planet`, `--protons`).
pub fn bright_of(args: &SilArgs) -> Result<BrightSky, CliError> {
    use startrack_sim::sim::protons::ProtonEnv;
    use startrack_sim::sky::bright::{EarthSpec, MoonSpec, PlanetSpec, SUN_EXCLUSION_DEG, SunSpec};
    let finite = |v: &[f64]| v.iter().all(|c| c.is_finite());
    let in_reach = |x: f64| (-100.0..=1124.0).contains(&x);
    let moon = match args.moon.as_deref() {
        None => None,
        Some(v)
            if finite(v) && (v.len() == 2 || v.len() == 3) && in_reach(v[0]) && in_reach(v[1]) =>
        {
            let phase_deg = v.get(2).copied().unwrap_or(0.0);
            if !(0.0..=180.0).contains(&phase_deg) {
                return Err(CliError::Usage(
                    "--moon: the phase angle is 0 to 180 deg".into(),
                ));
            }
            Some(MoonSpec {
                at_px: [v[0], v[1]],
                phase_deg,
            })
        }
        Some(_) => {
            return Err(CliError::Usage(
                "--moon takes X,Y[,PHASE_DEG], X and Y within -100 to 1124 px".into(),
            ));
        }
    };
    let earth = match args.earth_limb.as_deref() {
        None => None,
        Some(&[c, d])
            if [0.0, 1.0, 2.0, 3.0].contains(&c)
                && d.is_finite()
                && (0.0..=1400.0).contains(&d) =>
        {
            Some(EarthSpec {
                corner: c as u8,
                depth_px: d,
            })
        }
        Some(_) => {
            return Err(CliError::Usage(
                "--earth-limb takes CORNER,DEPTH_PX: corner 0 to 3, depth 0 to 1400 px".into(),
            ));
        }
    };
    let sun = match args.sun_angle_deg.as_deref() {
        None => None,
        Some(v)
            if finite(v)
                && (v.len() == 1 || v.len() == 2)
                && (SUN_EXCLUSION_DEG..=180.0).contains(&v[0]) =>
        {
            Some(SunSpec {
                angle_deg: v[0],
                azimuth_deg: v.get(1).copied().unwrap_or(0.0),
            })
        }
        Some(_) => {
            return Err(CliError::Usage(format!(
                "--sun-angle-deg takes A[,AZ], A from {SUN_EXCLUSION_DEG} (the baffle's exclusion) to 180 deg"
            )));
        }
    };
    let mut planets = Vec::new();
    for p in &args.planet {
        let v: Vec<f64> = p.split(',').filter_map(|c| c.trim().parse().ok()).collect();
        match v[..] {
            [x, y, mag]
                if finite(&v) && in_reach(x) && in_reach(y) && (-5.0..=6.0).contains(&mag) =>
            {
                planets.push(PlanetSpec { at_px: [x, y], mag });
            }
            _ => {
                return Err(CliError::Usage(
                    "--planet takes X,Y,MAG: X and Y within -100 to 1124 px, MAG -5 to 6".into(),
                ));
            }
        }
    }
    let protons = match args.protons.as_deref() {
        None => None,
        Some("quiet") => Some(ProtonEnv::Quiet),
        Some("saa") => Some(ProtonEnv::Saa),
        Some("flare") => Some(ProtonEnv::Flare),
        Some(other) => {
            return Err(CliError::Usage(format!(
                "--protons: quiet, saa or flare, not {other}"
            )));
        }
    };
    Ok(BrightSky {
        moon,
        earth,
        sun,
        planets,
        protons,
    })
}

/// Largest rate component of `--rate-deg-s`, deg/s.
pub const MAX_RATE_DEG_S: f64 = 10.0;

/// Longest `--exposure-ms`.
pub const MAX_EXPOSURE_MS: f64 = 10_000.0;

/// The turn during the exposures that `args` asks for (`None`: neither `--rate-deg-s` nor
/// `--exposure-ms`), with the frame period `period_us` lengthened to a longer exposure.
fn motion_of(
    args: &SilArgs,
    period_us: u64,
) -> Result<Option<startrack_sim::sky::motion::ExposureMotion>, CliError> {
    use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
    if args.rate_deg_s.is_none() && args.exposure_ms.is_none() {
        return Ok(None);
    }
    let rate = match args.rate_deg_s.as_deref() {
        None => [0.0; 3],
        Some(&[x, y, z])
            if [x, y, z]
                .iter()
                .all(|c| c.is_finite() && c.abs() <= MAX_RATE_DEG_S) =>
        {
            [x, y, z].map(f64::to_radians)
        }
        Some(_) => {
            return Err(CliError::Usage(format!(
                "--rate-deg-s takes WX,WY,WZ, each within -{MAX_RATE_DEG_S} to {MAX_RATE_DEG_S} deg/s"
            )));
        }
    };
    let accel = match args.slew_accel_deg_s2 {
        None => 0.0,
        Some(a) if a.is_finite() && a > 0.0 => a.to_radians(),
        Some(_) => {
            return Err(CliError::Usage(
                "--slew-accel-deg-s2: an acceleration above 0 deg/s^2".into(),
            ));
        }
    };
    let period_s = period_us as f64 * 1e-6;
    let exposure_s = match args.exposure_ms {
        None => period_s,
        Some(ms) if ms.is_finite() && ms > 0.0 && ms <= MAX_EXPOSURE_MS => ms * 1e-3,
        Some(_) => {
            return Err(CliError::Usage(format!(
                "--exposure-ms: above 0, at most {MAX_EXPOSURE_MS} ms"
            )));
        }
    };
    let profile = RateProfile {
        rate_rad_s: rate,
        accel_rad_s2: accel,
    };
    ExposureMotion::new(profile, period_s.max(exposure_s), exposure_s)
        .map(Some)
        .map_err(|e| CliError::Usage(e.to_string()))
}

fn create(path: &Path) -> Result<std::io::BufWriter<std::fs::File>, CliError> {
    std::fs::File::create(path)
        .map(std::io::BufWriter::new)
        .map_err(|e| io_error(path, &e))
}

fn io_error(path: &Path, e: &std::io::Error) -> CliError {
    LabError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    }
    .into()
}

/// Writes the telemetry CSV of `report`.
pub fn write_telemetry(out: &mut dyn Write, report: &SilReport) -> std::io::Result<()> {
    writeln!(out, "frame,mode,{}", startrack_homes::home::CSV_HEADER)?;
    for f in &report.frames {
        for m in &f.stars {
            writeln!(
                out,
                "{},{},{}",
                f.summary.frame,
                f.summary.mode.name(),
                csv_row(&m.star)
            )?;
        }
    }
    Ok(())
}

/// Writes the truth CSV of `report`.
pub fn write_truth(out: &mut dyn Write, report: &SilReport) -> std::io::Result<()> {
    writeln!(out, "frame,x_px,y_px,signal_e,a_px")?;
    for f in &report.frames {
        for t in &f.truth {
            writeln!(
                out,
                "{},{:.4},{:.4},{:.1},{:.3}",
                f.summary.frame, t.x_px, t.y_px, t.signal_e, t.a_px
            )?;
        }
    }
    Ok(())
}

/// Writes the attitude CSV of `report` (sky runs; nothing for a random scene).
pub fn write_attitude(out: &mut dyn Write, report: &SilReport) -> std::io::Result<()> {
    const ARCSEC: f64 = 206_264.806;
    writeln!(
        out,
        "frame,solved,solve_mode,used,matched,qw,qx,qy,qz,error_boresight_arcsec,error_roll_arcsec,sigma_boresight_arcsec,sigma_roll_arcsec,false_probability,t_mid_s,true_qw,true_qx,true_qy,true_qz,true_wx_deg_s,true_wy_deg_s,true_wz_deg_s,cuc_mid_s,true_cuc_mid_s,flags,wx_deg_s,wy_deg_s,wz_deg_s,sigma_wx_deg_s,sigma_wy_deg_s,sigma_wz_deg_s"
    )?;
    for f in &report.frames {
        let Some(c) = &f.attitude else { continue };
        let [tw, tx, ty, tz] = c.truth.normalized().unwrap_or(c.truth).0;
        // `+ 0.0` writes a negative zero as 0.
        let [wx, wy, wz] = c.true_rate_rad_s.map(|w| w.to_degrees() + 0.0);
        let truth = format!(
            "{:.6},{tw:.9},{tx:.9},{ty:.9},{tz:.9},{wx:.6},{wy:.6},{wz:.6}",
            c.t_mid_s
        );
        match (&c.fix, c.error_rad()) {
            (Ok(fix), Some(e)) => {
                let a = &fix.attitude;
                let [w, x, y, z] = a.q.0;
                writeln!(
                    out,
                    "{},1,{},{},{},{w:.9},{x:.9},{y:.9},{z:.9},{:.3},{:.3},{:.3},{:.3},{:.2e},{truth},{}",
                    f.summary.frame,
                    match fix.mode {
                        startrack_core::solver::SolveMode::Tracking => "tracking",
                        startrack_core::solver::SolveMode::LostInSpace => "lost_in_space",
                    },
                    fix.used,
                    fix.matched,
                    e[0].hypot(e[1]) * ARCSEC,
                    e[2].abs() * ARCSEC,
                    a.boresight_sigma_rad() * ARCSEC,
                    a.roll_sigma_rad() * ARCSEC,
                    fix.false_probability,
                    time_columns(c)
                )?;
            }
            _ => writeln!(
                out,
                "{},0,,,,,,,,,,,,,{truth},{}",
                f.summary.frame,
                time_columns(c)
            )?,
        }
    }
    Ok(())
}

/// The spacecraft-time and rate columns of an attitude row: `cuc_mid_s,true_cuc_mid_s,flags`
/// and the report's rate and its 1-sigma per axis, deg/s (empty without a rate).
fn time_columns(c: &sil::AttitudeCheck) -> String {
    let t = c
        .report
        .and_then(|r| r.time)
        .map_or(String::new(), |t| format!("{:.6}", t.cuc.to_seconds()));
    let truth = c.true_time_s.map_or(String::new(), |t| format!("{t:.6}"));
    let flags = c
        .report
        .map_or(String::new(), |r| super::gse::flag_names(r.flags));
    let rate = c
        .report
        .and_then(|r| r.rate)
        .map_or(",,,,,".to_string(), |w| {
            let s = |i: usize| w.cov_rad2_s2[i][i].max(0.0).sqrt().to_degrees();
            format!(
                "{:.6},{:.6},{:.6},{:.3e},{:.3e},{:.3e}",
                w.w_rad_s[0].to_degrees(),
                w.w_rad_s[1].to_degrees(),
                w.w_rad_s[2].to_degrees(),
                s(0),
                s(1),
                s(2)
            )
        });
    format!("{t},{truth},{flags},{rate}")
}

/// Runs `startrack sil --port P`: the SIL with its link on TCP, until stopped.
pub fn serve(args: &SilArgs) -> Result<startrack_homes::link_home::ServeReport, CliError> {
    let Some(port) = args.port else {
        return Err(CliError::Usage("--port is needed to serve the link".into()));
    };
    if !(0.0..=1.0).contains(&args.link_noise) {
        return Err(CliError::Usage(
            "--link-noise: a probability, 0 to 1".into(),
        ));
    }
    let config = startrack_homes::link_home::ServeConfig {
        sil: config_of(args)?,
        port,
        link_noise: args.link_noise,
        max_frames: None,
        stop: None,
        flash: args
            .flash
            .clone()
            .map(|path| startrack_homes::link_home::FlashConfig {
                path,
                power_cut_at_write: args.power_cut_at_write,
            }),
    };
    if args.power_cut_at_write == Some(0) {
        return Err(CliError::Usage(
            "--power-cut-at-write: N counts from 1".into(),
        ));
    }
    startrack_homes::link_home::serve(&config, &mut |p| {
        eprintln!("startrack sil: link on 127.0.0.1:{p}");
    })
    .map_err(CliError::Usage)
}

/// Runs `startrack sil`.
pub fn run(args: &SilArgs) -> Result<SilReport, CliError> {
    let config = config_of(args)?;
    let report = sil::run(&config).map_err(CliError::Usage)?;
    if let Some(p) = &args.telemetry {
        let mut f = create(p)?;
        write_telemetry(&mut f, &report)
            .and_then(|()| f.flush())
            .map_err(|e| io_error(p, &e))?;
    }
    if let Some(p) = &args.truth {
        let mut f = create(p)?;
        write_truth(&mut f, &report)
            .and_then(|()| f.flush())
            .map_err(|e| io_error(p, &e))?;
    }
    if let Some(p) = &args.attitude {
        let mut f = create(p)?;
        write_attitude(&mut f, &report)
            .and_then(|()| f.flush())
            .map_err(|e| io_error(p, &e))?;
    }
    for e in &report.events {
        if let Event::ModeChange {
            frame,
            from,
            to,
            reason,
        } = e
        {
            eprintln!(
                "frame {frame}: {} -> {} ({reason:?})",
                from.name(),
                to.name()
            );
        }
    }
    let count = |m: Mode| report.frames.iter().filter(|f| f.summary.mode == m).count();
    let missed: usize = report.frames.iter().map(|f| f.missed.len()).sum();
    let in_field: usize = report
        .frames
        .iter()
        .map(|f| {
            f.truth
                .iter()
                .filter(|t| sil::in_field(t, &Default::default()))
                .count()
        })
        .sum();
    eprintln!(
        "startrack sil: {} frames ({} acquisition, {} tracking), {} of {} in-field star-frames measured, RMS error {:.4} px per axis, chi2/dof {:.2} (acquisition {:.2}, tracking {:.2})",
        report.frames.len(),
        count(Mode::Acquisition),
        count(Mode::Tracking),
        in_field - missed,
        in_field,
        report.rms_error_px(),
        report.chi2_per_dof(None),
        report.chi2_per_dof(Some(Mode::Acquisition)),
        report.chi2_per_dof(Some(Mode::Tracking)),
    );
    if let Some(a) = report.attitude_summary() {
        eprintln!(
            "startrack sil: attitude in {} of {} frames ({} lost in space), {} wrong; RMS error cross-boresight {:.2} arcsec (bound {:.2}), roll {:.2} arcsec (bound {:.2}), mean NEES {:.2}",
            a.solved,
            a.frames,
            a.lost_in_space,
            a.wrong,
            a.rms_boresight_arcsec,
            a.bound_boresight_arcsec,
            a.rms_roll_arcsec,
            a.bound_roll_arcsec,
            a.mean_nees,
        );
    }
    Ok(report)
}
