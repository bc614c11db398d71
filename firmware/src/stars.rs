//! Stars per frame: detection, windows, calibration and centroids, in two modes.
//!
//! - **Acquisition** (no prior knowledge): every active raw line streams through the core's
//!   pre-filtered [`ScanDetector`] (`detect::prefilter`): per chunk of 16 samples a raw-ADU
//!   test against the chunk's worst-case level proves most chunks below the 2.5-sigma join
//!   threshold, and only the samples above that level are calibrated and thresholded; the
//!   background rows (every [`ACQ_BACKGROUND_STRIDE`]th, and the first
//!   [`ACQ_BACKGROUND_WARMUP_ROWS`]) are calibrated whole and update the background. The candidates are bit for bit those of a
//!   `LineDetector` with the same background stride fed every calibrated row (host test
//!   `scan`). The raw line and its levels also go into a ring of the last [`RING_LINES`]
//!   lines ([`Ring`], in `.bss` = AXI SRAM). When the scan closes a blob
//!   ([`ScanDetector::push_raw_line_closed`]), an [`ACQ_WINDOW_PX`]-square window around its
//!   peak waits until its last row has streamed, is copied from the ring, calibrated
//!   ([`FrameCalibration::calibrate_window`]) and centroided (CoG power 1, a
//!   [`COG_BOX_PX`] box, background from the window's perimeter median). A window whose
//!   top rows already left the ring (a blob taller than the ring allows) is reported with
//!   [`flags::RING_LOST`] and the detector's own position.
//! - **Tracking** (after a frame with at least [`MIN_TRACK_STARS`] centroids): the next frame
//!   reads only [`TRACK_WINDOW_PX`]-square windows centred on the last frame's stars
//!   ([`Capture`]: each window's rows are copied as the lines pass). When a window's last row
//!   arrives it is calibrated, the core's [`track_detect`] decides whether the star is still
//!   there (border background, eq. 8 SNR > 3, spike test), and a detected star is centroided
//!   as in acquisition. Full lines are not calibrated. When the table has a given-background
//!   curve ([`tracking_curve`]) and the star's background is known from its last full
//!   measurement, the window first goes through the fused raw-window CoG
//!   ([`startrack_core::centroid::raw_cog`]: no pixel is calibrated) anchored on the star's
//!   last pixel, through the star's `RawCogPlan` (kept across frames in a slot carried with
//!   the star, rebuilt only when the star moves to another pixel or the table or dark scale
//!   changes: ~1,300 instructions; applied every frame: ~2,600 instructions a star against
//!   ~11,500 for the full path; `cargo m7-bench`); only a result
//!   it flags (low SNR, saturated, a listed defect, clipped, re-anchoring failed, degenerate)
//!   goes through the full path (calibration, `track_detect`, CoG), which also refreshes the
//!   star's background. Stars measured by the fused path carry [`flags::FUSED`]. With fewer than [`MIN_TRACK_STARS`]
//!   stars found, or every [`REACQUIRE_EVERY`] frames (to pick up stars entering the
//!   field), the next frame is an acquisition frame.
//!
//! - **Pixel-phase correction**: both modes apply the calibration table's curve
//!   ([`startrack_core::centroid::pixcorr`], section 7) for the CoG's power 1, its
//!   [`COG_BOX_PX`] box and the median-perimeter background (`startrack calib build
//!   --psf-a-px A` builds it, box 7 by default): of several widths, the one nearest
//!   [`PSF_A_PX`]. The table is this camera's, so its widths are the optics'; the nominal
//!   width only chooses among them. Without such a curve the plain CoG is reported and
//!   [`flags::UNCORRECTED`] says so. Cost per star: a scan of at most 16 curve headers and
//!   a few tens of flops per axis.
//!
//! Memory (`.bss`, `llvm-size` of `cargo fw`): the ring 16 x 1072 x 2 = 34 KB, the capture
//! list 32 x ~600 B = 19 KB, the fused CoG's plans 32 x ~470 B = 15 KB, and the process
//! task's state: this pipeline (the scan detector, i.e. its `LineDetector` plus ~13 KB of
//! per-line buffers, electrons and flags for up to 2048 columns and 128 chunk bounds; one
//! window's scratch buffers, 15 x 15 pixels; the star lists) and the processor (sizes as
//! `.ci/test` prints them: README, "Firmware"). The scan replaced the
//! processor's 5 KB calibrated row; `.bss` grew by 8.4 KB against the whole-row path.
//!
//! Cost per acquisition line (M7, `cargo m7-bench` stage `scan_detect`, 13.17 instructions
//! a pixel with 2 of its 128 rows calibrated whole): ~13,500 instructions a 1024-pixel
//! line, plus ~1.1 a pixel over the frame for its ~31 whole rows of 1024 (16 warm-up rows,
//! every 64th row), against ~74 a pixel (~76,000 a line) for calibrating every row whole
//! before (`line_calibrate`) plus the detector's own pass. The very first frame after
//! start-up calibrates each line with the running dark-scale estimate, which moves from
//! line to line: the chunk bounds are then recomputed on every line (~300 instructions a
//! chunk, ~19 a pixel more) until the frame ends. Per line also a 2 KB copy into the ring
//! and the candidate list's copy (32 x 28 B); per star: a 9x9 window copy, its calibration
//! and a CoG (a few thousand operations). Per tracking line: a row test per window and the
//! rows that fall in windows.

use crate::lines::{GEOMETRY, LINE_LEN, LineBuf};
use startrack_core::calib::{FrameCalibration, LineLevels, PixelFlags};
use startrack_core::centroid::cog::{CogParams, CogPower, cog};
use startrack_core::centroid::pixcorr::{PixCorr, PixCorrBackground};
use startrack_core::centroid::raw_cog::{PlanError, RawCogParams, RawCogPlan, RawWindow};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput, estimate_background};
use startrack_core::detect::capture::{CAPTURE_MAX_PX, CAPTURE_MAX_SIDE};
use startrack_core::detect::{
    DetectConfig, Detection, LineRing, ScanDetector, ScanError, TrackConfig, WindowCapture,
    track_detect,
};
use startrack_core::units::{BiasAdu, Electrons};
use startrack_core::window::{Rect, Window};
use static_cell::StaticCell;

/// Raw lines kept for acquisition windows: a 9-row window completes at most a few rows
/// after its blob closes, so 16 leaves room for blobs up to ~8 rows below their peak.
pub const RING_LINES: usize = 16;
/// Side of an acquisition window (the CoG box plus a one-pixel perimeter).
pub const ACQ_WINDOW_PX: u16 = 9;
/// Side of a tracking window: the acquisition window plus a pixel of motion on each side.
pub const TRACK_WINDOW_PX: u16 = 11;
/// Side of the centre-of-gravity box (power 1).
pub const COG_BOX_PX: u8 = 7;
/// The optics' nominal PSF 80 %-energy radius, px: picks the nearest of the table's
/// pixel-phase curves when it holds several widths for the CoG's box.
pub const PSF_A_PX: f32 = 1.2;
/// Most stars per frame (candidates, windows and reported stars).
pub const MAX_STARS: usize = 32;
/// Fewest centroided stars for the next frame to be a tracking frame.
pub const MIN_TRACK_STARS: usize = 3;
/// Every this many frames in a row of tracking, one acquisition frame.
pub const REACQUIRE_EVERY: u32 = 16;
/// Acquisition's background stride: rows `y % ACQ_BACKGROUND_STRIDE == 0` (and the first)
/// are calibrated whole and update the detector's background, the others go through the
/// raw pre-filter. The telemetry's summary lines, which report a row's mean, are exactly
/// these rows ([`crate::telemetry::LINE_SUMMARY_EVERY`]).
pub const ACQ_BACKGROUND_STRIDE: u16 = crate::telemetry::LINE_SUMMARY_EVERY;
/// Acquisition's first rows that all update the background (calibrated whole): without
/// them the first row's own noise estimate would set the thresholds for hundreds of rows
/// at stride 64 and fill some blocks with noise candidates (host test `scan`).
pub const ACQ_BACKGROUND_WARMUP_ROWS: u16 = 16;

/// The raw-line ring of acquisition.
pub type Ring = LineRing<RING_LINES, LINE_LEN>;
/// The window list of tracking.
pub type Capture = WindowCapture<MAX_STARS>;

/// The ring, in `.bss` (AXI SRAM); filled by the CPU from the DMA'd line buffer after the
/// hand-off, so no DMA ever writes it. Initialised at run time: a const initialiser with
/// the geometry's non-zero fields would put the whole 34 KB in `.data`, i.e. also in flash.
static RING: StaticCell<Ring> = StaticCell::new();
/// The tracking window list, in `.bss`, initialised at run time for the same reason.
static CAPTURE: StaticCell<Capture> = StaticCell::new();

/// The ring and the window list; `None` when taken before.
pub fn take_buffers() -> Option<(&'static mut Ring, &'static mut Capture)> {
    let ring = RING.try_init(LineRing::new(GEOMETRY.first_active_col()))?;
    let capture = CAPTURE.try_init(WindowCapture::new(GEOMETRY))?;
    Some((ring, capture))
}

/// Flags the pipeline adds to a star record (bits 24..31 of [`StarRecord::flags`]).
pub mod flags {
    /// The window's top rows had left the raw-line ring: position and flux are the
    /// detector's, not a centroid.
    pub const RING_LOST: u8 = 1;
    /// The window could not be calibrated (the error was logged): position and flux are
    /// the detector's.
    pub const CALIB_FAILED: u8 = 2;
    /// Found in tracking mode (detection flags are then [`TrackFlags`] bits).
    ///
    /// [`TrackFlags`]: startrack_core::detect::TrackFlags
    pub const TRACKED: u8 = 4;
    /// The table has no pixel-phase curve for the CoG (power 1, box
    /// [`super::COG_BOX_PX`], median perimeter): the position is the plain CoG's, with its
    /// pixelisation bias (up to a few hundredths of a pixel for a narrow PSF).
    pub const UNCORRECTED: u8 = 8;
    /// Measured by the fused raw-window CoG (tracking; `centroid::raw_cog`): no
    /// `track_detect` verdict (bits 16..23 are 0), background carried from the star's last
    /// full measurement.
    pub const FUSED: u8 = 16;
}

/// The table's given-background pixel-phase curve for the tracking path's fused CoG (power 1,
/// box [`COG_BOX_PX`]), if it has one (`startrack calib build --psf-a-px` writes it).
pub fn tracking_curve<'t>(calibration: &FrameCalibration<'t>) -> Option<PixCorr<'t>> {
    calibration.table().pixcorr().find(
        CogPower::One,
        COG_BOX_PX,
        PixCorrBackground::Given,
        PSF_A_PX,
    )
}

/// A star's background as last measured (perimeter median of its window): level e-/px and
/// per-pixel variance e-^2; the tracking path's fused CoG takes it as given. With it the
/// slot of [`StarPipeline`]'s `plans` the fused CoG last measured the star with (`None`
/// after a full-path measurement).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct StarBackground {
    level_e: f32,
    variance_e2: f32,
    plan_slot: Option<u8>,
}

/// What a tracking window carries from the last frame: its star's pixel (the fused CoG's
/// anchor) and background, and the slot of `plans` its fused CoG uses this frame.
#[derive(Clone, Copy, Debug)]
struct TrackedStar {
    anchor: (u16, u16),
    background: Option<StarBackground>,
    slot: u8,
}

/// The table's pixel-phase curve for the firmware's CoG, if it has one.
pub fn cog_curve<'t>(calibration: &FrameCalibration<'t>) -> Option<PixCorr<'t>> {
    calibration.table().pixcorr().find(
        CogPower::One,
        COG_BOX_PX,
        PixCorrBackground::PerimeterMedian,
        PSF_A_PX,
    )
}

/// The frame's mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum Mode {
    /// Full-frame detection.
    Acquisition,
    /// Windows around the last frame's stars.
    Tracking,
}

/// One star as reported.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub struct StarRecord {
    /// Column, px (active area, pixel centres at integers).
    pub x_px: f32,
    /// Row, px.
    pub y_px: f32,
    /// Background-subtracted flux in the CoG box, e-.
    pub flux_e: f32,
    /// SNR (eq. 8 with the measured noise).
    pub snr: f32,
    /// Estimated 1-sigma error of `x_px`, px.
    pub sigma_x_px: f32,
    /// Estimated 1-sigma error of `y_px`, px.
    pub sigma_y_px: f32,
    /// Bits 0..15: [`CentroidFlags`]; 16..23: the detector's `DetectionFlags` (acquisition)
    /// or `TrackFlags` (tracking); 24..31: [`flags`].
    pub flags: u32,
}

impl StarRecord {
    /// A centroid as reported, with the pipeline's flags in bits 24..31 (bits 16..23 empty).
    fn from_centroid(c: &startrack_core::centroid::Centroid, pipeline: u8) -> Self {
        Self {
            x_px: c.x_px,
            y_px: c.y_px,
            flux_e: c.flux_e,
            snr: c.snr,
            sigma_x_px: c.sigma_x_px,
            sigma_y_px: c.sigma_y_px,
            flags: u32::from(c.flags.bits()) | (u32::from(pipeline) << 24),
        }
    }

    /// True when the position is a centroid that may be used for attitude.
    pub fn is_centroid(&self) -> bool {
        let pipeline = (self.flags >> 24) as u8;
        let centroid = CentroidFlags::from_bits_truncate(self.flags as u16);
        pipeline & (flags::RING_LOST | flags::CALIB_FAILED) == 0
            && !centroid.contains(CentroidFlags::DEGENERATE)
    }
}

/// What a frame produced besides its stars.
#[derive(Clone, Copy, Debug, Default, defmt::Format)]
pub struct FrameStats {
    /// Candidates the detector's full list lost (acquisition).
    pub candidates_dropped: u32,
    /// Windows that could not wait for their rows: the pending list was full.
    pub windows_dropped: u16,
    /// Windows whose rows had left the ring.
    pub ring_lost: u16,
    /// Tracking windows placed.
    pub track_windows: u16,
    /// Tracking windows without a star (or with missing rows).
    pub track_lost: u16,
    /// Stars not reported because the star list was full (the brightest are kept).
    pub stars_dropped: u16,
}

/// A closed blob waiting for its window's last row.
#[derive(Clone, Copy, Debug)]
struct Pending {
    rect: Rect,
    clipped: bool,
    detection: Detection,
}

/// Scratch buffers for one window.
struct Scratch {
    raw: [u16; CAPTURE_MAX_PX],
    levels: [LineLevels; CAPTURE_MAX_SIDE as usize],
    electrons: [Electrons; CAPTURE_MAX_PX],
    flags: [PixelFlags; CAPTURE_MAX_PX],
}

/// The per-frame star pipeline.
pub struct StarPipeline {
    mode: Mode,
    next_mode: Mode,
    tracking_frames: u32,
    /// Acquisition's detector, built on the frame's first acquisition line (it holds the
    /// frame's calibration); `None` in tracking frames.
    scan: Option<ScanDetector<'static, MAX_STARS>>,
    closed: heapless::Vec<Detection, MAX_STARS>,
    pending: heapless::Vec<Pending, MAX_STARS>,
    ring: &'static mut Ring,
    capture: &'static mut Capture,
    stars: heapless::Vec<StarRecord, MAX_STARS>,
    /// The background of each star of `stars` (same index), when measured or carried.
    star_bgs: heapless::Vec<Option<StarBackground>, MAX_STARS>,
    prev_stars: heapless::Vec<StarRecord, MAX_STARS>,
    prev_bgs: heapless::Vec<Option<StarBackground>, MAX_STARS>,
    /// Per tracking window (capture index): its star's anchor and background.
    tracked: heapless::Vec<TrackedStar, MAX_STARS>,
    /// The fused CoG's box plans (`RawCogPlan`, ~460 B each), kept across frames: a star
    /// measured by the fused path keeps its slot (in its `StarBackground`), and the slot's
    /// plan is rebuilt only when the star's anchor pixel (so its window), the table or the
    /// dark scale changed (`RawCogPlan::apply` refuses a stale plan).
    plans: [RawCogPlan; MAX_STARS],
    stats: FrameStats,
    scratch: Scratch,
}

/// Nearest pixel of a position, inside the active area.
fn pixel_of(v: f32, size: u16) -> u16 {
    let v = if v.is_finite() { v + 0.5 } else { 0.0 };
    (v.max(0.0) as u32).min(u32::from(size.saturating_sub(1))) as u16
}

impl StarPipeline {
    /// A pipeline that starts in acquisition, with its ring and window list (statics).
    pub fn new(ring: &'static mut Ring, capture: &'static mut Capture) -> Self {
        Self {
            mode: Mode::Acquisition,
            next_mode: Mode::Acquisition,
            tracking_frames: 0,
            scan: None,
            closed: heapless::Vec::new(),
            pending: heapless::Vec::new(),
            ring,
            capture,
            stars: heapless::Vec::new(),
            star_bgs: heapless::Vec::new(),
            prev_stars: heapless::Vec::new(),
            prev_bgs: heapless::Vec::new(),
            tracked: heapless::Vec::new(),
            plans: [RawCogPlan::EMPTY; MAX_STARS],
            stats: FrameStats::default(),
            scratch: Scratch {
                raw: [0; CAPTURE_MAX_PX],
                levels: [LineLevels {
                    bias_adu: [BiasAdu::ZERO; startrack_core::geometry::MAX_OUTPUTS],
                }; CAPTURE_MAX_SIDE as usize],
                electrons: [Electrons::ZERO; CAPTURE_MAX_PX],
                flags: [PixelFlags::empty(); CAPTURE_MAX_PX],
            },
        }
    }

    /// The current frame's mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Starts a frame in the mode decided at the end of the last one.
    pub fn start_frame(&mut self) {
        self.mode = self.next_mode;
        self.stars.clear();
        self.star_bgs.clear();
        self.tracked.clear();
        self.pending.clear();
        self.stats = FrameStats::default();
        self.scan = None;
        match self.mode {
            Mode::Acquisition => {
                self.ring.clear();
            }
            Mode::Tracking => {
                self.capture.reset();
                // Plan slots: a star keeps its last one (each slot served one window last
                // frame, so at most one star holds it); the others take a free one.
                let mut used = 0u64;
                for bg in self.prev_bgs.iter().flatten() {
                    if let Some(k) = bg.plan_slot.filter(|k| usize::from(*k) < MAX_STARS) {
                        used |= 1 << k;
                    }
                }
                let mut free = !used;
                for (s, bg) in self.prev_stars.iter().zip(self.prev_bgs.iter()) {
                    let anchor = (
                        pixel_of(s.x_px, GEOMETRY.active_cols),
                        pixel_of(s.y_px, GEOMETRY.active_rows),
                    );
                    let (rect, clipped) = Rect::centred_clipped(
                        anchor.0,
                        anchor.1,
                        TRACK_WINDOW_PX,
                        GEOMETRY.active_cols,
                        GEOMETRY.active_rows,
                    );
                    match self.capture.add(rect, clipped) {
                        Ok(_) => {
                            self.stats.track_windows += 1;
                            let slot = match bg.and_then(|b| b.plan_slot) {
                                Some(k) if usize::from(k) < MAX_STARS => k,
                                // At most MAX_STARS windows: a free slot is left (the
                                // lowest set bit of `free`; its plan is rebuilt).
                                _ => {
                                    let k = free.trailing_zeros().min(MAX_STARS as u32 - 1) as u8;
                                    free &= !(1 << k);
                                    k
                                }
                            };
                            // Capture indices follow the adds: same capacity, cannot fail.
                            let _ = self.tracked.push(TrackedStar {
                                anchor,
                                background: *bg,
                                slot,
                            });
                        }
                        Err(e) => defmt::warn!("stars: tracking window refused: {}", e),
                    }
                }
            }
        }
    }

    /// An acquisition row: `samples` is raw line `y` (the whole line, over-scan included),
    /// `levels` its bias levels, `calibration` this line's (the first frame's dark scale
    /// moves from line to line). The raw line goes into the ring and through the
    /// pre-filtered scan, which calibrates only the chunks that may hold a star (and the
    /// background rows whole, see [`Self::whole_line`]); the windows of the blobs it closes
    /// are measured once their last row has streamed.
    pub fn acquisition_line(
        &mut self,
        calibration: &FrameCalibration<'static>,
        y: u16,
        samples: &LineBuf,
        levels: &LineLevels,
    ) -> Result<(), ScanError> {
        if let Err(e) = self.ring.push(y, samples, levels) {
            defmt::error!("stars: ring, line {}: {}", y, e);
        }
        if let Some(scan) = self.scan.as_mut() {
            scan.set_conditions(*calibration.conditions());
        } else {
            self.scan = Some(
                ScanDetector::new(*calibration, DetectConfig::default(), ACQ_BACKGROUND_STRIDE)
                    .with_background_warmup(ACQ_BACKGROUND_WARMUP_ROWS),
            );
        }
        let taken = match self.scan.as_mut() {
            Some(scan) => scan.push_raw_line_closed(y, samples, levels, &mut self.closed),
            None => Ok(()),
        };
        match taken {
            Ok(()) => self.queue_closed(),
            Err(e) => defmt::error!("stars: detection, line {}: {}", y, e),
        }
        self.serve_pending(calibration, Some(y));
        taken
    }

    /// The last acquisition line's calibrated pixels and flags when it was calibrated whole
    /// (a background row: every [`ACQ_BACKGROUND_STRIDE`]th and the first
    /// [`ACQ_BACKGROUND_WARMUP_ROWS`]); `None` for the other rows,
    /// whose quiet pixels were never calibrated.
    pub fn whole_line(&self) -> Option<(&[Electrons], &[PixelFlags])> {
        self.scan.as_ref()?.whole_line()
    }

    /// A tracking row: copies the windows' pixels and measures the windows it completes.
    pub fn tracking_line(
        &mut self,
        calibration: &FrameCalibration<'_>,
        y: u16,
        samples: &LineBuf,
        levels: &LineLevels,
    ) -> u8 {
        match self.capture.push_line(y, samples, levels) {
            Ok(done) => {
                let mut n = 0u8;
                for i in done {
                    self.measure_tracked(calibration, i);
                    n = n.saturating_add(1);
                }
                n
            }
            Err(e) => {
                defmt::error!("stars: capture, line {}: {}", y, e);
                0
            }
        }
    }

    /// Ends the frame: completes what is open, decides the next mode, and returns the
    /// frame's stars and statistics.
    pub fn end_frame(
        &mut self,
        calibration: Option<&FrameCalibration<'_>>,
    ) -> (&[StarRecord], FrameStats) {
        match (self.mode, calibration) {
            (Mode::Acquisition, Some(c)) => {
                if let Some(scan) = self.scan.as_mut() {
                    scan.finish_closed(&mut self.closed);
                    self.stats.candidates_dropped = scan.detector().dropped();
                    self.queue_closed();
                }
                self.serve_pending(c, None);
            }
            (Mode::Tracking, Some(c)) => {
                for i in self.capture.finish() {
                    self.measure_tracked(c, i);
                }
            }
            (_, None) => {}
        }
        let usable = self.stars.iter().filter(|s| s.is_centroid()).count();
        let reacquire = self.mode == Mode::Tracking && self.tracking_frames + 1 >= REACQUIRE_EVERY;
        self.next_mode = if usable < MIN_TRACK_STARS || reacquire {
            Mode::Acquisition
        } else {
            Mode::Tracking
        };
        self.tracking_frames = match self.mode {
            Mode::Tracking => self.tracking_frames + 1,
            Mode::Acquisition => 0,
        };
        self.prev_stars.clear();
        self.prev_bgs.clear();
        for (s, bg) in self.stars.iter().zip(self.star_bgs.iter()) {
            if s.is_centroid() {
                // Same capacity: cannot fail.
                let _ = self.prev_stars.push(*s);
                let _ = self.prev_bgs.push(*bg);
            }
        }
        (&self.stars, self.stats)
    }

    /// Moves the candidates the last line closed into the pending list.
    fn queue_closed(&mut self) {
        for d in self.closed.iter() {
            let (rect, clipped) = Rect::centred_clipped(
                d.peak_x,
                d.peak_y,
                ACQ_WINDOW_PX,
                GEOMETRY.active_cols,
                GEOMETRY.active_rows,
            );
            let p = Pending {
                rect,
                clipped,
                detection: *d,
            };
            if self.pending.push(p).is_err() {
                self.stats.windows_dropped = self.stats.windows_dropped.saturating_add(1);
            }
        }
    }

    /// Measures the pending windows whose last row has streamed (all of them when `y` is
    /// `None`, at the end of the frame).
    fn serve_pending(&mut self, calibration: &FrameCalibration<'_>, y: Option<u16>) {
        let mut i = 0;
        while let Some(p) = self.pending.get(i).copied() {
            let last = p.rect.y0.saturating_add(p.rect.height).saturating_sub(1);
            if y.is_some_and(|y| y < last) {
                i += 1;
                continue;
            }
            self.pending.swap_remove(i);
            self.measure_acquired(calibration, &p);
        }
    }

    fn measure_acquired(&mut self, calibration: &FrameCalibration<'_>, p: &Pending) {
        let rect = p.rect;
        let n = rect.len();
        let det_flags = u32::from(p.detection.flags.bits()) << 16;
        let s = &mut self.scratch;
        let (Some(raw), Some(levels)) = (
            s.raw.get_mut(..n),
            s.levels.get_mut(..usize::from(rect.height)),
        ) else {
            return;
        };
        let pipeline = match self.ring.copy_window(rect, raw, levels) {
            Ok(()) => match Self::calibrate(calibration, s, rect)
                .then(|| Self::centroid(calibration, s, rect, p.clipped))
                .flatten()
            {
                Some(mut r) => {
                    r.flags |= det_flags;
                    let bg = Self::background(s, rect, p.clipped);
                    self.push_star(r, bg);
                    return;
                }
                None => flags::CALIB_FAILED,
            },
            Err(e) => {
                defmt::warn!("stars: window at ({}, {}): {}", rect.x0, rect.y0, e);
                self.stats.ring_lost = self.stats.ring_lost.saturating_add(1);
                flags::RING_LOST
            }
        };
        let d = &p.detection;
        let half = f32::from(ACQ_WINDOW_PX) / 2.0;
        self.push_star(
            StarRecord {
                x_px: d.x_px,
                y_px: d.y_px,
                flux_e: d.flux_e,
                snr: d.snr,
                sigma_x_px: half,
                sigma_y_px: half,
                flags: det_flags | (u32::from(pipeline) << 24),
            },
            None,
        );
    }

    fn measure_tracked(&mut self, calibration: &FrameCalibration<'_>, i: usize) {
        if let Some((r, bg)) = self.fused(calibration, i) {
            self.push_star(r, Some(bg));
            return;
        }
        let Some(w) = self.capture.window(i) else {
            return;
        };
        let (rect, clipped) = (w.rect, w.clipped);
        let n = rect.len();
        let s = &mut self.scratch;
        let copied = match (
            s.raw.get_mut(..n),
            s.levels.get_mut(..usize::from(rect.height)),
        ) {
            (Some(raw), Some(levels)) if !w.missing_rows => {
                raw.copy_from_slice(w.raw);
                levels.copy_from_slice(w.levels);
                true
            }
            _ => false,
        };
        if !copied || !Self::calibrate(calibration, s, rect) {
            self.stats.track_lost = self.stats.track_lost.saturating_add(1);
            return;
        }
        let verdict = match (s.electrons.get(..n), s.flags.get(..n)) {
            (Some(e), Some(f)) => Window::new(rect, e)
                .map(|window| track_detect(&window, f, clipped, &TrackConfig::default())),
            _ => None,
        };
        match (verdict, Self::centroid(calibration, s, rect, clipped)) {
            (Some(v), Some(mut r)) if v.detected => {
                r.flags |= (u32::from(v.flags.bits()) << 16) | (u32::from(flags::TRACKED) << 24);
                let bg = Self::background(s, rect, clipped);
                self.push_star(r, bg);
            }
            _ => self.stats.track_lost = self.stats.track_lost.saturating_add(1),
        }
    }

    /// The fused raw-window CoG of tracking window `i` (see the module docs), with the
    /// star's carried background; `None` when the path does not apply (no given-background
    /// curve, no background yet, rows missing) or flags its result, so that the full path
    /// measures the window. The window's plan (slot `plans[tracked[i].slot]`) is applied,
    /// and rebuilt first when it is stale (the star moved to another pixel, or the table or
    /// dark scale changed).
    fn fused(
        &mut self,
        calibration: &FrameCalibration<'_>,
        i: usize,
    ) -> Option<(StarRecord, StarBackground)> {
        let w = self.capture.window(i)?;
        let t = self.tracked.get(i)?;
        let bg = t.background?;
        if w.missing_rows || w.clipped {
            return None;
        }
        let curve = tracking_curve(calibration)?;
        let win = RawWindow {
            rect: w.rect,
            raw: w.raw,
            levels: w.levels,
        };
        let params = RawCogParams {
            box_side: COG_BOX_PX,
            level_e: bg.level_e,
            variance_e2: bg.variance_e2,
            curve: Some(curve),
        };
        let plan = self.plans.get_mut(usize::from(t.slot))?;
        let res = match plan.apply(calibration, &win, &params) {
            Ok(r) => r,
            Err(PlanError::Stale) => {
                plan.rebuild(calibration, w.rect, t.anchor, COG_BOX_PX)
                    .ok()?;
                plan.apply(calibration, &win, &params).ok()?
            }
            Err(PlanError::BadInput) => return None,
        };
        let c = res.centroid;
        let full_path = CentroidFlags::LOW_SNR
            | CentroidFlags::SATURATED
            | CentroidFlags::EXCLUDED_PIXEL
            | CentroidFlags::EDGE_CLIPPED
            | CentroidFlags::DEGENERATE
            | CentroidFlags::NOT_CONVERGED
            | CentroidFlags::CLAMPED;
        if res.general_path || c.flags.intersects(full_path) {
            return None;
        }
        let pipeline = flags::TRACKED | flags::FUSED;
        Some((
            StarRecord::from_centroid(&c, pipeline),
            StarBackground {
                plan_slot: Some(t.slot),
                ..bg
            },
        ))
    }

    /// The perimeter-median background of the calibrated window in `s.electrons`/`s.flags`
    /// (what the CoG subtracted), carried to the star's next tracking frame.
    fn background(s: &Scratch, rect: Rect, clipped: bool) -> Option<StarBackground> {
        let n = rect.len();
        let input = CentroidInput::new(Window::new(rect, s.electrons.get(..n)?)?)
            .with_pixel_flags(s.flags.get(..n)?)
            .with_clipped(clipped);
        let b = estimate_background(&input, Background::PerimeterMedian)?;
        Some(StarBackground {
            level_e: b.level_e(),
            variance_e2: b.variance_e2,
            plan_slot: None,
        })
    }

    /// Calibrates the window held in `s.raw`/`s.levels` into `s.electrons`/`s.flags`.
    fn calibrate(calibration: &FrameCalibration<'_>, s: &mut Scratch, rect: Rect) -> bool {
        let n = rect.len();
        let (Some(raw), Some(levels), Some(e), Some(f)) = (
            s.raw.get(..n),
            s.levels.get(..usize::from(rect.height)),
            s.electrons.get_mut(..n),
            s.flags.get_mut(..n),
        ) else {
            return false;
        };
        match calibration.calibrate_window(rect, raw, levels, e, f) {
            Ok(_) => true,
            Err(err) => {
                defmt::error!("stars: window calibration: {}", err);
                false
            }
        }
    }

    /// The CoG of the calibrated window in `s.electrons`/`s.flags`, corrected with the
    /// table's pixel-phase curve when it has one (else flagged [`flags::UNCORRECTED`]).
    fn centroid(
        calibration: &FrameCalibration<'_>,
        s: &Scratch,
        rect: Rect,
        clipped: bool,
    ) -> Option<StarRecord> {
        let n = rect.len();
        let input = CentroidInput::new(Window::new(rect, s.electrons.get(..n)?)?)
            .with_pixel_flags(s.flags.get(..n)?)
            .with_clipped(clipped);
        let c = cog(&input, &CogParams::new(CogPower::One, COG_BOX_PX));
        let (c, pipeline) = match cog_curve(calibration) {
            Some(curve) => (curve.apply(c), 0),
            None => (c, flags::UNCORRECTED),
        };
        Some(StarRecord::from_centroid(&c, pipeline))
    }

    /// Adds a star (and its background); when the list is full the faintest is replaced by a
    /// brighter one.
    fn push_star(&mut self, r: StarRecord, bg: Option<StarBackground>) {
        if let Err(r) = self.stars.push(r) {
            self.stats.stars_dropped = self.stats.stars_dropped.saturating_add(1);
            let faintest = self
                .stars
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.flux_e.total_cmp(&b.1.flux_e))
                .map(|(i, s)| (i, s.flux_e));
            if let Some((i, f)) = faintest
                && r.flux_e > f
                && let Some(slot) = self.stars.get_mut(i)
            {
                *slot = r;
                if let Some(b) = self.star_bgs.get_mut(i) {
                    *b = bg;
                }
            }
        } else {
            // Same capacity as `stars`, which had room: cannot fail.
            let _ = self.star_bgs.push(bg);
        }
    }
}
