//! Acquisition: every active raw line streams through the pre-filtered scan
//! ([`ScanDetector`]) and into the line ring; when the scan closes a blob, the centroid
//! window around its peak waits until its last row has streamed, is copied from the ring,
//! calibrated and measured ([`super::measure`]). A window whose top rows already left the
//! ring (a blob taller than the ring allows) is reported with
//! [`StarFlags::RING_LOST`] and the detector's own position; one whose calibration fails
//! with [`StarFlags::CALIB_FAILED`].
//!
//! # Trailed stars
//! A blob that may be a star trailed during the exposure (its second moments give a trail
//! of at least [`TRAIL_SCREEN_PX`]) gets a window
//! holding its extent plus [`TRAIL_MARGIN_PX`] each side (at most [`CAPTURE_MAX_SIDE`], 15
//! px: the ring's 16 lines and the scratch window), and the trailed-star fit with the trail
//! unknown ([`crate::centroid::trail_fit::trail_fit_free`]) tests it against the round
//! model at a false-alarm rate of 1e-3: a trailed star is reported at mid-exposure
//! ([`Provenance::TRAILED`]), its trail fitted, so lost in space works while the spacecraft
//! turns; a round one is measured as any star on its centroid window around the peak. A
//! trail that reaches within [`super::TRAIL_END_MARGIN_PX`] of its window's border (longer
//! than about 11 px along a row or column at the flight PSF) is flagged
//! [`StarFlags::TRAIL_UNKNOWN`], and so is a star called round whose width-free fit is wider
//! than [`SMEARED_WIDTH_RATIO`] times the PSF. Detection itself is unchanged: the blob's eq.
//! 8 SNR sums its pixels, the matched filter's statistic over the pixels above the join
//! level, at no cost per pixel (docs/tracker.md, "Lost in space at body rate").
//!
//! # Ranking while turning
//! Both bounded lists, the scan's candidates and the star list, rank a blob by its
//! agreement with the frame's common motion first ([`crate::detect::CommonMotion`]: the
//! trail axis and length most of the frame's star-wide elongated blobs share), after the
//! clean fit in the star list: at a solar flare's rate while the spacecraft turns, the
//! trailed stars are kept before the round hits that fit a narrow Gaussian cleanly and
//! before the tracks. Without a common motion (at rest) every blob is neutral and the lists
//! rank as they would without it.
//!
//! The candidates are bit for bit those of a `LineDetector` with the same background
//! stride fed every calibrated row (host test `scan`). Cost per line: the scan (~13 M7
//! instructions a pixel, `cargo m7-bench` `scan_detect`), a 2 KB copy into the ring and a
//! copy of the candidate list (`N` x 40 B); per star, a window copy and its measurement;
//! per screened blob the trailed test (two fits on up to 15 x 15 pixels).

use super::config::{CentroidMethod, TrackerConfig};
use super::list::{Carry, StarList};
use super::measure::{Policy, measure};
use super::record::{FrameSummary, LineOutcome, Provenance, StarFlags, StarRecord};
use super::{Ring, Shared};
use crate::calib::{FrameCalibration, LineLevels, PixelFlags};
use crate::centroid::CentroidInput;
use crate::clamp::clamp;
use crate::detect::{
    CAPTURE_MAX_SIDE, CommonMotion, Detection, DetectionFlags, MotionKey, ScanDetector,
};
use crate::geometry::ReadoutGeometry;
use crate::units::Electrons;
use crate::window::Rect;

/// A closed blob waiting for its window's last row.
#[derive(Clone, Copy, Debug)]
struct Pending {
    rect: Rect,
    clipped: bool,
    detection: Detection,
}

/// A blob is tested for a trail when its moments give a trail of at least this, px
/// (`sqrt(12 (l1 - l2))`, the covariance's eigenvalues: a segment of length `L` adds
/// `L^2 / 12` along itself). The moments are of the pixels above the join level, so a
/// trail's reads short; the fit finds its length.
pub const TRAIL_SCREEN_PX: f32 = crate::detect::MIN_TRAIL_PX;

/// The trail the trailed test starts from when blob `d` may be a trail (its moments give at
/// least [`TRAIL_SCREEN_PX`]), px over the exposure: `sqrt(12 (l1 - l2))` along the larger
/// eigenvector of its moments (a segment of length `L` adds `L^2 / 12` along itself);
/// `None` for a round blob. The window is then [`trail_window`]'s.
fn blob_trail(d: &Detection) -> Option<(f32, f32)> {
    blob_elongation(d).filter(|(x, y)| libm::sqrtf(x * x + y * y) >= TRAIL_SCREEN_PX)
}

/// The trail a blob's moments say, whatever its length (`None`: no finite moments).
fn blob_elongation(d: &Detection) -> Option<(f32, f32)> {
    let [xx, yy, xy] = d.moments_px2();
    let disc = libm::sqrtf((0.25 * (xx - yy) * (xx - yy) + xy * xy).max(0.0));
    // l1 - l2 = 2 disc.
    let l = libm::sqrtf(12.0 * 2.0 * disc);
    if !l.is_finite() {
        return None;
    }
    // The larger eigenvalue's eigenvector, from whichever of its two forms is longer.
    let l1 = 0.5 * (xx + yy) + disc;
    let (a, b) = ((xy, l1 - xx), (l1 - yy, xy));
    let (vx, vy) = if a.0 * a.0 + a.1 * a.1 >= b.0 * b.0 + b.1 * b.1 {
        a
    } else {
        b
    };
    let n = libm::sqrtf(vx * vx + vy * vy);
    if !(n.is_finite() && n > 0.0) {
        return Some((l, 0.0));
    }
    Some((l * vx / n, l * vy / n))
}

/// Acquisition's state within a frame.
pub(super) struct Acquisition<'t, const N: usize> {
    /// Built on the frame's first active line (it holds the frame's calibration).
    scan: Option<ScanDetector<'t, N>>,
    closed: heapless::Vec<Detection, N>,
    pending: heapless::Vec<Pending, N>,
    /// Sum and count of the whole rows' mean sky (saturated and excluded pixels left out),
    /// e- per pixel.
    sky_sum_e: f32,
    sky_rows: u32,
}

impl<'t, const N: usize> Acquisition<'t, N> {
    pub(super) const fn new() -> Self {
        Self {
            scan: None,
            closed: heapless::Vec::new(),
            pending: heapless::Vec::new(),
            sky_sum_e: 0.0,
            sky_rows: 0,
        }
    }

    /// Starts an acquisition frame.
    pub(super) fn start(&mut self, ring: &mut Ring) {
        ring.clear();
        self.scan = None;
        self.closed.clear();
        self.pending.clear();
        self.sky_sum_e = 0.0;
        self.sky_rows = 0;
    }

    /// Active row `y`: into the ring and the scan; the windows it completes are measured.
    #[allow(
        clippy::too_many_arguments,
        reason = "one call per line from the frame loop"
    )]
    pub(super) fn line(
        &mut self,
        cal: &FrameCalibration<'t>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        geometry: &ReadoutGeometry,
        y: u16,
        samples: &[u16],
        levels: &LineLevels,
        mut sh: Shared<'_, N>,
    ) -> LineOutcome {
        // The line has the geometry's length, at most the ring's: cannot fail.
        let _ = sh.ring.push(y, samples, levels);
        match self.scan.as_mut() {
            Some(scan) => scan.set_conditions(*cal.conditions()),
            None => {
                self.scan = Some(
                    ScanDetector::new(*cal, config.detect, config.background_stride)
                        .with_background_warmup(config.background_warmup_rows),
                );
            }
        }
        let Some(scan) = self.scan.as_mut() else {
            return LineOutcome::Refused;
        };
        if scan
            .push_raw_line_closed(y, samples, levels, &mut self.closed)
            .is_err()
        {
            sh.summary.lines_refused = sh.summary.lines_refused.saturating_add(1);
            return LineOutcome::Refused;
        }
        let outcome = match scan.whole_line() {
            Some((e, f)) => {
                if let Some(sky) = sky_mean(e, f) {
                    self.sky_sum_e += sky;
                    self.sky_rows += 1;
                }
                row_mean(e, f)
            }
            None => LineOutcome::Scanned,
        };
        self.queue_closed(config, geometry, sh.summary);
        self.serve(cal, policy, config, Some(y), &mut sh);
        outcome
    }

    /// Ends the frame: completes the open blobs and measures every waiting window.
    pub(super) fn finish(
        &mut self,
        cal: &FrameCalibration<'_>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        geometry: &ReadoutGeometry,
        mut sh: Shared<'_, N>,
    ) {
        if let Some(scan) = self.scan.as_mut() {
            scan.finish_closed(&mut self.closed);
            sh.summary.candidates_dropped = scan.detector().dropped();
            self.queue_closed(config, geometry, sh.summary);
        }
        if self.sky_rows > 0 {
            sh.summary.sky_e = self.sky_sum_e / self.sky_rows as f32;
        }
        self.serve(cal, policy, config, None, &mut sh);
        // The second pass: the common motion as the whole frame settled it.
        if let Some(scan) = self.scan.as_ref() {
            sh.stars.flag_off_motion(
                scan.detector().motion(),
                OFF_MOTION_WIDTH_FRACTION * config.psf_a_px,
            );
        }
    }

    /// Moves the candidates the last line closed into the pending list.
    fn queue_closed(
        &mut self,
        config: &TrackerConfig,
        geometry: &ReadoutGeometry,
        summary: &mut FrameSummary,
    ) {
        for d in self.closed.iter() {
            let (rect, clipped) = match blob_trail(d) {
                Some(_) => trail_window(d, config, geometry),
                None => Rect::centred_clipped(
                    d.peak_x,
                    d.peak_y,
                    config.window_px,
                    geometry.active_cols,
                    geometry.active_rows,
                ),
            };
            let p = Pending {
                rect,
                clipped,
                detection: *d,
            };
            if self.pending.push(p).is_err() {
                summary.windows_dropped = summary.windows_dropped.saturating_add(1);
            }
        }
    }

    /// Measures the pending windows whose last row has streamed (all of them when `y` is
    /// `None`, at the end of the frame).
    fn serve(
        &mut self,
        cal: &FrameCalibration<'_>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        y: Option<u16>,
        sh: &mut Shared<'_, N>,
    ) {
        let mut i = 0;
        while let Some(p) = self.pending.get(i).copied() {
            let last = p.rect.y0.saturating_add(p.rect.height).saturating_sub(1);
            if y.is_some_and(|y| y < last) {
                i += 1;
                continue;
            }
            self.pending.swap_remove(i);
            let motion = self
                .scan
                .as_ref()
                .map_or(&CommonMotion::EMPTY, |s| s.detector().motion());
            measure_pending(cal, policy, config, &p, motion, sh);
            // Measured: the star list (its rank: a window the PSF describes first) keeps it
            // or not, so its place in the detector's bounded list goes to the next
            // candidate. That list then holds only the candidates waiting for their rows;
            // ranked by the blob alone, at a solar flare's rate the brighter proton hits
            // filled it and the stars were never measured.
            if let Some(scan) = self.scan.as_mut() {
                scan.forget(&p.detection);
            }
        }
    }
}

/// An acquired star the trailed test does not call trailed whose fitted width (the
/// width-free fit's `psf_a_px`) exceeds the configured PSF's by this factor is a smeared
/// star, its trail unknown: flagged [`StarFlags::TRAIL_UNKNOWN`] (kept for tracking, not
/// used for the attitude). On the SIL's sky a still star fits within 3 % of the PSF's
/// width, one trailed 3.4 px a frame (0.5 deg/s in 100 ms) at 1.4-1.5 times it, 6.8 px at
/// 1.9-2.4 times.
pub const SMEARED_WIDTH_RATIO: f32 = 1.5;

/// The window of a blob that may be a trail: its extent plus [`TRAIL_MARGIN_PX`] each side,
/// odd, at least `window_px` and at most [`CAPTURE_MAX_SIDE`] a side, centred on the blob.
fn trail_window(d: &Detection, config: &TrackerConfig, geometry: &ReadoutGeometry) -> (Rect, bool) {
    let [x0, x1, y0, y1] = d.extent;
    let side = |lo: u16, hi: u16| {
        clamp(
            hi.saturating_sub(lo)
                .saturating_add(1 + 2 * TRAIL_MARGIN_PX)
                | 1,
            config.window_px,
            CAPTURE_MAX_SIDE,
        )
    };
    let centre = |v: f32, lo: u16, hi: u16| {
        let v = if v.is_finite() { v } else { f32::from(lo) };
        clamp(v + 0.5, f32::from(lo), f32::from(hi)) as u16
    };
    let (cx, cy) = (centre(d.x_px, x0, x1), centre(d.y_px, y0, y1));
    let (wx, wy) = (side(x0, x1), side(y0, y1));
    let (h, hc) = Rect::centred_clipped(cx, cy, wx, geometry.active_cols, geometry.active_rows);
    let (v, vc) = Rect::centred_clipped(cx, cy, wy, geometry.active_cols, geometry.active_rows);
    let rect = Rect {
        x0: h.x0,
        width: h.width,
        y0: v.y0,
        height: v.height,
    };
    (rect, (hc && h.width != wx) || (vc && v.height != wy))
}

/// Pixels a trail's window reaches beyond its blob on each side: the PSF's wings below the
/// join threshold (2.5 sigma of the flight PSF, 1.7 px) and a border pixel for the
/// background.
pub const TRAIL_MARGIN_PX: u16 = 3;

/// A trailed fit narrower across its trail than this fraction of the configured PSF's width
/// is a particle's track, not a star, and the window is measured as a round one (where the
/// particle-hit test judges it): the optics spread a star across its trail as they spread a
/// still one, while a proton's charge is spread by diffusion only. The tracker's
/// width-free fit serves stars down to two thirds of the configured width (docs/accuracy.md,
/// "Each star's own width"); on the SIL at the South Atlantic Anomaly's rate the tracks the
/// trailed test calls trails fit at 0.43 to 0.47 of it, its stars at 1.0.
pub const TRAIL_MIN_WIDTH_FRACTION: f32 = 0.5;

/// In a frame whose stars share a common trail, a record measured round, off that trail,
/// brighter than the median of the records on it and fitted narrower than this fraction
/// of the configured PSF's width is no star of the frame ([`StarFlags::TRAIL_UNKNOWN`],
/// the star list's second pass): a trail only widens a star, while a proton that crossed
/// the silicon near the normal fits narrower than the PSF (its charge spreads by diffusion
/// only); a star smeared by a trail below the moments' screen (1.3 px, 0.5 deg/s in 39 ms)
/// fits as wide as the PSF or wider.
pub const OFF_MOTION_WIDTH_FRACTION: f32 = 0.75;

/// A saturated blob of more than this many pixels is masked ([`StarFlags`] would only flag
/// a star's clipped core): four 7 x 7 windows' worth, more than the brightest star's wings
/// above the join threshold; a bloomed column alone is 1,024.
pub const MASK_MIN_PX: u32 = 196;

/// Measures one pending window, or reports the detector's position with the reason;
/// false when it is no star (masked on a saturated object, or a particle hit). The star
/// list ranks it by its blob's agreement with the frame's common motion `motion`.
fn measure_pending<const N: usize>(
    cal: &FrameCalibration<'_>,
    policy: &Policy<'_>,
    config: &TrackerConfig,
    p: &Pending,
    motion: &CommonMotion,
    sh: &mut Shared<'_, N>,
) -> bool {
    let key = p.detection.motion;
    // A saturated blob larger than any star's is a bright object or its bloomed columns:
    // masked, never a star (a star whose core clipped is reported, flagged saturated).
    if p.detection.flags.contains(DetectionFlags::SATURATED) && p.detection.pixels > MASK_MIN_PX {
        sh.summary.masked = sh.summary.masked.saturating_add(1);
        sh.summary.saturated_px = sh.summary.saturated_px.max(p.detection.pixels);
        return false;
    }
    let rect = p.rect;
    let detected = StarFlags::from_detection(p.detection.flags);
    let want_background = config.tracking_method == CentroidMethod::FusedCog1;
    let copied = match sh.scratch.inputs(rect) {
        Some((raw, levels)) => sh.ring.copy_window(rect, raw, levels).is_ok(),
        None => false,
    };
    let lost = if !copied {
        sh.summary.ring_lost = sh.summary.ring_lost.saturating_add(1);
        StarFlags::RING_LOST
    } else if sh.scratch.calibrate(cal, rect).is_err() {
        sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
        StarFlags::CALIB_FAILED
    } else if let Some(trail_start) = blob_trail(&p.detection) {
        // The trailed test on the blob's whole window; a round star is measured as any
        // other, on its centroid window around the peak.
        // A trail is as wide across as the optics make a still star; a proton's track is
        // narrower (charge diffusion only): such a "trail" is measured as a round window,
        // where the particle-hit test judges it.
        if let Some(input) = sh.scratch.window(rect, p.clipped)
            && let Some(record) = policy.free_trailed_record(&input, detected, trail_start)
            && record.psf_a_px >= TRAIL_MIN_WIDTH_FRACTION * config.psf_a_px
        {
            sh.stars.push_keyed(record, Carry::default(), key, motion);
            return true;
        }
        let sub = rect.centred_within(p.detection.peak_x, p.detection.peak_y, config.window_px);
        let sub_clipped =
            p.clipped || sub.width < config.window_px || sub.height < config.window_px;
        if let Some(input) = sh.scratch.sub_window(rect, sub, sub_clipped) {
            return push_measured(
                policy,
                &input,
                detected,
                want_background,
                None,
                (key, motion),
                sh.stars,
                sh.summary,
            );
        }
        sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
        StarFlags::CALIB_FAILED
    } else if let Some(input) = sh.scratch.window(rect, p.clipped) {
        return push_measured(
            policy,
            &input,
            detected,
            want_background,
            blob_elongation(&p.detection),
            (key, motion),
            sh.stars,
            sh.summary,
        );
    } else {
        sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
        StarFlags::CALIB_FAILED
    };
    let d = &p.detection;
    let half = f32::from(config.window_px) / 2.0;
    sh.stars.push_keyed(
        StarRecord {
            x_px: d.x_px,
            y_px: d.y_px,
            flux_e: d.flux_e,
            snr: d.snr,
            sigma_x_px: half,
            sigma_y_px: half,
            cov_xy_px2: 0.0,
            flags: detected | lost,
            provenance: Provenance::empty(),
            psf_a_px: 0.0,
            chi2_dof: 0.0,
        },
        Carry::default(),
        key,
        motion,
    );
    true
}

/// A whole calibrated row's mean sky: the mean of its pixels that are neither excluded nor
/// saturated, e- (`None` without one).
fn sky_mean(e: &[Electrons], f: &[PixelFlags]) -> Option<f32> {
    let (mut sum, mut n) = (0i64, 0i64);
    for (v, fl) in e.iter().zip(f.iter()) {
        if !fl.is_excluded() && !fl.contains(PixelFlags::SATURATED) {
            sum += i64::from(v.to_bits());
            n += 1;
        }
    }
    (n > 0).then(|| sum as f32 / (64.0 * n as f32))
}

/// Measures a round star's centroid window by the configured method and pushes it; a star
/// the round fit cannot describe ([`StarFlags::POOR_FIT`], no particle hit) whose blob has
/// `elongation` (its moments' trail, shorter than the screen's) goes through the trailed
/// test with the trail unknown, and is pushed trailed when that describes it cleanly: a
/// bright star smeared by less than [`TRAIL_SCREEN_PX`] fits a round Gaussian badly, and
/// ranked below every clean star it left lost in space the field's faint stars alone
/// (0.5 deg/s in 39 ms, 1.3 px). Otherwise the round result is pushed, flagged
/// [`StarFlags::TRAIL_UNKNOWN`] when its fitted width says it is smeared
/// ([`SMEARED_WIDTH_RATIO`]), and [`StarFlags::POOR_FIT`] (a particle hit is counted) when
/// the window is sharper than a star. The list ranks it by its blob's key against the
/// frame's common motion (the pair `(key, motion)`).
#[allow(
    clippy::too_many_arguments,
    reason = "one call per measured window from measure_pending"
)]
fn push_measured<const N: usize>(
    policy: &Policy<'_>,
    input: &CentroidInput<'_>,
    detected: StarFlags,
    want_background: bool,
    elongation: Option<(f32, f32)>,
    (key, motion): (MotionKey, &CommonMotion),
    stars: &mut StarList<N>,
    summary: &mut FrameSummary,
) -> bool {
    let mut m = measure(policy, input, detected, want_background);
    if m.hit_like {
        summary.hits = summary.hits.saturating_add(1);
    }
    if !m.hit_like
        && m.record.flags.contains(StarFlags::POOR_FIT)
        && let Some(e) = elongation
        && let Some(record) = policy.free_trailed_record(input, detected, e)
        && record.fit_is_clean()
        && record.psf_a_px >= TRAIL_MIN_WIDTH_FRACTION * policy.psf_a_px
    {
        stars.push_keyed(record, Carry::default(), key, motion);
        return true;
    }
    // A particle hit, or a star beside a hot pixel the table does not list yet (as sharp as
    // a hit, and persistent): kept, flagged, so the star list ranks it below every clean
    // star and identification leaves it out, while its window, if it gets one, goes on
    // feeding the in-flight defect watch.
    if m.hit {
        m.record.flags |= StarFlags::POOR_FIT;
    }
    if m.record.psf_a_px > SMEARED_WIDTH_RATIO * policy.psf_a_px {
        m.record.flags |= StarFlags::TRAIL_UNKNOWN;
    }
    stars.push_keyed(
        m.record,
        Carry {
            background: m.background,
            ..Carry::default()
        },
        key,
        motion,
    );
    true
}

/// A whole calibrated row's mean over the pixels that are not excluded, its OR-ed flags
/// and its saturated pixels.
fn row_mean(e: &[Electrons], f: &[PixelFlags]) -> LineOutcome {
    let (mut sum, mut used, mut saturated) = (0i64, 0i64, 0u16);
    let mut flags = PixelFlags::empty();
    for (v, fl) in e.iter().zip(f.iter()) {
        flags |= *fl;
        if !fl.is_excluded() {
            sum += i64::from(v.to_bits());
            used += 1;
        }
        if fl.contains(PixelFlags::SATURATED) {
            saturated = saturated.saturating_add(1);
        }
    }
    let mean_bits = if used == 0 {
        0
    } else {
        // Round to nearest; the mean of i32 values fits an i32.
        (2 * sum + used).div_euclid(2 * used) as i32
    };
    LineOutcome::Calibrated {
        mean_e: Electrons::from_bits(mean_bits),
        flags,
        saturated,
    }
}
