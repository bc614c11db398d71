//! The program as a DMA's linked list (`Chain`, `Link`) against the word feed (`Cursor::fill`,
//! what the board's CPU wrote into the DMA ring before): the links, walked as the DMA walks
//! them (each block `blocks` times), play exactly the word feed's pin sequence, for full and
//! windowed frames, any binning, one or two outputs and any exposure padding; each link
//! within the DMA's limits; and the CCD model clocked by the links reads what it reads when
//! clocked by the word feed.

use proptest::prelude::*;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, Chain, ChainError, Cursor, Limits, Link, MAX_BLOCK_WORDS, MAX_BLOCKS, PinMap, Program,
    ReadoutPlan, Step, Ticks, Timing, compile,
};
use startrack_core::window::Rect;
use startrack_sim::ccd_model::CcdModel;

fn ticks(pixel_rate_hz: u32) -> Ticks {
    let t = Timing::at_pixel_rate(pixel_rate_hz).validate(&Limits::CCD47_20);
    assert!(t.is_ok(), "{t:?}");
    t.unwrap_or_else(|_| unreachable!())
}

struct Buffers {
    words: Vec<u32>,
    steps: Vec<Step>,
}

fn buffers() -> Buffers {
    Buffers {
        words: vec![0; 4096],
        steps: vec![Step::EMPTY; 8192],
    }
}

fn compiled<'a>(
    g: ReadoutGeometry,
    request: ReadoutRequest<'_>,
    binning: Binning,
    exposure_us: u32,
    t: &Ticks,
    buf: &'a mut Buffers,
) -> Program<'a, 'a> {
    let plan = ReadoutPlan::new(g, request, binning, exposure_us);
    assert!(plan.is_ok(), "{plan:?}");
    let plan = plan.unwrap_or_else(|_| unreachable!());
    let p = compile(&plan, t, &PinMap::IN_ORDER, &mut buf.words, &mut buf.steps);
    assert!(p.is_ok(), "{p:?}");
    p.unwrap_or_else(|_| unreachable!())
}

/// The word feed: every word `Cursor::fill` writes, in `chunk`-word pieces, as into the ring.
fn word_feed(p: &Program<'_, '_>, chunk: usize) -> Vec<u32> {
    let mut cursor = Cursor::START;
    let mut buf = vec![0u32; chunk];
    let mut out = Vec::new();
    loop {
        let n = cursor.fill(p, &mut buf);
        out.extend_from_slice(&buf[..n]);
        if n < chunk {
            return out;
        }
    }
}

/// Every link within the MDMA's limits and the table; returns the links.
fn checked_links(chain: &Chain<'_, '_>) -> Vec<Link> {
    let links: Vec<Link> = chain.links().collect();
    for l in &links {
        assert!((1..=MAX_BLOCKS).contains(&l.blocks), "{l:?}");
        assert!((1..=MAX_BLOCK_WORDS).contains(&l.len_words), "{l:?}");
        assert!(
            (l.first_word + l.len_words) as usize <= chain.words().len(),
            "{l:?}"
        );
    }
    links
}

/// The chain of `p` with a rest run of `run` words equals the word feed, word for word.
fn assert_chain_is_the_feed(p: &Program<'_, '_>, run: u32) -> Vec<Link> {
    let mut table = vec![0u32; p.words().len() + run as usize];
    let chain = Chain::new(p, run, &mut table);
    assert!(chain.is_ok(), "{chain:?}");
    let chain = chain.unwrap_or_else(|_| unreachable!());
    let links = checked_links(&chain);
    let feed = word_feed(p, 256);
    let walked: Vec<u32> = chain.ticks().collect();
    assert_eq!(walked.len(), feed.len());
    // First difference, if any, named by its tick.
    let first_diff = walked.iter().zip(&feed).position(|(a, b)| a != b);
    assert_eq!(first_diff, None);
    let total: u64 = links.iter().map(Link::ticks).sum();
    assert_eq!(total, feed.len() as u64);
    links
}

/// A reduced CCD47-20 with the same layout (the model tests' sensor).
const SMALL: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 2,
    covered_px: 2,
    active_cols: 16,
    active_rows: 12,
    lines: 14,
    outputs: 2,
};

fn rects_strategy() -> impl Strategy<Value = Vec<Rect>> {
    prop::collection::vec((0u16..16, 1u16..8, 0u16..12, 1u16..6), 0..6).prop_map(|v| {
        let mut rs: Vec<Rect> = v
            .into_iter()
            .map(|(x0, w, y0, h)| Rect {
                x0,
                y0,
                width: w.min(16 - x0),
                height: h.min(12 - y0),
            })
            .collect();
        rs.sort_by_key(|r| r.y0);
        rs
    })
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(64)))]

    /// Windows or a full frame, any binning, either output count, exposures from none to
    /// 20 ms (padding up to 160,000 rest ticks) and rest runs of 0 to 300 words: the links
    /// play the word feed's sequence.
    #[test]
    fn links_play_the_word_feed(
        rects in prop::option::of(rects_strategy()),
        b in prop::sample::select(vec![1u16, 2, 4]),
        outputs in 1u8..=2,
        exposure_us in prop::sample::select(vec![0u32, 50, 1_000, 20_000]),
        run in prop::sample::select(vec![0u32, 1, 2, 7, 256, 300]),
    ) {
        let t = ticks(1_000_000);
        let g = ReadoutGeometry { outputs, ..SMALL };
        let binning = Binning::from_factor(b).unwrap_or(Binning::X1);
        let request = rects.as_deref().map_or(ReadoutRequest::FullFrame, ReadoutRequest::Windows);
        let mut buf = buffers();
        let p = compiled(g, request, binning, exposure_us, &t, &mut buf);
        assert_chain_is_the_feed(&p, run);
    }

    /// The model clocked by the links reads the same samples, at the same ticks, as clocked
    /// by the word feed (and the windows' pixels: `sequencer_model` proves the feed's).
    #[test]
    fn the_model_reads_the_same_through_the_links(
        rects in rects_strategy(),
        outputs in 1u8..=2,
    ) {
        let t = ticks(1_000_000);
        let g = ReadoutGeometry { outputs, ..SMALL };
        let mut buf = buffers();
        let p = compiled(g, ReadoutRequest::Windows(&rects), Binning::X1, 2_000, &t, &mut buf);
        let mut table = vec![0u32; p.words().len() + 64];
        let chain = Chain::new(&p, 64, &mut table).unwrap_or_else(|e| unreachable!("{e}"));
        let image = |c: usize, y: usize| 1 + ((y * 7919 + c * 104_729) % 65_521) as i64;
        let stale = |c: usize, s: usize| 1_000_000 + (c * 31 + s) as i64;
        let mut by_links = CcdModel::new(&g, PinMap::IN_ORDER, &t);
        by_links.load(image, stale);
        by_links.run(chain.ticks());
        let mut by_feed = CcdModel::new(&g, PinMap::IN_ORDER, &t);
        by_feed.load(image, stale);
        by_feed.run(word_feed(&p, 256));
        prop_assert!(by_links.faults.is_clean(), "{:?}", by_links.faults);
        prop_assert!(!by_links.samples().is_empty() || rects.is_empty());
        prop_assert_eq!(by_links.samples(), by_feed.samples());
        prop_assert_eq!(by_links.sample_ticks(), by_feed.sample_ticks());
        prop_assert_eq!(by_links.ticks(), by_feed.ticks());
    }
}

/// The board's frames: the real CCD47-20 through both outputs at 1 MHz, a full frame and 30
/// windows of 11 x 11, with a 1 s exposure and the board's 256-word rest run. Prints the link
/// counts (the descriptors the CPU writes) against the ticks (the words it wrote before).
#[test]
fn board_frames_link_to_the_word_feed() {
    let t = ticks(1_000_000);
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let rects: Vec<Rect> = (0..30u16)
        .map(|i| Rect {
            x0: 20 + 33 * i,
            y0: 10 + 33 * i,
            width: 11,
            height: 11,
        })
        .collect();
    for (name, request) in [
        ("full frame", ReadoutRequest::FullFrame),
        ("30 windows", ReadoutRequest::Windows(&rects)),
    ] {
        for exposure_us in [0, 1_000_000] {
            let mut buf = buffers();
            let p = compiled(g, request, Binning::X1, exposure_us, &t, &mut buf);
            let links = assert_chain_is_the_feed(&p, 256);
            let ticks: u64 = links.iter().map(Link::ticks).sum();
            println!(
                "{name}, exposure {exposure_us} us: {} steps, {} links, {ticks} ticks",
                p.steps().len(),
                links.len()
            );
            // One link a step (no step repeats more than 4096 times), and for a second's
            // exposure (at most 20 M rest ticks of 50 ns) at most 20 more: blocks of the
            // 256-word run, 4096 a link (1,048,576 ticks).
            if exposure_us == 0 {
                assert_eq!(links.len(), p.steps().len());
            } else {
                assert!(links.len() <= p.steps().len() + 20, "{}", links.len());
            }
        }
    }
}

/// A table too small, a run longer than a block: typed errors, never a short chain.
#[test]
fn refusals_are_typed() {
    let t = ticks(1_000_000);
    let mut buf = buffers();
    let p = compiled(
        SMALL,
        ReadoutRequest::FullFrame,
        Binning::X1,
        0,
        &t,
        &mut buf,
    );
    let mut small = vec![0u32; p.words().len() + 3];
    assert_eq!(
        Chain::new(&p, 4, &mut small).err(),
        Some(ChainError::Words {
            needed: p.words().len() + 4
        })
    );
    // The run is capped at a block's words.
    let mut big = vec![0u32; p.words().len() + MAX_BLOCK_WORDS as usize + 10];
    let chain = Chain::new(&p, u32::MAX, &mut big);
    assert!(chain.is_ok_and(|c| c.words().len() == p.words().len() + MAX_BLOCK_WORDS as usize));
}
