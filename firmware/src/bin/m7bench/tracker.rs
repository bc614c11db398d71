//! Stages `tracker_standby_frame`, `tracker_acquisition_frame`, `tracker_tracking_frame`,
//! `tracker_tracking_frame_windowed` and `tracker_acquisition_frame_trailed`, per frame: the tracker application as the board runs it (`core/src/tracker`, the flight
//! configuration: the Gauss fit in both modes), fed every line of a 1033-line CCD47-20 frame
//! with [`STARS`] stars, as the board's free-running readout delivers them. The standby frame
//! (commanded, as `startrack process` does) is the floor every frame pays: bias levels and
//! the dark scale's covered columns of every line. The acquisition frame then scans with the
//! standby frame's dark scale (the very first frame after start-up would use its own running
//! estimate, which moves from line to line and makes the scan recompute its chunk bounds on
//! every line), cuts each star's window from the ring and fits it; the tracking frame reads
//! the windows' rows, calibrates and tests each window and fits the star.
//!
//! `tracker_tracking_frame_windowed` is the next tracking frame as the board's windowed
//! readout delivers it: only the lines the tracker's own `readout_request()` reads
//! (`ReadoutRequest::reads_line`, what the sequencer's plan digitises and `ChannelLines`
//! hands over), in order, through the same `begin_frame` / `push_line` / `end_frame` that
//! `Tracker::run_frame` calls; 30 windows of 11 rows and the probe row, 331 lines (330 when
//! the probe row is one of a window's). The full-line stage stays
//! beside it as the cost of a free-running readout.
//!
//! Timed: `begin_frame`, every `push_line` and `end_frame`; not timed: making the lines. Both
//! frames must report every star (the second ones flagged tracked), else the bench fails.
//! Cost of the bench itself: two frames of raw lines, four LCG draws a sample.

use crate::harness::{Bench, Out};
use crate::inputs::{G, Lcg, PSF_SIGMA_PX, RAW_COLS, raw_line_noisy, raw_line_trailed};
use startrack_core::readout::ReadoutRequest;
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    Event, FrameInputs, FrameSummary, LineSummary, Mode, Provenance, StarRecord, TelemetrySink,
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
        self.tracked += usize::from(star.provenance.contains(Provenance::TRACKED));
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
        let mut ticks = begin(bench, table, &mut tracker, &mut sink, mode)?;
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
    windowed(out, bench, table, &mut tracker, &stars, rng)?;
    trailed_acquisition(out, bench, table, &mut tracker, &stars, rng)
}

/// Stars' trail along the rows in `tracker_acquisition_frame_trailed`, px (1 deg/s in
/// 100 ms on the 15-degree field is 6.8 px).
const TRAIL_PX: usize = 6;

/// `tracker_acquisition_frame_trailed`: the acquisition frame with every star trailed
/// [`TRAIL_PX`] along the rows, each found trailed by the trailed test and fitted with its
/// trail unknown (else the bench fails).
fn trailed_acquisition<'t>(
    out: &mut Out,
    bench: &Bench,
    table: &CalibTable<'t>,
    tracker: &mut Tracker<'t, '_, 32>,
    stars: &[(usize, usize); STARS],
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    tracker
        .command_mode(Mode::Acquisition)
        .map_err(|_| "tracker: acquisition refused")?;
    let mut sink = Count {
        stars: 0,
        tracked: 0,
    };
    let mut trailed = 0usize;
    let mut ticks = begin(bench, table, tracker, &mut sink, Mode::Acquisition)?;
    let mut line = [0u16; RAW_COLS];
    for y in 0..G.lines {
        raw_line_trailed(usize::from(y), stars, TRAIL_PX + 1, rng, &mut line);
        ticks += bench.measure(|| {
            tracker.push_line(y, &line, &mut sink);
        });
    }
    ticks += bench.measure(|| {
        tracker.end_frame(&mut sink);
    });
    for s in tracker.stars() {
        trailed += usize::from(s.provenance.contains(Provenance::TRAILED));
    }
    if sink.stars != STARS || trailed != STARS {
        return Err("tracker: not every trailed star reported as trailed");
    }
    bench.row(
        out,
        "tracker_acquisition_frame_trailed",
        "frame_30_stars",
        ticks,
        1,
    );
    Ok(())
}

/// Begins a frame with `table` (ticks of `begin_frame`); an error unless it runs in `mode`.
fn begin<'t>(
    bench: &Bench,
    table: &CalibTable<'t>,
    tracker: &mut Tracker<'t, '_, 32>,
    sink: &mut Count,
    mode: Mode,
) -> Result<u64, &'static str> {
    let inputs = FrameInputs {
        table: Some(*table),
        temperature_k: None,
        start_us: 0,
    };
    let ticks = bench.measure(|| {
        tracker.begin_frame(inputs, sink);
    });
    if tracker.mode() != mode {
        return Err("tracker: unexpected mode");
    }
    Ok(ticks)
}

/// The windowed tracking frame: the lines `tracker.readout_request()` reads, and no others.
fn windowed<'t>(
    out: &mut Out,
    bench: &Bench,
    table: &CalibTable<'t>,
    tracker: &mut Tracker<'t, '_, 32>,
    stars: &[(usize, usize); STARS],
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    let mut sink = Count {
        stars: 0,
        tracked: 0,
    };
    let mut ticks = begin(bench, table, tracker, &mut sink, Mode::Tracking)?;
    // What the sequencer reads for this request (a copy: the request borrows the tracker).
    let mut reads = [false; G.lines as usize];
    let mut rect_count = 0usize;
    match tracker.readout_request() {
        ReadoutRequest::Windows(rects) => {
            for (y, r) in (0..G.lines).zip(reads.iter_mut()) {
                *r = tracker.readout_request().reads_line(&G, y);
            }
            rect_count = rects.len();
        }
        ReadoutRequest::FullFrame => {}
    }
    let mut line = [0u16; RAW_COLS];
    let mut delivered = 0usize;
    for (y, _) in (0..G.lines).zip(reads).filter(|(_, r)| *r) {
        raw_line_noisy(usize::from(y), stars, rng, &mut line);
        delivered += 1;
        ticks += bench.measure(|| {
            tracker.push_line(y, &line, &mut sink);
        });
    }
    ticks += bench.measure(|| {
        tracker.end_frame(&mut sink);
    });
    // 30 windows that share no row (11 x 11 in the flight configuration), 330 lines, and the
    // probe row (one full row: its own line, or one of a window's).
    let side = usize::from(tracker.config().track_window_px());
    if rect_count != STARS + 1 || !(STARS * side..=STARS * side + 1).contains(&delivered) {
        return Err("tracker: windowed frame does not read the windows' rows");
    }
    if sink.stars != STARS || sink.tracked != STARS {
        return Err("tracker: windowed frame lost a star");
    }
    bench.row(
        out,
        "tracker_tracking_frame_windowed",
        "frame_30_stars",
        ticks,
        1,
    );
    Ok(())
}
