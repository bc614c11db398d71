//! The dark drift in housekeeping: the covered pixels' dark measured by the tracker against
//! the lab's dark law, on simulated frames whose dark follows that law (ratio ~1, in band)
//! or has grown by half since the lab (ratio ~1.5, `DARK_DRIFT`), and without a sensor
//! temperature (not measured). End to end: the law `calib frames` fits on the small lab set
//! travels in the table (section 11) and arms the tracker with no `set_dark_law` call; the
//! home's override wins over it; `calib build --dark-law` writes a law of the user's.

use fixed::types::U8F8;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::telemetry::{Housekeeping, status};
use startrack_core::link::{LinkService, TableUpload};
use startrack_core::table::{CalibTable, DarkLaw};
use startrack_core::tracker::{
    FixedTable, FixedTemperature, FrameSummary, LineSource, Ports, Tracker, TrackerBuffers,
    TrackerConfig,
};
use startrack_core::units::{ERatePerS, Kelvin};
use startrack_homes::home::{FrameClock, SimLines, block_on};
use startrack_homes::memory_tables::MemoryTables;
use startrack_sim::sim::effects::{DarkLaw as SimDarkLaw, Effects};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};
use std::convert::Infallible;

/// The ports a test's tracker runs on: one table, a fixed sensor temperature, the link as
/// telemetry sink and a clock of `period_us` a frame.
struct Bench<'t> {
    link: Box<LinkService>,
    tables: FixedTable<'t>,
    thermometer: FixedTemperature,
    period_us: u64,
}

impl<'t> Bench<'t> {
    fn new(table: CalibTable<'t>, sensor_k: Option<f64>, period_us: u64) -> Self {
        Self {
            link: Box::new(LinkService::new()),
            tables: FixedTable(Some(table)),
            thermometer: FixedTemperature(sensor_k.map(Kelvin::from_num)),
            period_us,
        }
    }

    /// Runs frame `k` of `source` through `tracker`.
    fn frame<S: LineSource<Error = Infallible>>(
        &mut self,
        tracker: &mut Tracker<'t, '_, 32>,
        source: &mut S,
        k: u32,
    ) -> FrameSummary {
        let mut clock = FrameClock {
            frame: k,
            period_us: self.period_us,
        };
        let mut ports = Ports {
            clock: &mut clock,
            thermometer: &mut self.thermometer,
            tables: &mut self.tables,
            telemetry: &mut *self.link,
        };
        let Ok(summary) = block_on(tracker.run_frame(source, &mut ports));
        summary
    }
}

/// A small readout (128 x 128 active, 16 covered columns a side) to keep the test fast.
fn small() -> SensorParams {
    SensorParams {
        geometry: ReadoutGeometry {
            overscan_px: 8,
            covered_px: 16,
            active_cols: 128,
            active_rows: 128,
            lines: 130,
            outputs: 2,
        },
        ..SensorParams::default()
    }
}

/// The flight configuration with 1 s exposures: the dark these tests measure is the
/// sensors' charge in 1 s (250 e- at 293 K on the default sensor), far above the read noise,
/// where the flight's 39 ms holds a few electrons.
const SECOND_FRAMES: TrackerConfig = TrackerConfig {
    exposure_ms: 1000,
    ..TrackerConfig::FLIGHT
};

/// The lab's law: the default sensor's 250 e- in the 1 s exposure at 293 K, doubling every
/// 6.5 K; band 0.8 to 1.25.
fn lab_law() -> DarkLaw {
    DarkLaw {
        rate_e_per_s: ERatePerS::from_num(250),
        reference_k: Kelvin::from_num(293),
        doubling_k: U8F8::from_num(6.5),
        band_low: U8F8::from_num(0.8),
        band_high: U8F8::from_num(1.25),
    }
}

/// Runs `frames` empty frames of a sensor at 286.5 K (half the dark of 293 K) whose dark at
/// 293 K is `dark_e`, with the table of the lab sensor, the law set and the thermometer
/// reading `sensor_k`; returns the link's housekeeping after the last frame.
fn run(dark_e: f64, sensor_k: Option<f64>, frames: u32) -> Housekeeping {
    let lab = SensorParams { seed: 5, ..small() };
    let table_bytes = Simulator::new(lab.clone(), Vec::new())
        .truth_table(TruthSections::ALL)
        .unwrap();
    let table = CalibTable::parse(&table_bytes).unwrap();
    let params = SensorParams {
        dark_mean_e: dark_e,
        effects: Effects {
            temperature_k: 286.5,
            dark_law: Some(SimDarkLaw {
                reference_k: 293.0,
                doubling_k: 6.5,
            }),
            ..Effects::default()
        },
        ..lab
    };
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker =
        Box::new(Tracker::<32>::new(SECOND_FRAMES, params.geometry, &mut buffers).unwrap());
    tracker.set_dark_law(Some(lab_law()));
    let mut source = SimLines::new(|frame| Simulator {
        frame,
        ..Simulator::new(params.clone(), Vec::new())
    });
    let mut bench = Bench::new(table, sensor_k, 100_000);
    for k in 0..frames {
        let summary = bench.frame(&mut tracker, &mut source, k);
        assert_eq!(summary.dark_drift, tracker.dark_drift());
    }
    let store = MemoryTables::new(params.geometry, Some(table_bytes.clone()));
    let hk = bench
        .link
        .housekeeping(TableUpload::active(&store, TABLE_KIND_CALIBRATION));
    // Through the wire and back.
    let mut buf = [0u8; startrack_core::link::telemetry::HK_LEN];
    let n = hk.encode(&mut buf).unwrap();
    assert_eq!(Housekeeping::decode(&buf[..n]), Some(hk));
    hk
}

fn ratio(hk: &Housekeeping) -> f64 {
    f64::from(hk.dark_ratio_u8f8) / 256.0
}

#[test]
fn a_sensor_on_its_lab_law_reads_one_in_band() {
    let hk = run(250.0, Some(286.5), 6);
    println!(
        "on the law: dark_ratio {:.3}, status {}",
        ratio(&hk),
        hk.status
    );
    assert!((ratio(&hk) - 1.0).abs() < 0.05, "{}", ratio(&hk));
    assert_eq!(hk.status & status::DARK_DRIFT, 0);
}

#[test]
fn a_dark_grown_by_half_is_reported_as_drift() {
    let hk = run(375.0, Some(286.5), 6);
    println!(
        "dark x1.5: dark_ratio {:.3}, status {}",
        ratio(&hk),
        hk.status
    );
    assert!((ratio(&hk) - 1.5).abs() < 0.075, "{}", ratio(&hk));
    assert_eq!(hk.status & status::DARK_DRIFT, status::DARK_DRIFT);
}

#[test]
fn without_a_sensor_temperature_nothing_is_measured() {
    let hk = run(375.0, None, 3);
    assert_eq!(hk.dark_ratio_u8f8, 0);
    assert_eq!(hk.status, 0);
}

/// The running ratio moves by 1/16 of a step a frame: after a jump from 1 to 1.5 it has
/// gone 1 - (15/16)^k of the way.
#[test]
fn the_running_ratio_follows_a_step_with_its_time_constant() {
    // First frames on the law, then the same sensor with half more dark: one tracker.
    let lab = SensorParams { seed: 6, ..small() };
    let table_bytes = Simulator::new(lab.clone(), Vec::new())
        .truth_table(TruthSections::ALL)
        .unwrap();
    let table = CalibTable::parse(&table_bytes).unwrap();
    let at = |dark_e: f64| SensorParams {
        dark_mean_e: dark_e,
        ..lab.clone()
    };
    let mut law = lab_law();
    law.reference_k = Kelvin::from_num(286.5);
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker =
        Box::new(Tracker::<32>::new(SECOND_FRAMES, lab.geometry, &mut buffers).unwrap());
    tracker.set_dark_law(Some(law));
    let mut source = SimLines::new(|frame| Simulator {
        frame,
        ..Simulator::new(at(if frame < 3 { 250.0 } else { 375.0 }), Vec::new())
    });
    let mut bench = Bench::new(table, Some(286.5), 100_000);
    let mut ratios = Vec::new();
    for k in 0..7 {
        let s = bench.frame(&mut tracker, &mut source, k);
        ratios.push(f64::from(s.dark_drift.ratio_u8f8) / 256.0);
    }
    println!("running ratio: {ratios:.3?}");
    assert!((ratios[2] - 1.0).abs() < 0.05, "{ratios:?}");
    for (k, r) in ratios.iter().enumerate().skip(3) {
        let want = 1.0 + 0.5 * (1.0 - (15.0f64 / 16.0).powi(k as i32 - 2));
        assert!((r - want).abs() < 0.03, "frame {k}: {r} against {want}");
    }
    assert!(!tracker.dark_drift().out_of_band);
}

use startrack_test_support::cli;
use startrack_test_support::table_fixtures;

use startrack_lab::LabError;
use startrack_lab::calib_frames::calibrate;
use startrack_lab::calib_frames::labset::LabSet;
use startrack_lab::table_build as calib_build;
use std::sync::OnceLock;

/// The small lab set (seed 11) and the table `calib frames` builds from it, once per binary.
fn lab_table() -> &'static (LabSet, Vec<u8>) {
    static T: OnceLock<(LabSet, Vec<u8>)> = OnceLock::new();
    T.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let set = LabSet::small(11);
        let paths = set.write(dir.path()).unwrap();
        let products = calibrate(&paths, &set.geometry, &|| ()).unwrap();
        (set, products.table(0).unwrap())
    })
}

/// Runs `frames` 1 s frames of the lab sensor at `sensor_k` whose regular dark at 293 K is
/// `dark_scale` times the lab's, through a tracker given only the lab table (and the
/// override `law`, if any); returns every frame's running ratio and the last summary's
/// drift flag.
fn run_lab(
    dark_scale: f64,
    sensor_k: f64,
    frames: u32,
    law: Option<DarkLaw>,
) -> (Vec<f64>, bool, Option<DarkLaw>) {
    let (lab, table_bytes) = lab_table();
    let table = CalibTable::parse(table_bytes).unwrap();
    let sensor = LabSet {
        dark_rate_e_per_s_at_293k: dark_scale * lab.dark_rate_e_per_s_at_293k,
        ..lab.clone()
    };
    let config = SECOND_FRAMES;
    let exposure_s = f64::from(config.exposure_ms) / 1000.0;
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker = Box::new(Tracker::<32>::new(config, lab.geometry, &mut buffers).unwrap());
    tracker.set_dark_law(law);
    let mut source = SimLines::new(|frame| sensor.frame_sensor(frame, exposure_s, sensor_k, false));
    let mut bench = Bench::new(table, Some(sensor_k), 1_100_000);
    let (mut ratios, mut out) = (Vec::new(), false);
    for k in 0..frames {
        let summary = bench.frame(&mut tracker, &mut source, k);
        ratios.push(f64::from(summary.dark_drift.ratio_u8f8) / 256.0);
        out = summary.dark_drift.out_of_band;
    }
    (ratios, out, tracker.dark_law())
}

/// The lab table's law at 288 K (5 K below its 293 K reference, a temperature none of the
/// lab darks was taken at): 11.7 e- a pixel in the 1 s frame, 0.8 % of noise over the 4160
/// covered pixels, the law itself within 2 % (`calib_frames`' tolerance): the running
/// ratio within 0.05 of 1, well inside the 0.8 to 1.25 band.
#[test]
fn the_table_from_lab_frames_arms_the_drift_check_at_another_temperature() {
    let (_, bytes) = lab_table();
    let law = CalibTable::parse(bytes)
        .unwrap()
        .dark_law()
        .expect("section 11");
    let (ratios, out, in_force) = run_lab(1.0, 288.0, 6, None);
    println!("lab table at 288 K: running ratio {ratios:.3?}, law {law:?}");
    assert_eq!(in_force, Some(law), "the tracker takes the table's law");
    let last = *ratios.last().unwrap();
    assert!((last - 1.0).abs() < 0.05, "{ratios:?}");
    assert!(!out);
}

/// The same sensor with its dark doubled since the lab: the ratio reads about 2 and the
/// drift bit is set.
#[test]
fn a_doubled_dark_against_the_lab_table_sets_the_drift_bit() {
    let (ratios, out, _) = run_lab(2.0, 288.0, 6, None);
    println!("dark x2 at 288 K: running ratio {ratios:.3?}");
    let last = *ratios.last().unwrap();
    assert!((last - 2.0).abs() < 0.1, "{ratios:?}");
    assert!(out);
}

/// A law the home sets wins over the table's: the same doubled dark, measured against a
/// law with twice the lab's rate, is in band; `None` goes back to the table's law.
#[test]
fn the_home_override_wins_over_the_table_law() {
    let (_, bytes) = lab_table();
    let table_law = CalibTable::parse(bytes).unwrap().dark_law().unwrap();
    let doubled = DarkLaw {
        rate_e_per_s: table_law.rate_e_per_s * 2,
        ..table_law
    };
    let (ratios, out, in_force) = run_lab(2.0, 288.0, 4, Some(doubled));
    println!("dark x2 against a doubled override: {ratios:.3?}");
    assert_eq!(in_force, Some(doubled));
    assert!((ratios.last().unwrap() - 1.0).abs() < 0.05, "{ratios:?}");
    assert!(!out);

    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker =
        Box::new(Tracker::<32>::new(SECOND_FRAMES, lab_table().0.geometry, &mut buffers).unwrap());
    tracker.set_dark_law(Some(doubled));
    assert_eq!(tracker.dark_law(), Some(doubled));
    tracker.set_dark_law(None);
    assert_eq!(tracker.dark_law(), None, "no table yet: no law");
}

#[test]
fn calib_build_writes_a_users_dark_law() {
    let dir = tempfile::tempdir().unwrap();
    let with = |law: &str| {
        let mut a = cli::bare_args(dir.path().join("t.bin"));
        a.gains = Some("1.5,1.6".into());
        a.dark_law = Some(law.into());
        calib_build::build(&a)
    };
    let (bytes, report) = with("12.5,253,7").unwrap();
    let law = CalibTable::parse(&bytes).unwrap().dark_law().unwrap();
    assert_eq!(law.rate_e_per_s, ERatePerS::from_num(12.5));
    assert_eq!(law.reference_k, Kelvin::from_num(253));
    assert_eq!(law.doubling_k, U8F8::from_num(7));
    assert_eq!([law.band_low, law.band_high], DarkLaw::DEFAULT_BAND);
    assert!(
        report.notes.iter().any(|n| n.starts_with("dark law 12.5")),
        "{:?}",
        report.notes
    );
    let (bytes, _) = with("12.5,253,7,0.9,1.1").unwrap();
    let law = CalibTable::parse(&bytes).unwrap().dark_law().unwrap();
    assert_eq!(
        [law.band_low, law.band_high],
        [U8F8::from_num(0.9), U8F8::from_num(1.1)]
    );
    for (bad, says) in [
        ("0,293,6.5", "RATE"),
        ("-1,293,6.5", "RATE"),
        ("20,50,6.5", "TREF"),
        ("20,293,1", "DOUBLING"),
        ("20,293,25", "DOUBLING"),
        ("20,293,6.5,1.2,0.9", "LOW"),
        ("20,293", "RATE,TREF,DOUBLING"),
        ("20,293,6.5,1", "RATE,TREF,DOUBLING"),
        ("20,x,6.5", "--dark-law"),
    ] {
        match with(bad) {
            Err(LabError::Invalid(m)) => assert!(m.contains(says), "{bad}: {m}"),
            other => panic!("{bad}: {other:?}"),
        }
    }
}

/// A replacement table of the same length whose only change is its law (twice the lab's
/// rate) is taken at the next frame: the sensor with its dark doubled reads about 2 against
/// the lab table, then about 1 against the new one, the ratio restarted.
#[test]
fn a_replacement_table_brings_its_own_law() {
    use startrack_core::table::SectionKind;
    let (lab, bytes_a) = lab_table();
    let law_a = CalibTable::parse(bytes_a).unwrap().dark_law().unwrap();
    let law_b = DarkLaw {
        rate_e_per_s: law_a.rate_e_per_s * 2,
        ..law_a
    };
    let mut raw = table_fixtures::RawTable::decompose(bytes_a);
    *raw.section_mut(SectionKind::DarkLaw) = law_b.encode().to_vec();
    let bytes_b = raw.build();
    assert_eq!(bytes_a.len(), bytes_b.len());
    let sensor = LabSet {
        dark_rate_e_per_s_at_293k: 2.0 * lab.dark_rate_e_per_s_at_293k,
        ..lab.clone()
    };
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker =
        Box::new(Tracker::<32>::new(SECOND_FRAMES, lab.geometry, &mut buffers).unwrap());
    let mut source = SimLines::new(|frame| sensor.frame_sensor(frame, 1.0, 288.0, false));
    let mut bench = Bench::new(CalibTable::parse(bytes_a).unwrap(), Some(288.0), 1_100_000);
    let mut ratios = Vec::new();
    for k in 0..6 {
        if k == 3 {
            bench.tables.0 = Some(CalibTable::parse(&bytes_b).unwrap());
        }
        let s = bench.frame(&mut tracker, &mut source, k);
        ratios.push((
            f64::from(s.dark_drift.ratio_u8f8) / 256.0,
            s.dark_drift.frames,
        ));
    }
    println!("lab table then its doubled-law twin: {ratios:.3?}");
    assert_eq!(tracker.dark_law(), Some(law_b));
    assert!((ratios[2].0 - 2.0).abs() < 0.1, "{ratios:?}");
    assert_eq!(ratios[3].1, 1, "the ratio restarts with the new law");
    assert!((ratios[5].0 - 1.0).abs() < 0.05, "{ratios:?}");
}
