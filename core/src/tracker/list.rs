//! A frame's star list: bounded, the best kept ([`ranks_above`]: a window the fitted PSF
//! describes before one it does not, then by its blob's agreement with the frame's common
//! motion, then the brighter), each record with what the next tracking frame needs of the
//! star ([`Carry`]). A particle hit the sharpness test lets pass is bright and fits the
//! Gaussian badly (`POOR_FIT`, chi^2 per degree of freedom in the tens to thousands on the
//! SIL's proton model): ranked by flux alone, a South Atlantic Anomaly frame's ~190 hits
//! filled the list and pushed out the stars. A hit that crossed the silicon near the normal
//! fits a narrow Gaussian cleanly; while the spacecraft turns, the stars' blobs agree with
//! the frame's common trail and the hits' round blobs do not
//! ([`crate::detect::CommonMotion`]): at a flare's rate and 1 deg/s, ranked by flux, 28 of
//! an acquisition frame's 32 were such hits. The list keeps each record's blob key and
//! looks its agreement up again at every comparison, so a record kept before the common
//! motion settled is ranked by it afterwards.
//!
//! Cost: a push is O(1) while the list has room; once full, a scan for the lowest ranked
//! (at most `N` compares, each two histogram lookups) per extra star.

use super::measure::StarBackground;
use super::predicted::PredictedStar;
use super::record::{StarFlags, StarRecord};
use crate::detect::{Agreement, CommonMotion, MotionKey};

/// What a star carries to the next tracking frame besides its position.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Carry {
    /// Its background as last measured on a full path (the fused CoG's given background).
    pub(crate) background: Option<StarBackground>,
    /// The fused CoG plan slot it was measured with.
    pub(crate) plan_slot: Option<u8>,
    /// Its motion between the last two frames, px per frame (tracked stars).
    pub(crate) velocity_px: Option<(f32, f32)>,
    /// Tracking frames in a row that measured it (0 from acquisition), saturating.
    pub(crate) tracked_frames: u8,
    /// The attitude stage's prediction it was measured for (its catalog identity).
    pub(crate) predicted: Option<PredictedStar>,
}

/// Up to `N` stars, of which at most `limit` are kept.
pub(crate) struct StarList<const N: usize> {
    records: heapless::Vec<StarRecord, N>,
    carries: heapless::Vec<Carry, N>,
    /// Each record's blob key in the common-motion histogram (acquisition; round else).
    keys: heapless::Vec<MotionKey, N>,
    limit: usize,
    /// Stars not kept (list full and fainter than all, or pushed out by a brighter one).
    pub(crate) dropped: u16,
}

impl<const N: usize> StarList<N> {
    pub(crate) const fn new() -> Self {
        Self {
            records: heapless::Vec::new(),
            carries: heapless::Vec::new(),
            keys: heapless::Vec::new(),
            limit: N,
            dropped: 0,
        }
    }

    /// Empties the list for a frame that keeps at most `limit` stars.
    pub(crate) fn clear(&mut self, limit: usize) {
        self.records.clear();
        self.carries.clear();
        self.keys.clear();
        self.limit = limit.min(N);
        self.dropped = 0;
    }

    pub(crate) fn records(&self) -> &[StarRecord] {
        &self.records
    }

    pub(crate) fn iter(&self) -> impl Iterator<Item = (&StarRecord, &Carry)> {
        self.records.iter().zip(self.carries.iter())
    }

    /// Each record's carry, in the records' order.
    pub(crate) fn carries(&self) -> &[Carry] {
        &self.carries
    }

    /// Adds a star with no blob key (tracking: every star neutral); see [`Self::push_keyed`].
    pub(crate) fn push(&mut self, record: StarRecord, carry: Carry) {
        self.push_keyed(record, carry, MotionKey::ROUND, &CommonMotion::EMPTY);
    }

    /// Adds a star whose blob has `key`; when the list is full the lowest ranked
    /// ([`ranks_above`], by the common motion `motion` as it stands) is replaced by one
    /// ranked above it.
    pub(crate) fn push_keyed(
        &mut self,
        record: StarRecord,
        carry: Carry,
        key: MotionKey,
        motion: &CommonMotion,
    ) {
        if self.records.len() < self.limit {
            // The limit is at most N: the three pushes have room.
            let _ = self.records.push(record);
            let _ = self.carries.push(carry);
            let _ = self.keys.push(key);
            return;
        }
        self.dropped = self.dropped.saturating_add(1);
        let ranked = |r: &StarRecord, k: MotionKey| (*r, motion.agreement(k));
        let mut lowest: Option<(usize, (StarRecord, Agreement))> = None;
        for (i, (s, k)) in self.records.iter().zip(self.keys.iter()).enumerate() {
            let s = ranked(s, *k);
            if lowest.is_none_or(|(_, l)| ranks_above(&l, &s)) {
                lowest = Some((i, s));
            }
        }
        if let Some((i, l)) = lowest
            && ranks_above(&ranked(&record, key), &l)
            && let (Some(r), Some(c), Some(k)) = (
                self.records.get_mut(i),
                self.carries.get_mut(i),
                self.keys.get_mut(i),
            )
        {
            *r = record;
            *c = carry;
            *k = key;
        }
    }
}

impl<const N: usize> StarList<N> {
    /// The second pass over an acquisition frame's list once the frame's common motion
    /// settled (`motion`, the whole frame's): a record measured round (not
    /// [`super::Provenance::TRAILED`]) whose blob does not agree with it, brighter than the
    /// median of those that do and narrower than `narrow_a_px` (the fit's 80 % radius) is
    /// no star of this frame (a proton hit that fits a narrow Gaussian cleanly: a star as
    /// bright as the frame's trailed stars shows their trail, and a trail only widens a
    /// star), and is flagged [`StarFlags::TRAIL_UNKNOWN`] (kept, not used for the
    /// attitude). Fainter ones are left alone (a faint star's trail may hide in its noise),
    /// and wider ones (a trail shorter than the moments' screen reads round on a bright
    /// star too). Nothing happens without a settled motion or with fewer than
    /// [`MIN_AGREEING`] agreeing records. Returns the records flagged. Cost: two scans of
    /// the list and a median of at most `N` fluxes (`N^2` compares).
    pub(crate) fn flag_off_motion(&mut self, motion: &CommonMotion, narrow_a_px: f32) -> u16 {
        if !motion.is_settled() {
            return 0;
        }
        let mut agreeing: heapless::Vec<f32, N> = heapless::Vec::new();
        for (r, k) in self.records.iter().zip(self.keys.iter()) {
            if motion.agreement(*k) == Agreement::Agrees && r.is_centroid() {
                // At most N records: cannot fail.
                let _ = agreeing.push(r.flux_e);
            }
        }
        if agreeing.len() < MIN_AGREEING {
            return 0;
        }
        let Some(median_e) = upper_median(&agreeing) else {
            return 0;
        };
        let mut flagged = 0u16;
        for (r, k) in self.records.iter_mut().zip(self.keys.iter()) {
            if motion.agreement(*k) != Agreement::Agrees
                && !r.provenance.contains(super::Provenance::TRAILED)
                && r.flux_e > median_e
                && r.psf_a_px > 0.0
                && r.psf_a_px < narrow_a_px
            {
                r.flags |= StarFlags::TRAIL_UNKNOWN;
                flagged = flagged.saturating_add(1);
            }
        }
        flagged
    }
}

/// The element of `v` at index `len / 2` in ascending order (`None` when empty), by
/// counting rather than sorting: at most `N^2` compares, no sort code in the image.
fn upper_median(v: &[f32]) -> Option<f32> {
    let k = v.len() / 2;
    v.iter().copied().find(|&x| {
        let below = v.iter().filter(|&&y| y < x).count();
        let equal = v.iter().filter(|&&y| y == x).count();
        below <= k && k < below + equal
    })
}

/// Records agreeing with the common motion [`StarList::flag_off_motion`] needs for a
/// median.
pub(crate) const MIN_AGREEING: usize = 3;

/// True when `a` ranks above `b` in a full list, each a record and its blob's agreement
/// with the frame's common motion: a clean fit ([`StarRecord::fit_is_clean`]) above one that
/// is not, then the higher agreement (all neutral without a common motion), then the larger
/// flux.
pub(crate) fn ranks_above(a: &(StarRecord, Agreement), b: &(StarRecord, Agreement)) -> bool {
    let poor = |s: &StarRecord| !s.fit_is_clean();
    match (poor(&a.0), poor(&b.0)) {
        (false, true) => true,
        (true, false) => false,
        _ if a.1 != b.1 => a.1 > b.1,
        _ => a.0.flux_e > b.0.flux_e,
    }
}
