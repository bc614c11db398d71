//! The sequencer's compiled tables clocked through the charge-transfer model of the CCD47-20:
//! a full frame gives the core's line layout, windows give exactly the windows' pixels (with
//! binning and one or two outputs), and broken tables fail the model.

use proptest::prelude::*;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, Limits, Line, LineSet, Phases, PinMap, Program, ReadoutPlan, SegmentId, SequenceError,
    Step, Ticks, Timing, check_program, compile,
};
use startrack_core::window::Rect;
use startrack_sim::ccd_model::CcdModel;

/// A reduced CCD47-20 with the same layout: 2 over-scan + 2 covered + 16 active + 2 + 2.
const SMALL: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 2,
    covered_px: 2,
    active_cols: 16,
    active_rows: 12,
    lines: 14,
    outputs: 2,
};

fn ticks() -> Ticks {
    let t = Timing::at_pixel_rate(1_000_000).validate(&Limits::CCD47_20);
    assert!(t.is_ok(), "{t:?}");
    t.unwrap_or_else(|_| unreachable!())
}

/// Image charge: distinct, non-zero, and not a sum of neighbours by accident.
fn image_e(c: usize, y: usize) -> i64 {
    1 + ((y * 7919 + c * 104_729) % 65_521) as i64
}

/// Charge a previous frame left in the store (must be flushed, never read).
fn stale_e(c: usize, s: usize) -> i64 {
    1_000_000 + (c * 31 + s) as i64
}

struct Compiled {
    words: Vec<u32>,
    steps: Vec<Step>,
}

fn compiled<'a>(
    geometry: ReadoutGeometry,
    request: ReadoutRequest<'_>,
    binning: Binning,
    t: &Ticks,
    buf: &'a mut Compiled,
) -> Program<'a, 'a> {
    let plan = ReadoutPlan::new(geometry, request, binning, 0);
    assert!(plan.is_ok(), "{plan:?}");
    let plan = plan.unwrap_or_else(|_| unreachable!());
    let p = compile(&plan, t, &PinMap::IN_ORDER, &mut buf.words, &mut buf.steps);
    assert!(p.is_ok(), "{p:?}");
    p.unwrap_or_else(|_| unreachable!())
}

fn buffers() -> Compiled {
    Compiled {
        words: vec![0; 4096],
        steps: vec![Step::EMPTY; 8192],
    }
}

/// Runs `words` on a freshly loaded model.
fn clock(
    geometry: &ReadoutGeometry,
    pins: PinMap,
    t: &Ticks,
    words: impl IntoIterator<Item = u32>,
) -> CcdModel {
    let mut m = CcdModel::new(geometry, pins, t);
    m.load(image_e, stale_e);
    m.run(words);
    m
}

/// What an ideal readout delivers, computed from the image alone: per digitised shift,
/// the binned charge under each output (the right one 0 with one output).
fn oracle(g: &ReadoutGeometry, rects: Option<&[Rect]>, b: usize) -> Vec<[i64; 2]> {
    let len = g.line_len();
    let os = usize::from(g.overscan_px);
    let par_cols = len - 2 * os;
    let prefix = g.first_active_col();
    // The over-scan and the covered columns read at each end.
    let edge = match rects {
        None => prefix,
        Some(rs) => ReadoutRequest::Windows(rs).edge_px(g),
    };
    let dual = g.outputs == 2;
    let n = if dual { len / 2 / b } else { len / b };
    let value = |r: usize, line: usize| {
        if line < usize::from(g.active_rows) && r >= os && r < os + par_cols {
            image_e(r - os, line)
        } else {
            0
        }
    };
    let block = |cols: std::ops::Range<usize>, rows: std::ops::Range<usize>| -> i64 {
        rows.flat_map(|l| cols.clone().map(move |r| (r, l)))
            .map(|(r, l)| value(r, l))
            .sum()
    };
    let hits = |r: &Rect, rows: &std::ops::Range<usize>| {
        usize::from(r.y0) < rows.end && usize::from(r.y0 + r.height) > rows.start
    };
    let mut out = Vec::new();
    for grp in 0..usize::from(g.lines) / b {
        let rows = grp * b..grp * b + b;
        if let Some(rs) = rects
            && !rs.iter().any(|r| hits(r, &rows))
        {
            continue;
        }
        let needed = |col: usize| match rects {
            None => true,
            Some(rs) => {
                col < edge
                    || col >= len - edge
                    || rs.iter().any(|r| {
                        hits(r, &rows)
                            && col >= prefix + usize::from(r.x0)
                            && col < prefix + usize::from(r.x0 + r.width)
                    })
            }
        };
        for k in 0..n {
            let left = k * b..k * b + b;
            let right = len - (k + 1) * b..len - k * b;
            let need = left.clone().any(needed) || (dual && right.clone().any(needed));
            if need {
                out.push([
                    block(left, rows.clone()),
                    if dual { block(right, rows.clone()) } else { 0 },
                ]);
            }
        }
    }
    out
}

#[test]
fn full_frame_is_the_core_line_layout_small_both_output_counts() {
    let t = ticks();
    for outputs in [1, 2] {
        let g = ReadoutGeometry { outputs, ..SMALL };
        let mut buf = buffers();
        let p = compiled(g, ReadoutRequest::FullFrame, Binning::X1, &t, &mut buf);
        assert_eq!(check_program(&p, &PinMap::IN_ORDER), Ok(()));
        let m = clock(&g, PinMap::IN_ORDER, &t, p.ticks());
        assert!(m.faults.is_clean(), "{:?}", m.faults);
        assert_eq!(m.pixels(), oracle(&g, None, 1));
        // The stale store rows went down the dump drain, not into a sample.
        assert!(m.dumped_e >= 1_000_000 * i64::from(g.lines) * m.par_cols() as i64);
    }
}

/// The real CCD47-20: 1033 lines of 1072 elements through both outputs, each element where
/// `geometry` says it is.
#[test]
fn full_frame_ccd47_20_both_outputs() {
    let t = ticks();
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let mut buf = Compiled {
        words: vec![0; 4096],
        steps: vec![Step::EMPTY; 4096],
    };
    let p = compiled(g, ReadoutRequest::FullFrame, Binning::X1, &t, &mut buf);
    let m = clock(&g, PinMap::IN_ORDER, &t, p.ticks());
    assert!(m.faults.is_clean(), "{:?}", m.faults);
    let px = m.pixels();
    let len = g.line_len();
    assert_eq!(px.len(), usize::from(g.lines) * len / 2);
    for (line, shifts) in px.chunks_exact(len / 2).enumerate() {
        let mut raw = vec![0i64; len];
        for (k, [l, r]) in shifts.iter().enumerate() {
            raw[k] = *l;
            raw[len - 1 - k] = *r;
        }
        for (col, &v) in raw.iter().enumerate() {
            let expect = match g.segment(col) {
                Some(startrack_core::geometry::Segment::OverScan) => 0,
                _ if line >= usize::from(g.active_rows) => 0,
                _ => image_e(col - usize::from(g.overscan_px), line),
            };
            assert_eq!(v, expect, "line {line} col {col}");
        }
    }
}

fn rects_strategy() -> impl Strategy<Value = Vec<Rect>> {
    prop::collection::vec((0u16..16, 1u16..8, 0u16..12, 1u16..6), 1..6).prop_map(|v| {
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
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(48)))]

    /// Windows (any list, overlapping or not) with any binning and either output count give
    /// exactly the windows' binned pixels plus the prefix columns, in readout order.
    #[test]
    fn windows_give_the_windows_pixels(
        rects in rects_strategy(),
        b in prop::sample::select(vec![1u16, 2, 4]),
        outputs in 1u8..=2,
    ) {
        let t = ticks();
        let g = ReadoutGeometry { outputs, ..SMALL };
        let binning = Binning::from_factor(b).unwrap_or(Binning::X1);
        let mut buf = buffers();
        let p = compiled(g, ReadoutRequest::Windows(&rects), binning, &t, &mut buf);
        prop_assert_eq!(check_program(&p, &PinMap::IN_ORDER), Ok(()));
        let m = clock(&g, PinMap::IN_ORDER, &t, p.ticks());
        prop_assert!(m.faults.is_clean(), "{:?}", m.faults);
        prop_assert_eq!(m.pixels(), oracle(&g, Some(&rects), usize::from(b)));
    }

    /// Full frames with binning 2 and 4.
    #[test]
    fn binned_full_frames(b in prop::sample::select(vec![2u16, 4]), outputs in 1u8..=2) {
        let t = ticks();
        let g = ReadoutGeometry { outputs, ..SMALL };
        let binning = Binning::from_factor(b).unwrap_or(Binning::X1);
        let mut buf = buffers();
        let p = compiled(g, ReadoutRequest::FullFrame, binning, &t, &mut buf);
        let m = clock(&g, PinMap::IN_ORDER, &t, p.ticks());
        prop_assert!(m.faults.is_clean(), "{:?}", m.faults);
        prop_assert_eq!(m.pixels(), oracle(&g, None, usize::from(b)));
    }
}

/// The words of `p` with `patch` applied to each word of one segment.
fn patched<'a>(
    p: &'a Program<'a, 'a>,
    segment: SegmentId,
    patch: impl Fn(usize, LineSet) -> LineSet + 'a,
) -> impl Iterator<Item = u32> + 'a {
    let pins = PinMap::IN_ORDER;
    let patch = std::rc::Rc::new(patch);
    p.steps().iter().flat_map(move |s| {
        let words: Vec<u32> = p
            .segment(s.segment)
            .iter()
            .enumerate()
            .map(|(i, &w)| {
                if s.segment == segment {
                    pins.bsrr(patch(i, pins.lines_of_port(PinMap::apply(0, w))))
                } else {
                    w
                }
            })
            .collect();
        std::iter::repeat_n(words, s.repeat as usize).flatten()
    })
}

fn windows() -> Vec<Rect> {
    vec![
        Rect {
            x0: 1,
            y0: 2,
            width: 4,
            height: 3,
        },
        Rect {
            x0: 9,
            y0: 6,
            width: 5,
            height: 4,
        },
    ]
}

/// The store's phases 2 and 3 swapped on the board: a valid-looking sequence (the checker
/// passes it) that moves charge the wrong way. The model loses it.
#[test]
fn swapped_phase_fails_the_model() {
    let t = ticks();
    let rects = windows();
    let mut buf = buffers();
    let p = compiled(
        SMALL,
        ReadoutRequest::Windows(&rects),
        Binning::X1,
        &t,
        &mut buf,
    );
    assert_eq!(check_program(&p, &PinMap::IN_ORDER), Ok(()));
    let mut board = PinMap::IN_ORDER;
    board.pins.swap(Line::S2 as usize, Line::S3 as usize);
    let m = clock(&SMALL, board, &t, p.ticks());
    assert!(!m.faults.is_clean(), "swapped S2/S3 went unnoticed");
    assert_ne!(m.pixels(), oracle(&SMALL, Some(&rects), 1));
    // The register's phases swapped on the left half: the left output reads nothing right.
    let mut board = PinMap::IN_ORDER;
    board.pins.swap(Line::R2L as usize, Line::R3L as usize);
    // The left half then shifts towards the split, in step with the right half, so its
    // charge leaves through the right output: no transfer fault, but the left output reads
    // nothing where the image has charge.
    let m = clock(&SMALL, board, &t, p.ticks());
    let px = m.pixels();
    let want = oracle(&SMALL, Some(&rects), 1);
    assert_eq!(px.len(), want.len());
    assert!(want.iter().any(|v| v[0] != 0));
    assert!(px.iter().all(|v| v[0] == 0), "{px:?}");
}

/// A line transfer that jumps from P12 straight to phase 3 (no shared phase): the checker
/// rejects it, and the model loses every row it clocks.
#[test]
fn missing_overlap_fails_the_checker_and_the_model() {
    let t = ticks();
    let rects = windows();
    let mut buf = buffers();
    let p = compiled(
        SMALL,
        ReadoutRequest::Windows(&rects),
        Binning::X1,
        &t,
        &mut buf,
    );
    let state_ticks = t.line_state as usize;
    let broken = |i: usize, s: LineSet| {
        if i < state_ticks {
            s.phases(Line::STORE, Phases(0b100))
        } else {
            s
        }
    };
    let words: Vec<u32> = patched(&p, SegmentId::LineTransfer, broken).collect();
    let m = clock(&SMALL, PinMap::IN_ORDER, &t, words.iter().copied());
    assert!(m.faults.lost_packets > 0, "{:?}", m.faults);
    assert!(m.faults.lost_e > 0);
    assert_ne!(m.pixels(), oracle(&SMALL, Some(&rects), 1));
    // The same edit in the word table fails the checker.
    let mut words = p.words().to_vec();
    let start = p.segment(SegmentId::FrameTransfer).len();
    for w in words.iter_mut().skip(start).take(state_ticks) {
        let s = PinMap::IN_ORDER.lines_of_port(PinMap::apply(0, *w));
        *w = PinMap::IN_ORDER.bsrr(broken(0, s));
    }
    let edited = p.relocated(&words);
    assert!(edited.is_some());
    let edited = edited.unwrap_or_else(|| unreachable!());
    assert!(matches!(
        check_program(&edited, &PinMap::IN_ORDER),
        Err(SequenceError::NoOverlap {
            group: Line::S1,
            ..
        })
    ));
}

/// The dump gate left open while pixels are read: the register drains, the samples hold no
/// signal.
#[test]
fn dump_gate_open_while_reading_fails_the_model() {
    let t = ticks();
    let rects = windows();
    let mut buf = buffers();
    let p = compiled(
        SMALL,
        ReadoutRequest::Windows(&rects),
        Binning::X1,
        &t,
        &mut buf,
    );
    let words: Vec<u32> = patched(&p, SegmentId::ReadPixel, |_, s| s.with(Line::Dg)).collect();
    let m = clock(&SMALL, PinMap::IN_ORDER, &t, words.iter().copied());
    let px = m.pixels();
    let want = oracle(&SMALL, Some(&rects), 1);
    assert_eq!(px.len(), want.len());
    assert_ne!(px, want);
    assert!(m.dumped_e > 0);
    // Every window pixel lost its charge.
    assert!(px.iter().all(|v| *v == [0, 0]), "{px:?}");
}

/// The line jobs read off the program, fed the model's CDS values as ADC words, unpack into
/// raw lines that hold the image where the request reads and nothing elsewhere; each job
/// ends on the tick of its last sample.
fn check_line_jobs(g: &ReadoutGeometry, request: ReadoutRequest<'_>) {
    use startrack_core::sequencer::LineJobs;
    let t = ticks();
    let mut buf = buffers();
    let p = compiled(*g, request, Binning::X1, &t, &mut buf);
    let m = clock(g, PinMap::IN_ORDER, &t, p.ticks());
    let px = m.pixels();
    let sample_ticks = m.sample_ticks();
    let outputs = usize::from(g.outputs);
    let len = g.line_len();
    let os = usize::from(g.overscan_px);
    let prefix = g.first_active_col();
    let mut next_px = 0;
    let mut lines_seen = Vec::new();
    for job in LineJobs::new(&p) {
        let n = job.words as usize / outputs;
        let words: Vec<u16> = px[next_px..next_px + n]
            .iter()
            .flat_map(|v| v[..outputs].iter().map(|&e| e as u16))
            .collect();
        // The job ends just after its last sample (the signal CONVST of its last pixel).
        let last_sample_tick = sample_ticks[2 * (next_px + n) - 1];
        assert_eq!(job.end_tick, last_sample_tick, "line {}", job.line);
        next_px += n;
        let mut line = vec![u16::MAX; len];
        let used = job.unpack(g.outputs, 1, &words, &mut line);
        assert_eq!(used, Ok(words.len()));
        let l = usize::from(job.line);
        lines_seen.push(job.line);
        for (col, &v) in line.iter().enumerate() {
            let active = col >= prefix && col < len - prefix;
            let edge = request.edge_px(g);
            let wanted = if active {
                request.reads_pixel((col - prefix) as u16, job.line)
            } else {
                col < edge || col >= len - edge
            };
            if !wanted {
                // Not asked for: untouched with one output; with two, the other half's
                // sample at the same shift may be there.
                if outputs == 1 {
                    assert_eq!(v, u16::MAX, "line {l} col {col} written");
                }
                continue;
            }
            let expect = if col < os || col >= len - os || l >= usize::from(g.active_rows) {
                0
            } else {
                image_e(col - os, l) as u16
            };
            assert_eq!(v, expect, "line {l} col {col}");
        }
    }
    assert_eq!(next_px, px.len());
    let want: Vec<u16> = (0..g.lines).filter(|&l| request.reads_line(g, l)).collect();
    assert_eq!(lines_seen, want);
}

#[test]
fn line_jobs_unpack_to_the_core_layout() {
    let rects = windows();
    for outputs in [1, 2] {
        let g = ReadoutGeometry { outputs, ..SMALL };
        check_line_jobs(&g, ReadoutRequest::FullFrame);
        check_line_jobs(&g, ReadoutRequest::Windows(&rects));
    }
    check_line_jobs(
        &ReadoutGeometry::CCD47_20_DUAL,
        ReadoutRequest::Windows(&rects),
    );
}
