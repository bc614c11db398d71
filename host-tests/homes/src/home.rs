//! The host's home for the core's tracker application ([`startrack_core::tracker`]): line
//! sources (a recorded frame, the simulated CCD47-20), a telemetry recorder, a clock, and
//! a runner that drives [`Tracker::run_frame`](startrack_core::tracker::Tracker::run_frame)
//! to completion. `startrack process`, `startrack sil`, the demo and the tests all run the
//! tracker through these, exactly as the board does through its own ports.
//!
//! Cost: the sources copy one raw line (2 KB) per line read; the simulated source renders
//! only the samples the tracker's request reads (over-scan and covered columns of each line
//! read, and the windows' pixels), so a tracking frame costs its windows, not a frame.

use startrack_core::calib::{
    CalibError, DarkScaleEstimator, FrameCalibration, LineLevels, PixelFlags,
};
use startrack_core::cycle::{CyclePorts, FrameCycle};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::LinkService;
use startrack_core::readout::ReadoutRequest;
use startrack_core::safe::{FaultRecord, Health, SetupFaults};
use startrack_core::table::CalibTable;
use startrack_core::table::pixcorr::{CurveHeader, PixCorrBackground};
use startrack_core::tracker::{
    Clock, Event, FixedTable, FixedTemperature, FrameSummary, Integration, LineSource, LineSummary,
    Mode, SourceLine, StarRecord, TelemetrySink, Tracker, TrackerBuffers, TrackerConfig,
    select_curve,
};
use startrack_core::units::Electrons;
use startrack_core::units::Kelvin;
use startrack_core::window::Rect;
use startrack_sim::sim::Simulator;
use std::cell::Cell;
use std::convert::Infallible;
use std::rc::Rc;

/// Stars a frame the host's tracker keeps (the board: 32): room for any field, so that a
/// miss is a detection miss, not a full list; losses are still counted.
pub const HOST_CAPACITY: usize = 1024;

/// What the tracker measured on one recorded frame ([`process_frame`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Processed {
    /// The acquisition frame's stars, as reported.
    pub stars: Vec<StarRecord>,
    /// Its summary.
    pub summary: FrameSummary,
    /// The configuration the tracker ran with.
    pub config: TrackerConfig,
    /// The pixel-phase curve a CoG method used (`None`: the Gauss fit, or no curve matched).
    pub curve: Option<CurveHeader>,
}

/// Runs the tracker on one recorded frame `raw` (row-major, the table's geometry): a
/// standby frame for the dark scale, then an acquisition frame. Returns the acquisition
/// frame's stars and summary.
pub fn process_frame(
    table: CalibTable<'_>,
    raw: &[u16],
    config: TrackerConfig,
    temperature_k: Option<Kelvin>,
) -> Result<Processed, String> {
    let geometry = *table.geometry();
    let mut source = FrameLines::new(geometry, raw).ok_or_else(|| {
        format!(
            "frame has {} samples, the table's geometry needs {}",
            raw.len(),
            usize::from(geometry.lines) * geometry.line_len()
        )
    })?;
    let frame = acquire_once(config, table, temperature_k, &mut source)?;
    let curve = config
        .acquisition_method
        .cog_power()
        .and_then(|p| {
            select_curve(
                &table,
                &config,
                p,
                config.box_px(),
                PixCorrBackground::PerimeterMedian,
            )
        })
        .map(|c| c.header());
    Ok(Processed {
        stars: frame.stars,
        summary: frame.summary,
        config,
        curve,
    })
}

/// A fresh host tracker run on one frame as the board runs after start-up: a standby frame
/// (the dark scale from the covered columns), then an acquisition frame calibrated with
/// it, both read from `source` (which gives the same frame twice). Returns the acquisition
/// frame as the telemetry port reported it.
pub fn acquire_once<S: LineSource<Error = Infallible>>(
    config: TrackerConfig,
    table: CalibTable<'_>,
    temperature_k: Option<Kelvin>,
    source: &mut S,
) -> Result<FrameRecord, String> {
    let mut buffers = Box::new(TrackerBuffers::new());
    let tracker = Tracker::<HOST_CAPACITY>::new(config, *table.geometry(), &mut buffers)
        .map_err(|e| e.to_string())?;
    let mut link = Box::new(LinkService::new());
    let mut cycle = Box::new(FrameCycle::new(tracker, &mut link, None, host_health()));
    let mut recorder = Recorder::default();
    let mut clock = FrameClock {
        frame: 0,
        period_us: 0,
    };
    let mut tables = FixedTable(Some(table));
    let mut thermometer = FixedTemperature(temperature_k);
    let mut ports = CyclePorts {
        clock: &mut clock,
        thermometer: &mut thermometer,
        tables: &mut tables,
        table_in_force: None,
        telemetry: &mut recorder,
    };
    for mode in [Mode::Standby, Mode::Acquisition] {
        cycle
            .tracker_mut()
            .command_mode(mode)
            .map_err(|e| e.to_string())?;
        let Ok(_) = block_on(cycle.run_frame(source, &mut ports));
    }
    recorder
        .frames
        .pop()
        .ok_or_else(|| "the tracker reported no frame".to_string())
}

/// Housekeeping at a host start: a fresh fault record, every set-up step done.
pub fn host_health() -> Health {
    Health::new(FaultRecord::FRESH, SetupFaults::empty())
}

/// Runs a tracker future to completion: the host's sources never wait.
pub fn block_on<F: std::future::Future>(f: F) -> F::Output {
    pollster::block_on(f)
}

/// A recorded frame (row-major, `lines x line_len` raw samples) as a line source: every
/// frame it is asked for is this frame again. Lines the request does not read are skipped.
pub struct FrameLines<'a> {
    geometry: ReadoutGeometry,
    raw: &'a [u16],
    request_lines: Vec<bool>,
    next: usize,
}

impl<'a> FrameLines<'a> {
    /// The frame `raw` of `geometry`; `None` when its size does not match.
    pub fn new(geometry: ReadoutGeometry, raw: &'a [u16]) -> Option<Self> {
        (raw.len() == usize::from(geometry.lines) * geometry.line_len()).then(|| Self {
            geometry,
            raw,
            request_lines: Vec::new(),
            next: usize::from(geometry.lines),
        })
    }
}

impl LineSource for FrameLines<'_> {
    type Error = Infallible;

    async fn start_frame(
        &mut self,
        _frame: u32,
        request: &ReadoutRequest<'_>,
    ) -> Result<(), Infallible> {
        self.request_lines = (0..self.geometry.lines)
            .map(|l| request.reads_line(&self.geometry, l))
            .collect();
        self.next = 0;
        Ok(())
    }

    async fn next_line(&mut self) -> Result<Option<SourceLine<'_>>, Infallible> {
        while self.next < self.request_lines.len() && !self.request_lines[self.next] {
            self.next += 1;
        }
        let line = self.next;
        let len = self.geometry.line_len();
        let Some(samples) = self.raw.get(line * len..(line + 1) * len) else {
            return Ok(None);
        };
        self.next += 1;
        Ok(Some(SourceLine {
            line: line as u16,
            samples,
        }))
    }
}

/// The simulated sensor as a line source: frame `k` of the tracker is rendered by
/// `scene(k)` (the stars where they are at that frame, the frame's own noise), and only the
/// samples the request reads are rendered; the others are 0.
///
/// With a [`FrameTiming`] it also models when: frame `k` integrates from `k` periods for the
/// exposure (the simulator's motion model, `startrack_sim::sky::motion`), the frame
/// transfer follows and then the board's readout of what the frame reads, so the frame's
/// [`Integration`] is its exposure after its start, and its lines end the exposure plus the
/// readout after it ([`Self::readout_done_us`]).
pub struct SimLines<F: FnMut(u32) -> Simulator> {
    scene: F,
    sim: Option<Simulator>,
    lines: Vec<(u16, Vec<(usize, usize)>)>,
    next: usize,
    buf: Vec<u16>,
    /// Samples rendered so far (what a readout would have digitised).
    pub samples_rendered: u64,
    /// The current frame's readout on the board, us ([`board_readout_us`]): 0 from the
    /// frame's start until its last line has been given, then the readout (after the
    /// exposure, with a [`FrameTiming`]). A [`ReadoutClock`] sharing it reads the time the
    /// frame's lines end.
    pub readout_done_us: Rc<Cell<u64>>,
    readout_us: u64,
    timing: Option<FrameTiming>,
    integrations: Vec<Option<Integration>>,
    integration: Option<Integration>,
}

/// When the simulated frames are taken: one every `period_us` from the clock's 0, each
/// integrating for `exposure_us` from its start (what the simulator renders), us.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameTiming {
    /// The frame period, us.
    pub period_us: u64,
    /// The exposure, us.
    pub exposure_us: u64,
}

impl<F: FnMut(u32) -> Simulator> SimLines<F> {
    /// A source whose frame `k` is `scene(k)`.
    pub fn new(scene: F) -> Self {
        Self {
            scene,
            sim: None,
            lines: Vec::new(),
            next: 0,
            buf: Vec::new(),
            samples_rendered: 0,
            readout_done_us: Rc::new(Cell::new(0)),
            readout_us: 0,
            timing: None,
            integrations: Vec::new(),
            integration: None,
        }
    }

    /// The source with frame `k` integrating over `integrations[k]` where that is `Some`,
    /// whatever the timing says: another run's instants replayed.
    pub fn with_integrations(mut self, integrations: Vec<Option<Integration>>) -> Self {
        self.integrations = integrations;
        self
    }

    /// The source with frames taken as `timing` says (their [`Integration`] and readout
    /// instants).
    pub fn with_timing(mut self, timing: FrameTiming) -> Self {
        self.timing = Some(timing);
        self
    }
}

/// The board's readout of `request` on `geometry`, us: its program compiled as the board's
/// sequencer compiles it (1 MHz pixels, `Limits::CCD47_20`, no exposure padding), from the
/// start of its frame transfer to its last sample. A request the plan refuses is read as a
/// full frame, as the board does.
pub fn board_readout_us(geometry: &ReadoutGeometry, request: &ReadoutRequest<'_>) -> u64 {
    use startrack_core::sequencer::{
        Binning, CompileError, Cost, Limits, PinMap, ReadoutPlan, SegmentId, Step, Timing, compile,
    };
    let Ok(ticks) = Timing::at_pixel_rate(1_000_000).validate(&Limits::CCD47_20) else {
        return 0;
    };
    let plan = ReadoutPlan::new(*geometry, *request, Binning::X1, 0)
        .or_else(|_| ReadoutPlan::new(*geometry, ReadoutRequest::FullFrame, Binning::X1, 0));
    let Ok(plan) = plan else { return 0 };
    let (mut words, mut steps) = (vec![0u32; 2048], vec![Step::EMPTY; 4096]);
    loop {
        match compile(&plan, &ticks, &PinMap::IN_ORDER, &mut words, &mut steps) {
            Ok(p) => {
                let c = Cost::of(&p);
                return (c.segment_ns(SegmentId::FrameTransfer) + c.frame_time_ns()) / 1000;
            }
            Err(CompileError::Words { needed }) => words.resize(needed, 0),
            Err(CompileError::Steps { needed }) => steps.resize(needed, Step::EMPTY),
            Err(_) => return 0,
        }
    }
}

/// The raw column spans `[start, end)` of line `line` that `request` reads: the whole line,
/// or the over-scan and the covered columns the request reads plus the windows' pixels. Empty when the line is
/// not read.
pub fn read_spans(
    geometry: &ReadoutGeometry,
    request: &ReadoutRequest<'_>,
    line: u16,
) -> Vec<(usize, usize)> {
    if !request.reads_line(geometry, line) {
        return Vec::new();
    }
    let len = geometry.line_len();
    let ReadoutRequest::Windows(rects) = request else {
        return vec![(0, len)];
    };
    let first = geometry.first_active_col();
    let edge = request.edge_px(geometry);
    let mut spans: Vec<(usize, usize)> = vec![(0, edge), (len - edge, len)];
    for r in rects.iter().filter(|r| r.contains(r.x0, line)) {
        let s = first + usize::from(r.x0);
        spans.push((s, s + usize::from(r.width)));
    }
    spans.sort_unstable();
    let mut merged: Vec<(usize, usize)> = Vec::new();
    for (s, e) in spans {
        match merged.last_mut() {
            Some(last) if s <= last.1 => last.1 = last.1.max(e),
            _ => merged.push((s, e)),
        }
    }
    merged
}

impl<F: FnMut(u32) -> Simulator> LineSource for SimLines<F> {
    type Error = Infallible;

    async fn start_frame(
        &mut self,
        frame: u32,
        request: &ReadoutRequest<'_>,
    ) -> Result<(), Infallible> {
        let sim = (self.scene)(frame);
        let g = sim.params.geometry;
        self.lines = (0..g.lines)
            .map(|l| (l, read_spans(&g, request, l)))
            .filter(|(_, spans)| !spans.is_empty())
            .collect();
        self.buf = vec![0; g.line_len()];
        self.sim = Some(sim);
        self.next = 0;
        self.readout_us = board_readout_us(&g, request);
        self.readout_done_us.set(0);
        self.integration = self.timing.map(|t| {
            let start_us = u64::from(frame) * t.period_us;
            Integration {
                start_us,
                end_us: start_us + t.exposure_us,
            }
        });
        if let Some(&Some(i)) = self.integrations.get(frame as usize) {
            self.integration = Some(i);
        }
        if let Some(i) = self.integration {
            // The frame transfer ends the exposure; the readout follows it.
            self.readout_us += i.duration_us();
        }
        Ok(())
    }

    async fn next_line(&mut self) -> Result<Option<SourceLine<'_>>, Infallible> {
        let (Some(sim), Some((line, spans))) = (&self.sim, self.lines.get(self.next)) else {
            self.readout_done_us.set(self.readout_us);
            return Ok(None);
        };
        self.next += 1;
        self.buf.fill(0);
        for &(s, e) in spans {
            for (c, v) in self.buf[s..e].iter_mut().enumerate() {
                *v = sim.raw_sample(s + c, usize::from(*line));
            }
            self.samples_rendered += (e - s) as u64;
        }
        Ok(Some(SourceLine {
            line: *line,
            samples: &self.buf,
        }))
    }

    fn integration(&self) -> Option<Integration> {
        self.integration
    }
}

/// A clock that reads frame number x frame period (the host has no readout timing).
#[derive(Clone, Copy, Debug)]
pub struct FrameClock {
    /// The current frame.
    pub frame: u32,
    /// Frame period, us.
    pub period_us: u64,
}

impl Clock for FrameClock {
    fn now_us(&mut self) -> u64 {
        u64::from(self.frame) * self.period_us
    }
}

/// A clock that reads frame number x frame period, plus the frame's board readout once its
/// last line has been given ([`SimLines::readout_done_us`], after the frame's exposure with
/// a [`FrameTiming`]): a report made after the lines reads the time the board's lines would
/// end. The host's own processing time is not in
/// it (it is not the M7's).
#[derive(Clone, Debug)]
pub struct ReadoutClock {
    /// The current frame.
    pub frame: u32,
    /// Frame period, us.
    pub period_us: u64,
    /// The source's readout once the frame's lines have ended, us.
    pub readout_done_us: Rc<Cell<u64>>,
}

impl Clock for ReadoutClock {
    fn now_us(&mut self) -> u64 {
        u64::from(self.frame) * self.period_us + self.readout_done_us.get()
    }
}

/// A frame as the telemetry port reported it.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    /// Its stars, in reported order.
    pub stars: Vec<StarRecord>,
    /// Its summary.
    pub summary: FrameSummary,
}

/// A telemetry sink that keeps everything.
#[derive(Clone, Debug, Default)]
pub struct Recorder {
    /// Frames, in order.
    pub frames: Vec<FrameRecord>,
    /// Events, in order.
    pub events: Vec<Event>,
    /// Line summaries, in order.
    pub lines: Vec<LineSummary>,
    pending: Vec<StarRecord>,
}

impl TelemetrySink for Recorder {
    fn line(&mut self, summary: &LineSummary) {
        self.lines.push(*summary);
    }

    fn star(&mut self, _frame: u32, star: &StarRecord) {
        self.pending.push(*star);
    }

    fn frame(&mut self, summary: &FrameSummary) {
        self.frames.push(FrameRecord {
            stars: std::mem::take(&mut self.pending),
            summary: *summary,
        });
    }

    fn event(&mut self, event: &Event) {
        self.events.push(*event);
    }
}

/// The `stars.csv` header: one star a line, active-area pixels (0-based, pixel centres at
/// integers), `flags` the [`startrack_core::tracker::StarFlags`] bits.
pub const CSV_HEADER: &str =
    "x_px,y_px,flux_e,snr,sigma_x_px,sigma_y_px,flags,provenance,psf_a_px,chi2_dof";

/// One star as a `stars.csv` line (no newline).
pub fn csv_row(s: &StarRecord) -> String {
    format!(
        "{:.4},{:.4},{:.1},{:.2},{:.4},{:.4},{},{},{:.3},{:.3}",
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
    )
}

/// Writes `stars` as `stars.csv` (header, then one star per line).
pub fn write_csv(out: &mut dyn std::io::Write, stars: &[StarRecord]) -> std::io::Result<()> {
    writeln!(out, "{CSV_HEADER}")?;
    for s in stars {
        writeln!(out, "{}", csv_row(s))?;
    }
    Ok(())
}

/// Every line's bias levels and the dark scale of a recorded frame, for host analyses that
/// calibrate a frame's pixels outside the tracker (the demo's comparison with the truth,
/// the detection tests).
#[derive(Clone, Debug, PartialEq)]
pub struct FrameLevels {
    /// The frame's geometry.
    pub geometry: ReadoutGeometry,
    /// Bias levels of every raw line.
    pub lines: Vec<LineLevels>,
    /// The covered columns' dark scale over the whole frame, or `None` without covered
    /// columns.
    pub dark_scale_e: Option<Electrons>,
}

/// Measures every line's bias and the frame's dark scale with `table`. `raw` holds the
/// frame row-major (`lines x line_len` samples of the table's geometry).
pub fn frame_levels(table: &CalibTable<'_>, raw: &[u16]) -> Result<FrameLevels, String> {
    let g = *table.geometry();
    let expected = usize::from(g.lines) * g.line_len();
    if raw.len() != expected {
        return Err(format!(
            "frame has {} samples, the table's geometry needs {expected}",
            raw.len()
        ));
    }
    let mut est = DarkScaleEstimator::new();
    let mut lines = Vec::with_capacity(usize::from(g.lines));
    for line in raw.chunks_exact(g.line_len()) {
        let lv = LineLevels::measure(&g, line).map_err(|e| e.to_string())?;
        est.add_line(table, line, &lv).map_err(|e| e.to_string())?;
        lines.push(lv);
    }
    Ok(FrameLevels {
        geometry: g,
        lines,
        dark_scale_e: est.estimate(),
    })
}

impl FrameLevels {
    /// Calibrates window `rect` of the frame `raw` with `cal`: electrons, per-pixel flags,
    /// OR-ed flags.
    pub fn calibrate_window(
        &self,
        cal: &FrameCalibration<'_>,
        raw: &[u16],
        rect: Rect,
    ) -> Result<(Vec<Electrons>, Vec<PixelFlags>, PixelFlags), CalibError> {
        let g = self.geometry;
        let len = g.line_len();
        let (x0, y0) = (usize::from(rect.x0), usize::from(rect.y0));
        let w = usize::from(rect.width);
        let mut win = Vec::with_capacity(rect.len());
        for y in y0..y0 + usize::from(rect.height) {
            let start = g.raw_line_of_y(y) * len + g.raw_col_of_x(x0);
            win.extend_from_slice(raw.get(start..start + w).ok_or(CalibError::BufferLength)?);
        }
        let lv_start = g.raw_line_of_y(y0);
        let lv = self
            .lines
            .get(lv_start..lv_start + usize::from(rect.height))
            .ok_or(CalibError::BufferLength)?;
        let mut e = vec![Electrons::ZERO; rect.len()];
        let mut f = vec![PixelFlags::empty(); rect.len()];
        let flags = cal.calibrate_window(rect, &win, lv, &mut e, &mut f)?;
        Ok((e, f, flags))
    }
}
