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
//! replaces the lowest ranked one if it ranks above it (one agreeing with the frame's
//! common motion above a round one above one that disagrees, [`super::CommonMotion`]; with
//! no common motion a round blob above an elongated one; then the brighter); either way one
//! candidate is lost and counted in [`LineDetector::dropped`]: the list always holds the
//! `N` best ranked by the histogram as it stands.
//!
//! Blob positions are means of the blob's pixels weighted by their positive signal: a seed for the centroid
//! methods, not a measurement.
//!
//! # Cost
//! State: ~12 KB (two run lists of [`MAX_RUNS`] 6-byte runs, [`MAX_OPEN`] blobs of ~70 bytes)
//! plus the `N` candidates and the common-motion histogram (228 bytes). Time: per pixel the threshold test, per run and per closed blob
//! the work described in `label.rs` and `candidate.rs` (part of `scan_detect` in
//! `cargo m7-bench`).

mod candidate;
mod label;

use super::DetectConfig;
use super::background::BlockBackground;
use super::motion::{CommonMotion, MotionKey};
use crate::calib::PixelFlags;
use crate::units::Electrons;

/// Most runs kept per line.
pub(crate) const MAX_RUNS: usize = 256;
/// Most blobs open at once.
pub(crate) const MAX_OPEN: usize = 128;

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
    /// The blob's extent: first and last column, first and last row (active pixels).
    pub extent: [u16; 4],
    /// The blob's second moments about its position, weighted by its pixels' positive
    /// signal: `(xx, yy, xy)` in 1/64 px^2, saturating at +-512 px^2 (a trailed star's is
    /// stretched along its trail); [`Self::moments_px2`] in px^2.
    pub moments_64ths: [i16; 3],
    /// The blob's trail axis and length bins in the frame's common-motion histogram
    /// ([`MotionKey::ROUND`] for a round blob).
    pub motion: MotionKey,
}

impl Detection {
    /// The blob's second moments `(xx, yy, xy)`, px^2.
    pub fn moments_px2(&self) -> [f32; 3] {
        self.moments_64ths.map(|m| f32::from(m) / 64.0)
    }
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

    /// Mean (relative), the covariance's eigenvalues (larger first) and the covariance
    /// `(xx, yy, xy)`, px and px^2.
    fn shape(&self) -> Option<Shape> {
        if self.w <= 0.0 {
            return None;
        }
        let (mx, my) = (self.x / self.w, self.y / self.w);
        let cxx = self.xx / self.w - mx * mx;
        let cyy = self.yy / self.w - my * my;
        let cxy = self.xy / self.w - mx * my;
        let half_tr = 0.5 * (cxx + cyy);
        let disc = libm::sqrtf((0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy).max(0.0));
        Some(Shape {
            mean: (mx, my),
            eigen: (half_tr + disc, half_tr - disc),
            cov: [cxx, cyy, cxy],
        })
    }
}

/// A blob's [`Moments::shape`].
#[derive(Clone, Copy, Debug)]
struct Shape {
    /// Mean, relative to the moments' reference, px.
    mean: (f32, f32),
    /// The covariance's eigenvalues, larger first, px^2.
    eigen: (f32, f32),
    /// The covariance `(xx, yy, xy)`, px^2.
    cov: [f32; 3],
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
    /// The counted blobs' trails so far: the frame's common motion.
    motion: CommonMotion,
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
            motion: CommonMotion::EMPTY,
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
    /// that the estimate is smoothed over `SMOOTH_LINES`-scale many
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
    pub(crate) fn background(&self) -> &BlockBackground {
        &self.background
    }

    /// The configuration.
    pub(crate) fn config(&self) -> &DetectConfig {
        &self.config
    }

    /// The candidates found so far (complete after [`Self::finish`]), in no order.
    pub fn candidates(&self) -> &[Detection] {
        &self.candidates
    }

    /// The common motion of the blobs counted so far ([`CommonMotion`]), by which the
    /// list ranks.
    pub fn motion(&self) -> &CommonMotion {
        &self.motion
    }

    /// Candidates lost because the list was full.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }

    /// Above-threshold pixels dropped because a run or blob table was full.
    pub fn dropped_pixels(&self) -> u32 {
        self.dropped_pixels
    }

    /// Takes candidate `d` out of the list (the tracker found it is no star: a particle hit,
    /// a saturated object), so that it no longer holds a place a star could take; false when
    /// the list does not hold it. The list's order changes (the last candidate takes its
    /// place). Cost: a scan of the list.
    pub fn forget(&mut self, d: &Detection) -> bool {
        match self.candidates.iter().position(|c| c == d) {
            Some(i) => {
                self.candidates.swap_remove(i);
                true
            }
            None => false,
        }
    }
}
