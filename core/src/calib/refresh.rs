//! In-flight refresh of the defect lists: new hot and telegraph pixels found in the windows
//! the tracker calibrates anyway, kept in a bounded candidate list, and the confirmed ones
//! applied to every later window as excluded pixels until a table update lists them.
//!
//! # Method
//! [`DefectWatch::observe`] takes one calibrated window (pixels, flags, the window's border
//! noise `sigma`) and the frame's star positions. A pixel is *watched* when it is inside
//! the window's border, it and its 8 neighbours carry no table flag (excluded, corrected
//! hot, saturated), and it lies at least [`WatchConfig::star_radius_px`] from every star
//! (3.5 px: the wing of the broadest tracked PSF, a = 2 px, is below 0.1 % of its peak
//! there, and what is left is smooth, which the neighbour median removes). For a watched
//! pixel `p` with 8-neighbour median `m` (the mean of the 4th and 5th values):
//! - its excess is `E = p - m`; it is a *hit* when `E > k sigma` ([`WatchConfig::hit_sigmas`],
//!   k = 5) and the pixel is isolated: the sum of its 4 neighbours' excesses `S4` is below
//!   `max(f E, 2 sigma_S4)`, `f` = [`WatchConfig::isolation`] = 0.15, half of the 0.31 E the
//!   4 neighbours of the sharpest star (a = 0.6 px, sigma 0.33 px, centred on the pixel)
//!   hold, and `sigma_S4 = 2.19 sigma` the noise of `S4` (so a noise-free hot pixel passes
//!   in 97.7 % of frames whatever its excess);
//! - a watched candidate with `E <= k sigma` is a *miss*, a *quiet* miss when also
//!   `E < quiet_sigmas sigma` (2): the low state of a telegraph pixel.
//!
//! Each sensor position is counted at most once a frame. A hit at a new position opens a
//! candidate; a candidate with `misses >= 2 hits + 2` is dropped (a cosmic ray: gone after
//! 4 misses). A candidate is confirmed *hot* with `hits >= N` ([`WatchConfig::confirm_hits`],
//! N = 4) and `hits >= 3 misses` (a hit fraction of at least 75 %). A confirmed pixel stays
//! watched and is re-classed *telegraph* once both `hits` and quiet misses reach
//! [`WatchConfig::telegraph_count`] (6); a telegraph pixel that spends 50 % of its frames
//! high is found directly that way without passing the hot test first.
//!
//! Why N = 4: `E` is the difference of a pixel and a median of 8, with variance
//! `sigma^2 (1 + pi / 16) = (1.094 sigma)^2`, so `E > 5 sigma` is a 4.57-sigma Gaussian tail:
//! `p = 2.4e-6` per watched pixel and frame. Thirty 11x11 windows watch ~1,300 pixels a
//! frame (44 of each window's 81 inner pixels lie 3.5 px or more from its star), ~0.003
//! false hits a frame. A false confirmation needs 4 hits in at most 5 frames at one
//! position: `5 p^4 = 1.7e-22` per position, below 1e-10 over a year of 10 Hz frames with
//! every watched pixel fresh each frame. Cosmic rays and faint untracked stars, not noise,
//! make most candidates: a cosmic ray does not recur, and a faint star drifting with the
//! field leaves the pixel before it recurs. A star held still on the detector (an inertial
//! hold) for more than N frames, faint enough (`S4` below `2 sigma_S4`, i.e. a peak below
//! ~14 sigma for a = 0.6 px centred on a pixel) and not tracked, can be confirmed: the
//! exclusion around the tracked stars covers only them.
//!
//! # Cost and memory
//! Per pixel inside the border: its lowest neighbour, which rules most pixels out (the
//! excess over it bounds `E`); for the others, the distance to the stars near the window
//! (at most `MAX_NEAR_STARS`), one sort of 8 values and the isolation sums; then a pass
//! over the candidates and confirmed pixels; the M7 count an 11x11 window is in
//! docs/calibration.md ("In orbit"). [`DefectWatch::apply`] is a pass over the confirmed
//! list. Memory: 16 B a candidate and 16 B a confirmed pixel, with the settings and
//! counters (the tracker's `DefectWatch<64, 32>`: docs/calibration.md).
//! No allocation, no recursion, no panic: a full list evicts its weakest candidate, a full
//! confirmed list counts what it could not keep.

use super::PixelFlags;
use crate::units::Electrons;
use crate::window::Rect;

/// Most stars near one window taken into account; a window with more is not watched.
pub(crate) const MAX_NEAR_STARS: usize = 16;
/// Most hits kept from one window (a window with more is a scene, not defects: the rest are
/// ignored).
const MAX_WINDOW_HITS: usize = 16;

/// The watch's settings (see the module docs for the reasoning behind the defaults).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WatchConfig {
    /// A hit needs an excess over the 8-neighbour median above this many noise sigmas (5).
    pub hit_sigmas: f32,
    /// A miss below this many sigmas is a quiet (low-state) miss (2).
    pub quiet_sigmas: f32,
    /// Isolation: the 4 neighbours' summed excess must stay below this fraction of the
    /// pixel's excess (or below 2 of its noise sigmas) (0.15).
    pub isolation: f32,
    /// Pixels closer than this to a star are not watched, px (3.5).
    pub star_radius_px: f32,
    /// Hits needed to confirm a hot pixel (4).
    pub confirm_hits: u16,
    /// Hits and quiet misses, each, that make a telegraph pixel (6).
    pub telegraph_count: u16,
}

impl WatchConfig {
    /// The defaults of the module docs.
    pub const DEFAULT: Self = Self {
        hit_sigmas: 5.0,
        quiet_sigmas: 2.0,
        isolation: 0.15,
        star_radius_px: 3.5,
        confirm_hits: 4,
        telegraph_count: 6,
    };
}

impl Default for WatchConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// What a confirmed pixel is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DefectKind {
    /// A steady excess.
    Hot,
    /// An excess that comes and goes (random telegraph signal).
    Telegraph,
}

/// A pixel position with its counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Defect {
    /// Active column.
    pub x_px: u16,
    /// Active row.
    pub y_px: u16,
    /// Frames with an isolated excess.
    pub hits: u16,
    /// Frames watched without one.
    pub misses: u16,
    /// Misses with hardly any excess (the low state of a telegraph pixel).
    pub quiet: u16,
    /// Hot or telegraph (for a candidate: `Hot`).
    pub kind: DefectKind,
    /// Frame of the last count.
    pub last_frame: u32,
}

impl Defect {
    fn opened(x_px: u16, y_px: u16, frame: u32) -> Self {
        Self {
            x_px,
            y_px,
            hits: 1,
            misses: 0,
            quiet: 0,
            kind: DefectKind::Hot,
            last_frame: frame,
        }
    }

    fn count(&mut self, obs: Observation, frame: u32) {
        match obs {
            Observation::Hit => self.hits = self.hits.saturating_add(1),
            Observation::Miss { quiet } => {
                self.misses = self.misses.saturating_add(1);
                if quiet {
                    self.quiet = self.quiet.saturating_add(1);
                }
            }
            Observation::Unclear => return,
        }
        self.last_frame = frame;
    }

    /// Weakness order: fewer hits, then more misses, then seen longer ago.
    fn strength(&self) -> (u16, u16, u32) {
        (self.hits, u16::MAX - self.misses, self.last_frame)
    }
}

/// One calibrated window as the watch sees it.
#[derive(Clone, Copy, Debug)]
pub struct WatchedWindow<'a> {
    /// Where the window lies on the active area.
    pub rect: Rect,
    /// `rect.len()` calibrated pixels, row-major.
    pub pixels_e: &'a [Electrons],
    /// One flag per pixel.
    pub flags: &'a [PixelFlags],
    /// The window's background noise, e- per pixel (the border's 1.4826 MAD).
    pub sigma_e: f32,
}

/// What the watch counted over its life.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WatchCounters {
    /// Windows observed.
    pub windows: u32,
    /// Windows refused (bad sizes, noise not positive, too many stars near).
    pub refused: u32,
    /// Candidates evicted by a full list (or new hits refused because every candidate was
    /// stronger).
    pub evicted: u32,
    /// Confirmed pixels not kept because the confirmed list was full.
    pub confirmed_lost: u32,
    /// Confirmed pixels dropped because the table in force now lists them.
    pub retired: u32,
    /// Pixels the overlay excluded (one a window it lay in).
    pub applied: u32,
}

/// The outcome at one watched position in one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Observation {
    Hit,
    Miss {
        quiet: bool,
    },
    /// Excess but not isolated: neither.
    Unclear,
}

/// The watch: up to `C` candidates and `D` confirmed pixels.
#[derive(Clone, Debug)]
pub struct DefectWatch<const C: usize, const D: usize> {
    config: WatchConfig,
    candidates: heapless::Vec<Defect, C>,
    confirmed: heapless::Vec<Defect, D>,
    counters: WatchCounters,
}

/// Flags that make a pixel unusable as a watched pixel or a neighbour.
const TABLE_FLAGS: PixelFlags = PixelFlags::SATURATED
    .union(PixelFlags::HOT_CORRECTED)
    .union(PixelFlags::HOT_EXCLUDED)
    .union(PixelFlags::TELEGRAPH)
    .union(PixelFlags::FOUND_IN_FLIGHT);

/// Flags the table sets for a pixel it lists.
const LISTED: PixelFlags = PixelFlags::HOT_CORRECTED
    .union(PixelFlags::HOT_EXCLUDED)
    .union(PixelFlags::TELEGRAPH);

/// Geometry of one window for the per-pixel test.
struct View<'a, 'w> {
    w: &'a WatchedWindow<'w>,
    stars: &'a [(f32, f32)],
    config: &'a WatchConfig,
}

impl View<'_, '_> {
    fn value(&self, c: usize, r: usize) -> Option<(i32, PixelFlags)> {
        let i = r * usize::from(self.w.rect.width) + c;
        Some((self.w.pixels_e.get(i)?.to_bits(), *self.w.flags.get(i)?))
    }

    /// The observation at window-relative (c, r); `None` when the pixel is not watched.
    /// With `hits_only`, a pixel that cannot be a hit (its excess over the lowest neighbour,
    /// an upper bound of `E`, is within `k sigma`) is a plain miss without the median's sort.
    fn observe(&self, c: usize, r: usize, hits_only: bool) -> Option<Observation> {
        let (wd, ht) = (
            usize::from(self.w.rect.width),
            usize::from(self.w.rect.height),
        );
        if c == 0 || r == 0 || c + 1 >= wd || r + 1 >= ht {
            return None;
        }
        let (x, y) = (
            f32::from(self.w.rect.x0) + c as f32,
            f32::from(self.w.rect.y0) + r as f32,
        );
        let r2 = self.config.star_radius_px * self.config.star_radius_px;
        if self
            .stars
            .iter()
            .any(|(sx, sy)| (sx - x) * (sx - x) + (sy - y) * (sy - y) < r2)
        {
            return None;
        }
        let (p, pf) = self.value(c, r)?;
        if pf.intersects(TABLE_FLAGS) {
            return None;
        }
        let mut n8 = [0i32; 8];
        for (slot, (dc, dr)) in n8.iter_mut().zip([
            (0, 0),
            (1, 0),
            (2, 0),
            (0, 1),
            (2, 1),
            (0, 2),
            (1, 2),
            (2, 2),
        ]) {
            let (v, f) = self.value(c + dc - 1, r + dr - 1)?;
            if f.intersects(TABLE_FLAGS) {
                return None;
            }
            *slot = v;
        }
        let sigma = self.w.sigma_e;
        let low = n8.iter().copied().min().unwrap_or(p);
        if hits_only
            && (i64::from(p) - i64::from(low)) as f32 / 64.0 <= self.config.hit_sigmas * sigma
        {
            return Some(Observation::Miss { quiet: false });
        }
        n8.sort_unstable();
        let m = (i64::from(*n8.get(3)?) + i64::from(*n8.get(4)?)) as f32 / 128.0;
        let excess = p as f32 / 64.0 - m;
        if excess <= self.config.hit_sigmas * sigma {
            return Some(Observation::Miss {
                quiet: excess < self.config.quiet_sigmas * sigma,
            });
        }
        let mut s4 = 0.0f32;
        for (dc, dr) in [(1, 0), (0, 1), (2, 1), (1, 2)] {
            let (v, _) = self.value(c + dc - 1, r + dr - 1)?;
            s4 += v as f32 / 64.0 - m;
        }
        // The noise of S4: four pixels less four times the median, 2 x 1.094 sigma.
        let limit = (self.config.isolation * excess).max(2.0 * 2.19 * sigma);
        Some(if s4 < limit {
            Observation::Hit
        } else {
            Observation::Unclear
        })
    }
}

impl<const C: usize, const D: usize> DefectWatch<C, D> {
    /// An empty watch.
    pub const fn new(config: WatchConfig) -> Self {
        Self {
            config,
            candidates: heapless::Vec::new(),
            confirmed: heapless::Vec::new(),
            counters: WatchCounters {
                windows: 0,
                refused: 0,
                evicted: 0,
                confirmed_lost: 0,
                retired: 0,
                applied: 0,
            },
        }
    }

    /// The confirmed pixels (the overlay), oldest first.
    pub fn confirmed(&self) -> &[Defect] {
        &self.confirmed
    }

    /// The unconfirmed candidates.
    pub fn candidates(&self) -> &[Defect] {
        &self.candidates
    }

    /// What the watch counted.
    pub fn counters(&self) -> WatchCounters {
        self.counters
    }

    /// Counts window `w` of frame `frame`; `stars_px` are the frame's star positions
    /// (active (x, y), px; those far from the window are skipped). Call it before
    /// [`Self::apply`], on the window as the table calibrated it.
    pub fn observe(&mut self, frame: u32, w: &WatchedWindow<'_>, stars_px: &[(f32, f32)]) {
        let rect = w.rect;
        let n = rect.len();
        if n == 0
            || w.pixels_e.len() != n
            || w.flags.len() != n
            || !w.sigma_e.is_finite()
            || w.sigma_e <= 0.0
        {
            self.counters.refused = self.counters.refused.saturating_add(1);
            return;
        }
        let reach = self.config.star_radius_px.max(0.0) + 1.0;
        let (x0, y0) = (f32::from(rect.x0) - reach, f32::from(rect.y0) - reach);
        let (x1, y1) = (
            f32::from(rect.x0) + f32::from(rect.width) + reach,
            f32::from(rect.y0) + f32::from(rect.height) + reach,
        );
        let mut near: heapless::Vec<(f32, f32), MAX_NEAR_STARS> = heapless::Vec::new();
        for s in stars_px {
            // A non-finite position excludes nothing it could not: skip it.
            if s.0 > x0 && s.0 < x1 && s.1 > y0 && s.1 < y1 && near.push(*s).is_err() {
                self.counters.refused = self.counters.refused.saturating_add(1);
                return;
            }
        }
        self.counters.windows = self.counters.windows.saturating_add(1);
        let view = View {
            w,
            stars: &near,
            config: &self.config,
        };
        let inside = |d: &Defect| {
            d.x_px >= rect.x0
                && d.y_px >= rect.y0
                && d.x_px - rect.x0 < rect.width
                && d.y_px - rect.y0 < rect.height
        };
        let at = |d: &Defect| {
            view.observe(
                usize::from(d.x_px - rect.x0),
                usize::from(d.y_px - rect.y0),
                false,
            )
        };
        // Confirmed pixels: counted, re-classed, retired when the table now lists them.
        let mut i = 0;
        while let Some(d) = self.confirmed.get_mut(i) {
            if inside(d) {
                let j = usize::from(d.y_px - rect.y0) * usize::from(rect.width)
                    + usize::from(d.x_px - rect.x0);
                if w.flags.get(j).is_some_and(|f| f.intersects(LISTED)) {
                    let _ = self.confirmed.swap_remove(i);
                    self.counters.retired = self.counters.retired.saturating_add(1);
                    continue;
                }
                if d.last_frame != frame {
                    if let Some(o) = at(d) {
                        d.count(o, frame);
                    }
                    if d.hits >= self.config.telegraph_count
                        && d.quiet >= self.config.telegraph_count
                    {
                        d.kind = DefectKind::Telegraph;
                    }
                }
            }
            i += 1;
        }
        // Candidates: counted, dropped, confirmed.
        let mut i = 0;
        while let Some(d) = self.candidates.get_mut(i) {
            if inside(d) && d.last_frame != frame {
                if let Some(o) = at(d) {
                    d.count(o, frame);
                }
                let d = *d;
                if d.misses >= d.hits.saturating_mul(2).saturating_add(2) {
                    let _ = self.candidates.swap_remove(i);
                    continue;
                }
                let telegraph =
                    d.hits >= self.config.telegraph_count && d.quiet >= self.config.telegraph_count;
                let hot = d.hits >= self.config.confirm_hits
                    && u32::from(d.hits) >= 3 * u32::from(d.misses);
                if hot || telegraph {
                    let _ = self.candidates.swap_remove(i);
                    let kind = if telegraph {
                        DefectKind::Telegraph
                    } else {
                        DefectKind::Hot
                    };
                    if self.confirmed.push(Defect { kind, ..d }).is_err() {
                        self.counters.confirmed_lost =
                            self.counters.confirmed_lost.saturating_add(1);
                    }
                    continue;
                }
            }
            i += 1;
        }
        // New positions: the window's hits that no list holds.
        let mut hits: heapless::Vec<(u16, u16), MAX_WINDOW_HITS> = heapless::Vec::new();
        // The sure misses first, on row slices: a pixel whose excess over its lowest
        // neighbour (an upper bound of `E`) is within `k sigma` cannot be a hit.
        let width = usize::from(rect.width);
        // In 1/64 e-, rounded down: the integer test below keeps every pixel the exact one
        // would (a difference at or below the floor is at or below the limit).
        let limit_bits = (self.config.hit_sigmas * w.sigma_e * 64.0).clamp(0.0, 2.0e9) as i64;
        'scan: for r in 1..usize::from(rect.height).saturating_sub(1) {
            let row = |k: usize| w.pixels_e.get(k * width..(k + 1) * width).unwrap_or(&[]);
            let rows = row(r - 1)
                .windows(3)
                .zip(row(r).windows(3))
                .zip(row(r + 1).windows(3));
            for (c, ((up, mid), down)) in rows.enumerate() {
                let ([u0, u1, u2], [m0, p, m2], [d0, d1, d2]) = (up, mid, down) else {
                    continue;
                };
                let low = u0
                    .min(u1)
                    .min(u2)
                    .min(m0)
                    .min(m2)
                    .min(d0)
                    .min(d1)
                    .min(d2)
                    .to_bits();
                if i64::from(p.to_bits()) - i64::from(low) <= limit_bits {
                    continue;
                }
                let c = c + 1;
                if view.observe(c, r, true) == Some(Observation::Hit) {
                    let x = rect.x0.saturating_add(c as u16);
                    let y = rect.y0.saturating_add(r as u16);
                    if hits.push((x, y)).is_err() {
                        break 'scan;
                    }
                }
            }
        }
        for (x, y) in hits {
            let known = |d: &Defect| d.x_px == x && d.y_px == y;
            if self.candidates.iter().any(known) || self.confirmed.iter().any(known) {
                continue;
            }
            self.open(Defect::opened(x, y, frame));
        }
    }

    /// Adds a new candidate, evicting the weakest when the list is full.
    fn open(&mut self, d: Defect) {
        if let Err(d) = self.candidates.push(d) {
            self.counters.evicted = self.counters.evicted.saturating_add(1);
            let weakest = self
                .candidates
                .iter()
                .enumerate()
                .min_by_key(|(_, c)| c.strength())
                .map(|(i, c)| (i, c.strength()));
            if let Some((i, s)) = weakest
                && s <= d.strength()
                && let Some(slot) = self.candidates.get_mut(i)
            {
                *slot = d;
            }
        }
    }

    /// Applies the confirmed pixels to a calibrated window: value 0 and
    /// [`PixelFlags::FOUND_IN_FLIGHT`]. Returns how many pixels it changed; a window with
    /// mismatched buffers is left alone.
    pub fn apply(
        &mut self,
        rect: Rect,
        pixels_e: &mut [Electrons],
        flags: &mut [PixelFlags],
    ) -> u16 {
        let n = rect.len();
        if pixels_e.len() != n || flags.len() != n {
            return 0;
        }
        let mut changed = 0u16;
        for d in self.confirmed.iter() {
            if d.x_px < rect.x0
                || d.y_px < rect.y0
                || d.x_px - rect.x0 >= rect.width
                || d.y_px - rect.y0 >= rect.height
            {
                continue;
            }
            let j = usize::from(d.y_px - rect.y0) * usize::from(rect.width)
                + usize::from(d.x_px - rect.x0);
            if let (Some(e), Some(f)) = (pixels_e.get_mut(j), flags.get_mut(j)) {
                *e = Electrons::ZERO;
                *f |= PixelFlags::FOUND_IN_FLIGHT;
                changed = changed.saturating_add(1);
            }
        }
        self.counters.applied = self.counters.applied.saturating_add(u32::from(changed));
        changed
    }

    /// Retires every confirmed pixel that `table` lists (hot or telegraph), wherever it lies:
    /// once a table update holds them, the overlay has nothing left to do for them. Returns
    /// how many were retired. Cost: a binary search of each list per confirmed pixel.
    pub(crate) fn retire_listed(&mut self, table: &crate::table::CalibTable<'_>) -> usize {
        let before = self.confirmed.len();
        let (hot, tel) = (table.hot_pixels(), table.telegraph_pixels());
        self.confirmed
            .retain(|d| hot.find(d.x_px, d.y_px).is_none() && !tel.contains(d.x_px, d.y_px));
        let n = before - self.confirmed.len();
        self.counters.retired = self
            .counters
            .retired
            .saturating_add(u32::try_from(n).unwrap_or(u32::MAX));
        n
    }

    /// True when a confirmed pixel lies in `rect`.
    pub(crate) fn touches(&self, rect: Rect) -> bool {
        self.confirmed.iter().any(|d| {
            d.x_px >= rect.x0
                && d.y_px >= rect.y0
                && d.x_px - rect.x0 < rect.width
                && d.y_px - rect.y0 < rect.height
        })
    }
}

impl<const C: usize, const D: usize> Default for DefectWatch<C, D> {
    fn default() -> Self {
        Self::new(WatchConfig::DEFAULT)
    }
}
