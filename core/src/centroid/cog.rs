//! Centre of gravity (CoG) in an n x n box: power 1 (paper eq. 2) and power 2 (eq. 6).
//!
//! # Formula
//! With `F_k = pixel_k - background` on the usable pixels of the box (excluded pixels
//! skipped) and `dx_k` the pixel centre's column offset from the box anchor:
//! ```text
//! x = anchor + sum(dx_k w_k) / W,   W = sum(w_k)
//! power 1:  w_k = F_k
//! power 2:  w_k = F_k^2 - v_k,      v_k = F_k + var_bg + var_level
//! ```
//! The power-2 weight subtracts the pixel's noise variance so that it is unbiased:
//! `E[F^2] = mu^2 + var`, and with `var = mu + var_bg` (shot noise in electrons plus the
//! background's variance) `E[F^2 - F - var_bg] = mu^2` exactly. `F_k` itself (not
//! `max(F_k, 0)`) is used in `v_k` for that reason; `var_level` is the variance of the
//! background estimate, which every `F_k` also carries. Without the subtraction, noise
//! pulls a power-2 centroid towards the box centre.
//!
//! # Error estimate
//! First-order propagation of the per-pixel noise through the ratio, better than the paper's
//! eq. 7 (`sigma ~ 1/SNR`) because it accounts for the PSF width and the box:
//! ```text
//! sigma_x^2 = [ sum((dx_k - x)^2 Var(w_k)) + var_level (sum((dx_k - x) dw_k/dF))^2 ] / W^2
//! power 1:  Var(w_k) = max(F_k, 0) + var_bg,             dw/dF = 1
//! power 2:  Var(w_k) = (4 max(w_k, 0) + 2 v'_k) v'_k,    dw/dF = 2 F_k - 1
//! ```
//! (`v'_k = max(F_k, 0) + var_bg`; `4 mu^2 v + 2 v^2` is the variance of `F^2` for a Gaussian
//! `F`, and `w_k` estimates `mu^2` without bias.) The host test `centroid_cog_noise` checks it
//! against the measured scatter at SNR 10..100. Flux is the power-1 sum in the box; SNR is
//! `flux / sqrt(sum(v'_k) + n^2 var_level)` (eq. 8 with measured noise, plus the background
//! estimate's own error).
//!
//! # Cost
//! Per pixel: one i64 subtraction, one int-to-float conversion, ~10 multiply-adds (power 2:
//! ~14). Per star: one pass over the window for the peak, one for the perimeter (a sort of at
//! most 120 values for the median), 3 divides and one square root per axis: a 5x5 box with a
//! 7x7 median background is a few hundred flops (an operation count, not an M7 measurement).
//!
//! # Lean power-1 path
//! Power 1 on a box without excluded pixels (the common case) sums integers, not floats:
//! with `F` the exact `I26F6` difference pixel - level (bits, 1/64 e-) and `Q = max(F, 0)`,
//! it accumulates `sum F`, `sum dx F`, `sum dy F`, `sum Q`, `sum dx Q`, `sum dy Q`,
//! `sum dx^2 Q`, `sum dy^2 Q` in i64, row by row, and the terms of `var_bg` in the error
//! sums come from the box's closed-form moments (`sum dx^2 = rows * sum_cols dx^2`, ...). The
//! per-star step converts the eight sums to f32 and solves as above: a few tens of flops per
//! star, none per pixel. `F` is taken in i32, so each product is one 32x32->64
//! multiply-accumulate. 16-bit-derived pixels and levels are within ±21.1 M e- (1.35e9 bits),
//! so `F` can leave i32 only when a pixel and the level are of opposite signs and beyond
//! ±16.7 M e- each: such a box is detected by the subtraction's overflow
//! flag and handed to the f32 path. No sum overflows: `|F| <= 2^31`, `|d| <= 15` (box side
//! <= `MAX_SIDE`), `d^2 < 2^8`, at most 961 < 2^10 pixels: every sum is below
//! `2^31 * 2^8 * 2^10 = 2^49`.
//! The sums are exact, so the path is at least as accurate as the f32 one; the host tests
//! compare both against f64 references.
//!
//! # Where it fails
//! - Pixelisation: an S-curve bias in the pixel phase for small PSFs, worse for power 2
//!   (paper Figures 3 and 4). Measured RMS over phases (host test `centroid_cog`), 5x5 box:
//!   power 1: 0.049 px at a = 0.5, 0.007 at 0.75, < 0.001 at 1..1.5; power 2: 0.148 px at
//!   a = 0.5, 0.083 at 0.75, 0.033 at 1, 0.0015 at 1.5.
//! - Truncation: a PSF wide relative to the box is pulled towards the box centre (Figure 2):
//!   power 1, a = 2 px: 0.163 px (3x3), 0.047 (5x5), 0.006 (7x7); a = 3 px: 0.22, 0.13, 0.058.
//!   Power 2 truncates less (a = 2, 5x5: 0.005 px). A residual background error also pulls
//!   the estimate towards the box centre.
//! - Anchor on the brightest pixel: at low SNR the box can jump to a neighbour, an error of
//!   up to a pixel that the error estimate does not include.
//! - Excluded pixels in the box bias the centroid away from them (flagged).
//! - Power 2 at low SNR: `W` can be 0 or negative (DEGENERATE), and the ratio is noisy.

use super::math::{self, pos};
use super::pixel_box::PixelBox;
use super::prepared::{Measured, Prepared};
use super::{Background, Centroid, CentroidFlags, CentroidInput};
/// Weights of the centre of gravity (defined with the pixel-phase curve format, which records
/// the power a curve was made for).
use crate::table::pixcorr::CogPower;

/// Where the box is centred.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Anchor {
    /// On the brightest usable pixel of the window (the paper's choice under noise).
    Peak,
    /// On the window's centre pixel (the detector already centred the window).
    WindowCentre,
}

/// Parameters of [`cog`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CogParams {
    /// Weights.
    pub power: CogPower,
    /// Side of the box, pixels; an even side is rounded up to the next odd one, 0 is 1.
    pub box_side: u8,
    /// Where the box is centred.
    pub anchor: Anchor,
    /// Background source.
    pub background: Background,
}

impl CogParams {
    /// A box of `box_side` anchored on the peak, background from the perimeter median.
    pub const fn new(power: CogPower, box_side: u8) -> Self {
        Self {
            power,
            box_side,
            anchor: Anchor::Peak,
            background: Background::PerimeterMedian,
        }
    }
}

/// The centre of gravity of `input` (see the module docs).
pub fn cog(input: &CentroidInput<'_>, params: &CogParams) -> Centroid {
    let p = match Prepared::new(input, params.background) {
        Ok(p) => p,
        Err(c) => return c,
    };
    let anchor = match params.anchor {
        Anchor::Peak => p.peak(),
        Anchor::WindowCentre => Some(p.centre()),
    };
    let Some((ac, ar)) = anchor else {
        return p.degenerate(CentroidFlags::empty());
    };
    let (bx, clipped) = p.box_around(ac, ar, params.box_side);
    let extra = if clipped {
        CentroidFlags::EDGE_CLIPPED
    } else {
        CentroidFlags::empty()
    };
    match cog_in_box(&p, bx, (ac, ar), params.power) {
        Some(m) => p.finish(m, extra),
        None => p.degenerate(extra),
    }
}

/// Sums of one axis for the error propagation.
#[derive(Clone, Copy, Default)]
struct AxisSums {
    /// sum(d w)
    dw: f32,
    /// sum(d^2 Var(w)), sum(d Var(w))
    d2var: f32,
    dvar: f32,
    /// sum(d dw/dF)
    dg: f32,
}

impl AxisSums {
    fn add(&mut self, d: f32, w: f32, var_w: f32, g: f32) {
        self.dw += d * w;
        self.d2var += d * d * var_w;
        self.dvar += d * var_w;
        self.dg += d * g;
    }

    /// (offset, sigma) given the weight sum `wsum`, the Var(w) sum and the dw/dF sum.
    fn solve(&self, wsum: f32, var_sum: f32, g_sum: f32, var_level: f32) -> (f32, f32) {
        let x = self.dw / wsum;
        // sum((d - x)^2 Var) and sum((d - x) g), expanded; each term divided by W twice.
        let a = (self.d2var - 2.0 * x * self.dvar + x * x * var_sum).max(0.0);
        let b = self.dg - x * g_sum;
        let var = a / wsum / wsum + var_level * (b / wsum) * (b / wsum);
        (x, math::sqrt(var))
    }
}

/// A caller's PSF or weight sigma made usable: at least 0.1 px, 1 px when not finite.
/// True where a CoG's `sigma_x`, `sigma_y` are known to miss its error by more than 10 %
/// (the pull table of docs/accuracy.md, `startrack accuracy`), for a star of 80 % radius
/// `psf_a_px` in a `box_px` box: every CoG without its pixel-phase correction (the
/// pixelisation bias is not in the noise model: pulls up to 18 for power 1 in 3x3, 25 for
/// power 2 at a = 0.7 px); a corrected one whose box is under 3 a (truncation: pulls up to
/// 1.6); a corrected power-2 CoG in a box of 7 or more below SNR 15 (sigmas 15-20 % too
/// large).
pub fn sigma_unreliable(
    power: CogPower,
    box_px: u8,
    psf_a_px: f32,
    corrected: bool,
    snr: f32,
) -> bool {
    !corrected
        || f32::from(box_px) < 3.0 * psf_a_px
        || (power == CogPower::Two && box_px >= 7 && snr < 15.0)
}

pub(crate) fn usable_sigma_px(sigma_px: f32) -> f32 {
    if sigma_px.is_finite() {
        sigma_px.max(0.1)
    } else {
        1.0
    }
}

/// The CoG of the usable pixels of `bx` (window-relative); `None` when the weight sum
/// or the flux is not positive.
pub(crate) fn cog_in_box(
    p: &Prepared<'_>,
    bx: PixelBox,
    anchor: (u16, u16),
    power: CogPower,
) -> Option<Measured> {
    if power == CogPower::One && !p.flags.contains(CentroidFlags::EXCLUDED_PIXEL) {
        return cog1_lean(p, bx, anchor);
    }
    cog_in_box_f32(p, bx, anchor, power)
}

/// [`cog_in_box`] on per-pixel f32 sums: any power, excluded pixels skipped.
fn cog_in_box_f32(
    p: &Prepared<'_>,
    bx: PixelBox,
    anchor: (u16, u16),
    power: CogPower,
) -> Option<Measured> {
    let var_bg = p.bg.variance_e2;
    let var_level = p.bg.level_variance_e2;
    let (mut wsum, mut var_sum, mut g_sum) = (0.0f32, 0.0f32, 0.0f32);
    let (mut flux, mut flux_var, mut n) = (0.0f32, 0.0f32, 0u32);
    let (mut sx, mut sy) = (AxisSums::default(), AxisSums::default());
    for (col, row, f) in p.box_pixels(bx) {
        let v = p.variance(f);
        let (w, var_w, g) = match power {
            CogPower::One => (f, v, 1.0),
            CogPower::Two => {
                let w = f * f - (f + var_bg + var_level);
                (w, (4.0 * pos(w) + 2.0 * v) * v, 2.0 * f - 1.0)
            }
        };
        let dx = f32::from(col) - f32::from(anchor.0);
        let dy = f32::from(row) - f32::from(anchor.1);
        wsum += w;
        var_sum += var_w;
        g_sum += g;
        sx.add(dx, w, var_w, g);
        sy.add(dy, w, var_w, g);
        flux += f;
        flux_var += v;
        n += 1;
    }
    // No star: nothing usable, or a weight sum or flux that is not positive.
    if n == 0 || wsum.is_nan() || wsum <= 0.0 || flux.is_nan() || flux <= 0.0 {
        return None;
    }
    let (ox, sigx) = sx.solve(wsum, var_sum, g_sum, var_level);
    let (oy, sigy) = sy.solve(wsum, var_sum, g_sum, var_level);
    let nf = n as f32;
    let snr = flux / math::sqrt(flux_var + nf * nf * var_level).max(f32::MIN_POSITIVE);
    Some(Measured {
        col: f32::from(anchor.0) + ox,
        row: f32::from(anchor.1) + oy,
        flux_e: flux,
        snr,
        sigma_col: sigx,
        sigma_row: sigy,
    })
}

/// An integer sum as f32 from the two 32-bit halves of its magnitude (two `vcvt`s and a
/// multiply-add instead of the library's i64 conversion): correctly rounded below 2^32, and
/// within 1 ulp above (the low half's rounding error, < 2^8, is then below 2^-24 of it).
#[inline(always)]
fn sum_f32(v: i64) -> f32 {
    let m = v.unsigned_abs();
    let r = (m >> 32) as u32 as f32 * 4_294_967_296.0 + m as u32 as f32;
    if v < 0 { -r } else { r }
}

/// `sum(d)` and `sum(d^2)` of the offsets `d = lo - anchor ..= hi - anchor` of a box side.
fn offset_sums(lo: u16, hi: u16, anchor: u16) -> (f32, f32) {
    let (mut s1, mut s2) = (0i32, 0i32);
    for c in lo..=hi {
        let d = i32::from(c) - i32::from(anchor);
        s1 += d;
        s2 += d * d;
    }
    (s1 as f32, s2 as f32)
}

/// The power-1 CoG of a box without excluded pixels (the common case): the lean path of
/// [`cog_in_box`], same formula and result (see "Lean power-1 path" in the module docs).
fn cog1_lean(p: &Prepared<'_>, bx: PixelBox, anchor: (u16, u16)) -> Option<Measured> {
    let width = usize::from(p.width);
    // The level fits i32 (a median of i32 bits or a saturated given level); if it did not,
    // or a difference overflows i32 below, the general path takes the box.
    let Ok(bg) = i32::try_from(p.bg.level_bits) else {
        return cog_in_box_f32(p, bx, anchor, CogPower::One);
    };
    let (c0, c1) = (usize::from(bx.col0), usize::from(bx.col1));
    let dx0 = i32::from(bx.col0) - i32::from(anchor.0);
    // Exact sums in Electrons bits (1/64 e-): S = sum F, Q = sum max(F, 0), with d-moments.
    // F is i32 here, so every product is one 32x32->64 multiply-accumulate.
    let (mut s0, mut sx, mut sy) = (0i64, 0i64, 0i64);
    let (mut q0, mut qx, mut qy, mut qxx, mut qyy) = (0i64, 0i64, 0i64, 0i64, 0i64);
    let mut overflow = false;
    for (row, dy) in (bx.row0..=bx.row1).zip(i32::from(bx.row0) - i32::from(anchor.1)..) {
        let start = usize::from(row) * width;
        let line = p.pixels.get(start + c0..=start + c1)?;
        // Pass 1: F and its column moment.
        let (mut rs, mut rx) = (0i64, 0i64);
        for (dx, e) in (dx0..).zip(line) {
            let (f, o) = e.to_bits().overflowing_sub(bg);
            overflow |= o;
            rs += i64::from(f);
            rx += i64::from(dx) * i64::from(f);
        }
        // Pass 2: Q = max(F, 0) and its moments (F recomputed: cheaper than storing it).
        let (mut rq, mut rqx, mut rqxx) = (0i64, 0i64, 0i64);
        for (dx, e) in (dx0..).zip(line) {
            let f = e.to_bits().wrapping_sub(bg);
            let q = i64::from(f.max(0));
            rq += q;
            rqx += i64::from(dx) * q;
            rqxx += i64::from(dx * dx) * q;
        }
        let dy = i64::from(dy);
        s0 += rs;
        sx += rx;
        sy += dy * rs;
        q0 += rq;
        qx += rqx;
        qxx += rqxx;
        qy += dy * rq;
        qyy += dy * dy * rq;
    }
    if overflow {
        return cog_in_box_f32(p, bx, anchor, CogPower::One);
    }
    if s0 <= 0 {
        return None;
    }
    // Per star: the sums in e- and the background variance's closed-form box moments.
    const E: f32 = 1.0 / 64.0;
    let var_bg = p.bg.variance_e2;
    let var_level = p.bg.level_variance_e2;
    let (sdx, sdx2) = offset_sums(bx.col0, bx.col1, anchor.0);
    let (sdy, sdy2) = offset_sums(bx.row0, bx.row1, anchor.1);
    let ncols = f32::from(bx.col1 - bx.col0 + 1);
    let nrows = f32::from(bx.row1 - bx.row0 + 1);
    let n = ncols * nrows;
    let wsum = sum_f32(s0) * E;
    let var_sum = sum_f32(q0) * E + n * var_bg;
    let sxs = AxisSums {
        dw: sum_f32(sx) * E,
        d2var: sum_f32(qxx) * E + var_bg * nrows * sdx2,
        dvar: sum_f32(qx) * E + var_bg * nrows * sdx,
        dg: nrows * sdx,
    };
    let sys = AxisSums {
        dw: sum_f32(sy) * E,
        d2var: sum_f32(qyy) * E + var_bg * ncols * sdy2,
        dvar: sum_f32(qy) * E + var_bg * ncols * sdy,
        dg: ncols * sdy,
    };
    let (ox, sigx) = sxs.solve(wsum, var_sum, n, var_level);
    let (oy, sigy) = sys.solve(wsum, var_sum, n, var_level);
    let snr = wsum / math::sqrt(var_sum + n * n * var_level).max(f32::MIN_POSITIVE);
    Some(Measured {
        col: f32::from(anchor.0) + ox,
        row: f32::from(anchor.1) + oy,
        flux_e: wsum,
        snr,
        sigma_col: sigx,
        sigma_row: sigy,
    })
}
