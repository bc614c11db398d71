//! The CCD clock sequencer on the board: the core's compiled program played into the clock
//! port by timer-paced DMA.
//!
//! # How
//! TIM6 (a basic timer, nothing else uses it) overflows once a tick (`Ticks::tick_ps`, 125 ns
//! at 1 MHz pixels); each update event requests one DMA1 stream 1 transfer (routed by
//! DMAMUX1) of a `u32` from a ring of BSRR words into GPIOE's BSRR, so each tick sets all
//! 16 clock lines, the ADC's CONVST among them, at once (pin map: [`PINS`], docs/hardware.md).
//! A DMA stream cannot jump between `(segment, repeat)` steps within a tick, so the task
//! keeps the ring full: the core's [`Cursor`] writes the program's next words into the part
//! of the ring the DMA has played (embassy-stm32's `WritableRingBuffer`, circular mode with
//! half/complete interrupts). The ring sits in the non-cacheable DMA region
//! ([`crate::memory`]); the tables it is fed from are CPU-only and cacheable.
//!
//! # Cost
//! One word copy per tick played: at 1 MHz pixels 8 M words/s, 6.0 instructions a word on
//! QEMU's M7 (`cargo m7-bench`'s `sequencer_feed_words`), and compiling a tracking frame of
//! 30 windows 0.50 M instructions (`sequencer_compile`; docs/sequencer.md). The
//! ring holds [`RING_WORDS`] ticks (512 us at 125 ns): the feeder must run once per half
//! ring (256 us), or the clocks stall (an underrun, reported as [`SeqError::Underrun`]). It
//! therefore runs in an interrupt-level executor (`main.rs`), which preempts the tracker.
//!
//! # Lines to the ADC reader
//! As the feeder queues a requested frame it walks the program's line jobs (`LineJobs`): when
//! a job's last word is queued it goes to [`LINE_JOBS`], tagged with the tracker's frame number
//! and whether it is the frame's last line, with the instant its last sample will be
//! taken (from the words still ahead of it in the ring and the tick), and the readout task
//! reads that line's words from the ADC board after that instant ([`crate::readout`]). The
//! board must buffer the samples of at least a line and a half ring (docs/hardware.md).
//!
//! # What each frame plays
//! The tracker's line source (`app.rs`'s `ChannelLines`) sends each frame's request as a
//! [`FrameRequest`] (the window list copied into a bounded message) to [`REQUESTS`]. The
//! [`plan_task`] (thread mode, below the feeder's priority) compiles it with the core
//! compiler into whichever of the two [`Tables`] is not being played, with the exposure the
//! tracker's configuration sets, and hands the result to the feeder ([`sequencer_task`]),
//! which plays it after the frame in play; the tables travel by ownership through two
//! channels, so a frame's tables are never written while the DMA ring is fed from them. A
//! request the plan or the compiler refuses (too many windows, a window outside, tables too
//! small) is compiled as a full frame instead, counted in [`FALLBACKS`] and logged. Until
//! the next request arrives the port holds the rest state (the image keeps integrating) in
//! [`IDLE_WORDS`] chunks; after [`MAX_WAIT_US`] without one the last program is replayed
//! unannounced (its lines are not read), so the image is not left to saturate.
//!
//! # Not yet
//! The waveforms have not been seen on a board (docs/hardware.md has the HIL steps).

use core::sync::atomic::{AtomicU32, Ordering};
use embassy_stm32::Peri;
use embassy_stm32::dma::{self, Priority, TransferOptions, WritableRingBuffer};
use embassy_stm32::gpio::{AnyPin, Level, Output, Speed};
use embassy_stm32::interrupt::typelevel::Binding;
use embassy_stm32::peripherals::{DMA1_CH1, TIM6};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::UpDma;
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant};
use startrack_core::sequencer::{
    Binning, CompileError, Cost, Cursor, Limits, LineJob, LineJobs, MAX_WINDOWS, PinMap, PlanError,
    Program, ProgramParts, ReadoutPlan, Step, Ticks, Timing, compile, rest,
};
use startrack_core::tracker::ReadoutRequest;
use startrack_core::window::Rect;

/// The clock port's pin map: line `l` on PE`l` (I1-I3 PE0-2, S1-S3 PE3-5, R1L-R3L PE6-8,
/// R1R-R3R PE9-11, RG PE12, SW PE13, DG PE14, CONVST PE15).
pub const PINS: PinMap = PinMap::IN_ORDER;

/// Ticks the DMA ring holds (two halves).
pub const RING_WORDS: usize = 4096;

/// Words of the segment table (the largest plan the board makes needs 503, host test
/// `sequencer_route`).
pub const MAX_WORDS: usize = 1024;

/// Program steps (the largest plan the board makes, 64 windows, needs 3,572: host test
/// `sequencer_route`).
pub const MAX_STEPS: usize = 4096;

/// A compiled frame's storage: CPU-only, cacheable (`.bss`, AXI SRAM), 36 KB (two: one
/// played, one compiled), within the 64 KB `startrack_core::sequencer::TABLE_RAM_BYTES` each.
pub struct Tables {
    /// The segment words.
    pub words: [u32; MAX_WORDS],
    /// The program.
    pub steps: [Step; MAX_STEPS],
}

impl Tables {
    /// Zeroed tables.
    pub const fn new() -> Self {
        Self {
            words: [0; MAX_WORDS],
            steps: [Step::EMPTY; MAX_STEPS],
        }
    }
}

/// A digitised line for the ADC reader.
pub struct LineReady {
    /// The tracker's frame number of the request the frame was compiled from.
    pub frame: u32,
    /// The frame's last digitised line.
    pub last: bool,
    /// When its last sample is taken.
    pub due: Instant,
    /// What it digitises and where each word goes.
    pub job: LineJob,
}

/// Lines queued on the clock port, for the readout task. Sixteen: a ring's worth of the
/// shortest (windowed) lines.
pub static LINE_JOBS: Channel<CriticalSectionRawMutex, LineReady, 16> = Channel::new();

/// Why the clocks stopped.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum SeqError {
    /// The feeder fell a whole ring behind the DMA: the port replayed stale words.
    Underrun,
}

/// The clock port driven by TIM6 and DMA1 stream 1.
pub struct Sequencer {
    timer: Timer<'static, TIM6>,
    ring: WritableRingBuffer<'static, u32>,
    _pins: [Output<'static>; 16],
    running: bool,
    /// Words queued since the clocks started.
    queued: u64,
    /// Line jobs the readout had no room for.
    pub dropped_lines: u32,
}

impl Sequencer {
    /// Takes the timer, the DMA stream, the 16 pins of GPIOE (PE0..PE15, in order) and the
    /// ring (in the non-cacheable DMA region); every line starts low.
    pub fn new(
        tim: Peri<'static, TIM6>,
        dma: Peri<'static, DMA1_CH1>,
        irq: impl Binding<
            <DMA1_CH1 as dma::ChannelInstance>::Interrupt,
            dma::InterruptHandler<DMA1_CH1>,
        > + 'static,
        pins: [Peri<'static, AnyPin>; 16],
        ring: &'static mut [u32; RING_WORDS],
    ) -> Self {
        let pins = pins.map(|p| Output::new(p, Level::Low, Speed::VeryHigh));
        let request = <DMA1_CH1 as UpDma<TIM6>>::request(&dma);
        let mut options = TransferOptions::default();
        options.priority = Priority::VeryHigh;
        let bsrr = embassy_stm32::pac::GPIOE.bsrr().as_ptr() as *mut u32;
        // SAFETY: `bsrr` is GPIOE's BSRR, a 32-bit write-only register whose every value is
        // valid; the ring is 'static and owned by the returned driver.
        let ring = unsafe {
            WritableRingBuffer::new(dma::Channel::new(dma, irq), request, bsrr, ring, options)
        };
        let timer = Timer::new(tim);
        Self {
            timer,
            ring,
            _pins: pins,
            running: false,
            queued: 0,
            dropped_lines: 0,
        }
    }

    /// Whether the clocks run.
    pub const fn running(&self) -> bool {
        self.running
    }

    /// Queues `n` ticks of `word` (the rest state while no frame is ready); the clocks must
    /// be running.
    pub async fn hold(&mut self, word: u32, n: usize) -> Result<(), SeqError> {
        let chunk = [word; IDLE_WORDS];
        let mut left = n;
        while left > 0 {
            let k = left.min(IDLE_WORDS);
            self.ring
                .write_exact(chunk.get(..k).unwrap_or(&[]))
                .await
                .map_err(|_| SeqError::Underrun)?;
            self.queued += k as u64;
            left -= k;
        }
        Ok(())
    }

    /// Queues every word of `program` after whatever is queued, starting the timer and the
    /// DMA on the first call (the ring is filled first). Returns when the last word is
    /// queued, so the next frame's program follows without a gap. With `frame` (the
    /// tracker's frame number) its line jobs go to [`LINE_JOBS`]; without, nothing is read.
    pub async fn play(
        &mut self,
        program: &Program<'_, '_>,
        frame: Option<u32>,
    ) -> Result<(), SeqError> {
        let mut cursor = Cursor::START;
        let mut chunk = [0u32; 256];
        let frame_start = self.queued;
        let mut jobs = LineJobs::new(program).peekable();
        if !self.running {
            let hz = 1_000_000_000_000 / u64::from(program.tick_ps().max(1));
            self.timer.stop();
            self.timer.set_frequency(Hertz(hz as u32), RoundTo::Faster);
            self.timer.enable_update_dma(true);
            // Prime the ring so the first update events find words; what does not fit is
            // queued once the DMA runs.
            self.ring.clear();
            let mut pending = 0..0;
            loop {
                let n = cursor.fill(program, &mut chunk);
                let (written, _) = self
                    .ring
                    .write_immediate(chunk.get(..n).unwrap_or(&[]))
                    .map_err(|_| SeqError::Underrun)?;
                self.queued += written as u64;
                if written < n {
                    pending = written..n;
                    break;
                }
                if n < chunk.len() {
                    break;
                }
            }
            self.ring.start();
            self.timer.start();
            self.running = true;
            let rest = chunk.get(pending).unwrap_or(&[]);
            self.ring
                .write_exact(rest)
                .await
                .map_err(|_| SeqError::Underrun)?;
            self.queued += rest.len() as u64;
            self.send_jobs(&mut jobs, frame, frame_start, program.tick_ps());
        }
        loop {
            let n = cursor.fill(program, &mut chunk);
            if n == 0 {
                return Ok(());
            }
            self.ring
                .write_exact(chunk.get(..n).unwrap_or(&[]))
                .await
                .map_err(|_| SeqError::Underrun)?;
            self.queued += n as u64;
            self.send_jobs(&mut jobs, frame, frame_start, program.tick_ps());
        }
    }

    /// Sends every job whose words are all queued, with the instant of its last sample
    /// (none for an unannounced frame: the jobs are walked past).
    fn send_jobs(
        &mut self,
        jobs: &mut core::iter::Peekable<LineJobs<'_, '_, '_>>,
        frame: Option<u32>,
        frame_start: u64,
        tick_ps: u32,
    ) {
        // Words queued but not yet played.
        let ahead = self.ring.len().unwrap_or(0) as u64;
        let played = self.queued.saturating_sub(ahead);
        let now = Instant::now();
        while let Some(job) = jobs.next_if(|j| frame_start + j.end_tick <= self.queued) {
            let ticks_left = (frame_start + job.end_tick).saturating_sub(played);
            let due =
                now + Duration::from_micros((ticks_left * u64::from(tick_ps)).div_ceil(1_000_000));
            let Some(frame) = frame else { continue };
            let last = jobs.peek().is_none();
            if LINE_JOBS
                .try_send(LineReady {
                    frame,
                    last,
                    due,
                    job,
                })
                .is_err()
            {
                self.dropped_lines = self.dropped_lines.wrapping_add(1);
            }
        }
    }

    /// Stops the clocks (timer first, then the DMA); the port keeps its last word.
    pub fn stop(&mut self) {
        self.timer.stop();
        self.timer.enable_update_dma(false);
        self.ring.request_reset();
        self.running = false;
        self.queued = 0;
    }
}

/// The pixel rate the frames are compiled for.
pub const PIXEL_RATE_HZ: u32 = 1_000_000;

/// Ticks of rest state queued at a time while no frame is ready (32 us at 125 ns).
pub const IDLE_WORDS: usize = 256;

/// Longest wait for the next request before the last program is replayed unannounced, us.
pub const MAX_WAIT_US: u64 = 200_000;

/// One frame's request as the sequencer gets it: the tracker's frame number, its exposure
/// and its windows copied (no borrow crosses tasks). Cost: ~530 bytes.
#[derive(Clone, Debug)]
pub struct FrameRequest {
    /// The tracker's frame number (tags the frame's lines).
    pub frame: u32,
    /// The exposure the tracker's configuration sets, us.
    pub exposure_us: u32,
    /// `None`: full frame; else the windows.
    pub windows: Option<heapless::Vec<Rect, MAX_WINDOWS>>,
    /// The request had more windows than a message holds (compiled as a full frame).
    pub truncated: bool,
}

impl FrameRequest {
    /// Copies `request` for frame `frame` with `exposure_us`.
    pub fn new(frame: u32, request: &ReadoutRequest<'_>, exposure_us: u32) -> Self {
        let (windows, truncated) = match request {
            ReadoutRequest::FullFrame => (None, false),
            ReadoutRequest::Windows(rects) => match heapless::Vec::from_slice(rects) {
                Ok(v) => (Some(v), false),
                Err(_) => (None, true),
            },
        };
        Self {
            frame,
            exposure_us,
            windows,
            truncated,
        }
    }
}

/// The latest request (a newer one replaces one not yet compiled).
pub static REQUESTS: Signal<CriticalSectionRawMutex, FrameRequest> = Signal::new();

/// Requests compiled as full frames instead (refused plan or compile), since start-up.
pub static FALLBACKS: AtomicU32 = AtomicU32::new(0);

/// A compiled frame on its way to the feeder, with the tables it lives in.
struct Compiled {
    tables: &'static mut Tables,
    parts: ProgramParts,
    frame: u32,
}

/// Tables the compiler may write (not being played).
static FREE_TABLES: Channel<CriticalSectionRawMutex, &'static mut Tables, 2> = Channel::new();

/// The next frame to play.
static READY: Channel<CriticalSectionRawMutex, Compiled, 1> = Channel::new();

/// Why a request was not compiled as asked.
#[derive(Clone, Copy, Debug, defmt::Format)]
enum Refused {
    Truncated,
    Plan(PlanError),
    Compile(CompileError),
}

/// Compiles `req` into `tables` (windows, or a full frame), falling back to a full frame
/// when the windows are refused; `None` only when the full frame fails too.
fn compile_request(req: &FrameRequest, ticks: &Ticks, tables: &mut Tables) -> Option<ProgramParts> {
    let asked = match (&req.windows, req.truncated) {
        (_, true) => Err(Refused::Truncated),
        (None, false) => Ok(ReadoutRequest::FullFrame),
        (Some(w), false) => Ok(ReadoutRequest::Windows(w.as_slice())),
    };
    let first = asked.and_then(|request| {
        let plan = ReadoutPlan::new(
            crate::lines::GEOMETRY,
            request,
            Binning::X1,
            req.exposure_us,
        )
        .map_err(Refused::Plan)?;
        compile(&plan, ticks, &PINS, &mut tables.words, &mut tables.steps)
            .map(|p| p.parts())
            .map_err(Refused::Compile)
    });
    let e = match first {
        Ok(parts) => return Some(parts),
        Err(e) => e,
    };
    let n = FALLBACKS.fetch_add(1, Ordering::Relaxed).wrapping_add(1);
    defmt::warn!(
        "sequencer: frame {} refused ({}), read as a full frame (fallbacks: {})",
        req.frame,
        e,
        n
    );
    let plan = ReadoutPlan::new(
        crate::lines::GEOMETRY,
        ReadoutRequest::FullFrame,
        Binning::X1,
        req.exposure_us,
    )
    .ok()?;
    match compile(&plan, ticks, &PINS, &mut tables.words, &mut tables.steps) {
        Ok(p) => Some(p.parts()),
        Err(e) => {
            defmt::error!("sequencer: full frame failed: {}", e);
            None
        }
    }
}

/// The compiler: each request from [`REQUESTS`] into free tables, then to the feeder. Runs
/// in thread mode, so the feeder preempts it; a frame's compile (O(row groups x windows))
/// never delays the clock ring.
#[embassy_executor::task]
pub async fn plan_task() {
    let ticks = match Timing::at_pixel_rate(PIXEL_RATE_HZ).validate(&Limits::CCD47_20) {
        Ok(t) => t,
        Err(e) => {
            defmt::error!("sequencer: timing refused: {}", e);
            return;
        }
    };
    loop {
        let req = REQUESTS.wait().await;
        let tables = FREE_TABLES.receive().await;
        match compile_request(&req, &ticks, tables) {
            Some(parts) => {
                READY
                    .send(Compiled {
                        tables,
                        parts,
                        frame: req.frame,
                    })
                    .await;
            }
            None => {
                if FREE_TABLES.try_send(tables).is_err() {
                    defmt::error!("sequencer: free tables channel full");
                }
            }
        }
    }
}

/// The feeder: plays each compiled frame after the one in play, the rest state while the
/// next is not ready, and the last one again (unannounced) after [`MAX_WAIT_US`]; logs the
/// first frame's cost and any underrun (then restarts the clocks with the next frame).
#[embassy_executor::task]
pub async fn sequencer_task(mut seq: Sequencer, tables: [&'static mut Tables; 2]) {
    for t in tables {
        if FREE_TABLES.try_send(t).is_err() {
            defmt::error!("sequencer: free tables channel full");
        }
    }
    let rest_word = PINS.bsrr(rest(crate::lines::GEOMETRY.outputs));
    let mut current: Option<Compiled> = None;
    let mut waited_ticks: u64 = 0;
    let mut logged = false;
    loop {
        let next = if seq.running() {
            READY.try_receive().ok()
        } else {
            Some(READY.receive().await)
        };
        let frame = match next {
            Some(next) => {
                if let Some(old) = current.replace(next)
                    && FREE_TABLES.try_send(old.tables).is_err()
                {
                    defmt::error!("sequencer: free tables channel full");
                }
                waited_ticks = 0;
                current.as_ref().map(|c| c.frame)
            }
            None => {
                let tick_ps = current.as_ref().map_or(1, |c| {
                    c.parts
                        .view(&c.tables.words, &c.tables.steps)
                        .map_or(1, |p| p.tick_ps())
                });
                if waited_ticks * u64::from(tick_ps) < MAX_WAIT_US * 1_000_000 {
                    if let Err(e) = seq.hold(rest_word, IDLE_WORDS).await {
                        defmt::warn!("sequencer: {}, clocks stopped", e);
                        seq.stop();
                    }
                    waited_ticks += IDLE_WORDS as u64;
                    continue;
                }
                waited_ticks = 0;
                None
            }
        };
        let Some(c) = current.as_ref() else { continue };
        let Some(program) = c.parts.view(&c.tables.words, &c.tables.steps) else {
            defmt::error!("sequencer: compiled tables shorter than their program");
            continue;
        };
        if !logged {
            let cost = Cost::of(&program);
            defmt::info!(
                "sequencer: {} words, {} steps, tick {} ps, frame {} us, {} mHz",
                program.words().len(),
                program.steps().len(),
                program.tick_ps(),
                cost.frame_time_ns() / 1000,
                cost.update_rate_mhz()
            );
            logged = true;
        }
        if let Err(e) = seq.play(&program, frame).await {
            defmt::warn!("sequencer: {}, clocks restarted", e);
            seq.stop();
        }
    }
}
