//! The frame's common motion: while the spacecraft turns across the boresight every star of
//! a frame trails the same way (to first order over a 15-degree field: the same axis and
//! nearly the same length), while proton tracks lie at random angles and lengths and hits
//! are round. A histogram of the elongated blobs' trail axis and length, filled as the
//! blobs close, finds that common trail; the bounded lists rank a blob by whether it agrees
//! ([`Agreement`]), so that at a solar flare's rate the trailed stars are kept before the
//! round hits and the tracks.
//!
//! A blob's trail is its second moments' (`sqrt(12 (l1 - l2))` along the larger
//! eigenvector, l1, l2 the covariance's eigenvalues: a segment of length `L` adds `L^2 / 12`
//! along itself); it is elongated from [`MIN_TRAIL_PX`], and votes when it is as wide across
//! its axis as a star ([`MIN_ACROSS_PX2`]: a track is narrower, its charge spread by
//! diffusion only, so few tracks vote). Its [`MotionKey`] is the
//! histogram's cell: [`ORIENT_BINS`] axis bins over 180 degrees (11.25 degrees each) times
//! [`LEN_BINS`] length bins a factor 1.5 wide from [`MIN_TRAIL_PX`]. The common motion is
//! the 3 x 3 block of cells (33.75 degrees, a factor 3.4 in length: a faint star's trail
//! reads short, its pixels above the join level only) holding the most blobs, accepted when
//! it holds more than random axes give: tracks are isotropic, so in its length band a block
//! of 3 of the 16 axis bins expects `mu = 3/16` of the band's blobs, and the block must hold
//! at least `mu + 5 sqrt(mu) + 4` ([`CommonMotion::is_settled`]). Until then, or in a frame
//! without one (at rest, no elongated blobs), every blob is [`Agreement::Neutral`] and the
//! lists rank as without this module: nothing changes at rest. A random track whose axis
//! and length fall in the common block agrees (the lists' other rules judge it: a track fits
//! narrower than a star).
//!
//! The lists are filled online: a blob ranked before the histogram settles is ranked
//! neutral, and the lists look its agreement up again at every later comparison (they keep
//! the key, not the verdict), so a round hit kept early gives its place to a star that
//! agrees once the common motion shows. What was dropped before is lost.
//!
//! Roll about the boresight trails the stars tangentially, their length growing with the
//! distance from the axis: no single block holds them, and the histogram settles only when
//! the stars of one part of the field align enough (those then rank first, the others as
//! at rest); a rolling frame at a flare's rate mostly keeps the round hits, as a frame
//! without the histogram does. Not handled: a histogram of the axis about the tangent to
//! the boresight would find it, at a second histogram's cost.
//!
//! # Cost
//! State: 16 x 6 block counters, 6 band totals and 6 block maxima, about 230 bytes. An
//! elongated blob's key: a few compares and divides and one square root, no trigonometry.
//! A vote: nine increments and compares, and the six bands' significance tests (a few
//! multiplies and a compare each); a lookup ([`CommonMotion::agreement`]): two compares.

/// A blob is elongated (may vote, and may agree) from this trail, px: the acquisition's
/// trailed-test screen.
pub const MIN_TRAIL_PX: f32 = 1.5;

/// An elongated blob votes only when its image is at least this wide across its axis (the
/// covariance's smaller eigenvalue), px^2: a star is as wide across its trail as the optics
/// make a still star (the flight PSF, 80 % radius 1.2 px: 0.45 px^2 before the join
/// threshold trims its wings), while a proton's charge spreads by diffusion only, its
/// track about the pixel's own width across (1/12 px^2 along a row or column, 1/6 along a
/// diagonal) plus the diffusion's (0.3 px on the SIL's model: 0.09 px^2). Narrower blobs
/// still get a key and may agree; they do not build the histogram. With optics sharper
/// than this no star votes, nothing settles and the lists rank as at rest.
pub const MIN_ACROSS_PX2: f32 = 0.3;

/// Axis bins over 180 degrees.
pub const ORIENT_BINS: usize = 16;

/// Length bins, each a factor 1.5 wide from [`MIN_TRAIL_PX`] (the last open-ended: 11.4 px
/// and longer).
pub const LEN_BINS: usize = 6;

/// The length bins' lower edges to the fourth power, px^4 (1.5, 2.25, 3.38, 5.06, 7.59,
/// 11.39 px): a trail `L` has `L^4 = 144 ((xx - yy)^2 + 4 xy^2)`, no square root needed.
const LEN_EDGES_PX4: [f32; LEN_BINS] = [
    5.0625, 25.628_906, 129.746_34, 656.840_8, 3_325.257, 16_834.11,
];

/// The in-quadrant boundaries of the doubled axis angle's 22.5-degree sectors as a
/// diamond angle (`tan b / (1 + tan b)` at 22.5, 45 and 67.5 degrees).
const DIAMOND_EDGES: [f32; 3] = [
    1.0 - core::f32::consts::FRAC_1_SQRT_2,
    0.5,
    core::f32::consts::FRAC_1_SQRT_2,
];

/// Sigmas of the Poisson excess a common block must show over isotropic tracks.
const SETTLE_SIGMAS: f32 = 5.0;

/// Blobs a common block must hold beyond that excess (a few blobs never settle it).
const SETTLE_FLOOR: f32 = 4.0;

/// A blob's histogram cell: its trail's axis and length bins, or round (shorter than
/// [`MIN_TRAIL_PX`], or no finite moments); and whether it is wide enough across to vote
/// ([`MIN_ACROSS_PX2`], the top bit).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MotionKey(u8);

/// [`MotionKey`]'s bit for a blob wide enough across to vote.
const WIDE: u8 = 0x80;

impl MotionKey {
    /// A round blob (or one without moments).
    pub const ROUND: Self = Self(0);

    /// The key of a blob with covariance `(xx, yy, xy)`, px^2.
    pub fn of_covariance([xx, yy, xy]: [f32; 3]) -> Self {
        // The doubled axis angle's vector: its angle is twice the major axis's, its length
        // l1 - l2.
        let (c, s) = (xx - yy, 2.0 * xy);
        let l4 = 144.0 * (c * c + s * s);
        if !l4.is_finite() || l4 < LEN_EDGES_PX4[0] {
            return Self::ROUND;
        }
        let len = LEN_EDGES_PX4.iter().filter(|&&e| l4 >= e).count() - 1;
        // The diamond angle, monotonic in the true angle: quadrant q in [0, 4), then the
        // fraction of the quadrant.
        let (q, f) = if s >= 0.0 {
            if c > 0.0 {
                (0, s / (c + s))
            } else {
                (1, -c / (s - c))
            }
        } else if c < 0.0 {
            (2, -s / (-c - s))
        } else {
            (3, c / (c - s))
        };
        let sector = (4 * q + DIAMOND_EDGES.iter().filter(|&&e| f >= e).count()) % ORIENT_BINS;
        // The smaller eigenvalue: half the trace less half the doubled-angle vector's length.
        let across = 0.5 * (xx + yy) - 0.5 * libm::sqrtf(c * c + s * s);
        let wide = if across >= MIN_ACROSS_PX2 { WIDE } else { 0 };
        // At most 16 * 6 = 96: fits the low 7 bits with 0 kept for round.
        Self((1 + sector * LEN_BINS + len) as u8 | wide)
    }

    /// True when the blob is wide enough across its axis to vote ([`MIN_ACROSS_PX2`]).
    pub fn votes(self) -> bool {
        self.0 & WIDE != 0 && self.bins().is_some()
    }

    /// The axis and length bins; `None` when round.
    pub fn bins(self) -> Option<(usize, usize)> {
        let k = usize::from(self.0 & !WIDE).checked_sub(1)?;
        (k < ORIENT_BINS * LEN_BINS).then_some((k / LEN_BINS, k % LEN_BINS))
    }
}

/// How a blob stands against the frame's common motion (ordered: a list keeps the higher).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Agreement {
    /// Elongated off the common motion's axis or length: a track, a pair.
    Disagrees,
    /// Round, or no common motion is settled: ranked as without a histogram.
    Neutral,
    /// Elongated along the common motion's block of axis and length.
    Agrees,
}

/// The histogram of a frame's elongated blobs and its common block; see the module doc.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CommonMotion {
    /// The blobs in the 3 x 3 block of cells centred on each (axis, length) cell (the axis
    /// wraps, the length does not): a vote adds one to the nine blocks holding its cell.
    blocks: [[u16; LEN_BINS]; ORIENT_BINS],
    /// Each length bin's blobs over every axis.
    band: [u16; LEN_BINS],
    /// Each length bin's largest 3 x 3 block (centred on that length bin) and its axis bin.
    row_max: [(u16, u8); LEN_BINS],
    /// The settled block's centre (axis, length), if any.
    settled: Option<(u8, u8)>,
}

impl CommonMotion {
    /// No blobs: nothing agrees or disagrees.
    pub const EMPTY: Self = Self {
        blocks: [[0; LEN_BINS]; ORIENT_BINS],
        band: [0; LEN_BINS],
        row_max: [(0, 0); LEN_BINS],
        settled: None,
    };

    /// Forgets every blob (a new frame).
    pub fn clear(&mut self) {
        *self = Self::EMPTY;
    }

    /// Counts blob `key` (a round one, or one too narrow across to vote, counts nothing):
    /// one more in each of the nine blocks holding its cell.
    pub fn vote(&mut self, key: MotionKey) {
        let Some((o, l)) = key.bins().filter(|_| key.votes()) else {
            return;
        };
        if let Some(b) = self.band.get_mut(l) {
            *b = b.saturating_add(1);
        }
        for lc in l.saturating_sub(1)..=(l + 1).min(LEN_BINS - 1) {
            let Some(m) = self.row_max.get_mut(lc) else {
                continue;
            };
            for d_o in 0..3 {
                let oc = (o + ORIENT_BINS + d_o - 1) % ORIENT_BINS;
                if let Some(n) = self.blocks.get_mut(oc).and_then(|r| r.get_mut(lc)) {
                    *n = n.saturating_add(1);
                    if *n > m.0 {
                        *m = (*n, oc as u8);
                    }
                }
            }
        }
        self.settled = self.settle();
    }

    /// The block with the largest excess over isotropic axes among those that clear the
    /// test.
    fn settle(&self) -> Option<(u8, u8)> {
        let mut best: Option<(f32, u8, u8)> = None;

        for (l, &(n, o)) in self.row_max.iter().enumerate() {
            let band: u32 = (l.saturating_sub(1)..=(l + 1).min(LEN_BINS - 1))
                .map(|lc| u32::from(self.band.get(lc).copied().unwrap_or(0)))
                .sum();
            let mu = band as f32 * 3.0 / ORIENT_BINS as f32;
            let excess = f32::from(n) - mu - SETTLE_FLOOR;
            // excess >= SETTLE_SIGMAS sqrt(mu), squared.
            if excess >= 0.0
                && excess * excess >= SETTLE_SIGMAS * SETTLE_SIGMAS * mu
                && best.is_none_or(|(e, _, _)| excess > e)
            {
                best = Some((excess, o, l as u8));
            }
        }
        best.map(|(_, o, l)| (o, l))
    }

    /// True when a common motion is settled.
    pub fn is_settled(&self) -> bool {
        self.settled.is_some()
    }

    /// The settled common motion's trail: its axis (degrees from the +x axis towards +y, 0
    /// to 180, the bin's centre) and its length bin's lower edge, px; `None` when none is.
    pub fn trail(&self) -> Option<(f32, f32)> {
        let (o, l) = self.settled?;
        let deg = (f32::from(o) + 0.5) * 180.0 / ORIENT_BINS as f32;
        let len = LEN_EDGES_PX4.get(usize::from(l)).copied().unwrap_or(0.0);
        Some((deg, libm::sqrtf(libm::sqrtf(len))))
    }

    /// How blob `key` stands against the settled common motion ([`Agreement::Neutral`] for
    /// every blob while none is).
    pub fn agreement(&self, key: MotionKey) -> Agreement {
        let (Some((o0, l0)), Some((o, l))) = (self.settled, key.bins()) else {
            return Agreement::Neutral;
        };
        let (o0, l0) = (usize::from(o0), usize::from(l0));
        let d_o = (o + ORIENT_BINS - o0) % ORIENT_BINS;
        if (d_o <= 1 || d_o == ORIENT_BINS - 1) && l.abs_diff(l0) <= 1 {
            Agreement::Agrees
        } else {
            Agreement::Disagrees
        }
    }
}

impl Default for CommonMotion {
    fn default() -> Self {
        Self::EMPTY
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The covariance of a trail of length `l` px at `deg` degrees on a round PSF of
    /// variance 0.5 px^2.
    fn cov(l: f32, deg: f32) -> [f32; 3] {
        let (s, c) = libm::sincosf(deg.to_radians());
        let v = l * l / 12.0;
        [0.5 + v * c * c, 0.5 + v * s * s, v * s * c]
    }

    #[test]
    fn keys_bin_axis_and_length() {
        assert_eq!(MotionKey::of_covariance([0.5, 0.5, 0.0]), MotionKey::ROUND);
        assert_eq!(MotionKey::of_covariance(cov(1.4, 30.0)), MotionKey::ROUND);
        assert_eq!(
            MotionKey::of_covariance([f32::NAN, 0.5, 0.0]),
            MotionKey::ROUND
        );
        for i in 0..ORIENT_BINS {
            let deg = (i as f32 + 0.5) * 180.0 / ORIENT_BINS as f32;
            for (l, len) in [1.6f32, 2.5, 4.0, 6.0, 9.0, 30.0].into_iter().enumerate() {
                let k = MotionKey::of_covariance(cov(len, deg));
                assert_eq!(k.bins(), Some((i, l)), "{deg} deg {len} px");
                // The axis has no sign.
                assert_eq!(MotionKey::of_covariance(cov(len, deg + 180.0)), k);
            }
        }
    }

    #[test]
    fn narrow_blobs_do_not_vote() {
        let [xx, yy, xy] = cov(4.0, 30.0);
        // A track: its across variance a pixel's and the diffusion's, not the optics'.
        let track = MotionKey::of_covariance([xx - 0.33, yy - 0.33, xy]);
        let star = MotionKey::of_covariance([xx, yy, xy]);
        assert_eq!(track.bins(), star.bins());
        assert!(star.votes() && !track.votes());
        let mut m = CommonMotion::EMPTY;
        for _ in 0..100 {
            m.vote(track);
        }
        assert!(!m.is_settled());
        for _ in 0..20 {
            m.vote(star);
        }
        assert!(m.is_settled());
        assert_eq!(m.agreement(track), Agreement::Agrees);
    }

    /// A deterministic stream in [0, 1).
    fn lcg(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    #[test]
    fn random_tracks_never_settle() {
        let mut state = 7u64;
        for _ in 0..200 {
            let mut m = CommonMotion::EMPTY;
            for _ in 0..800 {
                let len = 1.5 + 20.0 * lcg(&mut state) * lcg(&mut state);
                m.vote(MotionKey::of_covariance(cov(len, 180.0 * lcg(&mut state))));
                assert!(!m.is_settled());
            }
        }
    }

    #[test]
    fn common_trails_settle_among_tracks_and_agree() {
        let mut state = 11u64;
        let mut m = CommonMotion::EMPTY;
        let star = MotionKey::of_covariance(cov(2.4, 70.0));
        let off = MotionKey::of_covariance(cov(2.4, 120.0));
        assert_eq!(m.agreement(star), Agreement::Neutral);
        for i in 0..400 {
            let len = 1.5 + 20.0 * lcg(&mut state) * lcg(&mut state);
            m.vote(MotionKey::of_covariance(cov(len, 180.0 * lcg(&mut state))));
            if i % 5 == 0 {
                let len = 1.8 + 1.2 * lcg(&mut state);
                m.vote(MotionKey::of_covariance(cov(
                    len,
                    66.0 + 8.0 * lcg(&mut state),
                )));
            }
        }
        assert!(m.is_settled(), "{m:?}");
        assert_eq!(m.agreement(star), Agreement::Agrees);
        assert_eq!(m.agreement(off), Agreement::Disagrees);
        assert_eq!(m.agreement(MotionKey::ROUND), Agreement::Neutral);
        let deg = m.trail().map(|t| t.0);
        assert!(deg.is_some_and(|d| (d - 70.0).abs() < 12.0), "{deg:?}");
    }
}
