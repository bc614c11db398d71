//! The CCD clock sequencer on the board: the core's compiled program played into the clock
//! port by a DMA that repeats each segment itself.
//!
//! # How
//! TIM6 (a basic timer, nothing else uses it) overflows once a tick (`Ticks::tick_ps`, 50 ns
//! at 1 MHz pixels); each update event requests one transfer of DMA1 stream 1 (routed by
//! DMAMUX1, circular, one item, no interrupt), which writes 0 into GPIOE's BSRR (a word that
//! changes no line) and so raises the stream's transfer-complete flag once a tick. That flag
//! is a hardware request of the MDMA (channel 0), which plays the frame as a linked list
//! ([`super::mdma_list`]): each request moves the next word of the frame's chain table
//! (`startrack_core::sequencer::Chain`) into GPIOE's BSRR, setting all 16 clock lines, the
//! ADC's CONVST among them, at once (pin map: [`PINS`], docs/hardware.md), then clears the
//! flag (the node's mask write). Each node plays one program step: a segment's words,
//! repeated up to 4096 times by the MDMA itself. The CPU writes nodes, one a step, into a
//! ring of [`NODE_RING`] nodes ahead of the MDMA and links them to the node in play (the
//! last written node ends the list until the next are linked to it). The ring, the chain
//! tables and the pacing word sit in the non-cacheable DMA region ([`super::memory`]); the
//! compiled tables the chain is made from are CPU-only and cacheable.
//!
//! # Cost
//! One 40-byte node per program step instead of one word per tick: for a tracking frame of
//! 30 windows at 1 MHz, 1,681 nodes and its chain table, 0.21 M instructions on QEMU's M7
//! (`cargo m7-bench`'s `sequencer_chain_nodes`), where the word feed it replaces copied
//! 593,541 words for 3.57 M (`sequencer_feed_words`); compiling the frame is 0.50 M
//! (`sequencer_compile`; docs/sequencer.md). The feeder writes up to half a ring of nodes
//! at a time, until [`AHEAD_US`] of ticks are linked ahead of the MDMA, and sleeps for half
//! of what is ahead (about once a millisecond), in an interrupt-level executor (`main.rs`)
//! that preempts the tracker. If the MDMA reaches
//! the end of the list inside a frame (the feeder was late), the port holds its last word
//! until the feeder restarts the list: a gap in the clocks, reported as
//! [`SeqError::Underrun`].
//!
//! # Lines to the ADC reader
//! As the feeder links a requested frame's nodes it walks the program's line jobs
//! (`LineJobs`): when a job's last tick is linked it goes to [`LINE_JOBS`], tagged with the
//! tracker's frame number and whether it is the frame's last line, with the instant its last
//! sample will be taken (from the ticks linked ahead of it and the tick), and the readout
//! task reads that line's words from the ADC board after that instant ([`super::readout`]).
//! The board must buffer the samples of at least a line and what the feeder links ahead
//! (docs/hardware.md).
//!
//! # What each frame plays
//! The tracker's line source (`app.rs`'s `ChannelLines`) sends each frame's request as a
//! [`FrameRequest`] (the window list copied into a bounded message) to [`REQUESTS`]. The
//! [`plan_task`] (thread mode, below the feeder's priority) compiles it with the core
//! compiler into whichever of the two [`Tables`] is not being played, with the exposure the
//! tracker's configuration sets, and hands the result to the feeder ([`sequencer_task`]),
//! which links it after the frame in play (two chain tables alternate, so a frame's table is
//! written only once the MDMA has left the frame before); the tables travel by ownership
//! through two channels, so a frame's tables are never written while its chain is made from
//! them. A request the plan or the compiler refuses (too many windows, a window outside,
//! tables too small) is compiled as a full frame instead, counted in [`FALLBACKS`] and
//! logged. Each frame ends with one tick of the rest state, so when the next request is not
//! ready the list ends there and the port holds the rest state (the image keeps
//! integrating); after [`MAX_WAIT_US`] without one the last program is replayed unannounced
//! (its lines are not read), so the image is not left to saturate.
//!
//! # What only a board can show
//! The waveforms have not been seen on a board (docs/hardware.md has the HIL steps), nor
//! whether the MDMA serves each request within a tick (at 50 ns: the HIL step counts the
//! ticks on the analyser).

use crate::lines::{FrameRequest, REQUESTS};
use core::sync::atomic::{AtomicU32, Ordering};
use embassy_stm32::Peri;
use embassy_stm32::gpio::{AnyPin, Level, Output, Speed};
use embassy_stm32::pac;
use embassy_stm32::peripherals::{DMA1_CH1, MDMA_CH0, TIM6};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::UpDma;
use embassy_stm32::timer::low_level::{RoundTo, Timer};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::{Duration, Instant};
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, Chain, CompileError, Cost, Limits, LineJob, LineJobs, Link, Links, PinMap, PlanError,
    Program, ProgramParts, ReadoutPlan, SegmentId, Step, Ticks, Timing, compile,
};
use startrack_core::tracker::Integration;

use super::mdma_list::{MdmaChannel, Node, NodeConfig, NodeRing};

/// The clock port's pin map: line `l` on PE`l` (I1-I3 PE0-2, S1-S3 PE3-5, R1L-R3L PE6-8,
/// R1R-R3R PE9-11, RG PE12, SW PE13, DG PE14, CONVST PE15).
pub const PINS: PinMap = PinMap::IN_ORDER;

/// Nodes of the MDMA's ring (40 bytes each).
pub const NODE_RING: usize = 128;

/// Nodes the feeder writes at a time.
const NODE_BATCH: usize = NODE_RING / 2;

/// The feeder links nodes until this much is linked ahead of the node in play, us, and
/// wakes after half of what it linked ahead: about once a millisecond (a full frame's row
/// is two nodes of 576 us), so the line jobs reach the readout before their lines end.
const AHEAD_US: u64 = 2_000;

/// Words of rest state at the end of each chain table: a node of the exposure padding plays
/// up to 256 x 4096 ticks (52 ms at 50 ns).
pub const REST_RUN: u32 = 256;

/// Words of the segment table (the largest plan the board makes needs 1,106, host test
/// `sequencer_route`).
pub const MAX_WORDS: usize = 1152;

/// Words of a chain table: the segments and the rest run.
pub const CHAIN_WORDS: usize = MAX_WORDS + REST_RUN as usize;

/// Program steps (the largest plan the board makes, 64 windows, needs 3,572: host test
/// `sequencer_route`).
pub const MAX_STEPS: usize = 4096;

/// The DMA stream TIM6 paces, and the DMAMUX1 channel that routes its request.
const PACE_STREAM: usize = 1;

/// The MDMA channel that plays the list; its hardware request is DMA1 stream
/// [`PACE_STREAM`]'s transfer-complete flag (RM0433's MDMA request table: request `n` is
/// DMA1 stream `n`'s; check against the datasheet).
const MDMA_CHANNEL: usize = 0;

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

/// What the DMAs read to clock the port (in the non-cacheable DMA region): 15.4 KB.
#[repr(C)]
pub struct ClockBuffers {
    /// The MDMA's node ring.
    pub nodes: [Node; NODE_RING],
    /// Two chain tables: the frame in play's and the next one's.
    pub tables: [[u32; CHAIN_WORDS]; 2],
    /// The word the pacing stream writes into BSRR each tick (0 changes no line).
    pub zero: u32,
}

impl ClockBuffers {
    /// Zeroed buffers.
    pub const fn new() -> Self {
        Self {
            nodes: [Node::ZERO; NODE_RING],
            tables: [[0; CHAIN_WORDS]; 2],
            zero: 0,
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
    /// When the frame's image was integrated: from the end of the frame transfer of the
    /// program before this frame's to the start of this frame's (`None` for the first
    /// program after the clocks started).
    pub integration: Option<Integration>,
    /// What it digitises and where each word goes.
    pub job: LineJob,
}

/// Lines queued on the clock port, for the readout task. Sixteen; when it is full the
/// feeder keeps the next jobs until its next wake-up.
pub static LINE_JOBS: Channel<CriticalSectionRawMutex, LineReady, 16> = Channel::new();

/// Why the clocks stopped.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum SeqError {
    /// The MDMA reached the end of the list inside a frame: the clocks paused until the
    /// feeder linked more nodes.
    Underrun,
    /// The frame's chain does not fit the chain table.
    Chain,
}

/// The clock port driven by TIM6, DMA1 stream 1 (the pace) and MDMA channel 0 (the words).
pub struct Sequencer {
    timer: Timer<'static, TIM6>,
    _pace: Peri<'static, DMA1_CH1>,
    _mdma: Peri<'static, MDMA_CH0>,
    /// The DMAMUX request of TIM6's update event.
    request: u8,
    clock: &'static mut ClockBuffers,
    _pins: [Output<'static>; 16],
    running: bool,
    /// Which node the MDMA plays, where the next go.
    ring: NodeRing<NODE_RING>,
    /// The chain table the next frame is written to.
    table: usize,
    /// The first node of the frame in each chain table.
    table_first: [u64; 2],
    /// Line jobs the readout had no room for.
    pub dropped_lines: u32,
    /// When the last linked program's frame transfer ends (the next frame's integration
    /// starts).
    last_ft_end: Option<Instant>,
}

impl Sequencer {
    /// Takes the timer, the pacing DMA stream, the MDMA channel, the 16 pins of GPIOE
    /// (PE0..PE15, in order) and the DMA buffers (in the non-cacheable DMA region); every
    /// line starts low.
    pub fn new(
        tim: Peri<'static, TIM6>,
        pace: Peri<'static, DMA1_CH1>,
        mdma: Peri<'static, MDMA_CH0>,
        pins: [Peri<'static, AnyPin>; 16],
        clock: &'static mut ClockBuffers,
    ) -> Self {
        let pins = pins.map(|p| Output::new(p, Level::Low, Speed::VeryHigh));
        let request = <DMA1_CH1 as UpDma<TIM6>>::request(&pace);
        // The MDMA's clock (embassy-stm32 enables the DMAs' at start-up; this is idempotent).
        pac::RCC.ahb3enr().modify(|w| w.set_mdmaen(true));
        Self {
            timer: Timer::new(tim),
            _pace: pace,
            _mdma: mdma,
            request,
            clock,
            _pins: pins,
            running: false,
            ring: NodeRing::new(),
            table: 0,
            table_first: [0; 2],
            dropped_lines: 0,
            last_ft_end: None,
        }
    }

    /// Whether the clocks run.
    pub const fn running(&self) -> bool {
        self.running
    }

    /// Whether the MDMA has played every linked node (the port holds the rest state).
    pub fn played_out(&self) -> bool {
        self.progress() >= self.ring.written()
    }

    /// Waits `us` while the port holds its last word (the rest state between frames).
    pub async fn hold(&mut self, us: u64) {
        embassy_time::Timer::after_micros(us).await;
    }

    /// GPIOE's BSRR.
    fn bsrr() -> u32 {
        pac::GPIOE.bsrr().as_ptr() as u32
    }

    /// Starts TIM6 at the tick of `tick_ps` and the pacing stream.
    fn start_pace(&mut self, tick_ps: u32) {
        let st = pac::DMA1.st(PACE_STREAM);
        st.cr().modify(|w| w.set_en(false));
        while st.cr().read().en() {}
        pac::DMAMUX1
            .ccr(PACE_STREAM)
            .write(|w| w.set_dmareq_id(self.request));
        st.par().write_value(Self::bsrr());
        st.m0ar()
            .write_value(core::ptr::from_ref(&self.clock.zero) as u32);
        st.ndtr().write(|w| w.set_ndt(1));
        pac::DMA1.ifcr(0).write_value(stream_flags(PACE_STREAM));
        st.cr().write(|w| {
            w.set_dir(pac::dma::vals::Dir::MEMORY_TO_PERIPHERAL);
            w.set_circ(true);
            w.set_minc(false);
            w.set_pinc(false);
            w.set_msize(pac::dma::vals::Size::BITS32);
            w.set_psize(pac::dma::vals::Size::BITS32);
            w.set_pl(pac::dma::vals::Pl::VERY_HIGH);
            w.set_en(true);
        });
        let hz = 1_000_000_000_000 / u64::from(tick_ps.max(1));
        self.timer.stop();
        self.timer.set_frequency(Hertz(hz as u32), RoundTo::Faster);
        self.timer.enable_update_dma(true);
        self.timer.start();
        self.running = true;
    }

    /// What every node of a frame shares, for the chain table `table`.
    fn node_config(&self, table: usize) -> NodeConfig {
        let table = self
            .clock
            .tables
            .get(table)
            .map_or(0, |t| t.as_ptr() as u32);
        let mut clear = pac::dma::regs::Ixr(0);
        clear.set_tcif(PACE_STREAM, true);
        NodeConfig {
            table,
            bsrr: Self::bsrr(),
            trigger: PACE_STREAM as u8,
            mask_addr: pac::DMA1.ifcr(0).as_ptr() as u32,
            mask_data: clear.0,
        }
    }

    /// Address of ring slot `slot`.
    fn slot_addr(&self, slot: usize) -> u32 {
        self.clock
            .nodes
            .get(slot % NODE_RING)
            .map_or(0, |n| core::ptr::from_ref(n) as u32)
    }

    /// The node the MDMA plays (its index since the clocks started), or the count written
    /// when it has played them all.
    fn progress(&self) -> u64 {
        self.ring.progress(&Hw, self.slot_addr(0))
    }

    /// Ticks played (the start of the node in play).
    fn played(&self) -> u64 {
        self.ring.played(&Hw, self.slot_addr(0))
    }

    /// Loads the MDMA channel with the node in `slot` and enables it.
    fn start_mdma(&mut self, slot: usize) {
        let Some(n) = self.clock.nodes.get(slot) else {
            return;
        };
        // SAFETY: a valid node of the ring (volatile: written for the MDMA).
        let n = unsafe { core::ptr::read_volatile(n) };
        let ch = pac::MDMA.ch(MDMA_CHANNEL);
        ch.ifcr().write(|w| {
            w.set_cteif(true);
            w.set_cctcif(true);
            w.set_cbrtif(true);
            w.set_cbtif(true);
            w.set_cltcif(true);
        });
        ch.tcr().write_value(pac::mdma::regs::Tcr(n.ctcr));
        ch.bndtr().write_value(pac::mdma::regs::Bndtr(n.cbndtr));
        ch.sar().write_value(pac::mdma::regs::Sar(n.csar));
        ch.dar().write_value(pac::mdma::regs::Dar(n.cdar));
        ch.brur().write_value(pac::mdma::regs::Brur(n.cbrur));
        ch.lar().write_value(pac::mdma::regs::Lar(n.clar));
        ch.tbr().write_value(pac::mdma::regs::Tbr(n.ctbr));
        ch.mar().write_value(pac::mdma::regs::Mar(n.cmar));
        ch.mdr().write_value(pac::mdma::regs::Mdr(n.cmdr));
        ch.cr().write(|w| {
            w.set_pl(pac::mdma::vals::Pl::VERY_HIGH);
            w.set_en(true);
        });
    }

    /// Writes up to [`NODE_BATCH`] nodes of `links` (at most [`AHEAD_US`] ahead) behind
    /// the last one and links them to it ([`NodeRing::append`]), restarting the MDMA if it
    /// had reached the end of the list. Returns `(nodes written, whether the list ran dry
    /// before they were linked)`.
    async fn append(
        &mut self,
        links: &mut core::iter::Chain<Links<'_>, core::iter::Once<Link>>,
        config: &NodeConfig,
        tick_ps: u32,
    ) -> (usize, bool) {
        let ch = pac::MDMA.ch(MDMA_CHANNEL);
        if ch.isr().read().teif() {
            let esr = ch.esr().read().0;
            ch.ifcr().write(|w| w.set_cteif(true));
            defmt::error!("sequencer: MDMA transfer error (ESR {=u32:#x})", esr);
        }
        let base = self.slot_addr(0);
        let ahead_ticks = AHEAD_US * 1_000_000 / u64::from(tick_ps.max(1));
        let done = self.ring.append(
            &mut self.clock.nodes,
            base,
            &Hw,
            links,
            config,
            NODE_BATCH,
            ahead_ticks,
            cortex_m::asm::dsb,
        );
        if done.nodes > 0 && done.restart {
            while ch.cr().read().en() {
                embassy_time::Timer::after_micros(5).await;
            }
            self.start_mdma(done.first_slot);
        }
        (done.nodes, done.restart)
    }

    /// Links every node of `program` after whatever is linked, starting the clocks on the
    /// first call. Returns when the last node is written, so the next frame's program
    /// follows without a gap. With `frame` (the tracker's frame number) its line jobs go to
    /// [`LINE_JOBS`]; without, nothing is read.
    pub async fn play(
        &mut self,
        program: &Program<'_, '_>,
        frame: Option<u32>,
    ) -> Result<(), SeqError> {
        let k = self.table;
        // The other table's frame must have started: then this table's (the frame before
        // it) is played out.
        let other = self.table_first.get(k ^ 1).copied().unwrap_or(0);
        while self.progress() < other && self.progress() < self.ring.written() {
            embassy_time::Timer::after_micros(20).await;
        }
        let config = self.node_config(k);
        let Some(table) = self.clock.tables.get_mut(k) else {
            return Err(SeqError::Chain);
        };
        let chain = Chain::new(program, REST_RUN, table).map_err(|_| SeqError::Chain)?;
        // The frame ends on one tick of the rest state (the first word of the rest run), so
        // the port rests if the next frame is late.
        let rest = Link {
            first_word: (chain.words().len() - REST_RUN as usize) as u32,
            len_words: 1,
            blocks: 1,
        };
        let mut links = chain.links().chain(core::iter::once(rest));
        if let Some(t) = self.table_first.get_mut(k) {
            *t = self.ring.written();
        }
        self.table ^= 1;
        let tick_ps = program.tick_ps();
        if !self.running {
            self.start_pace(tick_ps);
        }
        let frame_start = self.ring.queued();
        // The frame transfer that opens this program: when it starts (its first tick, from
        // the ticks the MDMA has played) and ends; the image read by it integrated since
        // the previous program's ended.
        let tick_us = |ticks: u64| Duration::from_micros(ticks * u64::from(tick_ps) / 1_000_000);
        let (played, now) = (self.played(), Instant::now());
        let ft_start = if frame_start >= played {
            now + tick_us(frame_start - played)
        } else {
            now.checked_sub(tick_us(played - frame_start))
                .unwrap_or(now)
        };
        let ft_ticks = program
            .steps()
            .first()
            .filter(|s| s.segment == SegmentId::FrameTransfer)
            .map_or(0, |s| {
                program.segment(SegmentId::FrameTransfer).len() as u64 * u64::from(s.repeat)
            });
        let integration = self.last_ft_end.map(|start| Integration {
            start_us: start.as_micros(),
            end_us: ft_start.as_micros(),
        });
        self.last_ft_end = Some(ft_start + tick_us(ft_ticks));
        let mut jobs = LineJobs::new(program).peekable();
        let mut first_batch = true;
        loop {
            let (n, dry) = self.append(&mut links, &config, tick_ps).await;
            if dry && !first_batch && n > 0 {
                return Err(SeqError::Underrun);
            }
            first_batch = false;
            self.send_jobs(&mut jobs, frame, frame_start, tick_ps, integration);
            if n == 0 && links.clone().next().is_none() && jobs.peek().is_none() {
                return Ok(());
            }
            // Sleep for half the ticks linked ahead (at least 10 us, at most AHEAD_US / 2).
            let ahead = self.ring.queued().saturating_sub(self.played());
            let us = (ahead / 2 * u64::from(tick_ps) / 1_000_000).clamp(10, AHEAD_US / 2);
            embassy_time::Timer::after_micros(us).await;
        }
    }

    /// Sends every job whose ticks are all linked, with the instant of its last sample
    /// (none for an unannounced frame: the jobs are walked past), while the readout has
    /// room; the rest wait for the feeder's next wake-up.
    fn send_jobs(
        &mut self,
        jobs: &mut core::iter::Peekable<LineJobs<'_, '_, '_>>,
        frame: Option<u32>,
        frame_start: u64,
        tick_ps: u32,
        integration: Option<Integration>,
    ) {
        let played = self.played();
        let now = Instant::now();
        while let Some(job) = jobs.next_if(|j| {
            frame_start + j.end_tick <= self.ring.queued()
                && (frame.is_none() || !LINE_JOBS.is_full())
        }) {
            let ticks_left = (frame_start + job.end_tick).saturating_sub(played);
            let due =
                now + Duration::from_micros((ticks_left * u64::from(tick_ps)).div_ceil(1_000_000));
            let Some(frame) = frame else { continue };
            let last = jobs.peek().is_none();
            // Cannot fail: the job was taken only with room in the channel.
            if LINE_JOBS
                .try_send(LineReady {
                    frame,
                    last,
                    due,
                    integration,
                    job,
                })
                .is_err()
            {
                self.dropped_lines = self.dropped_lines.wrapping_add(1);
            }
        }
    }

    /// Stops the clocks (timer, MDMA, pacing stream); the port keeps its last word.
    pub fn stop(&mut self) {
        self.timer.stop();
        self.timer.enable_update_dma(false);
        pac::MDMA.ch(MDMA_CHANNEL).cr().modify(|w| w.set_en(false));
        pac::DMA1.st(PACE_STREAM).cr().modify(|w| w.set_en(false));
        self.running = false;
        self.ring = NodeRing::new();
        self.table_first = [0; 2];
        self.last_ft_end = None;
    }
}

/// The MDMA channel's registers as the ring reads them.
struct Hw;

impl MdmaChannel for Hw {
    fn enabled(&self) -> bool {
        pac::MDMA.ch(MDMA_CHANNEL).cr().read().en()
    }
    fn link_address(&self) -> u32 {
        pac::MDMA.ch(MDMA_CHANNEL).lar().read().lar()
    }
}

/// Every flag of DMA1 stream `n` (for its clear register).
fn stream_flags(n: usize) -> pac::dma::regs::Ixr {
    let mut f = pac::dma::regs::Ixr(0);
    f.set_feif(n, true);
    f.set_dmeif(n, true);
    f.set_teif(n, true);
    f.set_htif(n, true);
    f.set_tcif(n, true);
    f
}

/// The pixel rate the frames are compiled for.
pub const PIXEL_RATE_HZ: u32 = 1_000_000;

/// How long the feeder waits at a time for the next frame while the port rests, us.
pub const IDLE_US: u64 = 32;

/// Longest wait for the next request before the last program is replayed unannounced, us.
pub const MAX_WAIT_US: u64 = 200_000;

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
    let mut current: Option<Compiled> = None;
    // Time the port has rested (the list played out) waiting for the next frame, us.
    let mut waited_us: u64 = 0;
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
                waited_us = 0;
                current.as_ref().map(|c| c.frame)
            }
            None => {
                if waited_us < MAX_WAIT_US {
                    // Only the rest after the linked nodes are played counts as waiting.
                    let resting = seq.played_out();
                    seq.hold(IDLE_US).await;
                    if resting {
                        waited_us += IDLE_US;
                    }
                    continue;
                }
                waited_us = 0;
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
