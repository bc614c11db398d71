//! Stages `tracker_standby_frame`, `tracker_acquisition_frame` and `tracker_tracking_frame`,
//! per frame: the tracker application as the board runs it (`core/src/tracker`, the flight
//! configuration: the Gauss fit in both modes), fed every line of a 1033-line CCD47-20 frame
//! with [`STARS`] stars, as the board's free-running readout delivers them. The standby frame
//! (commanded, as `startrack process` does) is the floor every frame pays: bias levels and
//! the dark scale's covered columns of every line. The acquisition frame then scans with the
//! standby frame's dark scale (the very first frame after start-up would use its own running
//! estimate, which moves from line to line and makes the scan recompute its chunk bounds on
//! every line), cuts each star's window from the ring and fits it; the tracking frame reads
//! the windows' rows, calibrates and tests each window and fits the star.
//!
//! Timed: `begin_frame`, every `push_line` and `end_frame`; not timed: making the lines. Both
//! frames must report every star (the second ones flagged tracked), else the bench fails.
//! Cost of the bench itself: two frames of raw lines, four LCG draws a sample.

use crate::harness::{Bench, Out};
use crate::inputs::{G, Lcg, PSF_SIGMA_PX, RAW_COLS, raw_line_noisy};
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    Event, FrameInputs, FrameSummary, LineSummary, Mode, StarFlags, StarRecord, TelemetrySink,
    Tracker, TrackerBuffers, TrackerConfig,
};

/// Stars in the frame (the tracking frame's design load).
pub const STARS: usize = 30;

/// A telemetry sink that keeps what the bench checks.
struct Count {
    stars: usize,
    tracked: usize,
}

impl TelemetrySink for Count {
    fn line(&mut self, _summary: &LineSummary) {}
    fn star(&mut self, _frame: u32, star: &StarRecord) {
        self.stars += 1;
        self.tracked += usize::from(star.flags.contains(StarFlags::TRACKED));
    }
    fn frame(&mut self, _summary: &FrameSummary) {}
    fn event(&mut self, _event: &Event) {}
}

/// Measures and prints both stages with `table`.
pub fn run(
    out: &mut Out,
    bench: &Bench,
    table: &CalibTable<'_>,
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    let stars: [(usize, usize); STARS] = core::array::from_fn(|i| (40 + 31 * i, 50 + 29 * i));
    let config = TrackerConfig {
        // The synthetic stars' width, a = sigma / sqrt(0.31).
        psf_a_px: PSF_SIGMA_PX / 0.556_776_4,
        ..TrackerConfig::FLIGHT
    };
    let mut buffers = TrackerBuffers::new();
    let mut tracker =
        Tracker::<32>::new(config, G, &mut buffers).map_err(|_| "tracker configuration")?;
    let mut line = [0u16; RAW_COLS];
    tracker
        .command_mode(Mode::Standby)
        .map_err(|_| "tracker: standby refused")?;
    for (stage, mode) in [
        ("tracker_standby_frame", Mode::Standby),
        ("tracker_acquisition_frame", Mode::Acquisition),
        ("tracker_tracking_frame", Mode::Tracking),
    ] {
        if mode == Mode::Acquisition {
            tracker
                .command_mode(Mode::Acquisition)
                .map_err(|_| "tracker: acquisition refused")?;
        }
        let mut sink = Count {
            stars: 0,
            tracked: 0,
        };
        let inputs = FrameInputs {
            table: Some(*table),
            temperature_k: None,
            start_us: 0,
        };
        let mut ticks = bench.measure(|| {
            tracker.begin_frame(inputs, &mut sink);
        });
        if tracker.mode() != mode {
            return Err("tracker: unexpected mode");
        }
        for y in 0..G.lines {
            raw_line_noisy(usize::from(y), &stars, rng, &mut line);
            ticks += bench.measure(|| {
                tracker.push_line(y, &line, &mut sink);
            });
        }
        ticks += bench.measure(|| {
            tracker.end_frame(&mut sink);
        });
        let (stars, tracked) = match mode {
            Mode::Standby => (0, 0),
            Mode::Acquisition => (STARS, 0),
            Mode::Tracking => (STARS, STARS),
        };
        if sink.stars != stars || sink.tracked != tracked {
            return Err("tracker: not every star reported");
        }
        bench.row(out, stage, "frame_30_stars", ticks, 1);
    }
    Ok(())
}
