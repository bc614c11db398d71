//! Stages `sequencer_compile` and `sequencer_feed`, per tracking frame of 30 windows of
//! 11 x 11 at 1 MHz pixels through both outputs (the board's plan): what the board's
//! sequencer costs the M7 besides the tracker. `sequencer_compile`: the plan and the
//! compiler into the board's table sizes (thread mode, once a frame); `sequencer_feed`:
//! the feeder's work for the frame, every word copied out in 256-word chunks
//! (`Cursor::fill`, as into the DMA ring) and the line jobs walked (`LineJobs`, with the
//! look-ahead that marks the last line). The DMA ring's own waits are not counted.
//!
//! `sequencer_chain_nodes`: the same frame played by the MDMA's linked list instead: the
//! chain's word table written (`Chain::new`: the program's words and a 256-word rest run)
//! and every link made into an MDMA node in a ring of 128, 64 at a time, by the firmware's
//! own `NodeRing::append` (`mdma_list.rs`), as the board's feeder writes them; the DMA's playing is not counted (it cannot
//! run on QEMU), and the line jobs stay `sequencer_feed_jobs`.

use crate::harness::{Bench, Out};
use crate::inputs::G;
use crate::mdma_list::{MdmaChannel, Node, NodeConfig, NodeRing};
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, Chain, Cost, Cursor, Limits, LineJobs, PinMap, ReadoutPlan, Step, Timing, compile,
};
use startrack_core::window::Rect;

/// Windows of the tracking frame.
const WINDOWS: usize = 30;

pub fn run(out: &mut Out, bench: &Bench) -> Result<(), &'static str> {
    let mut rects = [Rect {
        x0: 0,
        y0: 0,
        width: 11,
        height: 11,
    }; WINDOWS];
    for (i, r) in rects.iter_mut().enumerate() {
        let i = i as u16;
        r.x0 = 20 + 33 * i;
        r.y0 = 10 + 33 * i;
    }
    let ticks = Timing::at_pixel_rate(1_000_000)
        .validate(&Limits::CCD47_20)
        .map_err(|_| "sequencer: timing refused")?;
    let mut words = [0u32; MAX_WORDS];
    let mut steps = [Step::EMPTY; 4096];
    let mut parts = None;
    let t_compile = bench.measure(|| {
        let plan = ReadoutPlan::new(G, ReadoutRequest::Windows(&rects), Binning::X1, 0);
        parts = plan.ok().and_then(|plan| {
            compile(&plan, &ticks, &PinMap::IN_ORDER, &mut words, &mut steps)
                .ok()
                .map(|p| p.parts())
        });
    });
    let parts = parts.ok_or("sequencer: 30 windows do not compile")?;
    let program = parts
        .view(&words, &steps)
        .ok_or("sequencer: tables shorter than the program")?;
    let mut chunk = [0u32; 256];
    let (mut copied, mut lines, mut last) = (0usize, 0u32, false);
    let t_words = bench.measure(|| {
        let mut cursor = Cursor::START;
        loop {
            let n = cursor.fill(&program, &mut chunk);
            copied += n;
            if n < chunk.len() {
                break;
            }
        }
    });
    let t_jobs = bench.measure(|| {
        let mut jobs = LineJobs::new(&program).peekable();
        while let Some(job) = jobs.next() {
            lines += u32::from(job.rows);
            last = jobs.peek().is_none();
        }
    });
    if lines != (WINDOWS * 11) as u32 {
        return Err("sequencer: not every line of the frame");
    }
    if !last {
        return Err("sequencer: no last line");
    }
    let total: u64 = Cost::of(&program).ticks_by_segment.iter().sum();
    if copied as u64 != total {
        return Err("sequencer: not every word of the frame");
    }
    let t_chain = chain_nodes(&program, total)?;
    bench.row(out, "sequencer_compile", "frame_30_windows", t_compile, 1);
    bench.row(out, "sequencer_feed_words", "frame_30_windows", t_words, 1);
    bench.row(out, "sequencer_feed_jobs", "frame_30_windows", t_jobs, 1);
    bench.row(
        out,
        "sequencer_chain_nodes",
        "frame_30_windows",
        t_chain(bench),
        1,
    );
    Ok(())
}

/// The board's segment table, words (the firmware's `MAX_WORDS`).
const MAX_WORDS: usize = 1152;
/// The board's chain table: the largest program's words and the rest run.
const CHAIN_WORDS: usize = MAX_WORDS + REST_RUN as usize;
/// The rest run's words.
const REST_RUN: u32 = 256;
/// Nodes in the board's ring.
const NODE_RING: usize = 128;

/// Times the chain table and every node of `program` (whose ticks are `total`) written into
/// a node ring; checks that the links play every tick.
fn chain_nodes(
    program: &startrack_core::sequencer::Program<'_, '_>,
    total: u64,
) -> Result<impl Fn(&Bench) -> u64, &'static str> {
    // Only the timing runs in the closure; the check is done once here.
    let mut table = [0u32; CHAIN_WORDS];
    let chain = Chain::new(program, REST_RUN, &mut table).map_err(|_| "chain: table too small")?;
    let linked: u64 = chain.links().map(|l| l.ticks()).sum();
    if linked != total {
        return Err("chain: the links do not play every tick");
    }
    let program = *program;
    Ok(move |bench: &Bench| {
        let mut table = [0u32; CHAIN_WORDS];
        let mut ring = [Node::ZERO; NODE_RING];
        let t = bench.measure(|| {
            let Ok(chain) = Chain::new(&program, REST_RUN, &mut table) else {
                return;
            };
            let base = ring.as_ptr() as u32;
            let config = NodeConfig {
                table: chain.words().as_ptr() as u32,
                bsrr: 0x5802_1018,
                trigger: 1,
                mask_addr: 0x4002_0008,
                mask_data: 1 << 11,
            };
            // The board's feeder: half a ring a batch, linked to the batch before (the MDMA,
            // which QEMU does not have, stands for one that plays each batch at once).
            let mut nodes = NodeRing::<NODE_RING>::new();
            let mut links = chain.links();
            while nodes
                .append(
                    &mut ring,
                    base,
                    &Played,
                    &mut links,
                    &config,
                    NODE_RING / 2,
                    u64::MAX,
                    || {},
                )
                .nodes
                > 0
            {}
        });
        core::hint::black_box(&ring);
        t
    })
}

/// An MDMA that has played every node linked so far.
struct Played;

impl MdmaChannel for Played {
    fn enabled(&self) -> bool {
        false
    }
    fn link_address(&self) -> u32 {
        0
    }
}
