//! The board's routing of the tracker's requests to the sequencer, on the host: the lines a
//! tracking frame's compiled program digitises (`LineJobs`, `LineJob::unpack`: what the
//! firmware's readout delivers), clocked through the charge-transfer model, give the tracker
//! the same stars as the whole frame; and the tables the firmware sets aside for a frame (two
//! of them, `firmware/src/board/stm32h743/sequencer.rs`) hold every plan the board compiles.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, Limits, LineJobs, PinMap, ReadoutPlan, Step, Ticks, Timing, compile,
};
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    FixedTable, FixedTemperature, LineSource, Mode, Ports, SourceLine, Tracker, TrackerBuffers,
};
use startrack_homes::home::{FrameClock, FrameLines, Recorder, block_on};
use startrack_homes::sil::{self, SIL_CAPACITY, SilConfig};
use startrack_host::cli::readout_plan::{self, ReadoutPlanArgs, plan_cost};
use startrack_sim::ccd_model::CcdModel;
use startrack_sim::sim::{SensorParams, Simulator};
use std::convert::Infallible;

/// A rendered frame as the board reads it: a full frame line by line; a windowed frame
/// through the compiled program, clocked through the charge-transfer model loaded with the
/// frame's covered and active samples, each line job's ADC words unpacked into a raw line as
/// the firmware's readout does. The over-scan elements hold no charge in the model (they are
/// register elements only): their words must read 0, and the amplifier's level there is
/// taken from the rendered frame.
struct ModelLines<'a> {
    geometry: ReadoutGeometry,
    raw: &'a [u16],
    ticks: Ticks,
    lines: Vec<(u16, Vec<u16>)>,
    next: usize,
    /// Windowed frames clocked through the model.
    windowed: u32,
}

impl LineSource for ModelLines<'_> {
    type Error = Infallible;

    async fn start_frame(
        &mut self,
        _frame: u32,
        request: &ReadoutRequest<'_>,
    ) -> Result<(), Infallible> {
        let g = self.geometry;
        let len = g.line_len();
        self.next = 0;
        self.lines.clear();
        if let ReadoutRequest::FullFrame = request {
            // The full frame's layout through the model is sequencer_model's test.
            for l in 0..g.lines {
                let row = &self.raw[usize::from(l) * len..][..len];
                self.lines.push((l, row.to_vec()));
            }
            return Ok(());
        }
        self.windowed += 1;
        let plan = ReadoutPlan::new(g, *request, Binning::X1, 100_000);
        let plan = plan.unwrap_or_else(|e| unreachable!("{e}"));
        let (mut w, mut s) = (vec![0; BOARD_MAX_WORDS], vec![Step::EMPTY; BOARD_MAX_STEPS]);
        let program = compile(&plan, &self.ticks, &PinMap::IN_ORDER, &mut w, &mut s);
        let program = program.unwrap_or_else(|e| unreachable!("{e}"));
        let mut model = CcdModel::new(&g, PinMap::IN_ORDER, &self.ticks);
        let raw = self.raw;
        let offset = model.raw_col(0);
        model.load(|c, y| i64::from(raw[y * len + c + offset]), |_, _| 0);
        model.run(program.ticks());
        let words: Vec<u16> = model
            .pixels()
            .iter()
            .flat_map(|p| [p[0], p[1]])
            .map(|q| u16::try_from(q).unwrap_or_else(|_| unreachable!("charge {q}")))
            .collect();
        let mut at = 0;
        let overscan = usize::from(g.overscan_px);
        for job in LineJobs::new(&program) {
            let n = job.words as usize;
            let mut line = vec![0u16; len];
            let used = job.unpack(g.outputs, 1, &words[at..at + n], &mut line);
            assert_eq!(used, Ok(n));
            at += n;
            let row = &raw[usize::from(job.line) * len..][..len];
            for c in (0..overscan).chain(len - overscan..len) {
                assert_eq!(line[c], 0, "over-scan column {c} holds charge");
                line[c] = row[c];
            }
            self.lines.push((job.line, line));
        }
        assert_eq!(at, words.len(), "words no line job took");
        Ok(())
    }

    async fn next_line(&mut self) -> Result<Option<SourceLine<'_>>, Infallible> {
        let Some((line, samples)) = self.lines.get(self.next) else {
            return Ok(None);
        };
        self.next += 1;
        Ok(Some(SourceLine {
            line: *line,
            samples,
        }))
    }
}

/// The SIL's field (20 stars, drifting): a tracker fed each rendered frame whole and one fed
/// what the board's sequencer reads of it (the windows clocked through the model) report
/// the same stars, bit for bit, in every frame, tracking frames included.
#[test]
fn windowed_readout_through_the_model_gives_the_full_frame_stars() {
    let config = SilConfig::default();
    let params = SensorParams {
        seed: config.seed,
        ..SensorParams::default()
    };
    let g = params.geometry;
    let base = sil::scene(&config, &params);
    let table_bytes = sil::truth_table(&config, &params).unwrap_or_else(|e| unreachable!("{e}"));
    let table = CalibTable::parse(&table_bytes).unwrap_or_else(|e| unreachable!("{e}"));
    let ticks = Timing::at_pixel_rate(1_000_000).validate(&Limits::CCD47_20);
    let ticks = ticks.unwrap_or_else(|e| unreachable!("{e}"));

    let (mut buf_full, mut buf_model) = (
        Box::new(TrackerBuffers::new()),
        Box::new(TrackerBuffers::new()),
    );
    let tracker = |b| Tracker::<SIL_CAPACITY>::new(config.tracker, g, b);
    let mut full = Box::new(tracker(&mut buf_full).unwrap_or_else(|e| unreachable!("{e}")));
    let mut routed = Box::new(tracker(&mut buf_model).unwrap_or_else(|e| unreachable!("{e}")));
    let (mut rec_full, mut rec_model) = (Recorder::default(), Recorder::default());
    let mut windowed = 0;
    let mut tracking_stars = 0;
    for k in 0..3u32 {
        let sim = Simulator {
            frame: k,
            ..Simulator::new(params.clone(), sil::stars_at(&base, config.drift_px, k))
        };
        let len = g.line_len();
        let mut raw = vec![0u16; usize::from(g.lines) * len];
        for (l, row) in raw.chunks_exact_mut(len).enumerate() {
            sim.render_line(l, row);
        }
        for (tracker, rec, board) in [
            (&mut full, &mut rec_full, false),
            (&mut routed, &mut rec_model, true),
        ] {
            let mut clock = FrameClock {
                frame: k,
                period_us: config.period_us,
            };
            let (mut tables, mut thermometer) = (FixedTable(Some(table)), FixedTemperature(None));
            let mut ports = Ports {
                clock: &mut clock,
                thermometer: &mut thermometer,
                tables: &mut tables,
                telemetry: rec,
            };
            if board {
                let mut source = ModelLines {
                    geometry: g,
                    raw: &raw,
                    ticks,
                    lines: Vec::new(),
                    next: 0,
                    windowed: 0,
                };
                let Ok(_) = block_on(tracker.run_frame(&mut source, &mut ports));
                windowed += source.windowed;
            } else {
                let mut source = FrameLines::new(g, &raw).unwrap_or_else(|| unreachable!());
                let Ok(_) = block_on(tracker.run_frame(&mut source, &mut ports));
            }
        }
        let (a, b) = (&rec_full.frames[k as usize], &rec_model.frames[k as usize]);
        assert_eq!(a.summary.mode, b.summary.mode, "frame {k}");
        assert!(
            same_bits(&a.stars, &b.stars),
            "frame {k}: {:?}\n{:?}",
            a.stars,
            b.stars
        );
        if b.summary.mode == Mode::Tracking {
            tracking_stars += b.stars.len();
        }
    }
    println!("{windowed} windowed frames through the model, {tracking_stars} tracked stars");
    assert!(windowed >= 2, "{windowed} windowed frames");
    assert!(tracking_stars >= 2 * 18, "{tracking_stars} tracked stars");
}

fn same_bits(
    a: &[startrack_core::tracker::StarRecord],
    b: &[startrack_core::tracker::StarRecord],
) -> bool {
    let key = |s: &startrack_core::tracker::StarRecord| {
        [
            s.x_px.to_bits(),
            s.y_px.to_bits(),
            s.flux_e.to_bits(),
            s.snr.to_bits(),
            s.sigma_x_px.to_bits(),
            s.sigma_y_px.to_bits(),
            s.flags.bits(),
        ]
    };
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| key(x) == key(y))
}

/// `firmware/src/board/stm32h743/sequencer.rs`'s `MAX_WORDS` and `MAX_STEPS` (the firmware crate does not
/// build for the host; keep them equal).
pub(crate) const BOARD_MAX_WORDS: usize = 1152;
pub(crate) const BOARD_MAX_STEPS: usize = 4096;

/// Every plan the board compiles (1 MHz, both outputs, binning 1: a full frame, or up to the
/// plan's 64 windows of 11 x 11) fits one of the board's table buffers.
#[test]
fn board_plans_fit_the_board_tables() {
    let (mut words, mut steps) = (0, 0);
    for (mode, n) in [
        (readout_plan::Mode::Full, 0),
        (readout_plan::Mode::Windows, 10),
        (readout_plan::Mode::Windows, 30),
        (readout_plan::Mode::Windows, 60),
        (readout_plan::Mode::Windows, 64),
    ] {
        let a = ReadoutPlanArgs {
            mode,
            pixel_rate_hz: 1_000_000,
            windows: n,
            window_px: 11,
            outputs: 2,
            binning: 1,
            exposure_us: 1_000_000,
            seed: 1,
            breakdown: false,
        };
        let c = plan_cost(&a);
        assert!(c.is_ok(), "{c:?}");
        let Ok(c) = c else { return };
        words = words.max(c.words);
        steps = steps.max(c.steps);
    }
    println!(
        "largest board plan: {words} words (of {BOARD_MAX_WORDS}), {steps} steps (of {BOARD_MAX_STEPS})"
    );
    assert!(words <= BOARD_MAX_WORDS && steps <= BOARD_MAX_STEPS);
}
