//! Tracking-mode detection: does a window predicted from the last frame's star still hold a
//! star?
//!
//! In tracking mode the firmware reads (and calibrates) only small windows around the stars
//! of the previous frame; this module decides, per window, whether the star is there.
//!
//! # Method
//! 1. Background and noise from the window's one-pixel border (the perimeter), robustly:
//!    `bg = median`, `sigma = 1.4826 MAD` over the border pixels that are neither excluded
//!    (hot by policy, telegraph) nor saturated; the level's own error is
//!    `var_level = (pi/2) sigma^2 / m` for `m` border pixels (the variance of a median).
//! 2. On the interior (the window less its border), `F = pixel - bg` (exact on the I26F6 bits,
//!    then f32). A pixel is *usable* unless it is excluded or a corrected hot pixel. Hot and
//!    telegraph pixels are never usable, so they never make a detection, whatever their value.
//! 3. The peak: the brightest usable interior pixel. The aperture (reported as `pixels`,
//!    so at least 1): the peak, and the pixels above `pixel_sigmas * sigma` (or saturated)
//!    8-connected to it. A faint star can pass the SNR test of step 4 with no pixel above
//!    the threshold: its aperture is then the peak alone.
//! 4. Flux and measured SNR in the `box_side` box around the peak (usable pixels, `n` of
//!    them), the paper's eq. 8 with the measured noise plus the level's error:
//!    `snr = S / sqrt(max(S, 0) + n sigma^2 + n^2 var_level)`, `S = sum(F)`. A fixed box, not
//!    the thresholded aperture, so that the SNR is not biased up by the pixels noise lifted.
//! 5. Spike rejection: a cosmic ray or an unlisted hot pixel is sharper than any star. With
//!    `e = min_sharpness * F_peak` the mean signal the 8 neighbours of the sharpest star would
//!    hold, the peak is a spike when their measured mean `f` is below it by more than
//!    `test_sigmas` of its error: `e - f > test_sigmas * sqrt((sigma^2 + e + var_level) / k)`
//!    over `k` usable neighbours (no usable neighbour: a spike). Faint stars pass (the test
//!    has no power at low SNR), bright lone pixels fail.
//! 6. Detected when `snr > min_snr` and the peak is not a spike.
//!
//! Flags ([`TrackFlags`]): saturated (a saturated interior pixel), edge (the window was
//! clipped at the active area's edge, or the peak sits next to the border: the star is
//! off-centre and its wing reaches the perimeter), an excluded pixel anywhere in the window,
//! low SNR (`snr < low_snr`), blended (a second peak, see below), no background (fewer than
//! [`MIN_BORDER_PX`] usable border pixels) and bad input.
//!
//! Blended: a usable interior pixel `q`, at least 2 px from the peak (Chebyshev), that is a
//! local maximum of its usable neighbours, exceeds `test_sigmas * sigma`, and rises above
//! the lowest usable pixel `m` on the straight path from the peak to it by more than
//! `test_sigmas` standard deviations of the difference:
//! `F_q - F_m > test_sigmas * sqrt(2 sigma^2 + max(F_q, 0) + max(F_m, 0))`.
//!
//! Measured (host test `track`, 9x9 windows, sigma_psf 1 px, 400 windows per point): noise
//! alone is detected in 0.5 % of windows; a star whose 3x3 core has true SNR 3, 4, 5, 6 in
//! 34, 68, 87, 97 %; pairs 4 px apart at 2:1 are flagged blended 100 %, single stars 0.3 %.
//!
//! # Cost
//! For an `n x n` window: two sorts of at most `4 n - 4` border values (median, then MAD;
//! the slice sort, O(m log m)); one pass over the interior for the peak;
//! the aperture by repeated forward/backward sweeps of a 32-bit-per-row mask (each sweep
//! ~10 integer operations per interior pixel; two or three sweeps for a compact star, at
//! most one per aperture pixel); the box and the 8 neighbours; for each interior local
//! maximum above `test_sigmas` a path of at most `n` pixels. About 2-4 k operations for 9x9. No
//! allocation, no recursion; the stack holds a `[i32; 120]` buffer and a `[u32; 31]` mask.
//!
//! # Where it fails
//! - A star whose wing covers more than half the border (the window too small for the PSF,
//!   or the star far off-centre) raises the median: the background is overestimated and the
//!   flux underestimated (flagged EDGE when the peak is next to the border).
//! - A faint star next to a bright one is flagged BLENDED only if the dip between them is
//!   significant; two stars closer than ~2 sigma_psf look like one.
//! - An unlisted hot pixel or a cosmic ray near the noise level passes the spike test (it has
//!   no power there); only the calibration table's hot-pixel list stops hot pixels reliably.
//! - Noise alone is detected with a small probability: the box sits on the brightest of the
//!   interior pixels, so its SNR is biased upwards on an empty window.
//! - A star off-centre in its pixel loses up to ~10 % of its 3x3 flux (sigma_psf 1 px), and
//!   the border median's own error adds `n^2 var_level` to the variance: for a 9x9 window
//!   the SNR is ~1.2 times lower than eq. 8 with the pixel noise alone.

use crate::calib::PixelFlags;
use crate::window::Window;

/// Largest window side accepted (the bitmask holds 32 columns; the centroid methods' limit).
pub(crate) const MAX_SIDE: u16 = crate::centroid::MAX_SIDE;
/// Fewest usable border pixels for a background estimate.
pub(crate) const MIN_BORDER_PX: usize = 5;
/// Largest border: `4 * MAX_SIDE - 4`.
const MAX_BORDER: usize = 4 * MAX_SIDE as usize - 4;

/// Tracking-detection settings.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackConfig {
    /// A pixel joins the aperture above this many noise sigmas (2.5, as the line detector).
    pub pixel_sigmas: f32,
    /// Side of the box around the peak whose signal gives the flux and the SNR (3).
    pub box_side: u8,
    /// Detected when the measured SNR (eq. 8) of the box exceeds this (3, as the paper).
    pub min_snr: f32,
    /// Below this SNR a result is flagged [`TrackFlags::LOW_SNR`] (5).
    pub low_snr: f32,
    /// Spike rejection: a peak whose 8 neighbours hold on average significantly less than
    /// this fraction of its signal is a cosmic ray or an unlisted hot pixel, not a star
    /// (0.07: half the 0.14 of the sharpest star the optics make, a Gaussian of
    /// sigma 0.5 px centred on a pixel; 0.51 at sigma 1 px).
    pub min_sharpness: f32,
    /// Significance (sigmas) of the spike test and of the dip between two peaks for
    /// [`TrackFlags::BLENDED`] (3).
    pub test_sigmas: f32,
}

impl TrackConfig {
    /// The defaults: the line detector's 2.5-sigma aperture, a 3x3 flux box, SNR above 3,
    /// low-SNR flag below 5, spike sharpness 0.07, 3-sigma spike and blend tests.
    pub(crate) const DEFAULT: Self = Self {
        pixel_sigmas: 2.5,
        box_side: 3,
        min_snr: 3.0,
        low_snr: 5.0,
        min_sharpness: 0.07,
        test_sigmas: 3.0,
    };
}

impl Default for TrackConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

bitflags::bitflags! {
    /// What tracking detection noticed about a window.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct TrackFlags: u8 {
        /// An interior pixel is saturated: flux is a lower bound.
        const SATURATED = 1;
        /// The window was clipped at the edge of the active area, or the peak is next to the
        /// border (the star is off-centre).
        const EDGE = 2;
        /// The window holds an excluded (hot by policy, or telegraph) pixel.
        const EXCLUDED_PIXEL = 4;
        /// SNR below the configured low-SNR level.
        const LOW_SNR = 8;
        /// A second significant peak: probably two stars.
        const BLENDED = 16;
        /// Too few usable border pixels to measure the background: nothing detected.
        const NO_BACKGROUND = 32;
        /// The window is smaller than 3x3, larger than [`MAX_SIDE`], or its pixel or flag
        /// slice has the wrong length: nothing detected.
        const BAD_INPUT = 64;
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for TrackFlags {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "TrackFlags({=u8:#x})", self.bits())
    }
}

/// The verdict on one window. Every field is finite.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TrackResult {
    /// A star is in the window.
    pub detected: bool,
    /// Column of the peak (active coordinates; the window's centre when there is none).
    pub peak_x: u16,
    /// Row of the peak.
    pub peak_y: u16,
    /// Background-subtracted signal of the aperture, e-.
    pub flux_e: f32,
    /// Measured SNR (eq. 8), 0 when nothing was measured.
    pub snr: f32,
    /// Aperture pixels.
    pub pixels: u16,
    /// Border median, e-.
    pub background_e: f32,
    /// Border noise (1.4826 MAD), e- per pixel.
    pub sigma_e: f32,
    /// Flags.
    pub flags: TrackFlags,
}

/// `f` when finite, else 0.
fn finite(f: f32) -> f32 {
    if f.is_finite() { f } else { 0.0 }
}

/// Decides whether `window` holds a star (see the module docs). `pixel_flags` is empty or
/// holds one flag per pixel, row-major; `clipped` says the window was cut by the active
/// area's edge.
pub fn track_detect(
    window: &Window<'_>,
    pixel_flags: &[PixelFlags],
    clipped: bool,
    config: &TrackConfig,
) -> TrackResult {
    let r = window.rect;
    let mut out = TrackResult {
        detected: false,
        peak_x: r.x0.saturating_add(r.width / 2),
        peak_y: r.y0.saturating_add(r.height / 2),
        flux_e: 0.0,
        snr: 0.0,
        pixels: 0,
        background_e: 0.0,
        sigma_e: 0.0,
        flags: if clipped {
            TrackFlags::EDGE
        } else {
            TrackFlags::empty()
        },
    };
    let (w, h) = (usize::from(r.width), usize::from(r.height));
    let n = r.len();
    if w < 3
        || h < 3
        || r.width > MAX_SIDE
        || r.height > MAX_SIDE
        || window.pixels_e.len() != n
        || !(pixel_flags.is_empty() || pixel_flags.len() == n)
    {
        out.flags |= TrackFlags::BAD_INPUT;
        return out;
    }
    let flag = |i: usize| pixel_flags.get(i).copied().unwrap_or_default();
    let bits = |i: usize| window.pixels_e.get(i).map_or(0, |e| e.to_bits());
    let on_border = |c: usize, rw: usize| c == 0 || rw == 0 || c + 1 == w || rw + 1 == h;
    if pixel_flags.iter().any(|f| f.is_excluded()) {
        out.flags |= TrackFlags::EXCLUDED_PIXEL;
    }

    // 1. Border median and MAD.
    let mut border = [0i32; MAX_BORDER];
    let mut m = 0usize;
    for i in 0..n {
        let (c, rw) = (i % w, i / w);
        let f = flag(i);
        if on_border(c, rw)
            && !f.is_excluded()
            && !f.contains(PixelFlags::SATURATED)
            && let Some(slot) = border.get_mut(m)
        {
            *slot = bits(i);
            m += 1;
        }
    }
    if m < MIN_BORDER_PX {
        out.flags |= TrackFlags::NO_BACKGROUND;
        return out;
    }
    let vals = border.get_mut(..m).unwrap_or(&mut []);
    // The slice sort (the instance the dark scale already links): i32 keys sort to one
    // order, so any sort gives the insertion sort's medians, in ~a third of its work for
    // an 11x11 window's 40 border values.
    vals.sort_unstable();
    let median = median_bits(vals);
    for v in vals.iter_mut() {
        // |v - median| < 2^32 fits i64; saturate into i32 (a MAD that large is meaningless).
        *v = (i64::from(*v) - median)
            .abs()
            .min(i64::from(i32::MAX))
            .try_into()
            .unwrap_or(i32::MAX);
    }
    vals.sort_unstable();
    let mad_e = median_bits(vals) as f32 / 64.0;
    let sigma = (1.4826 * mad_e).max(1.0 / 64.0);
    let var_bg = sigma * sigma;
    let var_level = core::f32::consts::FRAC_PI_2 * var_bg / m as f32;
    out.background_e = finite(median as f32 / 64.0);
    out.sigma_e = finite(sigma);

    // In f64 the difference of two i32 values is exact, and rounding it to f32 gives what
    // converting the i64 difference does, in the M7's hardware (it converts no 64-bit
    // integer: that is a library call).
    let median_f64 = median as f64;
    let signal = |i: usize| (f64::from(bits(i)) - median_f64) as f32 / 64.0;
    let usable = |i: usize| {
        let f = flag(i);
        !f.is_excluded() && !f.contains(PixelFlags::HOT_CORRECTED)
    };
    let saturated = |i: usize| flag(i).contains(PixelFlags::SATURATED);
    let thr = config.pixel_sigmas * sigma;
    let above = |i: usize| usable(i) && (saturated(i) || signal(i) > thr);

    // 2. The peak: brightest usable interior pixel.
    let mut peak: Option<(usize, i32)> = None;
    for i in 0..n {
        let (c, rw) = (i % w, i / w);
        if on_border(c, rw) || !usable(i) {
            continue;
        }
        if saturated(i) {
            out.flags |= TrackFlags::SATURATED;
        }
        if peak.is_none_or(|(_, b)| bits(i) > b) {
            peak = Some((i, bits(i)));
        }
    }
    let Some((p, _)) = peak else {
        return out;
    };
    let (pc, pr) = (p % w, p / w);
    out.peak_x = r.x0.saturating_add(pc as u16);
    out.peak_y = r.y0.saturating_add(pr as u16);
    if pc == 1 || pr == 1 || pc + 2 == w || pr + 2 == h {
        out.flags |= TrackFlags::EDGE;
    }
    // 3. The aperture: the peak, and above pixels 8-connected to it, by sweeps until stable.
    let mut mask = [0u32; MAX_SIDE as usize];
    if let Some(row) = mask.get_mut(pr) {
        *row = 1 << pc;
    }
    let interior = (w - 2) * (h - 2);
    for sweep in 0..interior {
        let mut changed = false;
        for k in 0..interior {
            // Alternate directions so that any path is followed in a few sweeps.
            let k = if sweep % 2 == 0 { k } else { interior - 1 - k };
            let (c, rw) = (1 + k % (w - 2), 1 + k / (w - 2));
            let i = rw * w + c;
            let bit = 1u32 << c;
            if mask.get(rw).is_some_and(|row| row & bit != 0) || !above(i) {
                continue;
            }
            let near = 7u32 << (c - 1);
            let touches = (rw - 1..=rw + 1).any(|y| mask.get(y).is_some_and(|row| row & near != 0));
            if touches && let Some(row) = mask.get_mut(rw) {
                *row |= bit;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    out.pixels = mask.iter().map(|row| row.count_ones() as u16).sum();

    // 4. Flux and SNR in the box around the peak (clipped to the window).
    let half = usize::from(config.box_side / 2);
    let (c1, r1) = ((pc + half).min(w - 1), (pr + half).min(h - 1));
    let (mut s, mut count) = (0.0f32, 0u16);
    for rw in pr.saturating_sub(half)..=r1 {
        for c in pc.saturating_sub(half)..=c1 {
            let i = rw * w + c;
            if usable(i) {
                s += signal(i);
                count += 1;
            }
        }
    }
    let nf = f32::from(count);
    let snr = finite(s / libm::sqrtf(s.max(0.0) + nf * var_bg + nf * nf * var_level).max(1e-30));
    out.flux_e = finite(s);
    out.snr = snr;
    if snr < config.low_snr {
        out.flags |= TrackFlags::LOW_SNR;
    }

    // 5. Spike test: the mean of the peak's usable neighbours against the sharpest star's.
    let fp = signal(p);
    let (mut nb_sum, mut nb_n) = (0.0f32, 0u16);
    for rw in pr - 1..=pr + 1 {
        for c in pc - 1..=pc + 1 {
            let i = rw * w + c;
            if i != p && usable(i) {
                nb_sum += signal(i);
                nb_n += 1;
            }
        }
    }
    let spike = nb_n == 0 || {
        let expected = config.min_sharpness * fp.max(0.0);
        let nb_mean = nb_sum / f32::from(nb_n);
        let sd = libm::sqrtf((var_bg + expected + var_level) / f32::from(nb_n));
        expected - nb_mean > config.test_sigmas * sd
    };
    out.detected = snr > config.min_snr && !spike;

    // 6. A second significant peak.
    if has_second_peak(w, h, p, &signal, &usable, config.test_sigmas, var_bg) {
        out.flags |= TrackFlags::BLENDED;
    }
    out
}

/// Median of a sorted non-empty slice, bits (mean of the middle two, rounded down).
fn median_bits(v: &[i32]) -> i64 {
    let n = v.len();
    let hi = i64::from(v.get(n / 2).copied().unwrap_or(0));
    if n % 2 == 1 {
        return hi;
    }
    let lo = i64::from(v.get(n / 2 - 1).copied().unwrap_or(0));
    (lo + hi).div_euclid(2)
}

/// True when the window has a significant second peak (see the module docs).
#[allow(clippy::too_many_arguments)]
fn has_second_peak(
    w: usize,
    h: usize,
    p: usize,
    signal: &dyn Fn(usize) -> f32,
    usable: &dyn Fn(usize) -> bool,
    blend_sigmas: f32,
    var_bg: f32,
) -> bool {
    let (pc, pr) = ((p % w) as isize, (p / w) as isize);
    let peak_thr = blend_sigmas * libm::sqrtf(var_bg);
    let at = |c: isize, r: isize| -> Option<usize> {
        (c >= 0 && r >= 0 && (c as usize) < w && (r as usize) < h)
            .then(|| r as usize * w + c as usize)
    };
    for qr in 1..h as isize - 1 {
        for qc in 1..w as isize - 1 {
            let steps = (qc - pc).abs().max((qr - pr).abs());
            let Some(q) = at(qc, qr) else { continue };
            if steps < 2 || !usable(q) {
                continue;
            }
            let fq = signal(q);
            if fq <= peak_thr {
                continue;
            }
            let is_max = (-1..=1).all(|dr| {
                (-1..=1).all(|dc| {
                    (dc == 0 && dr == 0)
                        || at(qc + dc, qr + dr).is_none_or(|j| !usable(j) || signal(j) <= fq)
                })
            });
            if !is_max {
                continue;
            }
            // Lowest usable pixel on the straight path between the two peaks.
            let mut low: Option<f32> = None;
            for k in 1..steps {
                let c = pc + ((qc - pc) * k * 2 + steps).div_euclid(2 * steps);
                let r = pr + ((qr - pr) * k * 2 + steps).div_euclid(2 * steps);
                if let Some(j) = at(c, r).filter(|&j| usable(j)) {
                    let f = signal(j);
                    low = Some(low.map_or(f, |l: f32| l.min(f)));
                }
            }
            let Some(fm) = low else { continue };
            let noise = libm::sqrtf(2.0 * var_bg + fq.max(0.0) + fm.max(0.0));
            if fq - fm > blend_sigmas * noise {
                return true;
            }
        }
    }
    false
}

#[cfg(test)]
mod tests {
    /// The window test's signal conversion: the i32 pixel less the i64 median through f64
    /// rounds to the f32 that converting the i64 difference gives, over the whole i32 range.
    #[test]
    fn f64_conversion_is_the_i64_conversion() {
        let mut seed = 0x9e37_79b9u32;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed as i32
        };
        let edges = [
            i32::MIN,
            i32::MIN + 1,
            -(1 << 24) - 1,
            -1,
            0,
            1,
            1 << 24,
            (1 << 24) + 3,
            i32::MAX,
        ];
        let pairs = edges
            .iter()
            .flat_map(|&b| edges.iter().map(move |&m| (b, m)))
            .collect::<heapless::Vec<(i32, i32), 81>>();
        for k in 0..200_000 {
            let (b, m) = pairs.get(k).copied().unwrap_or_else(|| (next(), next()));
            // The median: the floor of the mean of two i32 values, in i32's range.
            let median = (i64::from(m) + i64::from(b / 3)).div_euclid(2);
            let want = (i64::from(b) - median) as f32;
            let got = (f64::from(b) - median as f64) as f32;
            assert_eq!(got.to_bits(), want.to_bits(), "{b} {median}");
        }
    }
}
