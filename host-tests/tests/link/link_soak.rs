//! A SIL soak over the link: seeded random commands (pings, modes, star lists, parameters,
//! table uploads, resets) through a noisy link, checking after each step that the tracker
//! answers, that a table stays in force and only changes by a committed upload, and that the
//! counters agree. Some steps send nothing for a while, so frames run between commands.
//! `LINK_SOAK_STEPS` sets the length (default 12) and `LINK_SOAK_MIN_FRAMES` keeps it going
//! past the steps until the SIL has run that many frames (the long run:
//! `LINK_SOAK_STEPS=2000 LINK_SOAK_MIN_FRAMES=10000 LINK_SOAK_QUIET_MS=8000 cargo test
//! --release -p startrack-host --test link link_soak::random_commands -- --nocapture`; longer
//! quiet spells make the frames many beside the commands).
//!
//! The second soak keeps the tables in the flash store over the flash model in a file, and
//! every boot arms a power cut at a random flash step: an upload it hits stops the SIL, which
//! is restarted with the same file (a reboot); the table in force must then be the last one
//! committed (or the one whose upload was cut, had its header been written), and the next
//! upload succeeds. Resets remount the store. `LINK_SOAK_STEPS` sets its length too (the
//! long run: `LINK_SOAK_STEPS=2000 LINK_SOAK_MIN_FRAMES=10000 cargo test --release -p
//! startrack-host --test link link_soak::flash -- --nocapture`, which keeps going past the steps
//! until the SIL has run 10,000 frames).

use rand::{RngExt, SeedableRng};
use startrack_core::link::protocol as p;
use startrack_core::tracker::Mode;
use startrack_ground::{Ground, GroundError};
use startrack_homes::link_home::{FlashConfig, ServeConfig, ServeReport, serve};
use startrack_homes::sil::SilConfig;
use startrack_sim::flash_model::CRC32;
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// `name` from the environment, or `default`.
fn env_u32(name: &str, default: u32) -> u32 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// A quiet spell of the ground: nothing sent for up to `LINK_SOAK_QUIET_MS` (default 2,000
/// ms), so the SIL runs frames.
fn quiet(rng: &mut rand_chacha::ChaCha8Rng) {
    let max_ms = env_u32("LINK_SOAK_QUIET_MS", 2000).max(1);
    std::thread::sleep(Duration::from_millis(
        rng.random_range(0..u64::from(max_ms)),
    ));
}

/// Frames run since the last call, from the frame number a status reports (reset to 0 by a
/// reset: counts none of the frames lost between the last status and the reset, so a total
/// of these is at most the frames run).
fn frames_since(last: &mut u32, frame: u32) -> u32 {
    let ran = if frame >= *last { frame - *last } else { frame };
    *last = frame;
    ran
}

#[test]
fn random_commands_through_noise_keep_the_tracker_consistent() {
    let steps = env_u32("LINK_SOAK_STEPS", 12);
    let min_frames = env_u32("LINK_SOAK_MIN_FRAMES", 0);
    let Boot {
        server,
        stop,
        ground: mut g,
    } = boot(None, Duration::from_secs(30));

    let tables: Vec<Vec<u8>> = [3u8, 4]
        .iter()
        .map(|&tile| {
            Simulator::new(SensorParams::default(), Vec::new())
                .truth_table_tiled(TruthSections::ALL, tile)
                .expect("table")
        })
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
    let mut in_force = g.status().expect("status").table.expect("boot table");
    let mut resets = 0;
    let (mut step, mut frames, mut last_frame) = (0u32, 0u32, 0u32);
    while step < steps || frames < min_frames {
        step += 1;
        match rng.random_range(0..12) {
            0 => {
                g.reset().expect("reset");
                resets += 1;
            }
            1 => {
                let t = &tables[rng.random_range(0..tables.len())];
                let info = g.upload_table(t, 1024, 8).expect("upload");
                assert_eq!(info.crc32, CRC32.checksum(t));
                assert!(info.sequence > in_force.sequence || in_force.sequence == 0);
                in_force = info;
            }
            2 | 3 => {
                let m = [Mode::Standby, Mode::Acquisition, Mode::Tracking][rng.random_range(0..3)];
                match g.set_mode(m) {
                    Ok(()) => {}
                    Err(GroundError::Rejected { code: 7, .. }) => assert_eq!(m, Mode::Tracking),
                    Err(e) => panic!("step {step}: mode {m:?}: {e}"),
                }
            }
            4 => {
                // A parameter, valid or not: accepted, or refused with a typed reason.
                let v: u32 = rng.random_range(0..40);
                let mut d = vec![7u8];
                d.extend_from_slice(&v.to_be_bytes());
                match g.command("set-params", p::TC_SET_PARAMS, &d) {
                    Ok(_) => assert!((1..=32).contains(&v), "max_stars {v} accepted"),
                    Err(GroundError::Rejected { code: 8, .. }) => {
                        assert!(!(1..=32).contains(&v))
                    }
                    Err(e) => panic!("step {step}: set-params: {e}"),
                }
            }
            5 | 6 => {
                let lists = g.stars(1).expect("stars");
                assert_eq!(lists.len(), 1);
            }
            10 | 11 => quiet(&mut rng),
            _ => g.ping().expect("ping"),
        }
        let h = g.status().expect("status");
        let l = h.link;
        assert_eq!(l.accepted + l.rejected, l.packets, "step {step}: {l:?}");
        assert_eq!(h.table, Some(in_force), "step {step}: the table in force");
        assert!(h.totals.frames <= h.frame + 1, "step {step}: {h:?}");
        frames += frames_since(&mut last_frame, h.frame);
        if step % 100 == 0 {
            eprintln!("soak: step {step}, about {frames} frames, {resets} resets");
        }
    }
    stop.store(true, Ordering::Relaxed);
    let report = server.join().expect("server").expect("served");
    // A reset whose acceptance came late is sent again: at least the commanded ones.
    assert!(report.resets >= resets, "{report:?}");
    println!(
        "{step} steps, {} frames, {resets} resets, {} resumed uploads",
        report.frames, g.resumes
    );
}

/// A SIL served in a thread and the ground connected to it.
struct Boot {
    server: std::thread::JoinHandle<Result<ServeReport, String>>,
    stop: Arc<AtomicBool>,
    ground: Ground,
}

/// [`boot`] on the flash file `flash`, a power cut armed at flash step `cut_at`.
fn boot_flash(flash: &std::path::Path, cut_at: u64) -> Boot {
    boot(
        Some(FlashConfig {
            path: flash.to_path_buf(),
            power_cut_at_write: Some(cut_at),
        }),
        Duration::from_secs(10),
    )
}

/// Serves the SIL in a thread (tables in memory, or in the flash store with a power cut
/// armed) and connects the ground to it.
fn boot(flash: Option<FlashConfig>, timeout: Duration) -> Boot {
    let stop = Arc::new(AtomicBool::new(false));
    let config = ServeConfig {
        sil: SilConfig {
            stars: 6,
            ..SilConfig::default()
        },
        port: 0,
        link_noise: 1e-4,
        max_frames: None,
        stop: Some(stop.clone()),
        flash,
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let server = std::thread::spawn(move || {
        serve(&config, &mut |p| {
            let _ = tx.send(p);
        })
    });
    let port = rx.recv_timeout(Duration::from_secs(60)).expect("port");
    let mut ground = Ground::connect(port, timeout).expect("connect");
    ground.retries = 5;
    Boot {
        server,
        stop,
        ground,
    }
}

#[test]
fn flash_store_soak_with_power_cuts_keeps_a_committed_table() {
    let steps = env_u32("LINK_SOAK_STEPS", 12);
    let min_frames = env_u32("LINK_SOAK_MIN_FRAMES", 0);
    let dir = tempfile::tempdir().expect("tmp");
    let flash = dir.path().join("bank2.flash");
    let tables: Vec<Vec<u8>> = [3u8, 4]
        .iter()
        .map(|&tile| {
            Simulator::new(SensorParams::default(), Vec::new())
                .truth_table_tiled(TruthSections::ALL, tile)
                .expect("table")
        })
        .collect();
    // Flash steps of one upload of the larger table: 2 erases, its units, the header.
    let upload_steps = 2 + tables[0].len().div_ceil(32) as u64 + 1;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
    let mut b = boot_flash(&flash, rng.random_range(1..=2 * upload_steps));
    let mut in_force = b
        .ground
        .status()
        .expect("status")
        .table
        .expect("boot table");
    let (mut cuts, mut uploads, mut resets, mut frames, mut step) = (0, 0, 0u32, 0u32, 0u32);
    // Frames seen through the statuses (resets and reboots restart the frame number), for
    // `min_frames`; `frames` counts every boot's frames from the servers' reports.
    let (mut seen, mut last_frame) = (0u32, 0u32);
    while step < steps || seen < min_frames {
        step += 1;
        match rng.random_range(0..7) {
            0 => {
                b.ground.reset().expect("reset");
                resets += 1;
            }
            1..=3 => {
                let t = &tables[rng.random_range(0..tables.len())];
                match b.ground.upload_table(t, 1024, 8) {
                    Ok(info) => {
                        assert_eq!(info.crc32, CRC32.checksum(t));
                        assert!(info.sequence > in_force.sequence, "step {step}");
                        in_force = info;
                        uploads += 1;
                    }
                    Err(e) => {
                        // Only a power cut may stop an upload here.
                        let report = b.server.join().expect("server").expect("served");
                        assert!(report.power_cut, "step {step}: upload failed: {e}");
                        frames += report.frames;
                        cuts += 1;
                        b = boot_flash(&flash, rng.random_range(1..=2 * upload_steps));
                        last_frame = 0;
                        let now = b.ground.status().expect("status after reboot").table;
                        let now = now.expect("a table in force after the cut");
                        let cut_one = (now.len_bytes as usize, now.crc32)
                            == (t.len(), CRC32.checksum(t))
                            && now.sequence > in_force.sequence;
                        assert!(now == in_force || cut_one, "step {step}: {now:?}");
                        in_force = now;
                    }
                }
            }
            4 => {
                let lists = b.ground.stars(1).expect("stars");
                assert_eq!(lists.len(), 1);
            }
            5 => quiet(&mut rng),
            _ => b.ground.ping().expect("ping"),
        }
        let h = b.ground.status().expect("status");
        let l = h.link;
        assert_eq!(l.accepted + l.rejected, l.packets, "step {step}: {l:?}");
        assert_eq!(h.table, Some(in_force), "step {step}: the table in force");
        seen += frames_since(&mut last_frame, h.frame);
        if step % 100 == 0 {
            // Progress of a long run.
            eprintln!(
                "flash soak: step {step}, {uploads} uploads, {cuts} cuts, about {seen} frames"
            );
        }
    }
    b.stop.store(true, Ordering::Relaxed);
    let report = b.server.join().expect("server").expect("served");
    frames += report.frames;
    println!(
        "flash soak: {step} steps, {frames} frames, {uploads} uploads, {cuts} power cuts, {resets} resets"
    );
    assert!(cuts + uploads > 0, "no upload ran");
}
