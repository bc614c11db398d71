//! Gain and read noise per output by photon transfer (EMVA 1288 practice): for each pair of
//! frames of equal illumination, the mean signal above bias `mu` (ADU) and the temporal
//! variance `var = var(A - B) / 2` (ADU^2) over the output's active pixels, clipped at
//! [`CLIP_SIGMAS`] (defect pixels and hits left out, the cut corrected for); the difference
//! cancels every fixed pattern (column bias, PRNU, DSNU). Then
//! `var - var_bias = mu / gain` over the linear range (pairs below [`LINEAR_FRACTION`] of the
//! saturation signal, or of the ADC's range above bias when no pair saturates): the slope is
//! fitted through the origin, weighted by the variance's own error (`var sqrt(2 / N)`), and
//! the read noise is `gain sqrt(var_bias - 1/12)` (the 1/12 ADU^2 of the ADC's rounding taken
//! out).
//!
//! Saturation ([`saturation`]): of EMVA 1288's two readings of the saturation capacity (the
//! mean at the variance maximum of the photon transfer curve, or where the mean stops
//! rising), this is the second: the flat pairs in order of exposure, the first pair after
//! which a pair at least 1 % longer rises by less than [`PLATEAU_RISE`] starts the plateau,
//! and the full well is the plateau's mean in electrons through the gain. It is the level a
//! pixel's sample cannot pass on that output (the smaller of the pixel's full well and the
//! ADC's top), what a saturation threshold needs; the variance maximum lies a few percent
//! below it, where the pixels of highest response (PRNU) clip first. Its error is the
//! gain's: the plateau's mean over the output's pixels is exact to 1e-4. A ladder that stops
//! before the plateau gives no number (a note says by how much the mean still rose).
//!
//! Linearity error ([`linearity_error_pct`], EMVA 1288): the pairs whose mean is between
//! [`LINEARITY_RANGE`] (5 and 95 %) of the saturation signal, a straight line `a + b t` fitted
//! to mean against EXPTIME (the lamp is constant, so the exposure is the irradiation's
//! measure) by least squares, and the largest deviation from it relative to the line,
//! `max |mu - (a + b t)| / (a + b t)`, in percent. Its noise is the pair means' (about
//! `1 / sqrt(N mu)`, 1e-4 relative at 5 000 e- for 8 192 pixels); the lowest point weighs
//! most, as the deviation is relative.
//!
//! Error: the gain's relative standard error is about `sqrt(2 / (N pairs))` for `N` pixels per
//! output (0.06 % for the CCD47-20's 524 288 with 10 pairs). Cost: two passes over the pair's
//! active samples (mean, then variance).

use startrack_core::geometry::{Output, ReadoutGeometry, Segment};
use startrack_sim::fits::RawFrame;

/// Pairs whose mean is above this fraction of the saturation signal (of the ADC's range above
/// bias without one) are left out of the gain fit, the flat field and EPER (the linear
/// range, EMVA 1288's 70 %).
pub const LINEAR_FRACTION: f64 = 0.7;

/// A pair at least 1 % longer than the one before whose mean rises by less than this fraction
/// is on the plateau: the mean has stopped rising.
pub const PLATEAU_RISE: f64 = 0.001;

/// The linearity error's range of mean signal, as fractions of the saturation signal.
pub const LINEARITY_RANGE: (f64, f64) = (0.05, 0.95);

/// One pair's photon transfer point on one output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairPoint {
    /// Output amplifier.
    pub output: u8,
    /// Exposure of the pair, s.
    pub exptime_s: f64,
    /// Mean signal above the over-scan and the column bias, ADU.
    pub mean_adu: f64,
    /// Temporal variance, var(A - B) / 2, ADU^2.
    pub var_adu2: f64,
    /// Pixels used.
    pub pixels: usize,
}

/// Mean of the over-scan elements of `output` over the whole frame, ADU.
pub fn overscan_mean(frame: &RawFrame, g: &ReadoutGeometry, output: Output) -> f64 {
    let (s, e) = g.overscan_cols(output);
    let (mut sum, mut n) = (0.0, 0usize);
    for line in frame.lines() {
        for v in line.get(s..e).unwrap_or(&[]) {
            sum += f64::from(*v);
            n += 1;
        }
    }
    if n == 0 { 0.0 } else { sum / n as f64 }
}

/// True when raw (`col`, `line`) is an active pixel read by `output`.
pub fn active_of(g: &ReadoutGeometry, col: usize, line: usize, output: Output) -> bool {
    g.segment(col) == Some(Segment::Active)
        && line < usize::from(g.active_rows)
        && g.output_of_col(col) == output
}

/// The photon transfer point of the pair (`a`, `b`) on `output`; `column_bias_adu` is per raw
/// column.
pub fn pair_point(
    a: &RawFrame,
    b: &RawFrame,
    g: &ReadoutGeometry,
    output: Output,
    column_bias_adu: &[f64],
    exptime_s: f64,
) -> PairPoint {
    let (oa, ob) = (overscan_mean(a, g, output), overscan_mean(b, g, output));
    let cols: Vec<usize> = (0..g.line_len())
        .filter(|&c| active_of(g, c, 0, output))
        .collect();
    let rows = usize::from(g.active_rows).min(a.lines).min(b.lines);
    let (mut sum, mut n) = (0.0, 0usize);
    for l in 0..rows {
        let (Some(la), Some(lb)) = (a.line(l), b.line(l)) else {
            break;
        };
        for &c in &cols {
            let (x, y) = (
                f64::from(la.get(c).copied().unwrap_or(0)),
                f64::from(lb.get(c).copied().unwrap_or(0)),
            );
            let cb = column_bias_adu.get(c).copied().unwrap_or(0.0);
            sum += 0.5 * (x - oa + y - ob) - cb;
            n += 1;
        }
    }
    let nf = n.max(1) as f64;
    let mean = sum / nf;
    // The differences, clipped iteratively at CLIP_SIGMAS about their mean.
    let diffs: Vec<f64> = (0..rows)
        .filter_map(|l| Some((a.line(l)?, b.line(l)?)))
        .flat_map(|(la, lb)| {
            cols.iter().map(move |&c| {
                f64::from(la.get(c).copied().unwrap_or(0))
                    - f64::from(lb.get(c).copied().unwrap_or(0))
            })
        })
        .collect();
    let var = clipped_variance(&diffs);
    PairPoint {
        output: output.0,
        exptime_s,
        mean_adu: mean,
        var_adu2: var / 2.0,
        pixels: n,
    }
}

/// Pair differences further than this many sigmas from their mean are left out of the
/// variance (telegraph and hot pixels, cosmic-ray hits), and the variance is divided by the
/// share a normal distribution keeps inside the cut ([`clip_factor`]).
pub const CLIP_SIGMAS: f64 = 4.0;

/// Variance a normal distribution keeps when cut at `k` sigmas, as a fraction:
/// `1 - 2 k phi(k) / (2 Phi(k) - 1)` (0.99893 at 4 sigmas).
pub fn clip_factor(k: f64) -> f64 {
    let phi = (-0.5 * k * k).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let inside = libm::erf(k / std::f64::consts::SQRT_2);
    1.0 - 2.0 * k * phi / inside
}

/// Variance of `v` with three passes of clipping at [`CLIP_SIGMAS`], corrected for the cut.
pub fn clipped_variance(v: &[f64]) -> f64 {
    let stats = |lo: f64, hi: f64| {
        let (mut s, mut q, mut n) = (0.0, 0.0, 0usize);
        for &x in v.iter().filter(|x| (lo..=hi).contains(*x)) {
            s += x;
            q += x * x;
            n += 1;
        }
        let m = s / n.max(1) as f64;
        (m, (q - n as f64 * m * m) / (n as f64 - 1.0).max(1.0))
    };
    let (mut m, mut var) = stats(f64::MIN, f64::MAX);
    for _ in 0..3 {
        let band = CLIP_SIGMAS * var.max(0.0).sqrt();
        let (m2, v2) = stats(m - band, m + band);
        m = m2;
        var = v2 / clip_factor(CLIP_SIGMAS);
    }
    var
}

/// The photon transfer result of one output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputFit {
    /// Gain, e-/ADU.
    pub gain_e_per_adu: f64,
    /// Read noise, e- rms.
    pub read_noise_e: f64,
    /// Temporal variance of the bias pairs, ADU^2 (read noise and rounding).
    pub bias_var_adu2: f64,
    /// Pairs inside the linear range.
    pub pairs_fitted: usize,
}

/// Fits one output's gain and read noise from its flat points and its bias pair variance
/// (mean of the bias pairs); `top_adu` is the output's saturation signal (or the ADC's range
/// above bias without one), the points below [`LINEAR_FRACTION`] of it are fitted. `None`
/// when fewer than `min_pairs` points are in the linear range or the fit is not positive.
pub fn fit_output(
    flats: &[PairPoint],
    bias_var_adu2: f64,
    top_adu: f64,
    min_pairs: usize,
) -> Option<OutputFit> {
    let used: Vec<&PairPoint> = flats
        .iter()
        .filter(|p| p.mean_adu > 0.0 && p.mean_adu < LINEAR_FRACTION * top_adu)
        .collect();
    if used.len() < min_pairs {
        return None;
    }
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for p in &used {
        let w = 1.0 / (p.var_adu2 * p.var_adu2);
        let y = p.var_adu2 - bias_var_adu2;
        sxy += w * p.mean_adu * y;
        sxx += w * p.mean_adu * p.mean_adu;
    }
    let k = sxy / sxx;
    if !(k.is_finite() && k > 0.0) {
        return None;
    }
    let gain = 1.0 / k;
    let read_adu = (bias_var_adu2 - 1.0 / 12.0).max(0.0).sqrt();
    Some(OutputFit {
        gain_e_per_adu: gain,
        read_noise_e: gain * read_adu,
        bias_var_adu2,
        pairs_fitted: used.len(),
    })
}

/// Where one output's mean signal stops rising ([`saturation`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Saturation {
    /// Mean signal above bias on the plateau (the largest of its pairs), ADU.
    pub mean_adu: f64,
    /// Exposure of the plateau's first pair, s.
    pub exptime_s: f64,
}

/// Why a ladder gave no saturation: the mean still rose by `rise` (a fraction) from the pair
/// of `from_s` to the longest, `to_s` (both 0 with fewer than two exposures).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StillRising {
    /// Relative rise of the mean between the two longest exposures.
    pub rise: f64,
    /// The second longest exposure, s.
    pub from_s: f64,
    /// The longest exposure, s.
    pub to_s: f64,
}

/// The plateau of one output's flat points (any order): the first point after which a point
/// of an exposure at least 1 % longer rises by less than [`PLATEAU_RISE`]; its mean is the
/// largest from there on.
pub fn saturation(points: &[PairPoint]) -> Result<Saturation, StillRising> {
    let mut v: Vec<&PairPoint> = points.iter().filter(|p| p.exptime_s > 0.0).collect();
    v.sort_by(|a, b| a.exptime_s.total_cmp(&b.exptime_s));
    for (i, p) in v.iter().enumerate() {
        let next = v
            .get(i + 1..)
            .unwrap_or(&[])
            .iter()
            .find(|q| q.exptime_s >= 1.01 * p.exptime_s);
        if let Some(q) = next
            && p.mean_adu > 0.0
            && q.mean_adu < p.mean_adu * (1.0 + PLATEAU_RISE)
        {
            let top = v
                .get(i..)
                .unwrap_or(&[])
                .iter()
                .map(|q| q.mean_adu)
                .fold(f64::MIN, f64::max);
            return Ok(Saturation {
                mean_adu: top,
                exptime_s: p.exptime_s,
            });
        }
    }
    let n = v.len();
    match (n.checked_sub(2).and_then(|i| v.get(i)), v.last()) {
        (Some(a), Some(b)) if a.mean_adu > 0.0 => Err(StillRising {
            rise: b.mean_adu / a.mean_adu - 1.0,
            from_s: a.exptime_s,
            to_s: b.exptime_s,
        }),
        _ => Err(StillRising {
            rise: 0.0,
            from_s: 0.0,
            to_s: 0.0,
        }),
    }
}

/// EMVA 1288's linearity error of one output's flat points, percent, and the points it used:
/// those with a mean within [`LINEARITY_RANGE`] of `saturation_adu`. `None` with fewer than 3.
pub fn linearity_error_pct(points: &[PairPoint], saturation_adu: f64) -> Option<(f64, usize)> {
    let (lo, hi) = LINEARITY_RANGE;
    let used: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| {
            p.exptime_s > 0.0
                && p.mean_adu >= lo * saturation_adu
                && p.mean_adu <= hi * saturation_adu
        })
        .map(|p| (p.exptime_s, p.mean_adu))
        .collect();
    let line = fit_line(&used)?;
    let worst = used
        .iter()
        .map(|&(t, y)| {
            let f = line.0 + line.1 * t;
            if f > 0.0 {
                ((y - f) / f).abs()
            } else {
                f64::INFINITY
            }
        })
        .fold(0.0, f64::max);
    worst.is_finite().then_some((100.0 * worst, used.len()))
}

/// Least-squares line `y = a + b x` through (x, y) points: `Some((a, b))` with at least 3
/// points of distinct x.
pub fn fit_line(xy: &[(f64, f64)]) -> Option<(f64, f64)> {
    if xy.len() < 3 {
        return None;
    }
    let n = xy.len() as f64;
    let (mx, my) = xy
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / n, b + y / n));
    let (sxy, sxx) = xy.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    (sxx > 0.0).then(|| {
        let b = sxy / sxx;
        (my - b * mx, b)
    })
}
