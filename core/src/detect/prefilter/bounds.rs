//! The pre-filter's per-chunk bounds: for each chunk of [`CHUNK_PX`] columns, the raw level
//! `R` at or below which no regular pixel of the chunk can exceed its block's join threshold
//! (from the chunk's worst case: smallest column bias, smallest dark term, largest inverse
//! flat of its tiles on the row), and the two raw tests that use it: the quiet window
//! ([`window_quiet`], two samples per 32-bit word) and the exact mask ([`above_mask`]).
//! The method and why it is exact are in [`super`].
//!
//! # Cost
//! The bounds are recomputed when the tile row changes or the background is updated: per
//! chunk ~300 instructions on the M7 (two dark and two flat tiles, the f32 inverse and one or
//! two exact evaluations of the formula), ~2.3 a pixel at 8-row tiles. Each line then pays
//! one add and one shift per chunk for its `R`.

use super::{CHUNK_PX, ScanDetector};
use crate::calib::formula::{dark_16ths, pixel_bits_d as pixel_bits};
use crate::table::MapView;
use crate::units::{DarkRel, FlatInv, GainEPerAdu};

/// `ChunkBound::dcb` of a chunk that is not filtered: with any bias (< 2^20 in 1/16 ADU) its
/// `R` stays below -1, so every sample passes.
pub(super) const NO_FILTER: i32 = i32::MIN / 2;

/// Per chunk: the worst-case bound of the current tile row and background.
#[derive(Clone, Copy, Debug)]
pub(super) struct ChunkBound {
    /// Smallest column bias of the chunk, 1/16 ADU (|cb| < 2^15).
    pub(super) cb_min_16: i32,
    /// Output of the chunk; `None` when two outputs read it (not filtered).
    pub(super) output: Option<u8>,
    /// `d_max + cb_min_16` in 1/16 ADU, `d_max` the largest `d = 16 raw - offset` that cannot
    /// exceed the threshold (|.| < 2^22), or [`NO_FILTER`]: the line's
    /// `R = (dcb + 16 bias) >> 4` then costs one add and one shift.
    pub(super) dcb: i32,
    /// `1 - 2^k` of the quiet test's window (see [`window_quiet`]), with `2^k` the largest
    /// power of two at most half of `R + 1` for the line the bound was computed on, so the
    /// window stays valid while the bias moves by less than `R / 2`.
    pub(super) c1: i32,
    /// `!((2^k - 1) * 0x10001)`: the bits outside the window's low bits in both 16-bit
    /// lanes.
    pub(super) outside: u32,
}

impl<'t, const N: usize> ScanDetector<'t, N> {
    /// Recomputes each chunk's bound when the tile row changed or the background was updated.
    pub(super) fn update_bounds(&mut self, y: u16, [bias0, bias1]: [i32; 2], sat_m1: i32) {
        let t = self.cal.table();
        let (dl, fl) = (tile_log2(t.dark_map()), tile_log2(t.flat_map()));
        let key = (u32::from(y) >> dl, u32::from(y) >> fl);
        if self.bounds_key == Some(key) {
            return;
        }
        self.bounds_key = Some(key);
        if !self.thr_valid {
            self.thr = self
                .det
                .background()
                .thresholds(self.det.config().pixel_sigmas);
            self.thr_valid = true;
        }
        let ds = self.cal.dark_scale_bits();
        let width = self.width;
        let gains = [
            t.gain(crate::geometry::Output(0)),
            t.gain(crate::geometry::Output(1)),
        ];
        // First tile of row y in each map (row-major tiles).
        let (dmap, fmap) = (t.dark_map(), t.flat_map());
        let (drow, frow) = (tile_row_start(dmap, dl, y), tile_row_start(fmap, fl, y));
        for (c, bound) in self.chunks.iter_mut().enumerate() {
            let x0 = c * CHUNK_PX;
            if x0 >= width {
                break;
            }
            let x1 = (x0 + CHUNK_PX).min(width);
            let Some(out) = bound.output else {
                bound.dcb = NO_FILTER;
                (bound.c1, bound.outside) = (0, u32::MAX);
                continue;
            };
            // Worst case over the chunk's tiles on this row: smallest dark term, largest
            // inverse flat. The tiles by index, `x0 >> l ..= (x1 - 1) >> l` in the row's tile
            // range (x < active columns and y < active rows: the values `dark_rel` /
            // `flat_inv` give, without their per-pixel index and range checks).
            let (dt0, dt1) = (drow + (x0 >> dl), drow + ((x1 - 1) >> dl));
            let dark_min = (dt0..=dt1)
                .map(|i| {
                    let rel = dmap
                        .and_then(|m| m.tile_bits(i))
                        .map_or(DarkRel::ONE, |b| DarkRel::from_bits(b as u8));
                    dark_16ths(rel, ds)
                })
                .min()
                .unwrap_or(0);
            let (ft0, ft1) = (frow + (x0 >> fl), frow + ((x1 - 1) >> fl));
            let flat_max = (ft0..=ft1)
                .map(|i| {
                    fmap.and_then(|m| m.tile_bits(i))
                        .map_or(FlatInv::ONE, |b| FlatInv::from_bits(b as u16))
                })
                .max()
                .unwrap_or(FlatInv::ONE);
            let thr = self
                .thr
                .get(self.det.background().block_of(x0))
                .copied()
                .unwrap_or(i64::MAX);
            let [g0, g1] = gains;
            let gain = if out == 0 { g0 } else { g1 };
            bound.dcb = largest_quiet_d(thr, gain, dark_min, flat_max)
                .map_or(NO_FILTER, |d| d + bound.cb_min_16);
            // The quiet test's window for this line's R (any window is exact; one too wide
            // for a later line's R only sends its chunks to the exact mask).
            let bias = if c < self.split_chunk { bias0 } else { bias1 };
            let r = raw_threshold(bound, bias, sat_m1);
            let half = u32::try_from(r).map_or(0, |r| r.div_ceil(2));
            let span = if half == 0 {
                1
            } else {
                1u32 << (31 - half.leading_zeros())
            };
            bound.c1 = 1 - span as i32;
            bound.outside = !((span - 1) * 0x1_0001);
        }
    }
}

/// A map's `tile_log2` (16 without a map: every column in one tile).
pub(super) fn tile_log2(m: Option<MapView<'_>>) -> u8 {
    m.map_or(16, |m| m.header().tile_log2.min(16))
}

/// Index of the first tile of active row `y`'s tile row (row-major tiles; 0 without a map).
pub(super) fn tile_row_start(m: Option<MapView<'_>>, l: u8, y: u16) -> usize {
    m.map_or(0, |m| {
        (usize::from(y) >> l) * usize::from(m.header().tiles_x)
    })
}

/// The raw level at or below which no pixel of the chunk can be above the threshold, at
/// most `sat_m1` (below -1, or -1: every sample passes). `bias`: the chunk's output's bias
/// in 1/16 ADU.
#[inline(always)]
pub(super) fn raw_threshold(bound: &ChunkBound, bias: i32, sat_m1: i32) -> i32 {
    // offset = 16 bias + column bias; |dcb| < 2^22 or NO_FILTER, bias < 2^20: no overflow.
    // raw <= floor((d + off_min) / 16) implies 16 raw - offset <= d for every column.
    ((bound.dcb + bias) >> 4).min(sat_m1)
}

/// The pre-filter's fast test: true when every sample of `a` lies in
/// `base..=base + span - 1`, with `outside = !((span - 1) * 0x10001)`, `span` a power of two
/// and `base + span <= 65536`; so the chunk is quiet when `base + span - 1 <= R`.
///
/// Two samples per 32-bit word: `word - base * 0x10001` has each 16-bit lane equal to
/// `sample - base` when every sample lies in the window, and a lane bit at or above `k`
/// (`span = 2^k`) set otherwise (a lane above the window is at least `span`; a lane below
/// `base` borrows and wraps to at least `65536 - base >= span`; a borrow only disturbs a
/// lane that is already flagged). So an OR of those differences without a bit outside the
/// two lanes' low `k` bits proves every sample in the window: load, subtract and OR per
/// two samples.
#[inline(always)]
pub(super) fn window_quiet(a: &[u16; CHUNK_PX], base: u32, outside: u32) -> bool {
    let bb = base | (base << 16);
    let mut acc = 0u32;
    for p in a.as_chunks::<2>().0 {
        let [s0, s1] = *p;
        acc |= (u32::from(s0) | (u32::from(s1) << 16)).wrapping_sub(bb);
    }
    acc & outside == 0
}

/// The exact test: bit `i` set when sample `i` is above `r` (the sign of `r - sample`, both
/// fit i32). Out of line: inlined, the compiler kept the words loaded for
/// [`window_quiet`] on the stack for it (~8 stores a chunk).
#[inline(never)]
pub(super) fn above_mask(a: &[u16; CHUNK_PX], r: i32) -> u32 {
    let mut m = 0u32;
    for (i, &s) in a.iter().enumerate() {
        m |= ((r - i32::from(s)) as u32 >> 31) << i;
    }
    m
}

/// The largest `d` in the calibration's range (|d| < 2^21) with
/// `pixel_bits(d, gain, dark, flat) <= thr`, or `None` when the threshold is not positive
/// (a pixel at 0 e- or below might pass) or even the smallest `d` exceeds it.
///
/// Monotonicity makes every smaller `d` quiet too. A pixel with a larger dark term or a
/// smaller inverse flat (for a positive signal) calibrates lower, so `d` quiet for the worst
/// case is quiet for every pixel of the block; with a negative signal the result is at most
/// 0 <= `thr`.
fn largest_quiet_d(thr: i64, gain: GainEPerAdu, dark: i64, flat: FlatInv) -> Option<i32> {
    const D_MIN: i32 = -(1 << 21);
    const D_MAX: i32 = (1 << 21) - 1;
    if thr <= 0 {
        return None;
    }
    let e = |d: i32| i64::from(pixel_bits(d, gain, dark, flat));
    // The f32 inverse of the formula without its roundings,
    // d* = (thr 2^24 / flat + dark) 2^16 / gain, is where e(d) reaches thr; step below it
    // until the exact formula confirms (each failure doubles the step), so the result is
    // exact-safe whatever the float error. One or two exact evaluations when the estimate
    // holds. i64 to f32 is a library call on the M7, so
    // both go through i32 (saturated): a saturated estimate is only further from the limit,
    // which the stepping absorbs (the exact check decides, never the estimate).
    let to_f32 =
        |v: i64| i32::try_from(v).unwrap_or(if v < 0 { i32::MIN } else { i32::MAX }) as f32;
    let est = ((to_f32(thr) * 16_777_216.0 / f32::from(flat.to_bits()).max(1.0)) + to_f32(dark))
        * 65_536.0
        / (gain.to_bits() as f32).max(1.0);
    let d_est = if est.is_finite() {
        (est as i32).clamp(D_MIN, D_MAX)
    } else {
        D_MIN
    };
    // The estimate is within a unit or two of the limit (the f32 error and the formula's
    // roundings are each below one unit of d, 1/16 ADU): try just above it, then just
    // below, before stepping down (the first try that holds is the bound: the closer to the
    // limit, the fewer quiet chunks fail the pre-filter).
    for d in [
        d_est.saturating_add(1).min(D_MAX),
        d_est.saturating_sub(1).max(D_MIN),
    ] {
        if e(d) <= thr {
            return Some(d);
        }
    }
    let mut d = d_est;
    let mut step = 8i32;
    loop {
        d = d.saturating_sub(step).max(D_MIN);
        if e(d) <= thr {
            return Some(d);
        }
        if d == D_MIN {
            // Even the smallest d exceeds the threshold.
            return None;
        }
        step = step.saturating_mul(2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `window_quiet` and `above_mask` against their definitions on chunks around the edges
    /// of power-of-two windows ending at `r`: samples at `base - 1`, `base`, `r`, `r + 1`, 0
    /// and 65535 in either lane of a word, for `r` over the whole range.
    #[test]
    #[allow(clippy::indexing_slicing)]
    fn quiet_tests_are_exact() {
        let mut state = 0x1234_5678u32;
        let mut next = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            state >> 8
        };
        let mut checked = 0u32;
        let fixed: [i32; 14] = [
            -3, -1, 0, 1, 2, 3, 62, 63, 64, 1000, 1023, 1024, 65_533, 65_534,
        ];
        for i in 0..fixed.len() + 200 {
            // The edge cases, then random levels below the saturation level.
            let r = fixed
                .get(i)
                .copied()
                .unwrap_or_else(|| (next() % 65_535) as i32);
            let ru = r.max(0) as u32;
            // Any power-of-two window ending at r: the largest, or a random smaller one.
            let k_max = 31 - (ru + 1).leading_zeros();
            let k = if i % 2 == 0 {
                k_max
            } else {
                next() % (k_max + 1)
            };
            let span = 1u32 << k;
            let base = (ru + 1 - span) as i32;
            let keep = (span - 1) * 0x1_0001;
            let specials = [base - 1, base, base + 1, r - 1, r, r + 1, 0, 65_535];
            for _ in 0..200 {
                // Mostly inside the window, a few specials at random places.
                let mut a = [0u16; CHUNK_PX];
                for s in a.iter_mut() {
                    let v = if r >= 0 {
                        base + (next() % span) as i32
                    } else {
                        0
                    };
                    *s = v.clamp(0, 65_535) as u16;
                }
                for _ in 0..(next() % 3) {
                    let i = (next() as usize) % CHUNK_PX;
                    let v = specials[(next() as usize) % specials.len()];
                    a[i] = v.clamp(0, 65_535) as u16;
                }
                let want = a.iter().all(|&s| i32::from(s) <= r);
                let mask = a
                    .iter()
                    .enumerate()
                    .fold(0u32, |m, (i, &s)| m | (u32::from(i32::from(s) > r) << i));
                assert_eq!(above_mask(&a, r), mask, "r {r} chunk {a:?}");
                if r >= 0 {
                    // The fast test calls a chunk quiet exactly when every sample lies in
                    // base..=r (so never with a sample above r).
                    let quiet = window_quiet(&a, base as u32, !keep);
                    assert!(!quiet || want, "r {r} chunk {a:?}");
                    let inside = a.iter().all(|&s| (base..=r).contains(&i32::from(s)));
                    assert_eq!(quiet, inside, "r {r} span {span} chunk {a:?}");
                }
                checked += 1;
            }
        }
        assert_eq!(checked, 214 * 200);
    }
}
