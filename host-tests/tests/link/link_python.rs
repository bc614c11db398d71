//! The tracker's telemetry decoded by an independent client: the PyPI `spacepackets` package
//! (`link_python.py`), so the packets are standard PUS-C and not only self-consistent.
//! Skipped, with the reason printed, when python3 or its `spacepackets` is missing
//! (`.ci/run` installs it).

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::framing::{Deframer, Pushed, encoded_len_max};
use startrack_core::link::protocol as p;
use startrack_core::link::{LinkService, NoWindows, Targets};
use startrack_core::tracker::{
    Event, FrameSummary, Mode, ModeReason, Provenance, StarFlags, StarRecord, TelemetrySink,
    Tracker, TrackerBuffers, TrackerConfig,
};
use startrack_ground::{decode_tm, frame_telecommand};
use startrack_homes::memory_tables::MemoryTables;
use std::process::Command;

fn python_ready() -> Result<(), String> {
    let out = Command::new("python3")
        .args(["-c", "import spacepackets"])
        .output()
        .map_err(|e| format!("python3 not runnable: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "python3 has no spacepackets ({}): pip install spacepackets",
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

fn summary(frame: u32, stars: u16) -> FrameSummary {
    FrameSummary {
        next_mode: Mode::Tracking,
        calibrated: true,
        lines: 1033,
        stars,
        centroids: stars,
        ..FrameSummary::empty(frame, Mode::Acquisition, 0)
    }
}

#[test]
fn spacepackets_decodes_the_telemetry() {
    if let Err(why) = python_ready() {
        println!("skipped: {why}");
        return;
    }
    // Telemetry of every kind: a star list, an attitude, events, housekeeping, verification,
    // pong.
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker = Box::new(
        Tracker::<32>::new(
            TrackerConfig::FLIGHT,
            ReadoutGeometry::CCD47_20_DUAL,
            &mut buffers,
        )
        .expect("tracker"),
    );
    let mut tables = MemoryTables::new(ReadoutGeometry::CCD47_20_DUAL, None);
    let mut link = Box::new(LinkService::new());
    link.set_time(123_456_789);
    let stars: Vec<StarRecord> = (0..5)
        .map(|k| StarRecord {
            x_px: 10.25 + k as f32 * 100.0,
            y_px: 500.5 - k as f32,
            flux_e: 12_345.0 * (k + 1) as f32,
            snr: 40.0 + k as f32,
            sigma_x_px: 0.01,
            sigma_y_px: 0.02,
            cov_xy_px2: 0.0,
            flags: StarFlags::from_bits_retain(1 << k),
            provenance: Provenance::from_bits_retain(k as u8 & 3),
            psf_a_px: 1.25 + k as f32 * 0.1,
            chi2_dof: 0.97 + k as f32 * 0.01,
        })
        .collect();
    for s in &stars {
        link.star(7, s);
    }
    link.frame(&summary(7, 5));
    link.event(&Event::ModeChange {
        frame: 8,
        from: Mode::Acquisition,
        to: Mode::Tracking,
        reason: ModeReason::Acquired,
    });
    let fix = startrack_core::solver::Fix {
        attitude: startrack_core::attitude::Attitude {
            q: startrack_core::attitude::Quat([0.5, -0.5, 0.5, 0.5]),
            cov_rad2: [
                [1e-12, 2e-14, 0.0],
                [2e-14, 1.5e-12, 0.0],
                [0.0, 0.0, 3e-11],
            ],
        },
        mode: startrack_core::solver::SolveMode::Tracking,
        used: 30,
        matched: 28,
        false_probability: 1e-40,
        time_us: 987_654,
    };
    let report = startrack_core::link::telemetry::AttitudeReport {
        frame: 7,
        fix: Ok(fix),
        flags: startrack_core::link::telemetry::Validity::NO_VELOCITY,
        mid_exposure_us: fix.time_us,
        time: Some(startrack_core::time::SpacecraftTime {
            cuc: startrack_core::time::Cuc {
                coarse_s: 2_100_000_123,
                fine: 0x8001,
            },
            error_bound_us: 15,
        }),
        latency_us: 612_345,
        rate: Some(startrack_core::attitude::Rate {
            w_rad_s: [0.0175, -0.00125, 1e-4],
            cov_rad2_s2: [[4e-10, 0.0, 0.0], [0.0, 5e-10, 0.0], [0.0, 0.0, 9e-9]],
        }),
    };
    link.send_attitude(&report);
    let mut cmds = Vec::new();
    for (seq, kind) in [p::TC_PING, p::TC_HOUSEKEEPING].into_iter().enumerate() {
        cmds.extend(frame_telecommand(kind, &[], seq as u16).0);
    }
    cmds.extend(frame_telecommand(p::TC_SET_MODE, &[9], 2).0);
    link.receive(
        &cmds,
        &mut Targets {
            tracker: &mut tracker,
            tables: &mut tables,
            windows: &mut NoWindows,
        },
    );
    let mut out = vec![0u8; 1 << 16];
    let n = link.transmit(&mut out);
    let mut de = Box::new(Deframer::<{ encoded_len_max(p::MAX_TM_LEN) }>::new());
    let mut hex = String::new();
    let mut expected = Vec::new();
    for &b in &out[..n] {
        let Pushed::Packet(len) = de.push(b) else {
            continue;
        };
        let raw = de.packet(len);
        let t = decode_tm(raw).expect("decodes in Rust");
        hex.push_str(&raw.iter().map(|b| format!("{b:02x}")).collect::<String>());
        hex.push('\n');
        let mut e = serde_json::json!({
            "apid": t.apid, "service": t.kind.service, "subtype": t.kind.subtype,
            "time_us": t.time_us,
            "data": t.data.iter().map(|b| format!("{b:02x}")).collect::<String>(),
        });
        if t.kind == p::TM_STARS {
            e["frame"] = 7.into();
            e["mode"] = 1.into();
            e["stars"] = stars
                .iter()
                .map(|s| {
                    serde_json::json!([
                        s.x_px,
                        s.y_px,
                        s.flux_e,
                        s.snr,
                        s.sigma_x_px,
                        s.sigma_y_px,
                        s.flags.bits(),
                        s.provenance.bits(),
                        s.psf_a_px,
                        s.chi2_dof
                    ])
                })
                .collect();
        }
        if t.kind == p::TM_ATTITUDE {
            e["attitude"] = serde_json::json!({
                "frame": 7, "status": 2, "used": 30, "matched": 28,
                "q": fix.attitude.q.0, "cov_zz": 3e-11, "time_us": fix.time_us,
                "format": 2, "flags": 2, "coarse": 2_100_000_123u32, "fine": 0x8001,
                "bound_us": 15, "latency_us": 612_345, "w": [0.0175, -0.00125, 1e-4],
                "rate_cov_zz": 9e-9,
            });
        }
        if t.kind == p::TM_HOUSEKEEPING {
            e["housekeeping"] = true.into();
            e["mode"] = 1.into();
            e["next_mode"] = 2.into();
        }
        expected.push(e);
    }
    let kinds: Vec<_> = expected
        .iter()
        .map(|e| (e["service"].as_u64(), e["subtype"].as_u64()))
        .collect();
    for want in [
        (131, 2),
        (5, 1),
        (1, 1),
        (17, 2),
        (3, 25),
        (1, 2),
        (5, 2),
        (134, 2),
    ] {
        assert!(
            kinds.contains(&(Some(want.0), Some(want.1))),
            "TM[{},{}] in {kinds:?}",
            want.0,
            want.1
        );
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let pk = dir.path().join("packets.hex");
    let ex = dir.path().join("expected.json");
    std::fs::write(&pk, hex).expect("write");
    std::fs::write(&ex, serde_json::to_string(&expected).expect("json")).expect("write");
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/link/link_python.py");
    let out = Command::new("python3")
        .arg(script)
        .arg(&pk)
        .arg(&ex)
        .output()
        .expect("python3 runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{}", stdout.trim());
    assert_eq!(
        stdout.trim(),
        format!("spacepackets decoded {} packets", expected.len())
    );
}
