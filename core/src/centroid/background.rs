//! Where a centroid's background comes from ([`Background`]), what an estimate holds
//! ([`BackgroundEstimate`]), and how the border ring of a window becomes one: its mean and
//! sample variance, or its median and median absolute deviation (the model is told in
//! [`super`], "Background and noise"). The ring itself is walked by `Prepared`.
//!
//! # Cost
//! Mean: two passes over the ring (at most 116 pixels for a 31x31 window), one divide.
//! Median: two selections (`select_nth_unstable`, O(n) on average) of the ring's values, the
//! median's then the deviations'.

/// Where the background level and its per-pixel variance come from.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Background {
    /// Mean and sample variance of the window's border pixels (excluded pixels skipped).
    PerimeterMean,
    /// Median of the border pixels, variance from their median absolute deviation
    /// (`(1.4826 MAD)^2`): robust to a star's wing or a cosmic ray on the border.
    PerimeterMedian,
    /// Given by the caller (the detector's estimate), taken as exact.
    Given {
        /// Background level, e- per pixel.
        level_e: f32,
        /// Per-pixel variance of the background (read noise, sky and dark noise), e-^2.
        variance_e2: f32,
    },
}

/// A background estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BackgroundEstimate {
    /// Level, e- per pixel, in `Electrons` bits (1/64 e-; [`Self::level_e`] outside the
    /// crate).
    pub(crate) level_bits: i64,
    /// Per-pixel variance of the background, e-^2.
    pub variance_e2: f32,
    /// Variance of the level estimate itself (shared by every pixel), e-^2.
    pub level_variance_e2: f32,
}

impl BackgroundEstimate {
    /// Level in e-.
    pub(crate) fn level_e(&self) -> f32 {
        self.level_bits as f32 / 64.0
    }
}

/// f32 level in e- to `Electrons` bits, saturating, NaN to 0.
pub(crate) fn level_to_bits(level_e: f32) -> i64 {
    let b = level_e * 64.0;
    let r = if b >= 0.0 { b + 0.5 } else { b - 0.5 };
    // `as` saturates at the i32 range and maps NaN to 0.
    i64::from(r as i32)
}

/// A finite, non-negative f32 or 0.
pub(crate) fn sanitize_var(v: f32) -> f32 {
    if v.is_finite() && v > 0.0 { v } else { 0.0 }
}

/// The two middle order statistics of a non-empty slice, `(v[(n-1)/2], v[n/2])` of the
/// sorted order (equal for an odd length), found by selection (`select_nth_unstable`,
/// introselect: O(n) on average, no full sort), reordering `v`.
fn middle_pair<T: Ord + Copy>(v: &mut [T]) -> Option<(T, T)> {
    let n = v.len();
    if n == 0 {
        return None;
    }
    let (left, hi, _) = v.select_nth_unstable(n / 2);
    let hi = *hi;
    // For an even length the lower middle value is the largest of the left part.
    let lo = if n.is_multiple_of(2) {
        left.iter().copied().max().unwrap_or(hi)
    } else {
        hi
    };
    Some((lo, hi))
}

/// Mean and sample variance of a ring of pixel bits (`Electrons` bits; walked twice), the
/// mean rounded to the nearest bit; the level's own variance is `var / n`. `None` for an
/// empty ring. Inlined into `Prepared`'s mean (its one caller), as the median.
#[inline(always)]
pub(super) fn mean_estimate(ring: impl Iterator<Item = i64> + Clone) -> Option<BackgroundEstimate> {
    let (mut n, mut sum) = (0i64, 0i64);
    for b in ring.clone() {
        n += 1;
        sum += b;
    }
    if n == 0 {
        return None;
    }
    let mean = sum.div_euclid(n) + i64::from(2 * sum.rem_euclid(n) >= n);
    let ss: f32 = ring
        .map(|b| {
            let d = (b - mean) as f32 / 64.0;
            d * d
        })
        .sum();
    let var = if n > 1 {
        sanitize_var(ss / (n - 1) as f32)
    } else {
        0.0
    };
    Some(BackgroundEstimate {
        level_bits: mean,
        variance_e2: var,
        level_variance_e2: var / n as f32,
    })
}

/// Median of the ring's pixel bits `v` (reordered), variance from the median absolute
/// deviation (`(1.4826 MAD)^2`), the level's own variance `pi/2 var / n`. `None` for an
/// empty ring. Inlined into `Prepared`'s median (its one caller): out of line the call cost
/// ~15 instructions a star on the M7.
#[inline(always)]
pub(super) fn median_estimate(v: &mut [i32]) -> Option<BackgroundEstimate> {
    let n = v.len();
    let (lo, hi) = middle_pair(v)?;
    // Mean of the middle two, rounded towards minus infinity.
    let med = (i64::from(lo) + i64::from(hi)).div_euclid(2);
    // Absolute deviations in place (saturated at i32::MAX bits, 33.5 M e-: beyond the
    // calibrated range, and a MAD that large marks the window as useless anyway).
    for x in v.iter_mut() {
        *x = i32::try_from((i64::from(*x) - med).unsigned_abs()).unwrap_or(i32::MAX);
    }
    let (dlo, dhi) = middle_pair(v)?;
    let (dlo, dhi) = (dlo.unsigned_abs(), dhi.unsigned_abs());
    let mad_bits = (u64::from(dlo) + u64::from(dhi)) / 2;
    let mad = mad_bits as f32 / 64.0 * 1.4826;
    let var = if n > 1 { sanitize_var(mad * mad) } else { 0.0 };
    let level_var = var * core::f32::consts::FRAC_PI_2 / n as f32;
    Some(BackgroundEstimate {
        level_bits: med,
        variance_e2: var,
        level_variance_e2: level_var,
    })
}
