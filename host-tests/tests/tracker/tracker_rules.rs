//! The core's tracker application driven directly: the mode rules the SIL does not reach
//! (no table, commands, a held standby), refused lines, every configuration check, random
//! operation sequences (no panic, every loss counted), and the memory bound.

use startrack_test_support::field as common_field;

use common_field::field;
use startrack_core::detect::LineDetector;
use startrack_core::readout::ReadoutRequest;
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    CentroidMethod, CommandError, ConfigError, Event, FrameInputs, LineOutcome, Mode, ModeReason,
    Tracker, TrackerBuffers, TrackerConfig,
};
use startrack_homes::home::Recorder;
use startrack_sim::sim::SensorParams;

/// A tracker on the default sensor with its true table, and a recorder.
fn small_tracker(buffers: &mut TrackerBuffers) -> Tracker<'static, '_, 32> {
    Tracker::<32>::new(
        TrackerConfig::FLIGHT,
        SensorParams::default().geometry,
        buffers,
    )
    .unwrap()
}

fn inputs(table: Option<CalibTable<'_>>) -> FrameInputs<'_> {
    FrameInputs {
        table,
        temperature_k: None,
        start_us: 0,
    }
}

/// The mode rules that the SIL does not reach: no table, commands, refused lines.
#[test]
fn mode_rules_commands_and_refused_lines() {
    let (sim, table_bytes) = field(3, 0);
    let table = CalibTable::parse(&table_bytes).unwrap();
    let g = sim.params.geometry;
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut t = Tracker::<32>::new(TrackerConfig::FLIGHT, g, &mut buffers).unwrap();
    let mut rec = Recorder::default();
    // No stars yet: tracking cannot be commanded.
    assert_eq!(
        t.command_mode(Mode::Tracking),
        Err(CommandError::NothingToTrack)
    );
    // No table: standby, whatever was asked.
    t.begin_frame(inputs(None), &mut rec);
    assert_eq!(t.mode(), Mode::Standby);
    assert_eq!(t.readout_request(), ReadoutRequest::FullFrame);
    let mut line = vec![0u16; g.line_len()];
    sim.render_line(0, &mut line);
    assert!(matches!(
        t.push_line(0, &line, &mut rec),
        LineOutcome::Uncalibrated { .. }
    ));
    // Out of order, repeated, too short, past the frame: refused and counted.
    assert_eq!(t.push_line(0, &line, &mut rec), LineOutcome::Refused);
    sim.render_line(5, &mut line);
    assert!(matches!(
        t.push_line(5, &line, &mut rec),
        LineOutcome::Uncalibrated { .. }
    ));
    assert_eq!(t.push_line(3, &line, &mut rec), LineOutcome::Refused);
    assert_eq!(t.push_line(6, &line[1..], &mut rec), LineOutcome::Refused);
    assert_eq!(t.push_line(g.lines, &line, &mut rec), LineOutcome::Refused);
    let s = t.end_frame(&mut rec);
    assert_eq!((s.lines, s.lines_refused, s.calibrated), (2, 4, false));
    // The rules want acquisition; the next frame's start decides on the table then.
    assert_eq!(s.next_mode, Mode::Acquisition);
    // A line after the frame ended is refused too.
    assert_eq!(t.push_line(7, &line, &mut rec), LineOutcome::Refused);
    // The table arrives: acquisition at the next frame.
    t.begin_frame(inputs(Some(table)), &mut rec);
    assert_eq!(t.mode(), Mode::Acquisition);
    t.end_frame(&mut rec);
    // A commanded standby holds until the next command.
    t.command_mode(Mode::Standby).unwrap();
    for _ in 0..3 {
        t.begin_frame(inputs(Some(table)), &mut rec);
        assert_eq!(t.mode(), Mode::Standby);
        t.end_frame(&mut rec);
    }
    t.command_mode(Mode::Acquisition).unwrap();
    t.begin_frame(inputs(Some(table)), &mut rec);
    assert_eq!(t.mode(), Mode::Acquisition);
    // An acquisition frame with no star stays in acquisition.
    let s = t.end_frame(&mut rec);
    assert_eq!((s.stars, s.next_mode), (0, Mode::Acquisition));
    let changes: Vec<(u32, Mode, Mode, ModeReason)> = rec
        .events
        .iter()
        .filter_map(|e| match e {
            Event::ModeChange {
                frame,
                from,
                to,
                reason,
            } => Some((*frame, *from, *to, *reason)),
            _ => None,
        })
        .collect();
    assert_eq!(
        changes,
        [
            (
                1,
                Mode::Standby,
                Mode::Acquisition,
                ModeReason::TableAvailable
            ),
            (2, Mode::Acquisition, Mode::Standby, ModeReason::Command),
            (5, Mode::Standby, Mode::Acquisition, ModeReason::Command),
        ]
    );
    let tables: Vec<u32> = rec
        .events
        .iter()
        .filter_map(|e| match e {
            Event::TableChanged { frame, .. } => Some(*frame),
            _ => None,
        })
        .collect();
    assert_eq!(tables, [0, 1]);
    assert_eq!(rec.frames.len(), 6);
    // A configuration is checked, then applied at the next frame.
    assert_eq!(
        t.set_config(TrackerConfig {
            window_px: 8,
            ..TrackerConfig::FLIGHT
        }),
        Err(ConfigError::Window(8))
    );
    t.set_config(TrackerConfig {
        window_px: 9,
        ..TrackerConfig::FLIGHT
    })
    .unwrap();
    assert_eq!(t.config().window_px, 7);
    t.begin_frame(inputs(Some(table)), &mut rec);
    assert_eq!(t.config().window_px, 9);
    assert!(rec.events.contains(&Event::ConfigApplied { frame: 6 }));
}

/// Every configuration field the checks guard, one bad value each.
#[test]
fn bad_configurations_are_refused_with_their_reason() {
    let f = TrackerConfig::FLIGHT;
    let cases = [
        (TrackerConfig { window_px: 3, ..f }, ConfigError::Window(3)),
        (
            TrackerConfig { window_px: 15, ..f },
            ConfigError::Window(15),
        ),
        (
            TrackerConfig {
                acquisition_method: CentroidMethod::FusedCog1,
                ..f
            },
            ConfigError::FusedInAcquisition,
        ),
        (
            TrackerConfig {
                window_px: 13,
                tracking_method: CentroidMethod::FusedCog1,
                track_margin_px: 1,
                ..f
            },
            ConfigError::Window(13),
        ),
        (
            TrackerConfig {
                track_margin_px: 5,
                ..f
            },
            ConfigError::TrackMargin(5),
        ),
        (
            TrackerConfig {
                psf_a_px: f32::NAN,
                ..f
            },
            ConfigError::PsfWidth,
        ),
        (
            TrackerConfig {
                background_stride: 0,
                ..f
            },
            ConfigError::BackgroundStride,
        ),
        (
            TrackerConfig { max_stars: 33, ..f },
            ConfigError::MaxStars {
                max_stars: 33,
                capacity: 32,
            },
        ),
        (
            TrackerConfig {
                max_tracked: 0,
                ..f
            },
            ConfigError::MaxTracked(0),
        ),
        (
            TrackerConfig {
                min_track_stars: 40,
                ..f
            },
            ConfigError::MinTrackStars(40),
        ),
        (
            TrackerConfig {
                reacquire_every: 0,
                ..f
            },
            ConfigError::Period,
        ),
    ];
    for (c, e) in cases {
        assert_eq!(c.validate(32), Err(e), "{c:?}");
        assert!(!e.to_string().is_empty());
    }
    let mut thresholds = f;
    thresholds.detect.peak_sigmas = -1.0;
    assert_eq!(thresholds.validate(32), Err(ConfigError::Thresholds));
    assert_eq!(f.validate(32), Ok(()));
    let mut buffers = Box::new(TrackerBuffers::new());
    let long_lines = startrack_core::geometry::ReadoutGeometry {
        active_cols: 2048,
        ..SensorParams::default().geometry
    };
    assert!(matches!(
        Tracker::<32>::new(f, long_lines, &mut buffers),
        Err(ConfigError::Geometry)
    ));
    let _ = small_tracker(&mut buffers);
}

/// The application's memory: the buffers a home places and the tracker itself, for the
/// board's capacity (32 stars). Printed with `--nocapture`; the bounds keep them from
/// growing unnoticed (the board's RAM is 512 KB of AXI SRAM, 180 KB of it free:
/// docs/hardware.md). The tracker's bound is 45 KB since each star record carries its x-y
/// covariance (4 B a record, 128 B with the common motion's histogram over 44 KB).
#[test]
fn tracker_memory() {
    let buffers = std::mem::size_of::<TrackerBuffers>();
    let tracker = std::mem::size_of::<Tracker<'static, 'static, 32>>();
    let scan = std::mem::size_of::<startrack_core::detect::ScanDetector<'static, 32>>();
    let detector = std::mem::size_of::<LineDetector<32>>();
    let ring = std::mem::size_of::<startrack_core::tracker::Ring>();
    let capture = std::mem::size_of::<startrack_core::tracker::Capture>();
    let plan = std::mem::size_of::<startrack_core::centroid::raw_cog::RawCogPlan>();
    eprintln!(
        "TrackerBuffers {buffers} B (ring {ring}, capture {capture}, plans 32 x {plan}), Tracker<32> {tracker} B, of which the scan detector {scan} B (its line detector {detector} B)"
    );
    assert!(buffers <= 70 * 1024, "{buffers}");
    assert!(tracker <= 45 * 1024, "{tracker}");
}

/// One step of the random operation sequences below.
#[derive(Clone, Debug)]
enum Op {
    /// Begin a frame, with the table or without.
    Begin(bool),
    /// A line: its index, its length less the geometry's (0: right length), a sample
    /// pattern seed and a base level.
    Line(u16, u8, u64, u16),
    /// End the frame.
    End,
    /// A mode command.
    Command(u8),
    /// A configuration with this window and stride.
    Config(u16, u16),
}

fn op() -> impl proptest::strategy::Strategy<Value = Op> {
    use proptest::prelude::*;
    prop_oneof![
        1 => any::<bool>().prop_map(Op::Begin),
        8 => (0u16..1100, prop_oneof![4 => Just(0u8), 1 => any::<u8>()], any::<u64>(), any::<u16>())
            .prop_map(|(l, d, seed, base)| Op::Line(l, d, seed, base)),
        1 => Just(Op::End),
        1 => (0u8..3).prop_map(Op::Command),
        1 => (0u16..20, 0u16..80).prop_map(|(w, s)| Op::Config(w, s)),
    ]
}

proptest::proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(proptest::prelude::ProptestConfig::with_cases(32)))]
    /// Any sequence of frames, lines (any index, length, samples: saturated, flat, noise),
    /// commands and configurations: no panic, every line either taken or refused and
    /// counted, summaries that add up, and records that are finite.
    #[test]
    fn any_input_gives_records_or_counted_refusals(ops in proptest::collection::vec(op(), 1..60)) {
        let (_, table_bytes) = field(4, 0);
        let table = CalibTable::parse(&table_bytes).unwrap();
        let g = SensorParams::default().geometry;
        let mut buffers = Box::new(TrackerBuffers::new());
        let mut t = Tracker::<32>::new(TrackerConfig::FLIGHT, g, &mut buffers).unwrap();
        let mut rec = Recorder::default();
        let mut line = vec![0u16; g.line_len()];
        let (mut pushed, mut open) = (0u32, false);
        let mut frames = 0usize;
        for op in ops {
            match op {
                Op::Begin(with_table) => {
                    if open {
                        frames += 1;
                    }
                    t.begin_frame(inputs(with_table.then_some(table)), &mut rec);
                    open = true;
                    pushed = 0;
                }
                Op::Line(l, short, seed, base) => {
                    let mut x = seed | 1;
                    for v in line.iter_mut() {
                        x ^= x << 13;
                        x ^= x >> 7;
                        x ^= x << 17;
                        *v = match seed % 4 {
                            0 => u16::MAX,
                            1 => base,
                            _ => base.saturating_add((x % 512) as u16),
                        };
                    }
                    let len = g.line_len().saturating_sub(usize::from(short));
                    let outcome = t.push_line(l, &line[..len], &mut rec);
                    if open {
                        pushed += 1;
                    } else {
                        proptest::prop_assert_eq!(outcome, LineOutcome::Refused);
                    }
                }
                Op::End => {
                    let s = t.end_frame(&mut rec);
                    if open {
                        frames += 1;
                        proptest::prop_assert!(u32::from(s.lines) <= pushed);
                        proptest::prop_assert!(u32::from(s.lines) + u32::from(s.lines_refused) >= pushed);
                    }
                    open = false;
                }
                Op::Command(m) => {
                    let mode = [Mode::Standby, Mode::Acquisition, Mode::Tracking][usize::from(m)];
                    let _ = t.command_mode(mode);
                }
                Op::Config(w, s) => {
                    let c = TrackerConfig {
                        window_px: w,
                        background_stride: s,
                        ..TrackerConfig::FLIGHT
                    };
                    proptest::prop_assert_eq!(t.set_config(c).is_ok(), c.validate(32).is_ok());
                }
            }
        }
        proptest::prop_assert_eq!(rec.frames.len(), frames);
        for f in &rec.frames {
            proptest::prop_assert!(f.stars.len() <= 32);
            proptest::prop_assert_eq!(usize::from(f.summary.stars), f.stars.len());
            for s in &f.stars {
                for v in [s.x_px, s.y_px, s.flux_e, s.snr, s.sigma_x_px, s.sigma_y_px] {
                    proptest::prop_assert!(v.is_finite(), "{:?}", s);
                }
            }
        }
    }
}
