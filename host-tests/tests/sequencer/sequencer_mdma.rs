//! The firmware's MDMA nodes (`firmware/src/board/stm32h743/mdma_list.rs`, included here as the board
//! builds it) run through a model of the MDMA's linked-list mode as RM0433 describes it: each
//! node's registers loaded, one word a request from the source (incremented) to the
//! destination (fixed), the block repeated `BRC + 1` times with the source stepped back by
//! `SUV` after each, the mask write after each request, then the next node from `CxLAR`
//! until it is 0. The words it writes into BSRR are the word feed's, for the board's frames
//! and for any windows (property test); every request clears the pacing stream's flag.
//!
//! The feeder's ring (`NodeRing`, the same file): nodes written in batches into a small ring
//! while the model plays them, a request at a time, in any interleaving (property test):
//! the model never loads a node that was not written for it, plays the word feed's words,
//! and every time the list ran dry (the model caught up with the writer, or had loaded the
//! last node before the next batch was linked to it) the ring asks for the restart that
//! resumes it.

#[path = "../../../firmware/src/board/stm32h743/mdma_list.rs"]
#[allow(dead_code, reason = "the test reads the nodes, not every item")]
mod mdma_list;

use mdma_list::{Appended, CTCR, MdmaChannel, Node, NodeConfig, NodeRing};
use proptest::prelude::*;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, Chain, Cursor, Limits, PinMap, Program, ReadoutPlan, Step, Ticks, Timing, compile,
};
use startrack_core::window::Rect;

/// Where the model places the chain table, the node list and the registers.
const TABLE: u32 = 0x2400_8000;
const NODES: u32 = 0x2401_0000;
const BSRR: u32 = 0x5802_1018;
const LIFCR: u32 = 0x4002_0008;
const CLEAR_TC1: u32 = 1 << 11;

fn ticks() -> Ticks {
    let t = Timing::at_pixel_rate(1_000_000).validate(&Limits::CCD47_20);
    t.unwrap_or_else(|e| unreachable!("{e}"))
}

/// What the model saw: the words written to BSRR, and the requests whose mask write was not
/// the pacing stream's flag clear.
#[derive(Default)]
struct Played {
    bsrr: Vec<u32>,
    bad_masks: usize,
}

/// The MDMA's linked-list mode on `nodes` (at [`NODES`]) reading `table` (at [`TABLE`]),
/// starting with node 0 loaded into the registers. Panics on a field it does not model.
fn run_mdma(nodes: &[Node], table: &[u32]) -> Played {
    let mut out = Played::default();
    let load = |addr: u32| -> &Node {
        assert_eq!((addr - NODES) % 40, 0, "link address not on a node");
        assert_eq!(addr % 8, 0, "link address not 8-byte aligned");
        &nodes[((addr - NODES) / 40) as usize]
    };
    let mut n = *load(NODES);
    loop {
        // CTCR: source incremented by words, destination fixed, word sizes, 4-byte buffers,
        // one buffer a request (TRGM 00).
        assert_eq!(n.ctcr & 0b11, 0b10, "SINC");
        assert_eq!((n.ctcr >> 2) & 0b11, 0b00, "DINC");
        assert_eq!((n.ctcr >> 4) & 0b11, 0b10, "SSIZE");
        assert_eq!((n.ctcr >> 6) & 0b11, 0b10, "DSIZE");
        assert_eq!((n.ctcr >> 18) & 0x7f, 3, "TLEN");
        assert_eq!((n.ctcr >> 28) & 0b11, 0, "TRGM");
        let bndt = n.cbndtr & 0x1_ffff;
        let brsum = (n.cbndtr >> 18) & 1 == 1;
        let brc = n.cbndtr >> 20;
        let suv = n.cbrur & 0xffff;
        assert!(bndt > 0 && bndt % 4 == 0, "BNDT {bndt}");
        assert_eq!(n.cdar, BSRR);
        assert_eq!(n.ctbr & 0x3f, 1, "TSEL");
        assert_eq!((n.ctbr >> 16) & 0b11, 0, "SBUS/DBUS");
        let mut sar = n.csar;
        for block in 0..=brc {
            for _ in 0..bndt / 4 {
                let i = (sar - TABLE) / 4;
                out.bsrr.push(table[i as usize]);
                sar += 4;
                if (n.cmar, n.cmdr) != (LIFCR, CLEAR_TC1) {
                    out.bad_masks += 1;
                }
            }
            if block < brc {
                sar = if brsum { sar - suv } else { sar + suv };
            }
        }
        if n.clar == 0 {
            return out;
        }
        n = *load(n.clar);
    }
}

/// The nodes of `program`'s chain as the board writes them (here one list, not a ring) and
/// the chain table; asserts the model plays the word feed.
fn assert_nodes_play_the_feed(p: &Program<'_, '_>) -> usize {
    let mut table = vec![0u32; p.words().len() + 256];
    let chain = Chain::new(p, 256, &mut table).unwrap_or_else(|e| unreachable!("{e}"));
    let config = NodeConfig {
        table: TABLE,
        bsrr: BSRR,
        trigger: 1,
        mask_addr: LIFCR,
        mask_data: CLEAR_TC1,
    };
    let links: Vec<_> = chain.links().collect();
    let nodes: Vec<Node> = links
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let next = if i + 1 < links.len() {
                NODES + 40 * (i as u32 + 1)
            } else {
                0
            };
            config.node(l, next)
        })
        .collect();
    assert!(nodes.iter().all(|n| n.ctcr == CTCR));
    let played = run_mdma(&nodes, chain.words());
    let mut feed = Vec::new();
    let mut cursor = Cursor::START;
    let mut buf = vec![0u32; 256];
    loop {
        let k = cursor.fill(p, &mut buf);
        feed.extend_from_slice(&buf[..k]);
        if k < buf.len() {
            break;
        }
    }
    assert_eq!(played.bsrr.len(), feed.len());
    assert_eq!(
        played.bsrr.iter().zip(&feed).position(|(a, b)| a != b),
        None
    );
    assert_eq!(played.bad_masks, 0);
    nodes.len()
}

fn program<'a>(
    g: ReadoutGeometry,
    request: ReadoutRequest<'_>,
    exposure_us: u32,
    words: &'a mut [u32],
    steps: &'a mut [Step],
) -> Program<'a, 'a> {
    let plan = ReadoutPlan::new(g, request, Binning::X1, exposure_us)
        .unwrap_or_else(|e| unreachable!("{e}"));
    compile(&plan, &ticks(), &PinMap::IN_ORDER, words, steps)
        .unwrap_or_else(|e| unreachable!("{e}"))
}

/// The board's frames: a full frame and 30 windows of the CCD47-20 through both outputs at
/// 1 MHz, with a 1 s exposure.
#[test]
fn board_frames_through_the_mdma_model() {
    let rects: Vec<Rect> = (0..30u16)
        .map(|i| Rect {
            x0: 20 + 33 * i,
            y0: 10 + 33 * i,
            width: 11,
            height: 11,
        })
        .collect();
    for request in [ReadoutRequest::FullFrame, ReadoutRequest::Windows(&rects)] {
        let (mut words, mut steps) = (vec![0u32; 4096], vec![Step::EMPTY; 8192]);
        let p = program(
            ReadoutGeometry::CCD47_20_DUAL,
            request,
            1_000_000,
            &mut words,
            &mut steps,
        );
        let nodes = assert_nodes_play_the_feed(&p);
        println!("{} steps: {nodes} nodes", p.steps().len());
    }
}

const SMALL: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 2,
    covered_px: 2,
    active_cols: 16,
    active_rows: 12,
    lines: 14,
    outputs: 2,
};

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(32)))]

    /// Any windows, either output count, any exposure: the MDMA model plays the word feed.
    #[test]
    fn windows_through_the_mdma_model(
        v in prop::collection::vec((0u16..16, 1u16..8, 0u16..12, 1u16..6), 0..6),
        outputs in 1u8..=2,
        exposure_us in prop::sample::select(vec![0u32, 700, 30_000]),
    ) {
        let mut rects: Vec<Rect> = v
            .into_iter()
            .map(|(x0, w, y0, h)| Rect { x0, y0, width: w.min(16 - x0), height: h.min(12 - y0) })
            .collect();
        rects.sort_by_key(|r| r.y0);
        let (mut words, mut steps) = (vec![0u32; 4096], vec![Step::EMPTY; 8192]);
        let g = ReadoutGeometry { outputs, ..SMALL };
        let p = program(g, ReadoutRequest::Windows(&rects), exposure_us, &mut words, &mut steps);
        assert_nodes_play_the_feed(&p);
    }
}

/// The MDMA channel as the ring sees it, a request at a time (the same semantics as
/// [`run_mdma`], which checks the fields).
struct Model {
    en: bool,
    regs: Node,
    sar: u32,
    block: u32,
    word: u32,
    /// Index (since the start) of the node in play.
    abs: u64,
    /// Words played before it.
    node_start: u64,
    out: Vec<u32>,
}

impl MdmaChannel for Model {
    fn enabled(&self) -> bool {
        self.en
    }
    fn link_address(&self) -> u32 {
        self.regs.clar
    }
}

impl Model {
    fn load(&mut self, nodes: &[Node], slot: usize, abs: u64, shadow: &[Option<u64>]) {
        assert_eq!(
            shadow[slot],
            Some(abs),
            "node {abs} loaded from a slot not written for it"
        );
        self.regs = nodes[slot];
        self.sar = self.regs.csar;
        self.block = 0;
        self.word = 0;
        self.abs = abs;
        self.node_start = self.out.len() as u64;
        self.en = true;
    }

    /// One request: a word into BSRR, and the next node loaded at the end of this one.
    fn request(&mut self, nodes: &[Node], table: &[u32], shadow: &[Option<u64>]) {
        if !self.en {
            return;
        }
        self.out.push(table[((self.sar - TABLE) / 4) as usize]);
        self.sar += 4;
        self.word += 1;
        if self.word * 4 < (self.regs.cbndtr & 0x1_ffff) {
            return;
        }
        self.word = 0;
        self.block += 1;
        if self.block <= self.regs.cbndtr >> 20 {
            self.sar -= self.regs.cbrur & 0xffff;
            return;
        }
        if self.regs.clar == 0 {
            self.en = false;
            return;
        }
        let slot = ((self.regs.clar - NODES) / 40) as usize;
        self.load(nodes, slot, self.abs + 1, shadow);
    }
}

/// The ring of `R` nodes fed `p`'s chain in batches of `batch`, at most `ahead` ticks
/// ahead, the model playing `steps[i]` requests between batches; returns what the model
/// played and the restarts.
fn ring_play<const R: usize>(
    p: &Program<'_, '_>,
    batch: usize,
    ahead: u64,
    steps: &[u32],
) -> (Vec<u32>, usize) {
    let mut table = vec![0u32; p.words().len() + 16];
    let chain = Chain::new(p, 16, &mut table).unwrap_or_else(|e| unreachable!("{e}"));
    let config = NodeConfig {
        table: TABLE,
        bsrr: BSRR,
        trigger: 1,
        mask_addr: LIFCR,
        mask_data: CLEAR_TC1,
    };
    let mut links = chain.links();
    let mut ring = NodeRing::<R>::new();
    let mut nodes = [Node::ZERO; R];
    let mut shadow = [None; R];
    let mut m = Model {
        en: false,
        regs: Node::ZERO,
        sar: 0,
        block: 0,
        word: 0,
        abs: 0,
        node_start: 0,
        out: Vec::new(),
    };
    let mut restarts = 0;
    let words = chain.words();
    // A broken ring can link its nodes into a loop: bound the requests.
    let budget = 4 * p.ticks().count() + 1_000_000;
    let play = |m: &mut Model, nodes: &[Node; R], shadow: &[Option<u64>; R], n: u64| {
        for _ in 0..n {
            if !m.en {
                return;
            }
            m.request(nodes, words, shadow);
            assert!(
                m.out.len() <= budget,
                "the model plays past the frame: a loop"
            );
        }
    };
    for k in steps.iter().cycle() {
        let first = ring.written();
        let a: Appended = ring.append(
            &mut nodes,
            NODES,
            &m,
            &mut links,
            &config,
            batch,
            ahead,
            || {},
        );
        for i in first..ring.written() {
            shadow[i as usize % R] = Some(i);
        }
        if a.nodes > 0 && a.restart {
            // The channel ends with the node in play: let it, then start at the new nodes.
            play(&mut m, &nodes, &shadow, u64::MAX);
            m.load(&nodes, a.first_slot, first, &shadow);
            restarts += 1;
        }
        if a.nodes == 0 && links.clone().next().is_none() {
            play(&mut m, &nodes, &shadow, u64::MAX);
            return (m.out, restarts);
        }
        play(&mut m, &nodes, &shadow, u64::from(*k));
        // The ring reads the model's place exactly: the node in play and where it started.
        if m.en {
            assert_eq!(ring.progress(&m, NODES), m.abs);
            assert_eq!(ring.played(&m, NODES), m.node_start);
        } else {
            assert_eq!(ring.progress(&m, NODES), ring.written());
            assert_eq!(ring.played(&m, NODES), ring.queued());
        }
    }
    unreachable!("steps is not empty")
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(48)))]

    /// Any windows, any ring pace: the ring's nodes play the word feed, and the list runs
    /// dry only where the ring asked for a restart.
    #[test]
    fn the_ring_plays_the_feed_in_any_interleaving(
        v in prop::collection::vec((0u16..16, 1u16..8, 0u16..12, 1u16..6), 0..5),
        exposure_us in prop::sample::select(vec![0u32, 400]),
        batch in 1usize..8,
        ahead in prop::sample::select(vec![1u64, 50, 400, 5_000, u64::MAX]),
        steps in prop::collection::vec(1u32..300, 1..20),
    ) {
        let mut rects: Vec<Rect> = v
            .into_iter()
            .map(|(x0, w, y0, h)| Rect { x0, y0, width: w.min(16 - x0), height: h.min(12 - y0) })
            .collect();
        rects.sort_by_key(|r| r.y0);
        let (mut words, mut steps_buf) = (vec![0u32; 4096], vec![Step::EMPTY; 8192]);
        let p = program(SMALL, ReadoutRequest::Windows(&rects), exposure_us, &mut words, &mut steps_buf);
        let feed: Vec<u32> = p.ticks().collect();
        let (played, _) = ring_play::<8>(&p, batch, ahead, &steps);
        prop_assert_eq!(played.len(), feed.len());
        prop_assert_eq!(played.iter().zip(&feed).position(|(a, b)| a != b), None);
    }
}

/// The two paces at the ends: a model far behind the writer never runs dry after the
/// start; one far ahead runs dry at every batch, and each time the ring restarts it.
#[test]
fn restarts_only_when_the_list_ran_dry() {
    let (mut words, mut steps) = (vec![0u32; 4096], vec![Step::EMPTY; 8192]);
    let p = program(SMALL, ReadoutRequest::FullFrame, 0, &mut words, &mut steps);
    let feed: Vec<u32> = p.ticks().collect();
    let (slow, slow_restarts) = ring_play::<8>(&p, 4, u64::MAX, &[1]);
    assert_eq!(slow, feed);
    assert_eq!(slow_restarts, 1, "only the start");
    let (fast, fast_restarts) = ring_play::<8>(&p, 4, u64::MAX, &[100_000]);
    assert_eq!(fast, feed);
    let nodes = Chain::new(&p, 16, &mut vec![0u32; p.words().len() + 16])
        .map(|c| c.links().count())
        .unwrap_or(0);
    assert_eq!(fast_restarts, nodes.div_ceil(4));
}
