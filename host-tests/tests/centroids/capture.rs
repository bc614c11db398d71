//! Window capture from the line stream (`startrack_core::detect::WindowCapture`): the raw-line
//! ring of acquisition mode and the window list of tracking mode. The firmware fills both
//! from the DMA'd line buffers, so their logic is checked here against a plain model (a
//! whole frame in a `Vec`) on random line sequences, gaps included.

use proptest::prelude::*;
use startrack_core::calib::LineLevels;
use startrack_core::detect::{CAPTURE_MAX_SIDE, CaptureError, RingError};
use startrack_core::detect::{LineRing, WindowCapture};
use startrack_core::geometry::{MAX_OUTPUTS, ReadoutGeometry};
use startrack_core::units::BiasAdu;
use startrack_core::window::Rect;

const G: ReadoutGeometry = ReadoutGeometry::CCD47_20_DUAL;
const LINE: usize = G.line_len();
const R: usize = 8;

/// Raw sample of raw column `c` on active row `y` (distinct across the frame).
fn sample(c: usize, y: u16) -> u16 {
    ((c as u32 * 7919 + u32::from(y) * 104_729) % 65_536) as u16
}

fn line(y: u16) -> Vec<u16> {
    (0..LINE).map(|c| sample(c, y)).collect()
}

fn levels(y: u16) -> LineLevels {
    LineLevels {
        bias_adu: [BiasAdu::from_num(f64::from(y) + 0.25); MAX_OUTPUTS],
    }
}

/// The model's raw samples of `rect`, row-major.
fn model_window(rect: Rect) -> Vec<u16> {
    let first = G.first_active_col();
    (rect.y0..rect.y0 + rect.height)
        .flat_map(|y| {
            (rect.x0..rect.x0 + rect.width).map(move |x| sample(first + usize::from(x), y))
        })
        .collect()
}

fn copy(ring: &LineRing<R, LINE>, rect: Rect) -> Result<(Vec<u16>, Vec<LineLevels>), RingError> {
    let mut raw = vec![0u16; rect.len()];
    let mut lv = vec![levels(0); usize::from(rect.height)];
    ring.copy_window(rect, &mut raw, &mut lv)?;
    Ok((raw, lv))
}

fn rect(x0: u16, y0: u16, width: u16, height: u16) -> Rect {
    Rect {
        x0,
        y0,
        width,
        height,
    }
}

#[test]
fn ring_gives_windows_whose_rows_are_held_and_refuses_the_others() {
    let mut ring = Box::new(LineRing::<R, LINE>::new(G.first_active_col()));
    for y in 0..20 {
        ring.push(y, &line(y), &levels(y)).unwrap();
    }
    // Rows 12..=19 are held.
    let r = rect(100, 12, 7, 8);
    let (raw, lv) = copy(&ring, r).unwrap();
    assert_eq!(raw, model_window(r));
    assert_eq!(lv, (12..20).map(levels).collect::<Vec<_>>());
    assert_eq!(
        copy(&ring, rect(100, 11, 7, 7)).err(),
        Some(RingError::RowGone)
    );
    assert_eq!(
        copy(&ring, rect(100, 15, 7, 7)).err(),
        Some(RingError::RowNotYet)
    );
    assert_eq!(
        copy(&ring, rect(1050, 12, 7, 3)).err(),
        Some(RingError::OutsideLine)
    );
    let mut short = vec![0u16; 3];
    let mut lv = vec![levels(0); 3];
    assert_eq!(
        ring.copy_window(rect(0, 12, 2, 3), &mut short, &mut lv),
        Err(RingError::BufferLength)
    );
    let mut long = line(20);
    long.push(0);
    assert_eq!(
        ring.push(20, &long, &levels(20)),
        Err(RingError::LineLength)
    );
    // A shorter line (a binned or narrower readout) fills the start of its slot: windows
    // inside it come back, one reaching past its end is outside the line, even though the
    // slot's previous, longer line was there.
    let short_len = LINE / 2;
    for y in 20..23 {
        ring.push(y, &line(y)[..short_len], &levels(y)).unwrap();
    }
    let inside = rect((short_len - G.first_active_col() - 3) as u16, 20, 3, 3);
    assert_eq!(copy(&ring, inside).unwrap().0, model_window(inside));
    let past = rect((short_len - G.first_active_col() - 2) as u16, 20, 3, 3);
    assert_eq!(copy(&ring, past).err(), Some(RingError::OutsideLine));
    ring.clear();
    assert_eq!(
        copy(&ring, rect(100, 19, 3, 1)).err(),
        Some(RingError::RowNotYet)
    );
}

#[test]
fn capture_copies_windows_and_reports_each_once_at_its_last_row() {
    let mut cap = Box::new(WindowCapture::<8>::new(G));
    let a = rect(0, 0, 9, 9);
    let b = rect(1015, 30, 9, 9);
    let c = rect(500, 1020, 5, 4);
    for (i, r) in [a, b, c].into_iter().enumerate() {
        assert_eq!(cap.add(r, i == 0), Ok(i));
    }
    assert_eq!(
        cap.add(rect(1016, 0, 9, 9), false),
        Err(CaptureError::OutsideActiveArea)
    );
    assert_eq!(
        cap.add(rect(0, 0, CAPTURE_MAX_SIDE + 1, 3), false),
        Err(CaptureError::WindowSize)
    );
    assert_eq!(
        cap.add(rect(0, 0, 0, 3), false),
        Err(CaptureError::WindowSize)
    );
    let mut completed_at = vec![None; 3];
    for y in 0..G.active_rows {
        for i in cap.push_line(y, &line(y), &levels(y)).unwrap() {
            assert!(completed_at[i].is_none(), "window {i} completed twice");
            completed_at[i] = Some(y);
        }
        if y == 5 {
            assert_eq!(cap.add(rect(0, 5, 3, 3), false), Err(CaptureError::TooLate));
        }
    }
    assert_eq!(completed_at, vec![Some(8), Some(38), Some(1023)]);
    assert!(cap.finish().is_empty());
    for (i, r) in [a, b, c].into_iter().enumerate() {
        let w = cap.window(i).unwrap();
        assert_eq!(w.rect, r);
        assert_eq!(w.clipped, i == 0);
        assert!(w.complete && !w.missing_rows);
        assert_eq!(w.raw, model_window(r).as_slice());
        assert_eq!(
            w.levels,
            (r.y0..r.y0 + r.height)
                .map(levels)
                .collect::<Vec<_>>()
                .as_slice()
        );
    }
    assert_eq!(
        cap.push_line(3, &line(3), &levels(3)),
        Err(CaptureError::RowOrder)
    );
    assert_eq!(
        cap.push_line(2000, &line(3)[..10], &levels(3)),
        Err(CaptureError::LineLength)
    );
    cap.reset();
    assert!(cap.is_empty());
    assert_eq!(cap.add(a, false), Ok(0));
}

#[test]
fn capture_list_refuses_more_than_its_capacity() {
    let mut cap = Box::new(WindowCapture::<2>::new(G));
    assert!(cap.add(rect(0, 0, 3, 3), false).is_ok());
    assert!(cap.add(rect(10, 0, 3, 3), false).is_ok());
    assert_eq!(cap.add(rect(20, 0, 3, 3), false), Err(CaptureError::Full));
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(64)))]

    /// Random increasing line sequences (with gaps) into the ring: a window copies exactly
    /// when all its rows were pushed and not overwritten since, and then equals the
    /// model; otherwise the error says whether the rows are still to come or gone.
    #[test]
    fn ring_matches_the_model(
        gaps in prop::collection::vec(1u16..4, 1..60),
        windows in prop::collection::vec((0u16..1020, 0u16..200, 1u16..6, 1u16..10), 1..20),
    ) {
        let mut ring = Box::new(LineRing::<R, LINE>::new(G.first_active_col()));
        let mut pushed = Vec::new();
        let mut y = 0u16;
        for g in gaps {
            y += g;
            ring.push(y, &line(y), &levels(y)).unwrap();
            pushed.push(y);
            for &(x0, y0, w, h) in &windows {
                let r = rect(x0, y0, w, h);
                let rows = y0..y0 + h;
                // Pushed, and no later pushed row took its slot.
                let held = |row: u16| {
                    pushed.contains(&row)
                        && !pushed.iter().any(|&p| p > row && usize::from(p) % R == usize::from(row) % R)
                };
                let got = copy(&ring, r);
                if rows.clone().all(held) {
                    let (raw, lv) = got.unwrap();
                    prop_assert_eq!(raw, model_window(r));
                    prop_assert_eq!(lv, rows.map(levels).collect::<Vec<_>>());
                } else {
                    // The first row that fails decides the error.
                    let bad = rows.clone().find(|&row| !held(row)).unwrap();
                    let expect = if bad > y { RingError::RowNotYet } else { RingError::RowGone };
                    prop_assert_eq!(got.err(), Some(expect));
                }
            }
        }
    }

    /// Random windows and a frame with skipped lines: every window completes exactly once
    /// (at its last row, or at the first line after it, or at the frame's end), holds the
    /// model's samples on the rows that came, and says when rows are missing.
    #[test]
    fn capture_matches_the_model(
        windows in prop::collection::vec((0u16..1015, 0u16..120, 1u16..=15, 1u16..=15), 1..12),
        skipped in prop::collection::vec(0u16..140, 0..10),
        last_line in 60u16..140,
    ) {
        let mut cap = Box::new(WindowCapture::<16>::new(G));
        let windows: Vec<_> = windows.into_iter().map(|(x0, y0, w, h)| (x0.min(1024 - w), y0, w, h)).collect();
        for &(x0, y0, w, h) in &windows {
            cap.add(rect(x0, y0, w, h), false).unwrap();
        }
        let mut completed = vec![None; windows.len()];
        let arrived: Vec<u16> = (0..=last_line).filter(|y| !skipped.contains(y)).collect();
        for &y in &arrived {
            for i in cap.push_line(y, &line(y), &levels(y)).unwrap() {
                prop_assert!(completed[i].is_none());
                completed[i] = Some(y);
            }
        }
        for i in cap.finish() {
            prop_assert!(completed[i].is_none());
            completed[i] = Some(u16::MAX);
        }
        for (i, &(x0, y0, w, h)) in windows.iter().enumerate() {
            let r = rect(x0, y0, w, h);
            let last = y0 + h - 1;
            let expect_at = arrived.iter().copied().find(|&y| y >= last).unwrap_or(u16::MAX);
            prop_assert_eq!(completed[i], Some(expect_at));
            let win = cap.window(i).unwrap();
            let missing = (y0..=last).any(|y| !arrived.contains(&y));
            prop_assert_eq!(win.missing_rows, missing);
            let model = model_window(r);
            for (row, y) in (y0..=last).enumerate() {
                if arrived.contains(&y) {
                    let k = row * usize::from(w);
                    prop_assert_eq!(&win.raw[k..k + usize::from(w)], &model[k..k + usize::from(w)]);
                    prop_assert_eq!(win.levels[row], levels(y));
                }
            }
        }
    }
}
