//! Local background and noise for detection, per block of [`BLOCK_PX`] columns.
//!
//! For each line and block, the calibrated values (excluded pixels skipped) are sorted; the
//! median is the line's background and the distance from the 15.9 % quantile to the median
//! is one sigma. Both use only the lower half of the distribution, so a star covering less
//! than half a block barely moves them. Each block's estimate is smoothed over lines
//! (exponential, weight 1/[`SMOOTH_LINES`]), and a line is thresholded with the estimate of
//! the lines before it (the first line with its own). Cost: two selections
//! (`select_nth_unstable`, linear on average) of 64 values per block per updated line.

use crate::calib::PixelFlags;
use crate::units::Electrons;

/// Columns per background block.
pub(crate) const BLOCK_PX: usize = 64;
/// Most blocks (columns / 64, rounded up): lines up to 4096 pixels.
pub(crate) const MAX_BLOCKS: usize = 64;
/// Exponential smoothing length, lines.
pub(crate) const SMOOTH_LINES: i64 = 8;

/// Background and noise of one block.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct BlockLevel {
    /// Background, e- per pixel.
    pub background_e: Electrons,
    /// Noise sigma, e- (at least 1/64 e-).
    pub sigma_e: Electrons,
}

/// The join threshold of a block, I26F6 bits: `background + k sigma` (the one formula both
/// the calibrated scan and the raw pre-filter of [`super::prefilter`] use).
#[inline(always)]
pub(crate) fn threshold_bits(l: BlockLevel, k: f32) -> i64 {
    i64::from(l.background_e.to_bits()) + (k * l.sigma_e.to_bits() as f32) as i64
}

/// The running per-block background and noise estimate of the lines seen so far.
#[derive(Clone, Debug)]
pub(crate) struct BlockBackground {
    blocks: [BlockLevel; MAX_BLOCKS],
    n_blocks: usize,
    primed: bool,
}

impl BlockBackground {
    /// An estimator for lines of `width` pixels (at most `MAX_BLOCKS * BLOCK_PX`; wider lines
    /// share the last block's estimate).
    pub fn new(width: usize) -> Self {
        Self {
            blocks: [BlockLevel::default(); MAX_BLOCKS],
            n_blocks: width.div_ceil(BLOCK_PX).clamp(1, MAX_BLOCKS),
            primed: false,
        }
    }

    /// The estimate that applies to column `x`.
    pub fn at(&self, x: usize) -> BlockLevel {
        self.blocks
            .get(self.block_of(x))
            .copied()
            .unwrap_or_default()
    }

    /// The block whose estimate applies to column `x`.
    #[inline(always)]
    pub(crate) fn block_of(&self, x: usize) -> usize {
        (x / BLOCK_PX).min(self.n_blocks - 1)
    }

    /// Each block's join threshold for `k` sigmas
    /// ([`threshold_bits`]), computed once per line rather than per pixel (the
    /// f32-to-i64 conversion is a library call on the M7).
    pub(crate) fn thresholds(&self, k: f32) -> [i64; MAX_BLOCKS] {
        let mut t = [0i64; MAX_BLOCKS];
        for (t, l) in t.iter_mut().zip(self.blocks.iter()).take(self.n_blocks) {
            *t = threshold_bits(*l, k);
        }
        t
    }

    /// True once a line has been measured.
    pub fn is_primed(&self) -> bool {
        self.primed
    }

    /// Folds one line into the estimate.
    pub fn update(&mut self, pixels_e: &[Electrons], flags: &[PixelFlags]) {
        let first = !self.primed;
        for (b, level) in self.blocks.iter_mut().enumerate().take(self.n_blocks) {
            let start = b * BLOCK_PX;
            let end = (start + BLOCK_PX).min(pixels_e.len()).min(flags.len());
            let (Some(es), Some(fs)) = (pixels_e.get(start..end), flags.get(start..end)) else {
                continue;
            };
            // The usable values (not excluded, not saturated), without a branch per pixel:
            // each value is stored at the next free slot, which only advances for a usable
            // one (the iterator chain with `skip` and `filter` cost ~60 instructions a pixel
            // on the M7).
            let unusable = PixelFlags::HOT_EXCLUDED | PixelFlags::TELEGRAPH | PixelFlags::SATURATED;
            let mut v = [0i32; BLOCK_PX];
            let mut n = 0;
            for (e, f) in es.iter().zip(fs) {
                if let Some(slot) = v.get_mut(n) {
                    *slot = e.to_bits();
                }
                n += usize::from(!f.intersects(unusable));
            }
            if n < 4 {
                continue;
            }
            let v = v.get_mut(..n).unwrap_or(&mut []);
            // The two order statistics by selection (same values as a sort, a fraction of
            // its cost): the median, then the 15.9 % quantile among the values below it.
            let q = n * 159 / 1000;
            let (lower, med, _) = v.select_nth_unstable(n / 2);
            let median = i64::from(*med);
            let low = lower
                .select_nth_unstable(q.min(lower.len().saturating_sub(1)))
                .1;
            let low = i64::from(*low);
            let sigma = (median - low).max(1);
            if first {
                *level = BlockLevel {
                    background_e: Electrons::from_bits(median as i32),
                    sigma_e: Electrons::from_bits(sigma as i32),
                };
            } else {
                let bg = i64::from(level.background_e.to_bits());
                let sg = i64::from(level.sigma_e.to_bits());
                level.background_e =
                    Electrons::from_bits((bg + (median - bg) / SMOOTH_LINES) as i32);
                level.sigma_e =
                    Electrons::from_bits((sg + (sigma - sg) / SMOOTH_LINES).max(1) as i32);
            }
        }
        self.primed = true;
    }
}
