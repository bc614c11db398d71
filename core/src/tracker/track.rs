//! Tracking: the frame reads only windows placed on the last frame's stars, at their
//! positions moved on by their last motion; each window is `window_px + 2 track_margin_px`
//! square, so a star that moved up to the margin still has its whole centroid window read.
//! When a window's last row is in, it is calibrated, the window test
//! ([`track_detect`]: border background, eq. 8 SNR, spike and blend tests) decides whether
//! the star is there, and the centroid window around its peak is measured
//! ([`super::measure`]). Right after calibration the pixels found in flight are excluded
//! ([`crate::calib::refresh`], the overlay), and after the window test the window feeds the
//! defect watch with its border noise and the frame's predicted star positions (its cost
//! a window: docs/calibration.md, "In orbit"). With [`CentroidMethod::FusedCog1`] the raw window first goes
//! through the fused CoG with the star's carried background (a plan per star, rebuilt only
//! when the star moves to another pixel or the table or dark scale changes); a result it
//! flags goes through the full path; so does a window holding a pixel found in flight (the
//! fused CoG reads raw samples and would not exclude it). The fused path feeds no watch.
//!
//!
//! A star's trail is its image's motion over the frame's own integration, as the line
//! source reports it ([`super::Integration`], known once the frame's first line is in): a
//! tracked star's last motion scaled by this frame's integration over the interval between
//! the mid-integrations the motion was measured across. A star whose trail is at least
//! [`TRAIL_MIN_PX`] is trailed: its window is widened by its last motion (up to
//! [`CAPTURE_MAX_SIDE`]), and it is measured with the trailed-star fit
//! ([`crate::centroid::trail_fit`]) on the whole window, reported [`Provenance::TRAILED`] at
//! mid-exposure. A slower star is measured by the configured method, whose fit flags a
//! smear it cannot follow. When the integration (or the interval) is not known, the trail
//! is not either: the star is fitted with its last motion (a predicted star with its trail
//! over the configured exposure) to place its next window, and flagged
//! [`StarFlags::TRAIL_UNKNOWN`]. A star that moved at least
//! [`TRAIL_MIN_PX`] before [`TRAIL_SETTLE_FRAMES`] tracking frames measured its motion is
//! flagged [`StarFlags::TRAIL_UNKNOWN`]: it places the next window, the attitude stage skips
//! it. A trail longer than the window holds (a component beyond its side less 1 px: with
//! [`CAPTURE_MAX_SIDE`] 15, 14 px, 2.06 deg/s across the boresight in 100 ms) leaves the
//! position along it unmeasured: the star is flagged [`StarFlags::TRAIL_CLIPPED`] and the
//! attitude stage skips it.
//!
//! With the attitude stage's prediction ([`super::PredictedStar`]) the windows are placed
//! on the catalog's stars at their predicted positions instead, each sized by
//! [`super::predicted_window_side`] (the centroid window, the prediction's bound and the
//! trail over the configured exposure), and a star is measured with the trailed-star fit
//! from its predicted velocity times the frame's integration in its first tracked frame (no settling, never `TRAIL_UNKNOWN`); its prediction
//! goes with its record to the attitude stage, which checks it and keeps its identity.
//!
//! Cost per line: a row test per window and the copy of the rows inside windows; per
//! star, the window's calibration (121 pixels for 11x11), the window test (~2-4 k
//! operations) and the method; the fused CoG instead ~2,600 M7 instructions a 7x7 box
//! (`cargo m7-bench`, `centroid_cog1c_raw_planned_7x7`); a trailed star's fit on its
//! 11x11 to 15x15 window, about 2.5 to 4.6 times the trailed fit's 7x7 cost (~47,000
//! instructions, docs/speed.md) by its pixels.

use super::Shared;
use super::config::{CentroidMethod, TrackerConfig};
use super::list::{Carry, StarList};
use super::measure::{Policy, StarBackground, measure};
use super::predicted::{PredictedStar, predicted_window_side};
use super::record::{FrameSummary, LineOutcome, Provenance, StarFlags, StarRecord};
use super::{Capture, Integration, TRACK_WINDOWS, Watch};
use crate::calib::refresh::WatchedWindow;
use crate::calib::{FrameCalibration, LineLevels};
use crate::centroid::CentroidFlags;
use crate::centroid::CentroidInput;
use crate::centroid::raw_cog::{PlanError, RawCogParams, RawWindow};
use crate::detect::capture::CAPTURE_MAX_SIDE;
use crate::detect::track::TrackResult;
use crate::detect::track_detect;
use crate::geometry::ReadoutGeometry;
use crate::window::Rect;

/// A star to look for: one of the last frame's, or one the attitude stage predicts.
#[derive(Clone, Copy, Debug)]
struct Prior {
    x_px: f32,
    y_px: f32,
    carry: Carry,
}

impl Prior {
    /// The catalog star `p` at its predicted position.
    fn predicted(p: PredictedStar) -> Self {
        Self {
            x_px: p.x_px,
            y_px: p.y_px,
            carry: Carry {
                predicted: Some(p),
                ..Carry::default()
            },
        }
    }
}

/// A placed window: its star and the fused CoG's anchor pixel and plan slot.
#[derive(Clone, Copy, Debug)]
struct Placed {
    prior: Prior,
    anchor: (u16, u16),
    slot: u8,
}

/// Tracking's state: the last frame's stars, the attitude stage's prediction for the next
/// frame, and this frame's windows (capture order).
pub(super) struct Tracking {
    priors: heapless::Vec<Prior, TRACK_WINDOWS>,
    prediction: heapless::Vec<PredictedStar, TRACK_WINDOWS>,
    /// The current frame's windows came from a prediction.
    predicted_frame: bool,
    placed: heapless::Vec<Placed, TRACK_WINDOWS>,
    /// The windows' rectangles (capture order), then the probe row's.
    rects: heapless::Vec<Rect, { TRACK_WINDOWS + 1 }>,
    /// This frame's probe row ([`probe_row`]) and its raw column range.
    probe: Option<Probe>,
    /// This frame's integration, as the line source reported it (`None` until it does).
    integration: Option<Integration>,
    /// The last frame's mid-integration, us (`None`: not known).
    last_mid_us: Option<u64>,
    /// From the mid-integration of the frame before the last to the last's, us: the
    /// interval the stars' carried motion was measured over (`None`: not known).
    motion_interval_us: Option<u64>,
}

/// The full row a tracking frame reads besides its windows: a bloomed column crosses every
/// row, so its widest run of saturated columns measures the Moon or the Earth in the field as
/// the acquisition's largest saturated region does.
#[derive(Clone, Copy, Debug)]
struct Probe {
    /// Active row read.
    y: u16,
    /// Raw index of its first active column.
    first_col: usize,
    /// Active columns.
    cols: usize,
}

/// The probe row of tracking frame `frame`: one of four rows spread down the active area
/// (at 1/8, 3/8, 5/8 and 7/8 of its height) in turn, so that a partial bloom or a defect
/// row does not hold one answer for good.
pub(super) fn probe_row(frame: u32, active_rows: u16) -> u16 {
    let k = (frame % 4) as u16;
    let y = u32::from(active_rows) * u32::from(2 * k + 1) / 8;
    // Below active_rows, so it fits.
    y as u16
}

/// The widest run of raw samples at or above `saturation_adu` in `row`.
fn widest_saturated_run(row: &[u16], saturation_adu: u16) -> u16 {
    let (mut best, mut run) = (0u16, 0u16);
    for &v in row {
        if v >= saturation_adu {
            run = run.saturating_add(1);
            best = best.max(run);
        } else {
            run = 0;
        }
    }
    best
}

/// Flags of a fused result that send the window through the full path.
const FULL_PATH: CentroidFlags = CentroidFlags::LOW_SNR
    .union(CentroidFlags::SATURATED)
    .union(CentroidFlags::EXCLUDED_PIXEL)
    .union(CentroidFlags::EDGE_CLIPPED)
    .union(CentroidFlags::DEGENERATE)
    .union(CentroidFlags::NOT_CONVERGED)
    .union(CentroidFlags::CLAMPED);

/// A star that moved at least this far in the last frame, px, is measured as trailed.
pub const TRAIL_MIN_PX: f32 = 1.0;

/// Tracking frames in a row a moving star needs before its trail is trusted: its motion
/// comes from the last two positions, the first of which (acquisition's, or the first
/// tracking frame's, the trail then unknown) is a smeared star's.
pub const TRAIL_SETTLE_FRAMES: u8 = 2;

/// Flags `record` [`StarFlags::TRAIL_UNKNOWN`] when its star moved at least
/// [`TRAIL_MIN_PX`] from `prior` before its motion settled; returns its tracked-frame count.
/// A predicted star's motion is the attitude's: it is never flagged.
fn settle(record: &mut StarRecord, prior: &Prior) -> u8 {
    if prior.carry.predicted.is_some() {
        return prior
            .carry
            .tracked_frames
            .saturating_add(1)
            .max(TRAIL_SETTLE_FRAMES);
    }
    let (dx, dy) = (record.x_px - prior.x_px, record.y_px - prior.y_px);
    let moved = libm::sqrtf(dx * dx + dy * dy);
    // A non-finite move is no evidence of motion; the record's own flags say what it is.
    if moved.is_finite()
        && moved >= TRAIL_MIN_PX
        && prior.carry.tracked_frames < TRAIL_SETTLE_FRAMES
    {
        record.flags |= StarFlags::TRAIL_UNKNOWN;
    }
    prior.carry.tracked_frames.saturating_add(1)
}

/// The trail of a star whose last motion was `velocity_px`, if it is trailed.
fn trail_of(velocity_px: Option<(f32, f32)>) -> Option<(f32, f32)> {
    velocity_px.filter(|(vx, vy)| {
        let l = libm::sqrtf(vx * vx + vy * vy);
        l.is_finite() && l >= TRAIL_MIN_PX
    })
}

/// Whether a trail of `trail_px` (px, exposure start to end) is longer than `rect` holds: a
/// component beyond the window's side less 1 px, so that no end of it is in the window.
fn trail_clipped(trail_px: (f32, f32), rect: Rect) -> bool {
    // A NaN trail is no trail the window holds.
    let beyond = |t: f32, side: u16| t.is_nan() || t.abs() > f32::from(side.saturating_sub(1));
    beyond(trail_px.0, rect.width) || beyond(trail_px.1, rect.height)
}

/// The side of a trailed star's tracking window: `side` widened by the trail's larger
/// component (rounded up, kept odd), at most [`CAPTURE_MAX_SIDE`].
fn trailed_side(side: u16, trail_px: (f32, f32)) -> u16 {
    let extent = trail_px.0.abs().max(trail_px.1.abs());
    let widen = if extent.is_finite() {
        (libm::ceilf(extent).min(f32::from(CAPTURE_MAX_SIDE))) as u16
    } else {
        0
    };
    (side.saturating_add(widen) | 1)
        .min(CAPTURE_MAX_SIDE)
        .max(side)
}

/// Nearest pixel of a position, inside `0..size`.
fn pixel_of(v: f32, size: u16) -> u16 {
    let v = if v.is_finite() { v + 0.5 } else { 0.0 };
    (v.max(0.0) as u32).min(u32::from(size.saturating_sub(1))) as u16
}

impl Tracking {
    pub(super) const fn new() -> Self {
        Self {
            priors: heapless::Vec::new(),
            prediction: heapless::Vec::new(),
            predicted_frame: false,
            placed: heapless::Vec::new(),
            rects: heapless::Vec::new(),
            probe: None,
            integration: None,
            last_mid_us: None,
            motion_interval_us: None,
        }
    }

    /// A new frame: the last frame's integration closes the interval its stars' motion
    /// was measured over; this frame's is not known yet.
    pub(super) fn next_integration(&mut self) {
        let mid = self.integration.take().map(|i| i.mid_us());
        self.motion_interval_us = match (mid, self.last_mid_us) {
            (Some(m), Some(l)) if m > l => Some(m - l),
            _ => None,
        };
        self.last_mid_us = mid;
    }

    /// This frame's integration, once the line source knows it (a `None` keeps what it
    /// gave before).
    pub(super) fn set_integration(&mut self, integration: Option<Integration>) {
        self.integration = integration.or(self.integration);
    }

    /// The trail of the star `prior` over this frame's integration, px (exposure start to
    /// end), if it is trailed ([`TRAIL_MIN_PX`]), and whether it is known: a predicted
    /// star's velocity, or a tracked star's last motion over the interval it was measured
    /// across, times the integration. Without the integration (or the interval) it is not
    /// known, and is taken as the predicted star's trail over the configured exposure, or
    /// the tracked star's last motion.
    fn trail(&self, prior: &Prior, config: &TrackerConfig) -> Option<((f32, f32), bool)> {
        let integration_s = self.integration.map(|i| i.duration_us() as f32 * 1e-6);
        let (trail, known) = match prior.carry.predicted {
            Some(p) => match integration_s {
                Some(t) => (p.trail_px(t), true),
                None => (p.trail_px(config.exposure_s()), false),
            },
            None => {
                let v = prior.carry.velocity_px?;
                match (integration_s, self.motion_interval_us) {
                    (Some(t), Some(dt)) => {
                        let k = t / (dt as f32 * 1e-6);
                        ((v.0 * k, v.1 * k), true)
                    }
                    _ => (v, false),
                }
            }
        };
        trail_of(Some(trail)).map(|t| (t, known))
    }

    /// Stars the next tracking frame would look for.
    pub(super) fn priors_len(&self) -> usize {
        self.priors.len().max(self.prediction.len())
    }

    /// Takes the attitude stage's prediction for the next frame (replacing any): its valid
    /// stars ([`PredictedStar::is_valid`]), the first [`TRACK_WINDOWS`]; returns how many.
    pub(super) fn set_prediction(&mut self, stars: &[PredictedStar]) -> usize {
        self.prediction.clear();
        for p in stars.iter().filter(|p| p.is_valid()) {
            if self.prediction.push(*p).is_err() {
                break;
            }
        }
        self.prediction.len()
    }

    /// Stars predicted for the next frame.
    pub(super) fn prediction_len(&self) -> usize {
        self.prediction.len()
    }

    /// Forgets the prediction (a frame that does not track).
    pub(super) fn drop_prediction(&mut self) {
        self.prediction.clear();
        self.predicted_frame = false;
    }

    /// Whether the current (or last) frame's windows came from a prediction.
    pub(super) fn predicted_frame(&self) -> bool {
        self.predicted_frame
    }

    /// What this frame reads: its windows, then its probe row.
    pub(super) fn rects(&self) -> &[Rect] {
        &self.rects
    }

    /// Keeps the usable centroids of `stars`, the brightest `max` of them, for the next
    /// tracking frame.
    pub(super) fn keep_priors<const N: usize>(&mut self, stars: &StarList<N>, max: usize) {
        let mut order: heapless::Vec<(bool, f32, usize), N> = heapless::Vec::new();
        for (i, (s, _)) in stars.iter().enumerate() {
            if s.is_centroid() {
                // At most N stars in the list: cannot fail.
                let _ = order.push((!s.fit_is_clean(), s.flux_e, i));
            }
        }
        // The list's rank: clean fits first, then the brighter.
        crate::small_sort::sort_by(&mut order, |a, b| {
            a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)).then(a.2.cmp(&b.2))
        });
        self.priors.clear();
        for (_, _, i) in order.iter().take(max.min(TRACK_WINDOWS)) {
            if let Some((s, c)) = stars.iter().nth(*i) {
                // At most TRACK_WINDOWS taken: cannot fail.
                let _ = self.priors.push(Prior {
                    x_px: s.x_px,
                    y_px: s.y_px,
                    carry: *c,
                });
            }
        }
    }

    /// Places this frame's windows; returns how many.
    pub(super) fn start(
        &mut self,
        config: &TrackerConfig,
        geometry: &ReadoutGeometry,
        capture: &mut Capture,
        summary: &mut FrameSummary,
    ) -> u16 {
        capture.reset();
        self.placed.clear();
        self.rects.clear();
        // A prediction replaces the last frame's stars: the catalog's stars in the field.
        self.predicted_frame = !self.prediction.is_empty();
        if self.predicted_frame {
            self.priors.clear();
            for p in self.prediction.iter() {
                // Same capacity: cannot fail.
                let _ = self.priors.push(Prior::predicted(*p));
            }
            self.prediction.clear();
        }
        // Plan slots: a star keeps its last one (each slot served one window last frame,
        // so at most one star holds it); the others take a free one.
        let mut used = 0u64;
        for p in self.priors.iter() {
            if let Some(k) = p
                .carry
                .plan_slot
                .filter(|k| usize::from(*k) < TRACK_WINDOWS)
            {
                used |= 1 << k;
            }
        }
        let mut free = !used;
        let side = config.track_window_px();
        for p in self.priors.iter() {
            let (vx, vy) = p.carry.velocity_px.unwrap_or((0.0, 0.0));
            let anchor = (
                pixel_of(p.x_px + vx, geometry.active_cols),
                pixel_of(p.y_px + vy, geometry.active_rows),
            );
            let side = match p.carry.predicted {
                Some(pr) => predicted_window_side(
                    config.window_px,
                    pr.bound_px,
                    pr.trail_px(config.exposure_s()),
                ),
                None => trail_of(p.carry.velocity_px).map_or(side, |t| trailed_side(side, t)),
            };
            let (rect, clipped) = Rect::centred_clipped(
                anchor.0,
                anchor.1,
                side,
                geometry.active_cols,
                geometry.active_rows,
            );
            if capture.add(rect, clipped).is_err() {
                summary.track_refused = summary.track_refused.saturating_add(1);
                continue;
            }
            let slot = match p.carry.plan_slot {
                Some(k) if usize::from(k) < TRACK_WINDOWS => k,
                // At most TRACK_WINDOWS windows: a free slot is left.
                _ => {
                    let k = free.trailing_zeros().min(TRACK_WINDOWS as u32 - 1) as u8;
                    free &= !(1 << k);
                    k
                }
            };
            // Capture indices follow the adds; same capacity: cannot fail.
            let _ = self.placed.push(Placed {
                prior: *p,
                anchor,
                slot,
            });
            let _ = self.rects.push(rect);
            summary.read_px = summary
                .read_px
                .saturating_add(u32::from(rect.width) * u32::from(rect.height));
        }
        self.probe = None;
        if geometry.active_rows > 0 && geometry.active_cols > 0 {
            let y = probe_row(summary.frame, geometry.active_rows);
            let row = Rect {
                x0: 0,
                y0: y,
                width: geometry.active_cols,
                height: 1,
            };
            // One more than the windows' capacity: cannot fail.
            if self.rects.push(row).is_ok() {
                self.probe = Some(Probe {
                    y,
                    first_col: geometry.first_active_col(),
                    cols: usize::from(geometry.active_cols),
                });
                summary.read_px = summary
                    .read_px
                    .saturating_add(u32::from(geometry.active_cols));
            }
        }
        u16::try_from(self.placed.len()).unwrap_or(u16::MAX)
    }

    /// Active row `y`: copies the windows' pixels and measures the windows it completes.
    #[allow(
        clippy::too_many_arguments,
        reason = "one call per line from the frame loop"
    )]
    pub(super) fn line<const N: usize>(
        &mut self,
        cal: &FrameCalibration<'_>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        y: u16,
        samples: &[u16],
        levels: &LineLevels,
        mut sh: Shared<'_, N>,
    ) -> LineOutcome {
        if let Some(p) = self.probe.filter(|p| p.y == y)
            && let Some(row) = samples.get(p.first_col..p.first_col + p.cols)
        {
            sh.summary.probe_saturated_cols =
                Some(widest_saturated_run(row, cal.table().saturation_adu()));
        }
        match sh.capture.push_line(y, samples, levels) {
            Ok(done) => {
                let mut n = 0u8;
                for i in done {
                    self.measure(cal, policy, config, i, &mut sh);
                    n = n.saturating_add(1);
                }
                LineOutcome::Tracked { windows_done: n }
            }
            Err(_) => {
                sh.summary.lines_refused = sh.summary.lines_refused.saturating_add(1);
                LineOutcome::Refused
            }
        }
    }

    /// Ends the frame: the windows still open are measured with what they have.
    pub(super) fn finish<const N: usize>(
        &mut self,
        cal: &FrameCalibration<'_>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        mut sh: Shared<'_, N>,
    ) {
        for i in sh.capture.finish() {
            self.measure(cal, policy, config, i, &mut sh);
        }
    }

    /// Measures window `i`: the fused CoG when configured and it gives a clean result,
    /// else the full path.
    fn measure<const N: usize>(
        &self,
        cal: &FrameCalibration<'_>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        i: usize,
        sh: &mut Shared<'_, N>,
    ) {
        let Some(placed) = self.placed.get(i) else {
            return;
        };
        let predicted = placed.prior.carry.predicted;
        let velocity = |r: &StarRecord| {
            if let Some(p) = predicted {
                return Some(p.motion_px);
            }
            let v = (r.x_px - placed.prior.x_px, r.y_px - placed.prior.y_px);
            // A jump beyond the window is no motion of this star: forget it.
            let limit = f32::from(config.track_window_px());
            (v.0.abs() < limit && v.1.abs() < limit).then_some(v)
        };
        // A window holding a pixel found in flight takes the full path, which excludes it.
        let found = sh
            .capture
            .window(i)
            .is_some_and(|w| sh.watch.touches(w.rect));
        let trail = self.trail(&placed.prior, config);
        if policy.method == CentroidMethod::FusedCog1
            && !found
            && trail.is_none()
            && let Some((mut record, background)) = fused(cal, policy, placed, i, sh)
        {
            let v = velocity(&record);
            let tracked_frames = settle(&mut record, &placed.prior);
            sh.stars.push(
                record,
                Carry {
                    background: Some(background),
                    plan_slot: Some(placed.slot),
                    velocity_px: v,
                    tracked_frames,
                    predicted,
                },
            );
            return;
        }
        let Some(w) = sh.capture.window(i) else {
            return;
        };
        let (rect, clipped) = (w.rect, w.clipped);
        let copied = !w.missing_rows
            && match sh.scratch.inputs(rect) {
                Some((raw, levels)) => {
                    raw.copy_from_slice(w.raw);
                    levels.copy_from_slice(w.levels);
                    true
                }
                None => false,
            };
        if !copied {
            sh.summary.track_lost = sh.summary.track_lost.saturating_add(1);
            return;
        }
        if sh.scratch.calibrate(cal, rect).is_err() {
            sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
            return;
        }
        // The pixels found in flight are excluded before anything looks at the window.
        if let Some((e, f)) = sh.scratch.calibrated_mut(rect) {
            sh.watch.apply(rect, e, f);
        }
        // A window a saturated column crosses (saturated pixels in its top or bottom row) is
        // on a bright object or its bloomed columns: masked before the window test (whose
        // border, all saturated, has no background, so it would only call the star lost),
        // never a star, and neither its sky nor its pixels feed the frame's background or
        // the defect watch (a star whose core clipped is measured, flagged saturated).
        if crossed_by_saturation(sh, rect) {
            sh.summary.masked = sh.summary.masked.saturating_add(1);
            return;
        }
        let verdict = match sh.scratch.window(rect, clipped) {
            Some(input) => {
                let verdict =
                    track_detect(&input.window, input.pixel_flags, clipped, &config.track);
                self.watch(sh.watch, sh.summary.frame, &input, &verdict);
                verdict
            }
            None => {
                sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
                return;
            }
        };
        if !verdict.detected {
            sh.summary.track_lost = sh.summary.track_lost.saturating_add(1);
            return;
        }
        note_sky(sh.summary, verdict.background_e);
        if let Some((trail, known)) = trail {
            let Some(input) = sh.scratch.window(rect, clipped) else {
                sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
                return;
            };
            let mut record =
                policy.trailed_record(&input, StarFlags::from_track(verdict.flags), trail);
            record.provenance = Provenance::TRACKED | Provenance::TRAILED;
            if trail_clipped(trail, rect) {
                record.flags |= StarFlags::TRAIL_CLIPPED;
            }
            if !known {
                record.flags |= StarFlags::TRAIL_UNKNOWN;
            }
            let v = velocity(&record);
            let tracked_frames = settle(&mut record, &placed.prior);
            sh.stars.push(
                record,
                Carry {
                    background: None,
                    plan_slot: None,
                    velocity_px: v,
                    tracked_frames,
                    predicted,
                },
            );
            return;
        }
        let want_background = config.tracking_method == CentroidMethod::FusedCog1;
        let flags = StarFlags::from_track(verdict.flags);
        // The centroid window around the peak, inside the tracking window; when that is a
        // particle hit, around the predicted pixel (the star may be beside the hit). When
        // both are hits the star is kept, flagged `POOR_FIT` (its window holds a hit, or a
        // hot pixel the table does not list yet): its window goes on being placed and
        // watched for new defects, and identification ranks it last.
        let mut m = None;
        let mut last_hit = None;
        for (k, (px, py)) in [(verdict.peak_x, verdict.peak_y), placed.anchor]
            .into_iter()
            .enumerate()
        {
            if k == 1 && px.abs_diff(verdict.peak_x).max(py.abs_diff(verdict.peak_y)) <= 1 {
                break;
            }
            let sub = rect.centred_within(px, py, config.window_px);
            let sub_clipped = sub.width < config.window_px || sub.height < config.window_px;
            let Some(input) = sh.scratch.sub_window(rect, sub, sub_clipped) else {
                sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
                return;
            };
            let measured = measure(policy, &input, flags, want_background);
            if measured.hit_like {
                sh.summary.hits = sh.summary.hits.saturating_add(1);
            }
            if !measured.hit {
                m = Some(measured);
                break;
            }
            last_hit = Some(measured);
        }
        let Some(mut m) = m.or_else(|| {
            last_hit.map(|mut h| {
                h.record.flags |= StarFlags::POOR_FIT;
                h
            })
        }) else {
            return;
        };
        m.record.provenance = Provenance::TRACKED;
        let v = velocity(&m.record);
        let tracked_frames = settle(&mut m.record, &placed.prior);
        sh.stars.push(
            m.record,
            Carry {
                background: m.background,
                plan_slot: None,
                velocity_px: v,
                tracked_frames,
                predicted,
            },
        );
    }
}

/// True when a saturated pixel lies in the top or bottom row of the calibrated window
/// `rect`.
fn crossed_by_saturation<const N: usize>(sh: &mut Shared<'_, N>, rect: Rect) -> bool {
    let w = usize::from(rect.width);
    let h = usize::from(rect.height);
    let Some((_, f)) = sh.scratch.calibrated_mut(rect) else {
        return false;
    };
    let top = f.get(..w).unwrap_or(&[]);
    let bottom = f.get(w * h.saturating_sub(1)..).unwrap_or(&[]);
    top.iter()
        .chain(bottom)
        .any(|p| p.contains(crate::calib::PixelFlags::SATURATED))
}

/// Folds a tracking window's border background into the frame's mean sky (a running mean
/// over the windows that held their star).
fn note_sky(summary: &mut FrameSummary, background_e: f32) {
    if !background_e.is_finite() {
        return;
    }
    let n = f32::from(summary.sky_windows);
    summary.sky_e = (summary.sky_e * n + background_e) / (n + 1.0);
    summary.sky_windows = summary.sky_windows.saturating_add(1);
}

impl Tracking {
    /// Feeds the defect watch with a calibrated tracking window: the stars it must keep
    /// away from are every window's predicted star and this window's peak when it holds
    /// its star.
    fn watch(
        &self,
        watch: &mut Watch,
        frame: u32,
        input: &CentroidInput<'_>,
        verdict: &TrackResult,
    ) {
        let mut stars: heapless::Vec<(f32, f32), { TRACK_WINDOWS + 1 }> = heapless::Vec::new();
        for p in self.placed.iter() {
            let (vx, vy) = p.prior.carry.velocity_px.unwrap_or((0.0, 0.0));
            // At most TRACK_WINDOWS placed: cannot fail.
            let _ = stars.push((p.prior.x_px + vx, p.prior.y_px + vy));
        }
        if verdict.detected {
            let _ = stars.push((f32::from(verdict.peak_x), f32::from(verdict.peak_y)));
        }
        watch.observe(
            frame,
            &WatchedWindow {
                rect: input.window.rect,
                pixels_e: input.window.pixels_e,
                flags: input.pixel_flags,
                sigma_e: verdict.sigma_e,
            },
            &stars,
        );
    }
}

/// The fused raw-window CoG of window `i` with the star's carried background; `None` when
/// it does not apply (no given-background curve, no background yet, rows missing, the
/// window clipped) or flags its result, so that the full path measures the window. The
/// star's plan is applied, and rebuilt first when it is stale.
fn fused<const N: usize>(
    cal: &FrameCalibration<'_>,
    policy: &Policy<'_>,
    placed: &Placed,
    i: usize,
    sh: &mut Shared<'_, N>,
) -> Option<(StarRecord, StarBackground)> {
    let w = sh.capture.window(i)?;
    let bg = placed.prior.carry.background?;
    if w.missing_rows || w.clipped {
        return None;
    }
    let curve = policy.fused_curve?;
    let win = RawWindow {
        rect: w.rect,
        raw: w.raw,
        levels: w.levels,
    };
    let params = RawCogParams {
        box_side: policy.box_px,
        level_e: bg.level_e,
        variance_e2: bg.variance_e2,
        curve: Some(curve),
    };
    let plan = sh.plans.get_mut(usize::from(placed.slot))?;
    let res = match plan.apply(cal, &win, &params) {
        Ok(r) => r,
        Err(PlanError::Stale) => {
            plan.rebuild(cal, w.rect, placed.anchor, policy.box_px)
                .ok()?;
            plan.apply(cal, &win, &params).ok()?
        }
        Err(PlanError::BadInput) => return None,
    };
    let c = policy
        .cti
        .map_or(res.centroid, |k| k.corrected(res.centroid));
    if res.general_path || c.flags.intersects(FULL_PATH) {
        return None;
    }
    Some((
        StarRecord {
            provenance: Provenance::TRACKED | Provenance::FUSED,
            ..StarRecord::from_centroid(&c, StarFlags::empty())
        },
        bg,
    ))
}
