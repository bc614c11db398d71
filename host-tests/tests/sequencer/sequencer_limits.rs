//! The sequencer's typed refusals: every limit of the timing config, buffers too small
//! (with the exact size needed), bad pin maps and bad plans.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, CompileError, Limit, Limits, MAX_WINDOWS, PinMap, PinMapError, PlanError, ReadoutPlan,
    Step, Timing, TimingError, compile,
};
use startrack_core::window::Rect;

const BASE: Limits = Limits::CCD47_20;

fn at_1mhz() -> Timing {
    Timing::at_pixel_rate(1_000_000)
}

/// Each duration limit, raised just past what the default 1 MHz timing gives, is reported as
/// that limit; at the value it gives, the timing passes.
#[test]
fn every_limit_is_checked() {
    let t = at_1mhz();
    assert!(t.validate(&BASE).is_ok());
    // (limit, what the default timing gives in ns, the limits with that minimum set to v)
    type Set = fn(u32) -> Limits;
    let cases: [(Limit, u32, Set); 8] = [
        // The shorter serial state: a skipped element's, one 50 ns tick.
        (Limit::SerialState, 50, |v| Limits {
            min_serial_state_ns: v,
            ..BASE
        }),
        (Limit::ResetGate, 450, |v| Limits {
            min_reset_gate_ns: v,
            ..BASE
        }),
        (Limit::ResetSettle, 150, |v| Limits {
            min_reset_settle_ns: v,
            ..BASE
        }),
        (Limit::SignalSettle, 300, |v| Limits {
            min_signal_settle_ns: v,
            ..BASE
        }),
        (Limit::FtStep, 10_000, |v| Limits {
            min_ft_step_ns: v,
            ..BASE
        }),
        (Limit::LineStep, 40_000, |v| Limits {
            min_line_step_ns: v,
            ..BASE
        }),
        (Limit::DumpRegister, 1_000, |v| Limits {
            min_dump_ns: v,
            ..BASE
        }),
        // A parallel state is a third of the shortest row step, rounded up to ticks: the
        // dumped row's 3 us / 3 -> 20 ticks of 50 ns = 1,000 ns.
        (Limit::ParallelState, 1_000, |v| Limits {
            min_parallel_state_ns: v,
            ..BASE
        }),
    ];
    for (what, got_ns, limits) in cases {
        assert!(
            t.validate(&limits(got_ns)).is_ok(),
            "{what:?} at {got_ns} ns"
        );
        match t.validate(&limits(got_ns + 1)) {
            Err(TimingError::TooShort {
                what: w,
                got_ns: g,
                min_ns,
            }) => {
                assert_eq!((w, g, min_ns), (what, got_ns, got_ns + 1));
            }
            other => panic!("{what:?}: {other:?}"),
        }
    }
    // The dumped-row step is held to three parallel states (its states, rounded up to
    // whole ticks, would pass).
    let slow_dump_rows = Timing {
        dump_row_step_ns: 2_900,
        ..t
    };
    assert!(matches!(
        slow_dump_rows.validate(&BASE),
        Err(TimingError::TooShort {
            what: Limit::DumpRowStep,
            ..
        })
    ));
    // The pixel rate against the output's limit, and the tick against the DMA's.
    assert!(matches!(
        Timing::at_pixel_rate(BASE.max_pixel_rate_hz + 1).validate(&BASE),
        Err(TimingError::PixelRate { .. })
    ));
    assert!(matches!(
        Timing::at_pixel_rate(0).validate(&BASE),
        Err(TimingError::PixelRate { .. })
    ));
    let slow_dma = Limits {
        min_tick_ps: 50_001,
        ..BASE
    };
    assert_eq!(
        t.validate(&slow_dma),
        Err(TimingError::TickTooShort {
            tick_ps: 50_000,
            min_ps: 50_001
        })
    );
    assert_eq!(
        Timing {
            serial_state_ticks: 0,
            ..t
        }
        .validate(&BASE),
        Err(TimingError::ZeroTicks)
    );
}

/// Too-small buffers are refused with the exact size needed; that size then compiles.
#[test]
fn small_buffers_say_what_they_need() {
    let ticks = at_1mhz()
        .validate(&BASE)
        .unwrap_or_else(|e| unreachable!("{e}"));
    let plan = ReadoutPlan::new(
        ReadoutGeometry::CCD47_20_DUAL,
        ReadoutRequest::FullFrame,
        Binning::X1,
        0,
    )
    .unwrap_or_else(|e| unreachable!("{e}"));
    let (mut w, mut s) = (vec![0u32; 10], vec![Step::EMPTY; 10]);
    let needed_words = match compile(&plan, &ticks, &PinMap::IN_ORDER, &mut w, &mut s) {
        Err(CompileError::Words { needed }) => needed,
        other => panic!("{other:?}"),
    };
    w.resize(needed_words, 0);
    let needed_steps = match compile(&plan, &ticks, &PinMap::IN_ORDER, &mut w, &mut s) {
        Err(CompileError::Steps { needed }) => needed,
        other => panic!("{other:?}"),
    };
    // One frame transfer step and, per line, a line transfer and a run of reads.
    assert_eq!(needed_steps, 1 + 2 * 1033);
    s.resize(needed_steps, Step::EMPTY);
    let p = compile(&plan, &ticks, &PinMap::IN_ORDER, &mut w, &mut s);
    let p = p.unwrap_or_else(|e| unreachable!("{e}"));
    assert_eq!(
        (p.words().len(), p.steps().len()),
        (needed_words, needed_steps)
    );
    let mut shared = PinMap::IN_ORDER;
    shared.pins[15] = 0;
    assert!(matches!(
        compile(&plan, &ticks, &shared, &mut w, &mut s),
        Err(CompileError::Pins(PinMapError::SharedPin(..)))
    ));
}

#[test]
fn bad_plans_are_refused() {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let r = |x0, y0, width, height| Rect {
        x0,
        y0,
        width,
        height,
    };
    for bad in [r(1020, 0, 5, 5), r(0, 1020, 5, 5), r(3, 3, 0, 5)] {
        assert_eq!(
            ReadoutPlan::new(g, ReadoutRequest::Windows(&[bad]), Binning::X1, 0).err(),
            Some(PlanError::WindowOutside(bad))
        );
    }
    let many = vec![r(0, 0, 1, 1); MAX_WINDOWS + 1];
    assert_eq!(
        ReadoutPlan::new(g, ReadoutRequest::Windows(&many), Binning::X1, 0).err(),
        Some(PlanError::TooManyWindows)
    );
    // A register half of 6 elements cannot be binned by 4.
    let odd = ReadoutGeometry {
        overscan_px: 1,
        covered_px: 0,
        active_cols: 10,
        ..g
    };
    assert_eq!(
        ReadoutPlan::new(odd, ReadoutRequest::FullFrame, Binning::X4, 0).err(),
        Some(PlanError::Binning)
    );
    assert!(ReadoutPlan::new(odd, ReadoutRequest::FullFrame, Binning::X2, 0).is_ok());
}
