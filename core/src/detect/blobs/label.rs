//! Connected-component labelling, one line at a time: a line's runs of above-threshold
//! pixels join (8-connectivity) the blobs of the previous line's runs they touch, a run that
//! touches two blobs merges them (union-find over the open blobs), and a blob that gets no
//! run on a line is closed and handed to [`LineDetector::complete`]. The state and the rules
//! are told in [`super`].
//!
//! # Cost
//! Per pixel of a line the threshold test of its block ([`super::above_thr`]); per run a
//! scan of the previous line's runs and a find per touching run; per pixel of a run the
//! blob's sums and position moments (~10 f32 multiply-adds); per line a walk of the open
//! blobs (at most [`MAX_OPEN`]). Part of `scan_detect` in `cargo m7-bench`.

use super::{Blob, DetectionFlags, LineDetector, MAX_OPEN, MAX_RUNS, Run, above_thr};
use crate::calib::PixelFlags;
use crate::detect::DetectError;
use crate::detect::background::BLOCK_PX;
use crate::units::Electrons;

impl<const N: usize> LineDetector<N> {
    /// Takes calibrated active row `y` (all `width` pixels and their flags).
    pub fn push_line(
        &mut self,
        y: u16,
        pixels_e: &[Electrons],
        flags: &[PixelFlags],
    ) -> Result<(), DetectError> {
        if pixels_e.len() != usize::from(self.width) || flags.len() != pixels_e.len() {
            return Err(DetectError::LineLength);
        }
        let due = self.background_due(y);
        self.begin_line(y)?;
        // The first line primes the estimate with its own values; folding the same line in
        // again after it would leave every block unchanged (its median and sigma equal the
        // estimate), so it is not repeated.
        let priming = !self.background.is_primed();
        if priming {
            self.background.update(pixels_e, flags);
        }
        let thr = self.background.thresholds(self.config.pixel_sigmas);
        let last_block = self.background.block_of(usize::MAX);
        let up = |x: usize| {
            // The block of x, as `BlockBackground::block_of`.
            let b = (x / BLOCK_PX).min(last_block);
            let t = thr.get(b).copied().unwrap_or(i64::MAX);
            above_thr(t, pixels_e, flags, x)
        };
        let mut x = 0usize;
        let w = usize::from(self.width);
        while x < w {
            if !up(x) {
                x += 1;
                continue;
            }
            let x0 = x;
            while x + 1 < w && up(x + 1) {
                x += 1;
            }
            self.add_run(y, x0 as u16, x as u16, pixels_e, flags);
            x += 1;
        }
        self.end_line(y);
        if due && !priming {
            self.background.update(pixels_e, flags);
        }
        Ok(())
    }

    /// Starts row `y`: checks the order, closes everything when rows were skipped.
    pub(crate) fn begin_line(&mut self, y: u16) -> Result<(), DetectError> {
        if y < self.next_y {
            return Err(DetectError::RowOrder);
        }
        if y > self.next_y {
            // Skipped rows break connectivity: close everything open.
            self.close_all_before(y);
            self.prev_runs_mut().clear();
        }
        self.cur_runs_mut().clear();
        Ok(())
    }

    /// Ends row `y` after its runs were added (without the background update).
    pub(crate) fn end_line(&mut self, y: u16) {
        // Runs of this line point at roots; merged blobs are released.
        for i in 0..self.cur_runs().len() {
            if let Some(r) = self.cur_runs().get(i).map(|r| r.blob) {
                let root = self.find(r);
                if let Some(run) = self.cur_runs_mut().get_mut(i) {
                    run.blob = root;
                }
            }
        }
        let end = self.open_end;
        for (i, b) in self.blobs.iter_mut().enumerate().take(end) {
            if b.open && usize::from(b.parent) != i {
                b.open = false;
            }
        }
        self.close_all_before(y);
        self.cur_ix = !self.cur_ix;
        self.next_y = y.saturating_add(1);
    }

    /// Completes every open blob: call after the last line.
    pub fn finish(&mut self) {
        self.close_all_before(u16::MAX);
        self.prev_runs_mut().clear();
    }

    fn prev_runs(&self) -> &heapless::Vec<Run, MAX_RUNS> {
        let [a, b] = &self.runs;
        if self.cur_ix { a } else { b }
    }

    fn prev_runs_mut(&mut self) -> &mut heapless::Vec<Run, MAX_RUNS> {
        let [a, b] = &mut self.runs;
        if self.cur_ix { a } else { b }
    }

    fn cur_runs(&self) -> &heapless::Vec<Run, MAX_RUNS> {
        let [a, b] = &self.runs;
        if self.cur_ix { b } else { a }
    }

    fn cur_runs_mut(&mut self) -> &mut heapless::Vec<Run, MAX_RUNS> {
        let [a, b] = &mut self.runs;
        if self.cur_ix { b } else { a }
    }

    fn find(&self, mut i: u16) -> u16 {
        // Parents always point to an open root within MAX_OPEN steps.
        for _ in 0..MAX_OPEN {
            match self.blobs.get(usize::from(i)) {
                Some(b) if b.parent != i => i = b.parent,
                _ => break,
            }
        }
        i
    }

    /// Adds the run `x0..=x1` of row `y` (every pixel of it above the threshold; only its
    /// pixels are read from `pixels_e` and `flags`).
    pub(crate) fn add_run(
        &mut self,
        y: u16,
        x0: u16,
        x1: u16,
        pixels_e: &[Electrons],
        flags: &[PixelFlags],
    ) {
        let mut blob: Option<u16> = None;
        // The previous line's runs by index, not collected: a 512-byte list moved per run
        // cost ~450 instructions (a `memcpy`) on the M7, ~3 per pixel of the scan.
        for i in 0..self.prev_runs().len() {
            let Some(b) = self
                .prev_runs()
                .get(i)
                .filter(|p| p.x0 <= x1.saturating_add(1) && p.x1.saturating_add(1) >= x0)
                .map(|p| p.blob)
            else {
                continue;
            };
            let r = self.find(b);
            match blob {
                None => blob = Some(r),
                Some(into) if into != r => self.merge(r, into),
                _ => {}
            }
        }
        let id = match blob {
            Some(id) => id,
            None => match self.blobs.iter().position(|b| !b.open) {
                Some(free) => {
                    let id = free as u16;
                    self.open_end = self.open_end.max(free + 1);
                    if let Some(b) = self.blobs.get_mut(free) {
                        *b = Blob {
                            open: true,
                            parent: id,
                            peak_bits: i32::MIN,
                            x_min: u16::MAX,
                            ref_x: x0,
                            ref_y: y,
                            y_min: y,
                            ..Blob::default()
                        };
                    }
                    id
                }
                None => {
                    self.dropped_pixels += u32::from(x1 - x0) + 1;
                    return;
                }
            },
        };
        if self.cur_runs_mut().push(Run { x0, x1, blob: id }).is_err() {
            self.dropped_pixels += u32::from(x1 - x0) + 1;
            if let Some(b) = self.blobs.get_mut(usize::from(id)) {
                b.flags |= DetectionFlags::TRUNCATED;
            }
        }
        let bg = &self.background;
        let Some(b) = self.blobs.get_mut(usize::from(id)) else {
            return;
        };
        b.last_y = y;
        for x in x0..=x1 {
            let (Some(e), Some(f)) = (pixels_e.get(usize::from(x)), flags.get(usize::from(x)))
            else {
                continue;
            };
            let l = bg.at(usize::from(x));
            let w_bits = e.to_bits().saturating_sub(l.background_e.to_bits());
            let w = w_bits as f32 / 64.0;
            let sigma = l.sigma_e.to_bits() as f32 / 64.0;
            b.pixels += 1;
            b.sum_w_e += w;
            let (dx, dy) = (
                f32::from(x) - f32::from(b.ref_x),
                f32::from(y) - f32::from(b.ref_y),
            );
            b.moments.add(w.max(0.0), dx, dy);
            b.var_e2 += sigma * sigma;
            b.peak_sigmas = b.peak_sigmas.max(w / sigma.max(1.0 / 64.0));
            if e.to_bits() > b.peak_bits {
                b.peak_bits = e.to_bits();
                b.peak_x = x;
                b.peak_y = y;
            }
            if f.contains(PixelFlags::SATURATED) {
                b.flags |= DetectionFlags::SATURATED;
            }
        }
        b.x_min = b.x_min.min(x0);
        b.x_max = b.x_max.max(x1);
    }

    /// Merges root `from` into root `into`.
    fn merge(&mut self, from: u16, into: u16) {
        let (Some(a), Some(b)) = (
            self.blobs.get(usize::from(from)).copied(),
            self.blobs.get(usize::from(into)).copied(),
        ) else {
            return;
        };
        let apart = a.peak_x.abs_diff(b.peak_x).max(a.peak_y.abs_diff(b.peak_y)) >= 3;
        let Some(t) = self.blobs.get_mut(usize::from(into)) else {
            return;
        };
        if apart && a.pixels > 1 && b.pixels > 1 {
            t.flags |= DetectionFlags::BLENDED;
        }
        t.pixels += a.pixels;
        t.sum_w_e += a.sum_w_e;
        let (sx, sy) = (
            f32::from(a.ref_x) - f32::from(t.ref_x),
            f32::from(a.ref_y) - f32::from(t.ref_y),
        );
        t.moments.add_shifted(&a.moments, sx, sy);
        t.var_e2 += a.var_e2;
        t.peak_sigmas = t.peak_sigmas.max(a.peak_sigmas);
        if a.peak_bits > t.peak_bits {
            (t.peak_bits, t.peak_x, t.peak_y) = (a.peak_bits, a.peak_x, a.peak_y);
        }
        t.x_min = t.x_min.min(a.x_min);
        t.x_max = t.x_max.max(a.x_max);
        t.y_min = t.y_min.min(a.y_min);
        t.last_y = t.last_y.max(a.last_y);
        t.flags |= a.flags;
        if let Some(f) = self.blobs.get_mut(usize::from(from)) {
            f.parent = into;
        }
    }

    /// Completes the open root blobs whose last run is on a row before `y`.
    fn close_all_before(&mut self, y: u16) {
        for i in 0..self.open_end {
            // Test in place: copying every 70-byte blob per row cost ~6 instructions per
            // pixel of the scan on the M7.
            let done = self
                .blobs
                .get(i)
                .is_some_and(|b| b.open && usize::from(b.parent) == i && b.last_y < y);
            if !done {
                continue;
            }
            if let Some(s) = self.blobs.get_mut(i) {
                s.open = false;
                let b = *s;
                self.complete(&b);
            }
        }
        // Every open blob lies below `open_end`: shrink it past the closed ones.
        while self.open_end > 0 && self.blobs.get(self.open_end - 1).is_some_and(|b| !b.open) {
            self.open_end -= 1;
        }
    }
}
