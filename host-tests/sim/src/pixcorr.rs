//! Builds the core's pixel-phase correction curves ([`startrack_core::centroid::pixcorr`])
//! from the exact pixel-integrated Gaussian (paper eq. 3 and 5, f64, `libm::erf`).
//!
//! For a curve `(a, box, power, background)`: the noise-free CoG of a star at true phase `p`
//! (the other axis at phase 0) in a box anchored on the centre pixel, inside a window one
//! pixel wider on each side (the perimeter backgrounds' ring), gives the measured phase
//! `m(p)` on `[0, 1/2]`. With a given background each axis depends on its own phase only;
//! a perimeter background does not (the ring's level depends on both phases), so there `m(p)`
//! is the mean over 8 phases `q` across the axis, and the curve is refused
//! ([`BuildError::NotSeparable`]) when the residual over a grid of `(p, q)` exceeds
//! [`CROSS_AXIS_LIMIT_PX`] RMS: the star's wings reach the ring and no one-axis table
//! corrects it. Power 2 uses `E[F^2 - var] = F^2` of the noise-free pixel, which is
//! what the core's variance-subtracted weights estimate; with a perimeter background the
//! core also subtracts the ring's spread, which noise-free is the star's wing, and so does
//! this model. Where `m` is strictly increasing
//! (checked on a grid of 2001 phases, with a slope of at least [`MIN_SLOPE`]) each knot's
//! `p(m_k)` is found by bisection to 1e-12 px and stored as `c = p - m` in I1F15.
//!
//! Cost: in CoG evaluations of one window, 2001 for the monotonicity grid plus 60 bisection
//! steps per knot with a given background; eight times as many with a perimeter background
//! (one per cross-axis phase), plus 328 for its residual check, so a perimeter curve costs
//! about eight given ones. `time startrack calib build ... --psf-a-px A` against the same
//! command without `--psf-a-px` measures the curves of one width.

use crate::sim::psf::{pixel_fraction, sigma_of_a};
use fixed::types::{I1F15, U0F16, U8F8};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::{
    CurveHeader, MAX_KNOTS, MIN_KNOTS, PixCorr, PixCorrBackground,
};

/// Smallest slope `dm/dp` the builder accepts: a correction there multiplies the noise by at
/// most 1/0.05 = 20.
pub const MIN_SLOPE: f64 = 0.05;

/// The largest RMS residual (over true phases in both axes) a perimeter-background curve may
/// leave, px: two thirds of the 0.003 px required of the corrected CoG's systematic error,
/// to leave room for the rest.
pub const CROSS_AXIS_LIMIT_PX: f64 = 0.002;

/// Phases across the axis that a perimeter-background curve averages over: midpoints of 8
/// equal parts of the pixel.
fn cross_phases() -> impl Iterator<Item = f64> {
    (0..8).map(|i| -0.4375 + 0.125 * f64::from(i))
}

/// What to build a curve for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurveSpec {
    /// PSF 80 %-energy radius, px.
    pub a_px: f64,
    /// Box side, px (odd, 3..=29: the window is two pixels wider).
    pub box_side: u8,
    /// CoG weights.
    pub power: CogPower,
    /// Background source.
    pub background: PixCorrBackground,
    /// Knots over the half phase.
    pub knots: u8,
}

/// Why a curve cannot be built.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BuildError {
    /// Box side, knot count or width out of the format's range.
    Spec,
    /// `m(p)` is not increasing fast enough near this true phase (px): the CoG cannot be
    /// inverted there (e.g. power 2 on an undersampled PSF, a 3x3 box on a wide one).
    NotMonotone {
        /// Where, px.
        phase_px: f64,
        /// The slope dm/dp found there.
        slope: f64,
    },
    /// A correction does not fit I1F15.
    Range,
    /// A perimeter background's curve would leave this RMS residual (px) over true phases in
    /// both axes, more than [`CROSS_AXIS_LIMIT_PX`].
    NotSeparable {
        /// RMS residual, px.
        rms_px: f64,
    },
}

impl std::fmt::Display for BuildError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Spec => f.write_str("curve parameters out of range"),
            Self::NotMonotone { phase_px, slope } => write!(
                f,
                "the CoG is not invertible: slope dm/dp {slope:.3} at phase {phase_px:.3} px"
            ),
            Self::Range => f.write_str("correction out of the I1F15 range"),
            Self::NotSeparable { rms_px } => write!(
                f,
                "the perimeter background couples the axes: {rms_px:.4} px RMS left"
            ),
        }
    }
}

impl std::error::Error for BuildError {}

/// Median of a sorted, non-empty slice (mean of the middle two for an even length).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n.is_multiple_of(2) {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    } else {
        v[n / 2]
    }
}

/// The noise-free measured phase (px from the anchor, the centre pixel) of the CoG for a star
/// at true phase `p_x` along the axis and `p_y` across it.
pub fn measured_phase(spec: &CurveSpec, p_x: f64, p_y: f64) -> f64 {
    let s = sigma_of_a(spec.a_px);
    let half = i32::from(spec.box_side / 2);
    let wh = half + 1;
    let fx: Vec<f64> = (-wh..=wh)
        .map(|i| pixel_fraction(f64::from(i), p_x, s))
        .collect();
    let fy: Vec<f64> = (-wh..=wh)
        .map(|i| pixel_fraction(f64::from(i), p_y, s))
        .collect();
    let side = fx.len();
    let at = |c: usize, r: usize| fx[c] * fy[r];
    // Level and the variance the core subtracts from power-2 weights: noise-free, the ring's
    // spread is the star's wing, which the core takes for noise (flux-invariant: both scale
    // with the flux squared, like F^2).
    let (bg, var_sub) = match spec.background {
        PixCorrBackground::Given => (0.0, 0.0),
        kind => {
            let mut ring: Vec<f64> = (0..side)
                .flat_map(|r| (0..side).map(move |c| (c, r)))
                .filter(|&(c, r)| c == 0 || r == 0 || c + 1 == side || r + 1 == side)
                .map(|(c, r)| at(c, r))
                .collect();
            let n = ring.len() as f64;
            if kind == PixCorrBackground::PerimeterMean {
                let mean = ring.iter().sum::<f64>() / n;
                let var = ring.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
                (mean, var * (1.0 + 1.0 / n))
            } else {
                let med = median(&mut ring);
                let mut dev: Vec<f64> = ring.iter().map(|v| (v - med).abs()).collect();
                let var = (1.4826 * median(&mut dev)).powi(2);
                (med, var * (1.0 + std::f64::consts::FRAC_PI_2 / n))
            }
        }
    };
    let (mut sw, mut swx) = (0.0, 0.0);
    for r in 1..side - 1 {
        for c in 1..side - 1 {
            let f = at(c, r) - bg;
            let w = match spec.power {
                CogPower::One => f,
                CogPower::Two => f * f - var_sub,
            };
            sw += w;
            swx += w * (c as f64 - wh as f64);
        }
    }
    swx / sw
}

/// A built curve: its header, its knots in px (f64, before quantisation) and its bytes.
#[derive(Clone, Debug)]
pub struct Curve {
    /// The header as stored.
    pub header: CurveHeader,
    /// `c(m_k)`, px, exact.
    pub knots_px: Vec<f64>,
    /// Header and I1F15 knots, as the table stores them.
    pub bytes: Vec<u8>,
}

/// Builds the curve for `spec` (see the module docs).
pub fn build_curve(spec: &CurveSpec) -> Result<Curve, BuildError> {
    let valid = (3..=29).contains(&spec.box_side)
        && !spec.box_side.is_multiple_of(2)
        && (MIN_KNOTS..=MAX_KNOTS).contains(&spec.knots)
        && spec.a_px > 0.0
        && spec.a_px < 255.0;
    if !valid {
        return Err(BuildError::Spec);
    }
    let given = spec.background == PixCorrBackground::Given;
    let m = |p: f64| {
        if given {
            measured_phase(spec, p, 0.0)
        } else {
            cross_phases()
                .map(|q| measured_phase(spec, p, q))
                .sum::<f64>()
                / 8.0
        }
    };
    const GRID: usize = 2000;
    let mut prev = m(0.0);
    for i in 1..=GRID {
        let p = 0.5 * i as f64 / GRID as f64;
        let cur = m(p);
        let slope = (cur - prev) * 2.0 * GRID as f64;
        if slope.is_nan() || slope < MIN_SLOPE {
            return Err(BuildError::NotMonotone { phase_px: p, slope });
        }
        prev = cur;
    }
    let m_max = m(0.5);
    let n = usize::from(spec.knots);
    let mut knots_px = Vec::with_capacity(n);
    for k in 0..n {
        let target = m_max * k as f64 / (n - 1) as f64;
        let (mut lo, mut hi) = (0.0f64, 0.5f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if m(mid) < target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        knots_px.push(0.5 * (lo + hi) - target);
    }
    knots_px[0] = 0.0;
    let header = CurveHeader {
        power: spec.power,
        box_side: spec.box_side,
        background: spec.background,
        knots: spec.knots,
        a_px: U8F8::from_num(spec.a_px),
        phase_max_px: U0F16::checked_from_num(m_max).ok_or(BuildError::Range)?,
    };
    let mut bytes = header.to_bytes().to_vec();
    for c in &knots_px {
        let q = I1F15::checked_from_num(*c).ok_or(BuildError::Range)?;
        bytes.extend_from_slice(&q.to_bits().to_le_bytes());
    }
    if !given {
        let (curve, _) = PixCorr::parse(&bytes).map_err(|_| BuildError::Range)?;
        let (mut sum, mut n) = (0.0, 0.0);
        for i in 0..41 {
            let p = -0.49 + 0.98 * f64::from(i) / 40.0;
            for q in cross_phases() {
                let mp = measured_phase(spec, p, q);
                let (c, _) = curve.correction(mp as f32);
                sum += (mp + f64::from(c) - p).powi(2);
                n += 1.0;
            }
        }
        let rms_px = (sum / n).sqrt();
        if rms_px > CROSS_AXIS_LIMIT_PX {
            return Err(BuildError::NotSeparable { rms_px });
        }
    }
    Ok(Curve {
        header,
        knots_px,
        bytes,
    })
}

impl Curve {
    /// The curve as the core reads it.
    pub fn parsed(&self) -> Result<PixCorr<'_>, startrack_core::table::pixcorr::PixCorrError> {
        PixCorr::parse(&self.bytes).map(|(c, _)| c)
    }
}

/// Builds one curve per spec (any refusal is returned with the spec's index).
pub fn build_curves(specs: &[CurveSpec]) -> Result<Vec<Curve>, (usize, BuildError)> {
    specs
        .iter()
        .enumerate()
        .map(|(i, s)| build_curve(s).map_err(|e| (i, e)))
        .collect()
}

/// A whole calibration table: `spec`'s sections and a pixel-phase section holding `curves`
/// (a curve whose bytes were altered is reported with its index, never dropped).
pub fn write_table_with_curves(
    spec: &startrack_core::table::TableSpec<'_>,
    curves: &[Curve],
) -> Result<Vec<u8>, startrack_core::table::WriteError> {
    let parsed = curves
        .iter()
        .enumerate()
        .map(|(i, c)| {
            c.parsed().map_err(|error| {
                startrack_core::table::WriteError::Invalid(
                    startrack_core::table::TableError::PixCorrCurve {
                        index: i as u32,
                        error,
                    },
                )
            })
        })
        .collect::<Result<Vec<PixCorr<'_>>, _>>()?;
    let mut buf = vec![0u8; spec.encoded_len_with_pixcorr(&parsed)];
    let n = startrack_core::table::write_table_with_pixcorr(spec, &parsed, &mut buf)?;
    buf.truncate(n);
    Ok(buf)
}
