//! Connected-component labelling of above-threshold pixels, one line at a time, and the
//! bounded candidate list.
//!
//! Each line is cut into runs of consecutive pixels above the threshold. A run joins every
//! blob with a run on the previous line that touches it (8-connectivity: overlapping or
//! diagonally adjacent); a run that joins two blobs merges them. A blob that gets no run on
//! a line is complete: its SNR is measured and, above the minimum, it becomes a candidate.
//! State: the previous and current lines' runs ([`MAX_RUNS`] each) and at most
//! [`MAX_OPEN`] open blobs; when either is full, pixels are dropped and counted, and the
//! affected candidates are flagged.
//!
//! Candidates live in a `heapless::Vec` of capacity `N`. When it is full, a new candidate
//! replaces the faintest one if it is brighter; either way one candidate is lost and
//! counted in [`LineDetector::dropped`]: the list always holds the `N` brightest.
//!
//! Blob positions are means of the blob's pixels weighted by their positive signal: a seed for the centroid
//! methods, not a measurement.

use super::background::BlockBackground;
use super::{DetectConfig, DetectError};
use crate::calib::PixelFlags;
use crate::units::Electrons;

/// Most runs kept per line.
pub const MAX_RUNS: usize = 256;
/// Most blobs open at once.
pub const MAX_OPEN: usize = 128;

bitflags::bitflags! {
    /// What detection noticed about a candidate.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct DetectionFlags: u8 {
        /// A pixel of the blob is saturated: flux is a lower bound, position biased.
        const SATURATED = 1;
        /// The blob touches the edge of the active area: its window will be clipped.
        const EDGE = 2;
        /// Probably a close pair: two branches with peaks at least 3 px apart met, or the
        /// blob is elongated (covariance eigenvalues l1 > 2 l2 and l1 - l2 > 1 px^2).
        const BLENDED = 4;
        /// SNR between the minimum and the low-SNR level of the configuration.
        const LOW_SNR = 8;
        /// Some of the blob's pixels were dropped because a run or blob table was full.
        const TRUNCATED = 16;
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for DetectionFlags {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "DetectionFlags({=u8:#x})", self.bits())
    }
}

/// A star candidate.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Detection {
    /// Flux-weighted column of the blob, px (active coordinates).
    pub x_px: f32,
    /// Flux-weighted row of the blob, px.
    pub y_px: f32,
    /// Column of the brightest pixel.
    pub peak_x: u16,
    /// Row of the brightest pixel.
    pub peak_y: u16,
    /// Background-subtracted signal of the blob's pixels, e-.
    pub flux_e: f32,
    /// Pixels in the blob.
    pub pixels: u32,
    /// Measured SNR, eq. 8: flux / sqrt(flux + sum of the pixels' noise variances).
    pub snr: f32,
    /// Flags.
    pub flags: DetectionFlags,
}

/// True when pixel `x` belongs to a blob: above its block's threshold `thr`
/// ([`super::background::threshold_bits`]), or saturated, and not a listed hot or telegraph pixel.
#[inline(always)]
pub(crate) fn above_thr(thr: i64, pixels_e: &[Electrons], flags: &[PixelFlags], x: usize) -> bool {
    let (Some(&e), Some(&f)) = (pixels_e.get(x), flags.get(x)) else {
        return false;
    };
    px_above_thr(thr, e, f)
}

/// [`above_thr`] for one pixel's value and flags.
#[inline(always)]
pub(crate) fn px_above_thr(thr: i64, e: Electrons, f: PixelFlags) -> bool {
    if f.is_excluded() || f.contains(PixelFlags::HOT_CORRECTED) {
        return false;
    }
    f.contains(PixelFlags::SATURATED) || i64::from(e.to_bits()) > thr
}

#[derive(Clone, Copy, Debug)]
struct Run {
    x0: u16,
    x1: u16,
    blob: u16,
}

#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    w: f32,
    x: f32,
    y: f32,
    xx: f32,
    yy: f32,
    xy: f32,
}

impl Moments {
    fn add(&mut self, w: f32, dx: f32, dy: f32) {
        self.w += w;
        self.x += w * dx;
        self.y += w * dy;
        self.xx += w * dx * dx;
        self.yy += w * dy * dy;
        self.xy += w * dx * dy;
    }

    /// Adds `o`, whose coordinates are relative to a point (`sx`, `sy`) from ours.
    fn add_shifted(&mut self, o: &Moments, sx: f32, sy: f32) {
        self.w += o.w;
        self.x += o.x + sx * o.w;
        self.y += o.y + sy * o.w;
        self.xx += o.xx + 2.0 * sx * o.x + sx * sx * o.w;
        self.yy += o.yy + 2.0 * sy * o.y + sy * sy * o.w;
        self.xy += o.xy + sx * o.y + sy * o.x + sx * sy * o.w;
    }

    /// Mean (relative) and the covariance's eigenvalues (larger first), px and px^2.
    fn shape(&self) -> Option<((f32, f32), (f32, f32))> {
        if self.w <= 0.0 {
            return None;
        }
        let (mx, my) = (self.x / self.w, self.y / self.w);
        let cxx = self.xx / self.w - mx * mx;
        let cyy = self.yy / self.w - my * my;
        let cxy = self.xy / self.w - mx * my;
        let half_tr = 0.5 * (cxx + cyy);
        let disc = libm::sqrtf((0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy).max(0.0));
        Some(((mx, my), (half_tr + disc, half_tr - disc)))
    }
}

#[derive(Clone, Copy, Debug, Default)]
struct Blob {
    open: bool,
    /// Index of the blob this one was merged into (itself for a root).
    parent: u16,
    last_y: u16,
    pixels: u32,
    sum_w_e: f32,
    /// Position moments with weights max(w, 0), coordinates relative to (ref_x, ref_y) so
    /// that f32 keeps its precision: sums of w, w dx, w dy, w dx^2, w dy^2, w dx dy.
    moments: Moments,
    ref_x: u16,
    ref_y: u16,
    var_e2: f32,
    /// Largest (value - background) / sigma of the blob's pixels.
    peak_sigmas: f32,
    peak_bits: i32,
    peak_x: u16,
    peak_y: u16,
    x_min: u16,
    x_max: u16,
    y_min: u16,
    flags: DetectionFlags,
}

/// The streaming detector: feed it calibrated lines in row order with [`Self::push_line`],
/// then call [`Self::finish`]; `N` is the candidate list's capacity.
#[derive(Clone, Debug)]
pub struct LineDetector<const N: usize> {
    config: DetectConfig,
    width: u16,
    rows: u16,
    background: BlockBackground,
    /// The previous and the current line's runs; `cur_ix` tells which is current, so that
    /// ending a line flips a flag instead of swapping two 1.5 KB vectors.
    runs: [heapless::Vec<Run, MAX_RUNS>; 2],
    cur_ix: bool,
    blobs: [Blob; MAX_OPEN],
    next_y: u16,
    candidates: heapless::Vec<Detection, N>,
    dropped: u32,
    dropped_pixels: u32,
    /// The background is updated on rows `y` with `y % bg_stride == 0` (1: every row).
    bg_stride: u16,
    /// Rows `y < bg_warmup` all update the background, whatever the stride (0: none).
    bg_warmup: u16,
    /// Every open blob has an index below this (the per-row loops stop there).
    open_end: usize,
}

impl<const N: usize> LineDetector<N> {
    /// A detector for an active area of `width` x `rows` pixels.
    pub fn new(config: DetectConfig, width: u16, rows: u16) -> Self {
        Self {
            config,
            width,
            rows,
            background: BlockBackground::new(usize::from(width)),
            runs: [heapless::Vec::new(), heapless::Vec::new()],
            cur_ix: false,
            blobs: [Blob::default(); MAX_OPEN],
            next_y: 0,
            candidates: heapless::Vec::new(),
            dropped: 0,
            dropped_pixels: 0,
            bg_stride: 1,
            bg_warmup: 0,
            open_end: 0,
        }
    }

    /// Updates the background only on rows `y` with `y % lines == 0` (and on the first row
    /// pushed), instead of on every row (0 counts as 1). The raw pre-filter
    /// ([`super::prefilter::ScanDetector`]) calibrates whole lines only on those rows; a
    /// detector with the same stride fed every calibrated line finds exactly the same
    /// candidates.
    pub fn with_background_stride(mut self, lines: u16) -> Self {
        self.bg_stride = lines.max(1);
        self
    }

    /// With a background stride, also updates the background on every row `y < rows`, so
    /// that the estimate is smoothed over [`super::background::SMOOTH_LINES`]-scale many
    /// lines before the stride starts: without it, the first line's own noise estimate
    /// (32 lower-half samples a block) dominates the first few hundred rows at stride 64,
    /// and a block whose sigma it underestimates fills with noise candidates.
    pub fn with_background_warmup(mut self, rows: u16) -> Self {
        self.bg_warmup = rows;
        self
    }

    /// True when row `y`'s pixels update the background (every pixel of it is then needed).
    pub fn background_due(&self, y: u16) -> bool {
        !self.background.is_primed() || y < self.bg_warmup || y.is_multiple_of(self.bg_stride)
    }

    /// The running background and noise estimate.
    pub fn background(&self) -> &BlockBackground {
        &self.background
    }

    /// The configuration.
    pub fn config(&self) -> &DetectConfig {
        &self.config
    }

    /// The candidates found so far (complete after [`Self::finish`]), in no order.
    pub fn candidates(&self) -> &[Detection] {
        &self.candidates
    }

    /// Candidates lost because the list was full.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Above-threshold pixels dropped because a run or blob table was full.
    pub fn dropped_pixels(&self) -> u32 {
        self.dropped_pixels
    }

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
            let b = (x / super::background::BLOCK_PX).min(last_block);
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

    fn complete(&mut self, b: &Blob) {
        let saturated = b.flags.contains(DetectionFlags::SATURATED);
        if !saturated
            && (b.pixels < self.config.min_pixels || b.peak_sigmas <= self.config.peak_sigmas)
        {
            return;
        }
        let s = b.sum_w_e;
        let snr = s / libm::sqrtf(s.max(0.0) + b.var_e2).max(f32::MIN_POSITIVE);
        if snr.is_nan() || snr <= self.config.min_snr {
            return;
        }
        let mut flags = b.flags;
        let (x, y) = match b.moments.shape() {
            Some(((mx, my), (l1, l2))) => {
                // A single star is round to within noise; a pair is elongated along the line
                // joining it (its variance grows by f (1 - f) d^2 for fluxes f, 1 - f and
                // separation d).
                if l1 > 2.0 * l2 && l1 - l2 > 1.0 {
                    flags |= DetectionFlags::BLENDED;
                }
                (f32::from(b.ref_x) + mx, f32::from(b.ref_y) + my)
            }
            None => (f32::from(b.peak_x), f32::from(b.peak_y)),
        };
        if snr < self.config.low_snr {
            flags |= DetectionFlags::LOW_SNR;
        }
        if b.x_min == 0
            || b.x_max.saturating_add(1) >= self.width
            || b.y_min == 0
            || b.last_y.saturating_add(1) >= self.rows
        {
            flags |= DetectionFlags::EDGE;
        }
        let d = Detection {
            x_px: x.clamp(f32::from(b.x_min), f32::from(b.x_max)),
            y_px: y.clamp(f32::from(b.y_min), f32::from(b.last_y)),
            peak_x: b.peak_x,
            peak_y: b.peak_y,
            flux_e: s,
            pixels: b.pixels,
            snr,
            flags,
        };
        if let Err(d) = self.candidates.push(d) {
            self.dropped += 1;
            let faintest = self
                .candidates
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.flux_e.total_cmp(&b.1.flux_e))
                .map(|(i, c)| (i, c.flux_e));
            if let Some((i, f)) = faintest
                && d.flux_e > f
                && let Some(slot) = self.candidates.get_mut(i)
            {
                *slot = d;
            }
        }
    }
}

/// Reporting the candidates a line completed (acquisition centroiding in the firmware): kept
/// apart from the detector's internals, it compares the candidate list before and after.
impl<const N: usize> LineDetector<N> {
    /// [`Self::push_line`], then writes into `closed` the candidates that this line
    /// completed and the list kept (a new candidate, or one that replaced a fainter one);
    /// a candidate the full list refused is not reported (it is counted in
    /// [`Self::dropped`]). Cost: a copy of the candidate list per line.
    pub fn push_line_closed(
        &mut self,
        y: u16,
        pixels_e: &[Electrons],
        flags: &[PixelFlags],
        closed: &mut heapless::Vec<Detection, N>,
    ) -> Result<(), DetectError> {
        let before = self.candidates.clone();
        closed.clear();
        self.push_line(y, pixels_e, flags)?;
        self.changed_since(&before, closed);
        Ok(())
    }

    /// [`Self::finish`], reporting the candidates it completed like [`Self::push_line_closed`].
    pub fn finish_closed(&mut self, closed: &mut heapless::Vec<Detection, N>) {
        let before = self.candidates.clone();
        closed.clear();
        self.finish();
        self.changed_since(&before, closed);
    }

    fn changed_since(
        &self,
        before: &heapless::Vec<Detection, N>,
        closed: &mut heapless::Vec<Detection, N>,
    ) {
        for (i, c) in self.candidates.iter().enumerate() {
            if before.get(i) != Some(c) {
                // `closed` has the list's capacity, so this cannot fail.
                let _ = closed.push(*c);
            }
        }
    }
}
