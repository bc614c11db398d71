//! In-flight defects into a table update (`TC[133,7]`): the watch confirms unlisted hot
//! pixels in simulated tracking frames, the command writes the table in force with them
//! added into the flash store's inactive slot through the upload path, and after a reboot
//! the table in force lists them and a fresh tracker's overlay is empty. A power cut at any
//! flash step of the commit leaves the old table or the new one in force, never another.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::protocol::{self as p, TABLE_KIND_CALIBRATION};
use startrack_core::link::telemetry::event;
use startrack_core::link::{
    LinkService, NoWindows, Rejection, TableUpload, Targets, UploadRefusal,
};
use startrack_core::table::{AmendError, CalibTable, HotPolicy};
use startrack_core::tracker::{
    FixedTemperature, Mode, Ports, TableStore, Tracker, TrackerBuffers, TrackerConfig,
};
use startrack_ground::{decode_tm, frame_telecommand};
use startrack_homes::flash_home::{FLASH_TILE_LOG2, FlashHome};
use startrack_homes::home::{FrameClock, SimLines, block_on};
use startrack_homes::sil::stars_at;
use startrack_sim::sim::effects::{Effects, HotPixels};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator, Star};
use std::collections::HashSet;
use std::path::PathBuf;

/// The CCD47-20's lines (the acquisition ring takes whole 1072-element lines), 128 rows
/// only, to keep the run short.
const GEOMETRY: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 8,
    covered_px: 16,
    active_cols: 1024,
    active_rows: 128,
    lines: 130,
    outputs: 2,
};

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("startrack-defect-commit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    let _ = std::fs::remove_file(&p);
    p
}

/// Sends telecommand `kind` to `link` and returns what it answered (decoded TM packets).
fn command<const N: usize>(
    link: &mut LinkService,
    tracker: &mut Tracker<'static, '_, N>,
    tables: &mut dyn TableUpload,
    kind: p::MessageType,
    seq: u16,
) {
    let (bytes, _) = frame_telecommand(kind, &[], seq);
    let mut windows = NoWindows;
    link.receive(
        &bytes,
        &mut Targets {
            tracker,
            tables,
            windows: &mut windows,
        },
    );
}

/// Every TM packet `link` has queued, decoded: (service, subtype, data).
fn drain(link: &mut LinkService) -> Vec<(u8, u8, Vec<u8>)> {
    let mut bytes = vec![0u8; 1 << 16];
    let n = link.transmit(&mut bytes);
    bytes[..n]
        .split(|&b| b == 0)
        .filter(|f| !f.is_empty())
        .filter_map(|f| {
            let mut pkt = f.to_vec();
            let m = cobs::decode_in_place(&mut pkt).ok()?;
            let t = decode_tm(&pkt[..m])?;
            Some((t.kind.service, t.kind.subtype, t.data))
        })
        .collect()
}

/// The event numbers among `tms`.
fn events(tms: &[(u8, u8, Vec<u8>)]) -> Vec<u16> {
    tms.iter()
        .filter(|(s, _, _)| *s == 5)
        .map(|(_, _, d)| u16::from_be_bytes([d[0], d[1]]))
        .collect()
}

/// The store while out of reach: busy, nothing readable.
struct Held;

impl TableUpload for Held {
    fn begin(&mut self, _: u8, _: u32, _: u32) -> Result<(), UploadRefusal> {
        Err(UploadRefusal::Busy)
    }
    fn chunk(&mut self, _: u32, _: &[u8]) -> Result<(), UploadRefusal> {
        Err(UploadRefusal::Busy)
    }
    fn commit(&mut self) -> Result<startrack_core::link::TableInfo, UploadRefusal> {
        Err(UploadRefusal::Busy)
    }
    fn abort(&mut self) {
        panic!("the commit was given up");
    }
    fn active(&self, _: u8) -> Option<startrack_core::link::TableInfo> {
        None
    }
}

/// The run: a sensor with 1 % hot pixels (1,000 to 3,000 e- in 1 s) whose table lists
/// none, 12 stars drifting (0.3, -0.2) px a frame, tracked until the watch has confirmed
/// some; the flash holds the table (a fresh bank, the table uploaded at bring-up).
struct Run {
    params: SensorParams,
    table: Vec<u8>,
    hot_truth: HashSet<(u16, u16)>,
}

fn setup() -> Run {
    let plain = SensorParams {
        seed: 11,
        geometry: GEOMETRY,
        ..SensorParams::default()
    };
    let params = SensorParams {
        effects: Effects {
            temperature_k: 293.0,
            hot: Some(HotPixels {
                fraction: 0.01,
                rate_min_e_per_s: 1000.0,
                rate_max_e_per_s: 3_000.0,
                reference_k: 293.0,
                doubling_k: 9.0,
                exposure_s: 1.0,
            }),
            ..Effects::default()
        },
        ..plain.clone()
    };
    let hot_truth = Simulator::new(params.clone(), Vec::new())
        .hot_pixels_truth()
        .iter()
        .map(|h| (h.x, h.y))
        .collect();
    // In its flash form (8 x 8 px tiles), as the SIL's flash store holds it.
    let table = Simulator::new(plain, Vec::new())
        .truth_table_tiled(TruthSections::ALL, FLASH_TILE_LOG2)
        .unwrap();
    Run {
        params,
        table,
        hot_truth,
    }
}

/// Runs `frames` frames with the table `home` has in force; the link is the telemetry port.
fn frames<const N: usize>(
    run: &Run,
    tracker: &mut Tracker<'static, '_, N>,
    home: &mut FlashHome,
    link: &mut LinkService,
    frames: std::ops::Range<u32>,
) {
    // A 4 x 3 grid of stars, 20,000 to 42,000 e-, 250 px apart across and 25 px down,
    // drifting (0.3, -0.2) px a frame: over 60 frames they stay 8 px or more inside the area.
    let base: Vec<Star> = (0..12)
        .map(|i| Star {
            x_px: 100.3 + 250.0 * f64::from(i % 4),
            y_px: 42.6 + 25.0 * f64::from(i / 4),
            signal_e: 20_000.0 + 2_000.0 * f64::from(i),
            a_px: 1.2,
        })
        .collect();
    let mut source = SimLines::new(|frame| Simulator {
        frame,
        ..Simulator::new(run.params.clone(), stars_at(&base, (0.3, -0.2), frame))
    });
    let mut thermometer = FixedTemperature(None);
    for k in frames {
        let mut clock = FrameClock {
            frame: k,
            period_us: 100_000,
        };
        let mut table = startrack_core::tracker::FixedTable(home.active_table());
        let mut ports = Ports {
            clock: &mut clock,
            thermometer: &mut thermometer,
            tables: &mut table,
            telemetry: &mut *link,
        };
        let Ok(s) = block_on(tracker.run_frame(&mut source, &mut ports));
        if std::env::var_os("DEFECT_COMMIT_TRACE").is_some() {
            println!(
                "frame {}: {:?}, {} centroids, {} windows, {} candidates, {} confirmed",
                s.frame,
                s.mode,
                s.centroids,
                s.track_windows,
                tracker.defect_watch().candidates().len(),
                tracker.new_defects().len()
            );
        }
    }
}

#[test]
fn confirmed_defects_go_into_the_table_and_survive_a_reboot() {
    let run = setup();
    let path = tmp("flash.bin");
    let mut home = FlashHome::open(&path, GEOMETRY, Some(&run.table)).unwrap();
    let old = home.active(TABLE_KIND_CALIBRATION).unwrap();
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker =
        Box::new(Tracker::<32>::new(TrackerConfig::FLIGHT, GEOMETRY, &mut buffers).unwrap());
    let mut link = Box::new(LinkService::new());

    // Nothing confirmed yet: nothing to commit.
    command(
        &mut link,
        &mut tracker,
        &mut home,
        p::TC_TABLE_COMMIT_DEFECTS,
        1,
    );
    let tms = drain(&mut link);
    let rejected = tms.iter().find(|t| (t.0, t.1) == (1, 2)).expect("rejected");
    assert_eq!(
        u16::from_be_bytes([rejected.2[4], rejected.2[5]]),
        Rejection::Amend(AmendError::NothingToAdd).code()
    );

    frames(&run, &mut tracker, &mut home, &mut link, 0..40);
    let confirmed: Vec<(u16, u16)> = tracker
        .new_defects()
        .iter()
        .map(|d| (d.x_px, d.y_px))
        .collect();
    println!("confirmed in flight: {confirmed:?}");
    assert!(!confirmed.is_empty(), "the watch confirmed nothing");
    assert!(confirmed.iter().all(|p| run.hot_truth.contains(p)));
    let pending = tracker.new_defects().len();
    drain(&mut link);

    // The command; the erase is the owner's step between link rounds.
    let steps0 = home.steps();
    command(
        &mut link,
        &mut tracker,
        &mut home,
        p::TC_TABLE_COMMIT_DEFECTS,
        2,
    );
    // An upload from the ground meanwhile is refused busy.
    command(&mut link, &mut tracker, &mut home, p::TC_TABLE_ABORT, 3);
    // Rounds in which the store is out of reach (the board's erase task holds it: every
    // call busy, nothing readable) leave the commit waiting.
    for _ in 0..3 {
        let mut windows = NoWindows;
        link.poll(&mut Targets {
            tracker: &mut *tracker,
            tables: &mut Held,
            windows: &mut windows,
        });
        assert!(link.defect_commit_pending());
    }
    let mut rounds = 0;
    while link.defect_commit_pending() {
        home.service().unwrap();
        let mut windows = NoWindows;
        link.poll(&mut Targets {
            tracker: &mut *tracker,
            tables: &mut home,
            windows: &mut windows,
        });
        rounds += 1;
        assert!(rounds < 1000);
    }
    let tms = drain(&mut link);
    let ev = events(&tms);
    assert!(ev.contains(&event::DEFECTS_COMMITTED), "{ev:?}");
    assert!(!ev.contains(&event::TABLE_REFUSED), "{ev:?}");
    let busy = tms.iter().filter(|t| (t.0, t.1) == (1, 2)).count();
    assert_eq!(
        busy, 1,
        "the ground's abort is refused while the commit runs"
    );
    let new = home.active(TABLE_KIND_CALIBRATION).unwrap();
    println!(
        "table {} -> {} B, sequence {} -> {}, {} flash steps, {rounds} link rounds",
        old.len_bytes,
        new.len_bytes,
        old.sequence,
        new.sequence,
        home.steps() - steps0
    );
    assert_eq!(new.sequence, old.sequence + 1);
    assert_eq!(new.len_bytes, old.len_bytes + 12 * pending as u32 + 8 + 16);

    // The frames after the commit use the new table: the overlay empties as it lists them.
    frames(&run, &mut tracker, &mut home, &mut link, 40..41);
    assert_eq!(
        tracker.new_defects().len(),
        0,
        "{:?}",
        tracker.new_defects()
    );

    // A reboot: the store mounted again, the new table in force with every pixel listed
    // and excluded, a fresh tracker's overlay empty.
    home.persist().unwrap();
    drop(home);
    let mut home = FlashHome::open(&path, GEOMETRY, None).unwrap();
    assert_eq!(home.active(TABLE_KIND_CALIBRATION), Some(new));
    let t: CalibTable<'static> = home.active_table().unwrap();
    for &(x, y) in &confirmed {
        let h = t.hot_pixels().find(x, y).expect("listed");
        assert_eq!(h.policy, HotPolicy::Exclude);
    }
    let mut buffers2 = Box::new(TrackerBuffers::new());
    let mut fresh =
        Box::new(Tracker::<32>::new(TrackerConfig::FLIGHT, GEOMETRY, &mut buffers2).unwrap());
    frames(&run, &mut fresh, &mut home, &mut link, 0..12);
    assert!(
        fresh
            .new_defects()
            .iter()
            .all(|d| !confirmed.contains(&(d.x_px, d.y_px)))
    );
    assert!(fresh.mode() == Mode::Tracking || fresh.mode() == Mode::Acquisition);
    std::fs::remove_file(&path).unwrap();
}

/// Runs the commit of `tracker`'s defects on the flash in `path` with the power cut during
/// flash step `cut.0` (after it with `cut.1`; none: no cut), then reboots; returns the table
/// in force after the reboot, the flash steps done and whether the power was cut.
fn commit_with_cut<const N: usize>(
    tracker: &mut Tracker<'static, '_, N>,
    path: &std::path::Path,
    cut: Option<(u64, bool)>,
) -> (Option<startrack_core::link::TableInfo>, u64, bool) {
    let mut home = FlashHome::open(path, GEOMETRY, None).unwrap();
    let steps0 = home.steps();
    match cut {
        Some((n, false)) => home.cut_power_at(n),
        Some((n, true)) => home.cut_power_after(n),
        None => {}
    }
    let mut link = Box::new(LinkService::new());
    command(&mut link, tracker, &mut home, p::TC_TABLE_COMMIT_DEFECTS, 1);
    let mut rounds = 0;
    while link.defect_commit_pending() && rounds < 1000 {
        let _ = home.service();
        let mut windows = NoWindows;
        link.poll(&mut Targets {
            tracker: &mut *tracker,
            tables: &mut home,
            windows: &mut windows,
        });
        rounds += 1;
    }
    let steps = home.steps() - steps0;
    let cut_happened = home.power_cut();
    home.reboot().unwrap();
    // The table in force loads and parses (FlashHome checks it at load).
    let info = home.active(TABLE_KIND_CALIBRATION);
    assert_eq!(info.is_some(), home.active_table().is_some());
    (info, steps, cut_happened)
}

#[test]
fn a_power_cut_at_any_step_of_the_commit_leaves_the_old_or_the_new_table() {
    let run = setup();
    let path = tmp("before.bin");
    let mut home = FlashHome::open(&path, GEOMETRY, Some(&run.table)).unwrap();
    let old = home.active(TABLE_KIND_CALIBRATION).unwrap();
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker =
        Box::new(Tracker::<32>::new(TrackerConfig::FLIGHT, GEOMETRY, &mut buffers).unwrap());
    let mut link = Box::new(LinkService::new());
    frames(&run, &mut tracker, &mut home, &mut link, 0..30);
    assert!(!tracker.new_defects().is_empty());
    home.persist().unwrap();
    drop(home);
    let work = tmp("cut.bin");
    let fresh_copy = || std::fs::copy(&path, &work).unwrap();

    fresh_copy();
    let (new, total, _) = commit_with_cut(&mut tracker, &work, None);
    let new = new.unwrap();
    assert_eq!(new.sequence, old.sequence + 1);
    assert_ne!(new.crc32, old.crc32);
    // During: every erase, the first units, one in the middle, the last ones and the header;
    // after: the last data unit and the header.
    let mut cuts: Vec<(u64, bool)> = [1, 2, 3, 4, total / 2, total - 2, total - 1, total]
        .into_iter()
        .map(|n| (n, false))
        .collect();
    cuts.extend([(total - 1, true), (total, true)]);
    let (mut kept, mut took) = (0, 0);
    for (n, after) in cuts {
        fresh_copy();
        let (info, _, cut) = commit_with_cut(&mut tracker, &work, Some((n, after)));
        assert!(cut, "step {n} of {total}: no cut");
        let info = info.expect("a table in force");
        let key = (info.crc32, info.len_bytes);
        if key == (old.crc32, old.len_bytes) {
            kept += 1;
        } else if key == (new.crc32, new.len_bytes) {
            took += 1;
        } else {
            panic!("step {n}: another table in force: {info:?}");
        }
    }
    println!("{total} flash steps; power cut: old table {kept} times, new table {took}");
    assert!(kept > 0 && took > 0);
    // After a cut that kept the old table, the commit runs again and succeeds.
    fresh_copy();
    let _ = commit_with_cut(&mut tracker, &work, Some((2, false)));
    let (again, _, _) = commit_with_cut(&mut tracker, &work, None);
    assert_eq!(again.map(|i| i.crc32), Some(new.crc32));
    std::fs::remove_file(&path).unwrap();
    std::fs::remove_file(&work).unwrap();
}
