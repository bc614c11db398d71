//! Acquisition: every active raw line streams through the pre-filtered scan
//! ([`ScanDetector`]) and into the line ring; when the scan closes a blob, the centroid
//! window around its peak waits until its last row has streamed, is copied from the ring,
//! calibrated and measured ([`super::measure`]). A window whose top rows already left the
//! ring (a blob taller than the ring allows) is reported with
//! [`StarFlags::RING_LOST`] and the detector's own position; one whose calibration fails
//! with [`StarFlags::CALIB_FAILED`].
//!
//! The candidates are bit for bit those of a `LineDetector` with the same background
//! stride fed every calibrated row (host test `scan`). Cost per line: the scan (~13 M7
//! instructions a pixel, `cargo m7-bench` `scan_detect`), a 2 KB copy into the ring and a
//! copy of the candidate list (`N` x 28 B); per star, a window copy and its measurement.

use super::config::{CentroidMethod, TrackerConfig};
use super::list::Carry;
use super::measure::{Policy, measure};
use super::record::{FrameSummary, LineOutcome, Provenance, StarFlags, StarRecord};
use super::{Ring, Shared};
use crate::calib::{FrameCalibration, LineLevels, PixelFlags};
use crate::detect::{Detection, DetectionFlags, ScanDetector};
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
        sh: Shared<'_, N>,
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
        self.serve(cal, policy, config, Some(y), sh);
        outcome
    }

    /// Ends the frame: completes the open blobs and measures every waiting window.
    pub(super) fn finish(
        &mut self,
        cal: &FrameCalibration<'_>,
        policy: &Policy<'_>,
        config: &TrackerConfig,
        geometry: &ReadoutGeometry,
        sh: Shared<'_, N>,
    ) {
        if let Some(scan) = self.scan.as_mut() {
            scan.finish_closed(&mut self.closed);
            sh.summary.candidates_dropped = scan.detector().dropped();
            self.queue_closed(config, geometry, sh.summary);
        }
        if self.sky_rows > 0 {
            sh.summary.sky_e = self.sky_sum_e / self.sky_rows as f32;
        }
        self.serve(cal, policy, config, None, sh);
    }

    /// Moves the candidates the last line closed into the pending list.
    fn queue_closed(
        &mut self,
        config: &TrackerConfig,
        geometry: &ReadoutGeometry,
        summary: &mut FrameSummary,
    ) {
        for d in self.closed.iter() {
            let (rect, clipped) = Rect::centred_clipped(
                d.peak_x,
                d.peak_y,
                config.window_px,
                geometry.active_cols,
                geometry.active_rows,
            );
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
        mut sh: Shared<'_, N>,
    ) {
        let mut i = 0;
        while let Some(p) = self.pending.get(i).copied() {
            let last = p.rect.y0.saturating_add(p.rect.height).saturating_sub(1);
            if y.is_some_and(|y| y < last) {
                i += 1;
                continue;
            }
            self.pending.swap_remove(i);
            measure_pending(cal, policy, config, &p, &mut sh);
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

/// A saturated blob of more than this many pixels is masked ([`StarFlags`] would only flag
/// a star's clipped core): four 7 x 7 windows' worth, more than the brightest star's wings
/// above the join threshold; a bloomed column alone is 1,024.
pub const MASK_MIN_PX: u32 = 196;

/// An acquired star whose fitted width (the width-free fit's `psf_a_px`) exceeds the
/// configured PSF's by this factor is a smeared star, its trail unknown: flagged
/// [`StarFlags::TRAIL_UNKNOWN`] (kept for tracking, not used for the attitude). On the SIL's
/// sky a still star fits within 3 % of the PSF's width, one trailed 3.4 px a frame (0.5
/// deg/s in 100 ms) at 1.4-1.5 times it, 6.8 px at 1.9-2.4 times.
pub const SMEARED_WIDTH_RATIO: f32 = 1.5;

/// Measures one pending window, or reports the detector's position with the reason;
/// false when it is no star (masked on a saturated object, or a particle hit).
fn measure_pending<const N: usize>(
    cal: &FrameCalibration<'_>,
    policy: &Policy<'_>,
    config: &TrackerConfig,
    p: &Pending,
    sh: &mut Shared<'_, N>,
) -> bool {
    let rect = p.rect;
    // A saturated blob larger than any star's is a bright object or its bloomed columns:
    // masked, never a star (a star whose core clipped is reported, flagged saturated).
    if p.detection.flags.contains(DetectionFlags::SATURATED) && p.detection.pixels > MASK_MIN_PX {
        sh.summary.masked = sh.summary.masked.saturating_add(1);
        sh.summary.saturated_px = sh.summary.saturated_px.max(p.detection.pixels);
        return false;
    }
    let detected = StarFlags::from_detection(p.detection.flags);
    let want_background = config.tracking_method == CentroidMethod::FusedCog1;
    let copied = match sh.scratch.inputs(rect) {
        Some((raw, levels)) => sh.ring.copy_window(rect, raw, levels).is_ok(),
        None => false,
    };
    let lost = if !copied {
        sh.summary.ring_lost = sh.summary.ring_lost.saturating_add(1);
        StarFlags::RING_LOST
    } else if sh.scratch.calibrate(cal, rect).is_ok()
        && let Some(input) = sh.scratch.window(rect, p.clipped)
    {
        let mut m = measure(policy, &input, detected, want_background);
        if m.hit_like {
            sh.summary.hits = sh.summary.hits.saturating_add(1);
        }
        if m.hit {
            return false;
        }
        if m.record.psf_a_px > SMEARED_WIDTH_RATIO * config.psf_a_px {
            m.record.flags |= StarFlags::TRAIL_UNKNOWN;
        }
        sh.stars.push(
            m.record,
            Carry {
                background: m.background,
                ..Carry::default()
            },
        );
        return true;
    } else {
        sh.summary.calib_failed = sh.summary.calib_failed.saturating_add(1);
        StarFlags::CALIB_FAILED
    };
    let d = &p.detection;
    let half = f32::from(config.window_px) / 2.0;
    sh.stars.push(
        StarRecord {
            x_px: d.x_px,
            y_px: d.y_px,
            flux_e: d.flux_e,
            snr: d.snr,
            sigma_x_px: half,
            sigma_y_px: half,
            flags: detected | lost,
            provenance: Provenance::empty(),
            psf_a_px: 0.0,
            chi2_dof: 0.0,
        },
        Carry::default(),
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
