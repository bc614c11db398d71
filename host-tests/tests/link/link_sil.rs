//! The SIL served over TCP and driven by the ground client and `startrack gse`: status,
//! mode, table upload, star lists, a raw window, reset, the errors' exit codes, and over a
//! sky scene the attitude reports.

use startrack_core::link::WindowKind;
use startrack_core::tracker::Mode;
use startrack_ground::{Ground, GroundError};
use startrack_homes::link_home::{ServeConfig, ServeReport, serve};
use startrack_homes::sil::SilConfig;
use startrack_host::cli::gse::{self, GseArgs, GseCommand};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::Duration;

struct Server {
    port: u16,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Result<ServeReport, String>>>,
}

impl Server {
    fn start(link_noise: f64) -> Self {
        Self::start_with(
            SilConfig {
                stars: 8,
                ..SilConfig::default()
            },
            link_noise,
        )
    }

    fn start_with(sil: SilConfig, link_noise: f64) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let config = ServeConfig {
            sil,
            port: 0,
            link_noise,
            max_frames: Some(200),
            stop: Some(stop.clone()),
            flash: None,
        };
        let (tx, rx) = mpsc::channel();
        let handle = std::thread::spawn(move || {
            serve(&config, &mut |p| {
                let _ = tx.send(p);
            })
        });
        let port = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("the server reports its port");
        Self {
            port,
            stop,
            handle: Some(handle),
        }
    }

    fn finish(mut self) -> ServeReport {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .take()
            .expect("joined once")
            .join()
            .expect("server thread")
            .expect("server ran")
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn tiled_table() -> Vec<u8> {
    Simulator::new(SensorParams::default(), Vec::new())
        .truth_table_tiled(TruthSections::ALL, 3)
        .expect("table")
}

#[test]
fn ground_drives_the_sil_over_tcp() {
    let server = Server::start(0.0);
    let mut g = Ground::connect(server.port, Duration::from_secs(60)).expect("connect");
    g.ping().expect("ping");

    // Status before and after frames: the counters move, the table is the boot table.
    let h0 = g.status().expect("status");
    let boot_table = h0.table.expect("the SIL boots with the truth table");
    assert_eq!(boot_table.sequence, 0);
    assert!(h0.link.accepted >= 1, "{h0:?}");

    // Star lists: frame numbers consecutive, stars found once acquisition ran.
    let lists = g.stars(3).expect("stars");
    assert_eq!(lists.len(), 3);
    for w in lists.windows(2) {
        assert_eq!(w[1].0, w[0].0 + 1, "consecutive frames");
    }
    assert!(
        lists
            .iter()
            .any(|(_, m, s)| *m != Mode::Standby && !s.is_empty()),
        "{lists:?}"
    );

    // Tracking can be refused (typed), standby accepted and taken at the next frame.
    g.set_mode(Mode::Standby).expect("standby accepted");
    let lists = g.stars(2).expect("stars");
    assert_eq!(lists.last().map(|l| l.1), Some(Mode::Standby));
    match g.set_mode(Mode::Tracking) {
        Err(GroundError::Rejected { code, .. }) => assert_eq!(code, 7, "nothing to track"),
        other => panic!("tracking from standby: {other:?}"),
    }

    // Table upload: a tiled table in chunks, committed, in force with a new sequence.
    let table = tiled_table();
    let info = g.upload_table(&table, 1000, 8).expect("upload");
    assert_eq!(info.len_bytes as usize, table.len());
    assert_eq!(info.sequence, 1);
    // A corrupt table is refused at commit (CRC-32 announced for other bytes), the one in
    // force kept.
    let mut bad = table.clone();
    bad[100] ^= 0xFF;
    let crc_ok = startrack_sim::flash_model::CRC32.checksum(&table);
    let mut begin = vec![1u8];
    begin.extend_from_slice(&(bad.len() as u32).to_be_bytes());
    begin.extend_from_slice(&crc_ok.to_be_bytes());
    g.command(
        "table-begin",
        startrack_core::link::protocol::TC_TABLE_BEGIN,
        &begin,
    )
    .expect("begin");
    for (k, part) in bad.chunks(1024).enumerate() {
        let mut d = ((k * 1024) as u32).to_be_bytes().to_vec();
        d.extend_from_slice(part);
        g.command("chunk", startrack_core::link::protocol::TC_TABLE_CHUNK, &d)
            .expect("chunk");
    }
    match g.command(
        "commit",
        startrack_core::link::protocol::TC_TABLE_COMMIT,
        &[],
    ) {
        Err(GroundError::Rejected {
            code, parameter, ..
        }) => {
            assert_eq!(code, 9);
            assert_eq!(parameter >> 16, 7, "CRC-32 mismatch");
        }
        other => panic!("corrupt table committed: {other:?}"),
    }
    let h = g.status().expect("status");
    assert_eq!(
        h.table.map(|t| t.sequence),
        Some(1),
        "the good upload stays in force"
    );

    // Back to acquisition with the uploaded table: stars again.
    g.set_mode(Mode::Acquisition).expect("acquisition");
    let lists = g.stars(2).expect("stars");
    assert!(lists.iter().any(|(_, _, s)| !s.is_empty()), "{lists:?}");

    // A raw window of the next frame.
    let px = g.window(100, 200, 16, WindowKind::Raw).expect("window");
    assert_eq!(px.len(), 256);
    assert!(px.iter().all(|&v| (0..=65535).contains(&v)));
    assert!(px.iter().any(|&v| v > 0));

    // A calibrated window of a corner without stars: the bias, the dark and the gains are
    // taken off, leaving noise around zero electrons (the raw one sits on the bias).
    let raw = g.window(2, 2, 8, WindowKind::Raw).expect("raw window");
    let cal = g
        .window(2, 2, 8, WindowKind::Calibrated)
        .expect("calibrated window");
    let mean = |v: &[i32], scale: f64| v.iter().map(|&x| f64::from(x) * scale).sum::<f64>() / 64.0;
    assert!(mean(&raw, 1.0) > 100.0, "raw ADU on the bias: {raw:?}");
    assert!(
        mean(&cal, 1.0 / 64.0).abs() < 10.0,
        "calibrated e-: {cal:?}"
    );

    // Reset: the tracker restarts at frame 0 and keeps the uploaded table.
    g.reset().expect("reset");
    let h = g.status().expect("status after reset");
    assert_eq!(h.table.map(|t| t.sequence), Some(1));
    assert!(
        h.link.accepted <= 2,
        "a fresh link's counters: {:?}",
        h.link
    );
    drop(g);
    let report = server.finish();
    assert_eq!(report.resets, 1);
}

#[test]
fn gse_command_prints_json_and_exits_by_error_kind() {
    let server = Server::start(0.0);
    let args = |command| GseArgs {
        port: server.port,
        timeout_s: 60.0,
        command,
    };
    let mut out = Vec::new();
    gse::run(&args(GseCommand::Status), &mut out).expect("status");
    let v: serde_json::Value = serde_json::from_slice(&out).expect("JSON");
    assert!(
        v["mode"].is_string() && v["link"]["accepted"].as_u64() >= Some(1),
        "{v}"
    );

    let e = gse::run(
        &args(GseCommand::Mode {
            mode: "sleep".into(),
        }),
        &mut Vec::new(),
    )
    .expect_err("unknown mode");
    assert_eq!(e.exit_code(), 1, "{e}");

    let mut csv = Vec::new();
    gse::run(
        &args(GseCommand::Stars {
            frames: 1,
            out: None,
        }),
        &mut csv,
    )
    .expect("stars");
    let csv = String::from_utf8(csv).expect("utf-8");
    assert!(csv.starts_with(
        "frame,mode,x_px,y_px,flux_e,snr,sigma_x_px,sigma_y_px,flags,provenance,psf_a_px,chi2_dof\n"
    ));

    // The SIL's table lists every defect of its sensor: nothing to commit, the tracker says
    // why (rejection 12, NothingToAdd), and housekeeping shows no pending defect.
    let e =
        gse::run(&args(GseCommand::CommitDefects), &mut Vec::new()).expect_err("nothing to commit");
    assert!(
        e.to_string().contains("in-flight defects not committed"),
        "{e}"
    );
    assert_eq!(v["defects_pending"].as_u64(), Some(0), "{v}");

    let port = server.port;
    let _ = server.finish();
    // Nobody listening any more: a link error, exit code 3, one line.
    let e = gse::run(
        &GseArgs {
            port,
            timeout_s: 2.0,
            command: GseCommand::Ping,
        },
        &mut Vec::new(),
    )
    .expect_err("no server");
    assert_eq!(e.exit_code(), 3, "{e}");
    assert!(!e.to_string().contains('\n'));
}

#[test]
fn a_noisy_link_loses_commands_never_the_tracker() {
    // One received byte in 5,000 has a bit flipped: a 1 KB chunk arrives corrupted about
    // one time in five.
    let server = Server::start(2e-4);
    // A lost command is sent again after 5 s (a share of the 30 s timeout).
    let mut g = Ground::connect(server.port, Duration::from_secs(30)).expect("connect");
    g.retries = 5;
    for _ in 0..20 {
        g.ping().expect("ping through noise");
    }
    let table = tiled_table();
    let info = g
        .upload_table(&table, 1024, 8)
        .expect("upload through noise");
    assert_eq!(info.len_bytes as usize, table.len());
    assert_eq!(
        info.crc32,
        startrack_sim::flash_model::CRC32.checksum(&table),
        "the table in force is the one sent, byte for byte"
    );
    let h = g.status().expect("status");
    let l = h.link;
    assert!(
        g.resumes > 0 && l.crc_errors + l.framing_errors > 0,
        "noise seen: {l:?}"
    );
    // Every decoded packet got one verification; the corrupted ones were rejected.
    assert_eq!(l.accepted + l.rejected, l.packets, "{l:?}");
    assert!(l.rejected >= l.crc_errors, "{l:?}");
    let _ = server.finish();
}

/// Over a sky scene the served SIL runs the attitude stage after every frame, as the board
/// does: the ground reads one report a frame, each within 5 of its own sigmas of the truth on
/// every axis; a truncated or garbled report is an error, never misread. After the ground's
/// time-set command the reports are on spacecraft time from the next sync pulse: the set
/// time plus the counter since that pulse, within the stated bound.
#[test]
fn ground_reads_the_attitude_reports_of_the_sil_over_the_sky() {
    use rand::SeedableRng;
    use startrack_core::link::protocol as p;
    use startrack_core::link::telemetry::ATTITUDE_LEN;
    use startrack_core::link::telemetry::Validity;
    use startrack_core::time::Cuc;
    use startrack_ground::{AttitudeDecodeError, decode_attitude};
    use startrack_sim::sky::field::{FieldSpec, random_attitude};
    use startrack_sim::sky::scene::SkyScene;

    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let q0 = random_attitude(&mut rng);
    let f = FieldSpec::ccd47_15deg(0.0).camera.focal_length_px;
    let scene = SkyScene::ccd47_15deg(q0, [0.2 / f, 0.3 / f, 1e-5]);
    let server = Server::start_with(
        SilConfig {
            sky: Some(scene),
            ..SilConfig::default()
        },
        0.0,
    );
    let mut g = Ground::connect(server.port, Duration::from_secs(60)).expect("connect");
    let before = g.attitude(1).expect("attitude report");
    assert!(
        before[0].flags.contains(Validity::TIME_NOT_SYNCHRONISED) && before[0].time.is_none(),
        "{before:?}"
    );
    // The next pulse is at 2,200,000,000 s. The SIL's pulses fall at counter 0.75 s + k s
    // (its spacecraft epoch is SIL_EPOCH_US, a quarter past a second).
    let set_s = 2_200_000_000u32;
    g.set_time(Cuc {
        coarse_s: set_s,
        fine: 0,
    })
    .expect("time-set accepted");
    // A malformed time code is refused with its reason.
    match g.command("time-set", p::TC_TIME_SET, &[0x2E, 0, 0, 0, 1, 0, 0]) {
        Err(GroundError::Rejected {
            code, parameter, ..
        }) => assert_eq!((code, parameter), (13, 0x2E)),
        other => panic!("time-set with P-field 0x2E: {other:?}"),
    }
    let mut synced = Vec::new();
    for r in g.attitude(30).expect("attitude reports") {
        if let Some(t) = r.time {
            synced.push((r, t));
        }
    }
    assert!(
        synced.len() >= 10,
        "{} reports on spacecraft time",
        synced.len()
    );
    for (r, t) in &synced {
        assert!(!r.flags.contains(Validity::TIME_NOT_SYNCHRONISED));
        assert!(r.flags.contains(Validity::NO_VELOCITY));
        // The counter of the set pulse: the last 0.75 s + k s before the report's.
        let since_pulse_s = t.cuc.to_seconds() - f64::from(set_s);
        let counter_s = r.mid_exposure_us as f64 * 1e-6;
        let frac = (counter_s - since_pulse_s - 0.75).rem_euclid(1.0);
        let off_us = frac.min(1.0 - frac) * 1e6;
        assert!(
            off_us <= f64::from(t.error_bound_us),
            "frame {}: {off_us} us off, bound {} us",
            r.frame,
            t.error_bound_us
        );
    }
    let reports: Vec<_> = synced.iter().map(|(r, _)| *r).take(4).collect();
    assert_eq!(reports.len(), 4);
    for w in reports.windows(2) {
        assert!(w[1].frame > w[0].frame, "frames increase: {reports:?}");
    }
    for r in &reports {
        let fix = r.fix.as_ref().expect("every frame of the sky solves");
        let e = fix.attitude.q.error_vector(scene.attitude(r.frame));
        for (i, v) in e.iter().enumerate() {
            let sigma = fix.attitude.cov_rad2[i][i].sqrt();
            assert!(
                sigma > 0.0 && v.abs() < 5.0 * sigma,
                "frame {}: axis {i} error {v:e} rad, sigma {sigma:e}",
                r.frame
            );
        }
        assert!(fix.matched >= 10, "frame {}: {fix:?}", r.frame);
    }

    // The ground tool prints them (the link takes one ground station at a time): a header
    // and one row a frame, each with its attitude.
    drop(g);
    let mut csv = Vec::new();
    gse::run(
        &GseArgs {
            port: server.port,
            timeout_s: 60.0,
            command: GseCommand::Attitude { frames: 2 },
        },
        &mut csv,
    )
    .expect("gse attitude");
    // The velocity command (this scene is at rest against the stars: zero) makes the
    // attitude of the ICRF: the apparent flag goes; a speed beyond the limit is rejected.
    let gse_run = |command| {
        gse::run(
            &GseArgs {
                port: server.port,
                timeout_s: 60.0,
                command,
            },
            &mut Vec::new(),
        )
    };
    let too_fast = gse_run(GseCommand::Velocity {
        km_s: vec![400.0, 0.0, 0.0],
        at: f64::from(set_s),
    });
    assert_eq!(too_fast.map_err(|e| e.exit_code()), Err(2));
    gse_run(GseCommand::Velocity {
        km_s: vec![0.0, 0.0, 0.0],
        at: f64::from(set_s),
    })
    .expect("gse velocity");
    let mut g = Ground::connect(server.port, Duration::from_secs(60)).expect("connect");
    for r in g.attitude(2).expect("attitude reports") {
        assert!(r.flags.is_empty(), "{r:?}");
    }
    drop(g);
    let _ = server.finish();
    let csv = String::from_utf8(csv).expect("utf-8");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 3, "{csv}");
    assert_eq!(lines[0], gse::ATTITUDE_CSV_HEADER);
    for row in &lines[1..] {
        let cols: Vec<&str> = row.split(',').collect();
        assert_eq!(cols.len(), 21, "{row}");
        assert!(cols[11].parse::<f64>().expect("t_mid_s") >= 2.2e9, "{row}");
        assert_eq!(cols[14], "no_velocity", "{row}");
        let w: Vec<f64> = cols[15..18]
            .iter()
            .map(|c| c.parse().expect("rate"))
            .collect();
        // The scene turns by (0.2 / f, 0.3 / f, 1e-5) rad a frame of 0.1 s: 0.029, 0.044 deg/s.
        assert!(
            (w[0] - 0.0295).abs() < 1e-3 && (w[1] - 0.0442).abs() < 1e-3,
            "{row}"
        );
        assert!(matches!(cols[1], "tracking" | "lost_in_space"), "{row}");
        let q: Vec<f64> = cols[4..8].iter().map(|c| c.parse().expect("q")).collect();
        let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-6, "{row}");
    }

    // A report cut short, or with a status the protocol lacks, does not decode.
    let mut bytes = [0u8; ATTITUDE_LEN];
    let n = reports[0].encode(&mut bytes).expect("encodes");
    assert_eq!(n, ATTITUDE_LEN);
    assert_eq!(decode_attitude(&bytes), Ok(reports[0]));
    assert_eq!(
        decode_attitude(&bytes[..ATTITUDE_LEN - 1]),
        Err(AttitudeDecodeError::Length {
            got: ATTITUDE_LEN - 1
        })
    );
    bytes[7] = 0;
    assert_eq!(decode_attitude(&bytes), Err(AttitudeDecodeError::Format(0)));
    bytes[7] = 2;
    bytes[4] = 9;
    assert_eq!(decode_attitude(&bytes), Err(AttitudeDecodeError::Status(9)));
}
