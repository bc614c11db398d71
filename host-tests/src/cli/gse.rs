//! `startrack gse --port P COMMAND`: the ground tool, driving a tracker's link (the SIL's
//! `startrack sil --port P`) with [`startrack_ground::Ground`].
//!
//! - `status`: housekeeping as JSON on standard output;
//! - `ping`;
//! - `mode standby|acquisition|tracking`;
//! - `upload-table FILE`: the table in chunks, then commit;
//! - `stars --frames N [--out FILE]`: the next N frames' star lists as CSV
//!   (`frame,mode,` and the `stars.csv` columns);
//! - `attitude --frames N`: the next N frames' attitude reports (`TM[134,2]`) as CSV,
//!   [`ATTITUDE_CSV_HEADER`] (status `too_few_stars`, `not_identified`, `tracking` or
//!   `lost_in_space`; the quaternion takes ICRS to the camera, scalar first; `t_mid_s` the
//!   mid-exposure in spacecraft time, CUC seconds; `flags` the validity flags' names joined
//!   by `+`; empty fields without an attitude, a time or a rate);
//! - `time-set SECONDS`: the spacecraft time (CUC seconds) of the tracker's next sync pulse;
//! - `velocity VX,VY,VZ --at SECONDS`: the spacecraft's velocity (ICRF, km/s) at a spacecraft
//!   time, for the attitude stage's aberration;
//! - `window X Y SIZE --out FILE [--calibrated]`: a window of the next frame as FITS;
//! - `reset`.
//!
//! Errors are one line on standard error; the exit code says which kind ([`GseError::exit_code`]).

use startrack_core::link::WindowKind;
use startrack_core::link::telemetry::{AttitudeMissing, AttitudeReport, Housekeeping, Validity};
use startrack_core::solver::SolveMode;
use startrack_core::time::Cuc;
use startrack_core::tracker::Mode;
use startrack_ground::{Ground, GroundError};
use startrack_homes::home::{CSV_HEADER, csv_row};
use startrack_sim::fits::{MapF32, write_map};
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

/// Options of `startrack gse`.
#[derive(Clone, Debug, clap::Args)]
pub struct GseArgs {
    /// The tracker's link: TCP port on 127.0.0.1.
    #[arg(long)]
    pub port: u16,
    /// Longest wait for an answer, s.
    #[arg(long, default_value_t = 30.0)]
    pub timeout_s: f64,
    /// What to do.
    #[command(subcommand)]
    pub command: GseCommand,
}

/// The ground tool's commands.
#[derive(Clone, Debug, clap::Subcommand)]
pub enum GseCommand {
    /// Housekeeping as JSON.
    Status,
    /// Is the tracker answering.
    Ping,
    /// Set the mode from the next frame on.
    Mode {
        /// standby, acquisition or tracking.
        mode: String,
    },
    /// Upload a calibration table (chunks, then commit).
    UploadTable {
        /// The table file.
        file: PathBuf,
        /// Chunk size, bytes (at most 1024).
        #[arg(long, default_value_t = 1024)]
        chunk: usize,
    },
    /// The next frames' star lists as CSV.
    Stars {
        /// Frames.
        #[arg(long, default_value_t = 1)]
        frames: u16,
        /// Output file (default: standard output).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// The next frames' attitude reports as CSV.
    Attitude {
        /// Frames.
        #[arg(long, default_value_t = 1)]
        frames: usize,
    },
    /// A window of the next frame as FITS.
    Window {
        /// Left column, px.
        x: u16,
        /// Top row, px.
        y: u16,
        /// Side, px (at most 64).
        size: u16,
        /// Calibrated electrons instead of raw ADU.
        #[arg(long)]
        calibrated: bool,
        /// Output FITS file.
        #[arg(long)]
        out: PathBuf,
    },
    /// Set the spacecraft time of the next sync pulse (`TC[9,128]`).
    TimeSet {
        /// CUC seconds since 1958-01-01 TAI (a fraction allowed, to 2^-16 s).
        seconds: f64,
    },
    /// Send the spacecraft's velocity (`TC[134,1]`).
    Velocity {
        /// ICRF, barycentric, km/s: VX,VY,VZ.
        #[arg(value_delimiter = ',', allow_hyphen_values = true)]
        km_s: Vec<f64>,
        /// The spacecraft time it holds at, CUC seconds.
        #[arg(long)]
        at: f64,
    },
    /// Reset the tracker.
    Reset,
    /// Write the pixels confirmed in flight into a new calibration table (`TC[133,7]`).
    CommitDefects,
}

/// Why `startrack gse` failed.
#[derive(Debug)]
pub enum GseError {
    /// A bad option or a file that could not be read or written (exit code 1).
    Usage(String),
    /// The tracker rejected the command (exit code 2).
    Rejected(GroundError),
    /// No link or no answer (exit code 3).
    Link(GroundError),
}

impl GseError {
    /// The process exit code.
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::Usage(_) => 1,
            Self::Rejected(_) => 2,
            Self::Link(_) => 3,
        }
    }
}

impl std::fmt::Display for GseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Usage(m) => f.write_str(m),
            Self::Rejected(e) | Self::Link(e) => write!(f, "{e}"),
        }
    }
}

impl From<GroundError> for GseError {
    fn from(e: GroundError) -> Self {
        match e {
            GroundError::Rejected { .. } => Self::Rejected(e),
            _ => Self::Link(e),
        }
    }
}

/// The mode named `s`.
pub fn parse_mode(s: &str) -> Option<Mode> {
    [Mode::Standby, Mode::Acquisition, Mode::Tracking]
        .into_iter()
        .find(|m| m.name() == s)
}

/// Housekeeping as a JSON object.
pub fn status_json(h: &Housekeeping) -> serde_json::Value {
    let t = &h.totals;
    let l = &h.link;
    serde_json::json!({
        "mode": h.mode.name(),
        "next_mode": h.next_mode.name(),
        "calibrated": h.calibrated,
        "temperature_source": format!("{:?}", h.temperature_source),
        "temperature_k": f64::from(h.temperature_k_bits) / 65536.0,
        "frame": h.frame,
        "stars": h.stars,
        "centroids": h.centroids,
        "uptime_us": h.uptime_us,
        "setup_faults": h.setup_faults,
        "dark_ratio": (h.dark_ratio_u8f8 != 0).then(|| f64::from(h.dark_ratio_u8f8) / 256.0),
        "dark_drift": h.status & startrack_core::link::telemetry::status::DARK_DRIFT != 0,
        "defects_pending": h.defects_pending,
        "totals": {
            "frames": t.frames,
            "lines_refused": t.lines_refused,
            "candidates_dropped": t.candidates_dropped,
            "windows_dropped": t.windows_dropped,
            "ring_lost": t.ring_lost,
            "calib_failed": t.calib_failed,
            "track_refused": t.track_refused,
            "track_lost": t.track_lost,
            "stars_dropped": t.stars_dropped,
        },
        "link": {
            "rx_bytes": l.rx_bytes,
            "packets": l.packets,
            "framing_errors": l.framing_errors,
            "crc_errors": l.crc_errors,
            "accepted": l.accepted,
            "rejected": l.rejected,
            "tm_queued": l.tm_queued,
            "tm_dropped": l.tm_dropped,
            "stars_not_sent": l.stars_not_sent,
        },
        "table": h.table.map(|i| serde_json::json!({
            "kind": i.kind,
            "len_bytes": i.len_bytes,
            "crc32": format!("{:08x}", i.crc32),
            "sequence": i.sequence,
        })),
    })
}

/// Header of the attitude CSV ([`attitude_row`]).
pub const ATTITUDE_CSV_HEADER: &str = "frame,status,used,matched,qw,qx,qy,qz,sigma_boresight_arcsec,sigma_roll_arcsec,false_probability,t_mid_s,time_bound_us,latency_us,flags,wx_deg_s,wy_deg_s,wz_deg_s,sigma_wx_deg_s,sigma_wy_deg_s,sigma_wz_deg_s";

/// The names of a report's validity flags joined by `+` (empty for none).
pub fn flag_names(f: Validity) -> String {
    f.iter_names()
        .map(|(n, _)| n.to_ascii_lowercase())
        .collect::<Vec<_>>()
        .join("+")
}

/// The time, flag and rate columns of an attitude row (after `false_probability`).
fn time_rate_columns(r: &AttitudeReport) -> String {
    let (t, bound) = r.time.map_or((String::new(), String::new()), |t| {
        (
            format!("{:.6}", t.cuc.to_seconds()),
            t.error_bound_us.to_string(),
        )
    });
    let rate = r.rate.map_or(",,,,,".to_string(), |w| {
        let d = |v: f64| v.to_degrees();
        let s = |i: usize| w.cov_rad2_s2[i][i].max(0.0).sqrt().to_degrees();
        format!(
            "{:.6},{:.6},{:.6},{:.3e},{:.3e},{:.3e}",
            d(w.w_rad_s[0]),
            d(w.w_rad_s[1]),
            d(w.w_rad_s[2]),
            s(0),
            s(1),
            s(2)
        )
    });
    format!(
        "{t},{bound},{},{},{rate}",
        r.latency_us,
        flag_names(r.flags)
    )
}

/// One attitude report as a row of [`ATTITUDE_CSV_HEADER`].
pub fn attitude_row(r: &AttitudeReport) -> String {
    const ARCSEC_PER_RAD: f64 = 206_264.806;
    match &r.fix {
        Ok(fix) => {
            let a = &fix.attitude;
            let [w, x, y, z] = a.q.0;
            let mode = match fix.mode {
                SolveMode::Tracking => "tracking",
                SolveMode::LostInSpace => "lost_in_space",
            };
            format!(
                "{},{mode},{},{},{w:.9},{x:.9},{y:.9},{z:.9},{:.3},{:.3},{:.2e},{}",
                r.frame,
                fix.used,
                fix.matched,
                a.boresight_sigma_rad() * ARCSEC_PER_RAD,
                a.roll_sigma_rad() * ARCSEC_PER_RAD,
                fix.false_probability,
                time_rate_columns(r)
            )
        }
        Err(AttitudeMissing::TooFewStars { used }) => {
            format!(
                "{},too_few_stars,{used},0,,,,,,,,{}",
                r.frame,
                time_rate_columns(r)
            )
        }
        Err(AttitudeMissing::NotIdentified { used }) => {
            format!(
                "{},not_identified,{used},0,,,,,,,,{}",
                r.frame,
                time_rate_columns(r)
            )
        }
    }
}

/// Runs `startrack gse`, writing its output to `out`.
pub fn run(args: &GseArgs, out: &mut dyn Write) -> Result<(), GseError> {
    if !(args.timeout_s.is_finite() && args.timeout_s > 0.0 && args.timeout_s <= 3600.0) {
        return Err(GseError::Usage("--timeout-s: 0 to 3600 s".into()));
    }
    let io = |e: std::io::Error| GseError::Usage(e.to_string());
    // Check the local inputs before touching the link.
    let mode = match &args.command {
        GseCommand::Mode { mode } => Some(parse_mode(mode).ok_or_else(|| {
            GseError::Usage(format!(
                "mode {mode:?}: one of standby, acquisition, tracking"
            ))
        })?),
        _ => None,
    };
    let table = match &args.command {
        GseCommand::UploadTable { file, .. } => Some(
            std::fs::read(file).map_err(|e| GseError::Usage(format!("{}: {e}", file.display())))?,
        ),
        _ => None,
    };
    let mut g = Ground::connect(args.port, Duration::from_secs_f64(args.timeout_s))?;
    match &args.command {
        GseCommand::Status => {
            let h = g.status()?;
            let text = serde_json::to_string_pretty(&status_json(&h))
                .map_err(|e| GseError::Usage(e.to_string()))?;
            writeln!(out, "{text}").map_err(io)?;
        }
        GseCommand::Ping => {
            g.ping()?;
            writeln!(out, "pong").map_err(io)?;
        }
        GseCommand::Mode { .. } => {
            if let Some(m) = mode {
                g.set_mode(m)?;
            }
        }
        GseCommand::UploadTable { chunk, .. } => {
            let bytes = table.unwrap_or_default();
            let info = g.upload_table(&bytes, *chunk, 8)?;
            writeln!(
                out,
                "table in force: {} bytes, CRC-32 {:08x}, sequence {}",
                info.len_bytes, info.crc32, info.sequence
            )
            .map_err(io)?;
        }
        GseCommand::Stars { frames, out: path } => {
            let lists = g.stars(*frames)?;
            let mut text = format!("frame,mode,{CSV_HEADER}\n");
            for (frame, m, stars) in &lists {
                for s in stars {
                    text.push_str(&format!("{frame},{},{}\n", m.name(), csv_row(s)));
                }
            }
            match path {
                Some(p) => std::fs::write(p, text)
                    .map_err(|e| GseError::Usage(format!("{}: {e}", p.display())))?,
                None => out.write_all(text.as_bytes()).map_err(io)?,
            }
        }
        GseCommand::Attitude { frames } => {
            let reports = g.attitude(*frames)?;
            let mut text = format!("{ATTITUDE_CSV_HEADER}\n");
            for r in &reports {
                text.push_str(&attitude_row(r));
                text.push('\n');
            }
            out.write_all(text.as_bytes()).map_err(io)?;
        }
        GseCommand::Window {
            x,
            y,
            size,
            calibrated,
            out: path,
        } => {
            let kind = if *calibrated {
                WindowKind::Calibrated
            } else {
                WindowKind::Raw
            };
            let px = g.window(*x, *y, *size, kind)?;
            let scale = if *calibrated { 1.0 / 64.0 } else { 1.0 };
            let map = MapF32 {
                rows: usize::from(*size),
                cols: usize::from(*size),
                data: px.iter().map(|&v| v as f32 * scale).collect(),
                keys: vec![
                    ("X0".into(), f64::from(*x)),
                    ("Y0".into(), f64::from(*y)),
                    ("CALIB".into(), f64::from(u8::from(*calibrated))),
                ],
            };
            write_map(path, &map)
                .map_err(|e| GseError::Usage(format!("{}: {e}", path.display())))?;
        }
        GseCommand::TimeSet { seconds } => {
            let cuc = (seconds.is_finite() && *seconds >= 0.0)
                .then(|| Cuc::from_ticks((seconds * 65_536.0).round() as u64))
                .flatten()
                .ok_or_else(|| GseError::Usage(format!("time-set {seconds}: 0 to 2^32 s")))?;
            g.set_time(cuc)?;
        }
        GseCommand::Velocity { km_s, at } => {
            let &[x, y, z] = &km_s[..] else {
                return Err(GseError::Usage("velocity takes VX,VY,VZ".into()));
            };
            let at = (at.is_finite() && *at >= 0.0)
                .then(|| Cuc::from_ticks((at * 65_536.0).round() as u64))
                .flatten()
                .ok_or_else(|| GseError::Usage(format!("--at {at}: 0 to 2^32 s")))?;
            g.set_velocity([x, y, z].map(|c| c * 1000.0), at)?;
        }
        GseCommand::Reset => g.reset()?,
        GseCommand::CommitDefects => {
            let (hot, tel, info) = g.commit_defects()?;
            writeln!(
                out,
                "committed {hot} hot and {tel} telegraph pixels: table in force {} bytes, CRC-32 {:08x}, sequence {}",
                info.len_bytes, info.crc32, info.sequence
            )
            .map_err(io)?;
        }
    }
    Ok(())
}
