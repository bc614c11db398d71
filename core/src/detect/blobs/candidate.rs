//! From a closed blob to a star candidate: the counting rules of the configuration (pixels,
//! peak sigmas, saturation), the measured SNR (eq. 8), the shape test for blends, the flags,
//! the blob's vote in the frame's common motion, and the bounded list that keeps the `N`
//! best ranked ([`ranks_above`]); plus the reporting of the candidates a line completed,
//! for the firmware's acquisition centroiding.
//!
//! # Cost
//! Per closed blob one square root for the SNR and one for the covariance's eigenvalues,
//! and an elongated blob's key and vote ([`crate::detect::CommonMotion`]); on a full list a
//! scan for the lowest ranked candidate (`N` compares, each two histogram lookups). The `_closed` variants copy
//! the candidate list once per line.

use super::{Blob, Detection, DetectionFlags, LineDetector};
use crate::calib::PixelFlags;
use crate::clamp::clamp;
use crate::detect::DetectError;
use crate::detect::motion::{CommonMotion, MotionKey};
use crate::units::Electrons;

impl<const N: usize> LineDetector<N> {
    /// Completes blob `b`: a candidate when it counts (its size and peak, or saturated) and
    /// its SNR passes, kept in the list by the overflow policy of [`super`].
    pub(super) fn complete(&mut self, b: &Blob) {
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
        let mut moments_64ths = [0i16; 3];
        let mut motion = MotionKey::ROUND;
        let (x, y) = match b.moments.shape() {
            Some(super::Shape {
                mean: (mx, my),
                eigen: (l1, l2),
                cov,
            }) => {
                // Saturating float-to-int casts; NaN gives 0.
                moments_64ths = cov.map(|m| (m * 64.0) as i16);
                motion = MotionKey::of_covariance(cov);
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
            x_px: clamp(x, f32::from(b.x_min), f32::from(b.x_max)),
            y_px: clamp(y, f32::from(b.y_min), f32::from(b.last_y)),
            peak_x: b.peak_x,
            peak_y: b.peak_y,
            flux_e: s,
            pixels: b.pixels,
            snr,
            flags,
            extent: [b.x_min, b.x_max, b.y_min, b.last_y],
            moments_64ths,
            motion,
        };
        // A blob the table overflow cut, or the edge clipped, has no trustworthy shape.
        if !flags.intersects(DetectionFlags::TRUNCATED | DetectionFlags::EDGE) {
            self.motion.vote(motion);
        }
        if let Err(d) = self.candidates.push(d) {
            self.dropped += 1;
            let m = &self.motion;
            let mut lowest: Option<(usize, &Detection)> = None;
            for (i, c) in self.candidates.iter().enumerate() {
                if lowest.is_none_or(|(_, l)| ranks_above(m, l, c)) {
                    lowest = Some((i, c));
                }
            }
            if let Some((i, _)) = lowest.filter(|(_, l)| ranks_above(m, &d, l))
                && let Some(slot) = self.candidates.get_mut(i)
            {
                *slot = d;
            }
        }
    }
}

/// True when candidate `a` ranks above `b` in a full list: by their agreement with the
/// frame's common motion `m` as it stands ([`crate::detect::Agreement`]: a trailed star of a
/// turning frame above a round hit above a track at another angle; every blob neutral
/// without one), then a round blob above an elongated one ([`DetectionFlags::BLENDED`]: a
/// pair, a trailed star, or a proton's track), then the larger flux. A solar flare's
/// proton tracks, brighter than most stars and elongated, then take no place a star could
/// have.
fn ranks_above(m: &CommonMotion, a: &Detection, b: &Detection) -> bool {
    let long = |d: &Detection| d.flags.contains(DetectionFlags::BLENDED);
    match m.agreement(a.motion).cmp(&m.agreement(b.motion)) {
        core::cmp::Ordering::Greater => return true,
        core::cmp::Ordering::Less => return false,
        core::cmp::Ordering::Equal => {}
    }
    match (long(a), long(b)) {
        (false, true) => true,
        (true, false) => false,
        _ => a.flux_e > b.flux_e,
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
