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
//! One word copy per tick played: at 1 MHz pixels 8 M words/s (not yet measured). The
//! ring holds [`RING_WORDS`] ticks (512 us at 125 ns): the feeder must run once per half
//! ring (256 us), or the clocks stall (an underrun, reported as [`SeqError::Underrun`]). It
//! therefore runs in an interrupt-level executor (`main.rs`), which preempts the tracker.
//!
//! # Lines to the ADC reader
//! As the feeder queues a frame it walks the program's line jobs (`LineJobs`): when a job's
//! last word is queued it goes to [`LINE_JOBS`] with the instant its last sample will be
//! taken (from the words still ahead of it in the ring and the tick), and the readout task
//! reads that line's words from the ADC board after that instant ([`crate::readout`]). The
//! board must buffer the samples of at least a line and a half ring (docs/hardware.md).
//!
//! # Not yet
//! The frames are full frames: the tracker's requests (windows) are not routed here, and
//! the waveforms have not been seen on a board (docs/hardware.md has the HIL steps).

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
use embassy_time::{Duration, Instant};
use startrack_core::sequencer::{Cursor, LineJob, LineJobs, PinMap, Program, Step};

/// The clock port's pin map: line `l` on PE`l` (I1-I3 PE0-2, S1-S3 PE3-5, R1L-R3L PE6-8,
/// R1R-R3R PE9-11, RG PE12, SW PE13, DG PE14, CONVST PE15).
pub const PINS: PinMap = PinMap::IN_ORDER;

/// Ticks the DMA ring holds (two halves).
pub const RING_WORDS: usize = 4096;

/// Words of the segment table (the largest plan needs ~1,000).
pub const MAX_WORDS: usize = 4096;

/// Program steps (a full frame ~2,100, 60 windows through one output ~3,000).
pub const MAX_STEPS: usize = 5120;

/// A compiled frame's storage: CPU-only, cacheable (`.bss`, AXI SRAM), 56 KB of the 64 KB
/// `startrack_core::sequencer::TABLE_RAM_BYTES`.
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
    /// Frame number since the clocks started (wraps).
    pub frame: u32,
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
    /// Frames queued since the clocks started.
    frame: u32,
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
            frame: 0,
            dropped_lines: 0,
        }
    }

    /// Queues every word of `program` after whatever is queued, starting the timer and the
    /// DMA on the first call (the ring is filled first). Returns when the last word is
    /// queued, so the next frame's program follows without a gap.
    pub async fn play(&mut self, program: &Program<'_, '_>) -> Result<(), SeqError> {
        let mut cursor = Cursor::START;
        let mut chunk = [0u32; 256];
        let frame_start = self.queued;
        let frame = self.frame;
        self.frame = self.frame.wrapping_add(1);
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

    /// Sends every job whose words are all queued, with the instant of its last sample.
    fn send_jobs(
        &mut self,
        jobs: &mut core::iter::Peekable<LineJobs<'_, '_, '_>>,
        frame: u32,
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
            if LINE_JOBS.try_send(LineReady { frame, due, job }).is_err() {
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

/// The frames the clock port plays while the tracker's requests are not yet routed here:
/// full frames of [`crate::lines::GEOMETRY`] at [`PIXEL_RATE_HZ`], back to back.
pub const PIXEL_RATE_HZ: u32 = 1_000_000;

/// Compiles the full-frame plan into `tables` and plays it frame after frame; logs the
/// frame's cost first and any underrun (then restarts the clocks).
#[embassy_executor::task]
pub async fn sequencer_task(mut seq: Sequencer, tables: &'static mut Tables) {
    use startrack_core::sequencer::{Binning, Cost, Limits, ReadoutPlan, Timing, compile};
    use startrack_core::tracker::ReadoutRequest;
    let plan = match ReadoutPlan::new(
        crate::lines::GEOMETRY,
        ReadoutRequest::FullFrame,
        Binning::X1,
        0,
    ) {
        Ok(p) => p,
        Err(e) => {
            defmt::error!("sequencer: plan refused: {}", e);
            return;
        }
    };
    let ticks = match Timing::at_pixel_rate(PIXEL_RATE_HZ).validate(&Limits::CCD47_20) {
        Ok(t) => t,
        Err(e) => {
            defmt::error!("sequencer: timing refused: {}", e);
            return;
        }
    };
    let program = match compile(&plan, &ticks, &PINS, &mut tables.words, &mut tables.steps) {
        Ok(p) => p,
        Err(e) => {
            defmt::error!("sequencer: compile failed: {}", e);
            return;
        }
    };
    let cost = Cost::of(&program);
    defmt::info!(
        "sequencer: {} words, {} steps, tick {} ps, frame {} us, {} mHz",
        program.words().len(),
        program.steps().len(),
        program.tick_ps(),
        cost.frame_time_ns() / 1000,
        cost.update_rate_mhz()
    );
    loop {
        if let Err(e) = seq.play(&program).await {
            defmt::warn!("sequencer: {}, clocks restarted", e);
            seq.stop();
        }
    }
}
