//! The pixel-phase correction curves of table section 7: their byte format, their checks and
//! their evaluation `c(m)`. What a curve corrects, and how a centroid is corrected with it,
//! is told in [`crate::centroid::pixcorr`].
//!
//! A curve tabulates `c(m) = p(m) - m` for one `(a, box, power, background)` of the centre of
//! gravity: `m` the *measured* phase (position inside the central pixel), `p` the true one.
//! The host builds the curves from the exact pixel-integrated Gaussian in f64
//! (`startrack_sim::pixcorr`) and stores them with the calibration (section kind 7, see
//! [`crate::table`]); the firmware picks one with [`PixCorrSet::find`].
//!
//! # Format (compact, read in place)
//! One curve is an 8-byte header and `n` knots:
//! ```text
//! 0  u8   power (1 or 2)
//! 1  u8   box side (odd, 3..=MAX_CURVE_BOX_SIDE)
//! 2  u8   background the curve was made for (0 given, 1 perimeter mean, 2 perimeter median)
//! 3  u8   n, the number of knots (MIN_KNOTS..=MAX_KNOTS)
//! 4  u16  a, the PSF's 80 %-energy radius the curve was made for, U8F8 px (> 0)
//! 6  u16  m_max = m(1/2), the largest measured phase, U0F16 px (0 < m_max <= 1/2)
//! 8  n x i16  c(m_k), I1F15 px (range [-1, 1) px, step 2^-15 = 3.1e-5 px),
//!             at m_k = m_max k / (n - 1), k = 0..n-1; c(0) = 0
//! ```
//! Only the half phase `[0, m_max]` is stored: `c` is odd (mirror symmetry of the pixel).
//! A truncated CoG never reads past `m_max = m(1/2) < 1/2`: when the true centre crosses the
//! pixel edge the anchor moves to the neighbour and the reading jumps from `m_max` to
//! `1 - m_max`. 33 knots take 74 bytes.
//!
//! # Evaluation and cost
//! `m = x - round(x)` (the CoG is within `m_max` of its anchor, so `round(x)` is the anchor).
//! `c(|m|)` by a Catmull-Rom cubic through the four nearest knots (a ghost knot by the odd
//! symmetry at 0, a linear one past `m_max`), sign restored; past `m_max` (noise only) the
//! end value, slope 0. The error estimate
//! is scaled by the slope `dp/dm = 1 + c'(m)` of the same cubic. Per axis: a floor by integer
//! conversion, about 20 flops, four knot reads (I1F15 to f32 by one multiply); no division
//! (`(n - 1) / m_max`, the end knot and the ghost knot are computed once, by
//! [`PixCorr::parse`]). Measured inside `centroid_cog1c_7x7` and `centroid_cog1c_raw_7x7`
//! of `cargo m7-bench`.

use fixed::types::{U0F16, U8F8};

/// Largest box side a curve may be made for: the centroid methods' largest window side
/// (`centroid::MAX_SIDE`, which the centroid module checks equal at compile time).
pub const MAX_CURVE_BOX_SIDE: u8 = 31;

/// Weights of the centre of gravity, which a curve records as its power (the CoG of
/// [`crate::centroid::cog`] takes it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CogPower {
    /// Weights `F` (eq. 2): the most accurate at high SNR.
    One,
    /// Weights `F^2 - var` (eq. 6, noise-unbiased): fewer outliers at low SNR.
    Two,
}

/// Fewest knots a curve may have.
pub const MIN_KNOTS: u8 = 5;
/// Most knots a curve may have.
pub const MAX_KNOTS: u8 = 129;
/// Size of a curve's header in bytes.
pub const CURVE_HEADER_LEN: usize = 8;

/// The background source a curve was made for (it shapes the truncation part of the curve).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum PixCorrBackground {
    /// A level given by the caller ([`crate::centroid::Background::Given`]): the true level.
    Given = 0,
    /// The perimeter mean ([`crate::centroid::Background::PerimeterMean`]).
    PerimeterMean = 1,
    /// The perimeter median ([`crate::centroid::Background::PerimeterMedian`]).
    PerimeterMedian = 2,
}

impl PixCorrBackground {
    /// The kind with this code.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0 => Some(Self::Given),
            1 => Some(Self::PerimeterMean),
            2 => Some(Self::PerimeterMedian),
            _ => None,
        }
    }
}

/// What a curve corrects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CurveHeader {
    /// CoG weights.
    pub power: CogPower,
    /// Box side, px (odd).
    pub box_side: u8,
    /// Background source.
    pub background: PixCorrBackground,
    /// Number of knots over the half phase `[0, 1/2]`.
    pub knots: u8,
    /// PSF 80 %-energy radius, px (U8F8).
    pub a_px: U8F8,
    /// The largest measured phase `m(1/2)`, px (U0F16, in `(0, 1/2]`).
    pub phase_max_px: U0F16,
}

impl CurveHeader {
    /// Bytes the curve takes (header and knots).
    pub const fn encoded_len(&self) -> usize {
        CURVE_HEADER_LEN + 2 * self.knots as usize
    }

    /// The 8 header bytes.
    pub fn to_bytes(&self) -> [u8; CURVE_HEADER_LEN] {
        let a = self.a_px.to_bits().to_le_bytes();
        let m = self.phase_max_px.to_bits().to_le_bytes();
        let power = match self.power {
            CogPower::One => 1,
            CogPower::Two => 2,
        };
        [
            power,
            self.box_side,
            self.background as u8,
            self.knots,
            a[0],
            a[1],
            m[0],
            m[1],
        ]
    }
}

/// Why a curve is rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PixCorrError {
    /// Fewer bytes than the header and its knots need.
    TooShort,
    /// Power not 1 or 2.
    Power(u8),
    /// Box side even, below 3 or above [`MAX_CURVE_BOX_SIDE`].
    BoxSide(u8),
    /// Unknown background code.
    Background(u8),
    /// Knot count outside [`MIN_KNOTS`]`..=`[`MAX_KNOTS`].
    Knots(u8),
    /// PSF width 0.
    Width,
    /// `m_max` is 0 or above 1/2.
    PhaseMax,
    /// The first knot is not 0 (the symmetry requires it).
    FirstKnot,
}

impl core::fmt::Display for PixCorrError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooShort => f.write_str("pixel-phase curve truncated"),
            Self::Power(p) => write!(f, "pixel-phase curve: power {p} (1 or 2)"),
            Self::BoxSide(s) => write!(f, "pixel-phase curve: box side {s} (odd, 3..=31)"),
            Self::Background(b) => write!(f, "pixel-phase curve: background code {b}"),
            Self::Knots(n) => write!(f, "pixel-phase curve: {n} knots (5..=129)"),
            Self::Width => f.write_str("pixel-phase curve: PSF width 0"),
            Self::PhaseMax => f.write_str("pixel-phase curve: largest phase not in (0, 1/2]"),
            Self::FirstKnot => f.write_str("pixel-phase curve: first knot not zero"),
        }
    }
}

impl core::error::Error for PixCorrError {}

/// One checked curve, borrowing its knots (little-endian `i16`, I1F15 px), with the
/// constants [`PixCorr::correction`] needs precomputed at parse time (so a curve parsed once
/// and reused costs no divide per call). A centroid is corrected with `PixCorr::apply`
/// ([`crate::centroid::pixcorr`]).
#[derive(Clone, Copy, Debug)]
pub struct PixCorr<'a> {
    header: CurveHeader,
    knots: &'a [u8],
    /// `m_max`, px.
    m_max: f32,
    /// `(n - 1) / m_max`: knot intervals per px of measured phase.
    scale: f32,
    /// The last stored knot, px (the value past `m_max`).
    last: f32,
    /// The ghost knot past the last: `2 c(n-1) - c(n-2)`, px.
    ghost: f32,
}

/// I1F15 bits to px: exact in f32 (the `fixed` conversion is a generic routine).
#[inline(always)]
fn i1f15(bits: i16) -> f32 {
    f32::from(bits) * (1.0 / 32_768.0)
}

/// `floor(v)` by integer conversion (libm's `floorf` is a call): exact for every finite f32
/// (values of magnitude 2^23 and above are integers already); 0 for NaN.
#[inline(always)]
fn floor_f32(v: f32) -> f32 {
    if v.abs() >= 8_388_608.0 {
        return v;
    }
    // |v| < 2^23: the conversion truncates towards zero and is exact back to f32.
    let t = v as i32 as f32;
    if t > v { t - 1.0 } else { t }
}

/// Reads knot `i` (bits) of a little-endian i16 slice.
fn knot_bits(knots: &[u8], i: usize) -> Option<i16> {
    let j = i.checked_mul(2)?;
    Some(i16::from_le_bytes([*knots.get(j)?, *knots.get(j + 1)?]))
}

impl<'a> PixCorr<'a> {
    /// Checks the curve at the start of `bytes`; returns it and the bytes it takes.
    pub fn parse(bytes: &'a [u8]) -> Result<(Self, usize), PixCorrError> {
        let h = bytes
            .get(..CURVE_HEADER_LEN)
            .ok_or(PixCorrError::TooShort)?;
        let byte = |i: usize| h.get(i).copied().unwrap_or(0);
        let power = match byte(0) {
            1 => CogPower::One,
            2 => CogPower::Two,
            p => return Err(PixCorrError::Power(p)),
        };
        let box_side = byte(1);
        if box_side < 3 || box_side.is_multiple_of(2) || box_side > MAX_CURVE_BOX_SIDE {
            return Err(PixCorrError::BoxSide(box_side));
        }
        let background =
            PixCorrBackground::from_code(byte(2)).ok_or(PixCorrError::Background(byte(2)))?;
        let knots = byte(3);
        if !(MIN_KNOTS..=MAX_KNOTS).contains(&knots) {
            return Err(PixCorrError::Knots(knots));
        }
        let a_bits = u16::from_le_bytes([byte(4), byte(5)]);
        if a_bits == 0 {
            return Err(PixCorrError::Width);
        }
        let m_bits = u16::from_le_bytes([byte(6), byte(7)]);
        if m_bits == 0 || m_bits > 0x8000 {
            return Err(PixCorrError::PhaseMax);
        }
        let header = CurveHeader {
            power,
            box_side,
            background,
            knots,
            a_px: U8F8::from_bits(a_bits),
            phase_max_px: U0F16::from_bits(m_bits),
        };
        let len = header.encoded_len();
        let data = bytes
            .get(CURVE_HEADER_LEN..len)
            .ok_or(PixCorrError::TooShort)?;
        if knot_bits(data, 0) != Some(0) {
            return Err(PixCorrError::FirstKnot);
        }
        let n = usize::from(knots);
        let last = i1f15(knot_bits(data, n - 1).unwrap_or(0));
        let before = i1f15(knot_bits(data, n - 2).unwrap_or(0));
        let m_max = header.phase_max_px.to_num::<f32>();
        Ok((
            Self {
                header,
                knots: data,
                m_max,
                scale: f32::from(knots - 1) / m_max,
                last,
                ghost: 2.0 * last - before,
            },
            len,
        ))
    }

    /// What the curve corrects.
    pub fn header(&self) -> CurveHeader {
        self.header
    }

    /// The stored knots: little-endian i16, I1F15 px.
    pub fn knot_bytes(&self) -> &'a [u8] {
        self.knots
    }

    /// Stored knot `k` in px (0 outside).
    #[inline(always)]
    fn stored(&self, k: usize) -> f32 {
        i1f15(knot_bits(self.knots, k).unwrap_or(0))
    }

    /// The correction `c(m)` and its slope `dc/dm` at measured phase `m` (px, taken modulo
    /// one pixel into `[-1/2, 1/2]`); `(0, 0)` for a non-finite `m`.
    pub fn correction(&self, m: f32) -> (f32, f32) {
        if !m.is_finite() {
            return (0.0, 0.0);
        }
        let m = m - floor_f32(m + 0.5);
        let (sign, u) = if m < 0.0 { (-1.0, -m) } else { (1.0, m) };
        if u >= self.m_max {
            return (sign * self.last, 0.0);
        }
        let last = usize::from(self.header.knots) - 1;
        // 0 <= t < n - 1 (up to rounding: k is capped so that k + 1 is a stored knot).
        let t = u * self.scale;
        let k = (t as usize).min(last - 1);
        let f = t - k as f32;
        // Ghost knots: c(-h) = -c(h) (odd symmetry) before the first, a linear continuation
        // past the last.
        let p0 = if k == 0 {
            -self.stored(1)
        } else {
            self.stored(k - 1)
        };
        let (p1, p2) = (self.stored(k), self.stored(k + 1));
        let p3 = if k + 2 > last {
            self.ghost
        } else {
            self.stored(k + 2)
        };
        let (b, c, d) = (
            0.5 * (p2 - p0),
            p0 - 2.5 * p1 + 2.0 * p2 - 0.5 * p3,
            1.5 * (p1 - p2) + 0.5 * (p3 - p0),
        );
        let value = p1 + f * (b + f * (c + f * d));
        let slope = (b + f * (2.0 * c + 3.0 * f * d)) * self.scale;
        (sign * value, slope)
    }
}

/// The curves of a table's pixel-phase section, read in place.
#[derive(Clone, Copy, Debug, Default)]
pub struct PixCorrSet<'a> {
    count: usize,
    bytes: &'a [u8],
}

impl<'a> PixCorrSet<'a> {
    /// Checks `count` curves back to back filling `bytes` exactly; on failure the index of
    /// the first bad curve and why (a length mismatch is reported on curve `count`).
    pub fn parse(count: usize, bytes: &'a [u8]) -> Result<Self, (usize, PixCorrError)> {
        let mut off = 0usize;
        for i in 0..count {
            let rest = bytes.get(off..).ok_or((i, PixCorrError::TooShort))?;
            let (_, len) = PixCorr::parse(rest).map_err(|e| (i, e))?;
            off += len;
        }
        if off != bytes.len() {
            return Err((count, PixCorrError::TooShort));
        }
        Ok(Self { count, bytes })
    }

    /// Number of curves.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True when there is no curve.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The curves in stored order.
    pub fn iter(&self) -> impl Iterator<Item = PixCorr<'a>> + 'a {
        let bytes = self.bytes;
        let mut off = 0usize;
        (0..self.count).map_while(move |_| {
            let (c, len) = PixCorr::parse(bytes.get(off..)?).ok()?;
            off += len;
            Some(c)
        })
    }

    /// The curve for this power, box and background whose PSF width is nearest `a_px`
    /// (a scan of the section: a few curves, a few header reads each).
    pub fn find(
        &self,
        power: CogPower,
        box_side: u8,
        background: PixCorrBackground,
        a_px: f32,
    ) -> Option<PixCorr<'a>> {
        self.iter()
            .filter(|c| {
                let h = c.header;
                h.power == power && h.box_side == box_side && h.background == background
            })
            .min_by(|x, y| {
                let dx = (x.header.a_px.to_num::<f32>() - a_px).abs();
                let dy = (y.header.a_px.to_num::<f32>() - a_px).abs();
                dx.total_cmp(&dy)
            })
    }
}
