//! Charge-transfer inefficiency by extended pixel edge response (EPER) from the flats: the
//! charge that traps hold back from a uniformly lit area spills past its last edge in
//! readout order, into the extra store rows after the last active row (parallel) and into
//! the covered columns after the last active column (serial, when an output reads the line
//! to its far end: a single-output readout).
//!
//! # Why the edge gives the trap law directly
//! In a flat every pixel holds the same `q`; each defers the fraction `f(q, n)` of it (`n`
//! transfers) released over the next elements with weights `w_k`. Inside the area a pixel
//! loses `f q` and gains the same from its predecessors; past the edge nothing is lost, so
//! the first element after it holds `E_0 = f q` exactly and the next ones the tail
//! `E_j = f q sum_{k > j} w_k`. Hence `f = E_0 / q`, the weights are the differences of the
//! tail, and over the flats' signal levels `f / n = eps (q / q_ref)^-alpha` gives `eps` and
//! `alpha` by a log-linear fit ([`ChargeTraps`], the simulator's law, which
//! [`crate::cti::CtiExperiment::fit`] turns into the table's centroid coefficients).
//!
//! Levels: each line's over-scan median per output and the column bias (as the core
//! calibrates), then per frame and output the median over columns (parallel) or over active
//! lines (serial) of the element, so hot pixels do not pull it. The baseline of an edge
//! element is the same median over the covered columns of the same line (parallel: they are
//! dark too and their own trail is of their dark only) or over the far covered columns
//! (serial). Signal `q` is the median of the last 4 active rows (columns) before the edge.
//!
//! Cost: one pass over the extra lines and the edge columns of each flat, a median per
//! element; nothing with more than a line held.

use startrack_core::geometry::{Output, ReadoutGeometry};
use startrack_sim::fits::RawFrame;
use startrack_sim::sim::effects::ChargeTraps;

/// Edge elements measured after the last active row (column).
pub const TAIL: usize = 4;
/// Active rows (columns) before the edge whose median is the signal.
pub const SIGNAL_ROWS: usize = 4;
/// Reference charge of the fitted law, e-.
pub const REFERENCE_E: f64 = 1000.0;

/// The edge response of one flat on one output, ADU above the levels.
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeResponse {
    /// Output.
    pub output: u8,
    /// Signal of the lit area before the parallel edge, ADU.
    pub signal_adu: f64,
    /// The first [`TAIL`] extra lines above their baseline, ADU.
    pub parallel_adu: Vec<f64>,
    /// The first [`TAIL`] covered columns past the serial edge above the baseline, ADU (when
    /// the output reads past the far edge of the active area).
    pub serial_adu: Option<Vec<f64>>,
    /// Signal before the serial edge, ADU.
    pub serial_signal_adu: f64,
}

/// What EPER measured: the trap law and the points it was fitted to.
#[derive(Clone, Debug, PartialEq)]
pub struct EperResult {
    /// The trap law (serial fraction 0 when not measurable; one exponent, the parallel one).
    pub traps: ChargeTraps,
    /// True when the serial law was measured (a single-output readout).
    pub serial_measured: bool,
    /// Per flat and output: (signal e-, parallel fraction deferred per transfer, serial
    /// fraction per transfer or NaN).
    pub points: Vec<(f64, f64, f64)>,
    /// Mean release delay seen in the parallel tail, elements.
    pub mean_delay: f64,
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// Line `l`'s samples above their levels (over-scan median of each output, column bias), ADU.
fn leveled(f: &RawFrame, g: &ReadoutGeometry, l: usize, cb_adu: &[f64]) -> Option<Vec<f64>> {
    let line = f.line(l)?;
    let mut level = [0.0f64; 2];
    for (o, slot) in level.iter_mut().enumerate().take(usize::from(g.outputs)) {
        let (s, e) = g.overscan_cols(Output(o as u8));
        let mut v: Vec<f64> = line.get(s..e)?.iter().map(|x| f64::from(*x)).collect();
        *slot = median(&mut v)?;
    }
    Some(
        line.iter()
            .enumerate()
            .map(|(c, v)| {
                let o = usize::from(g.output_of_col(c).0);
                f64::from(*v) - level[o] - cb_adu.get(c).copied().unwrap_or(0.0)
            })
            .collect(),
    )
}

/// The edge response of flat `f` on every output; `None` for a readout without
/// [`TAIL`] extra lines.
pub fn edge_response(
    f: &RawFrame,
    g: &ReadoutGeometry,
    cb_adu: &[f64],
) -> Option<Vec<EdgeResponse>> {
    let rows = usize::from(g.active_rows);
    if usize::from(g.lines) < rows + TAIL || rows < SIGNAL_ROWS {
        return None;
    }
    let first = g.first_active_col();
    let cols = usize::from(g.active_cols);
    let [(cl0, cl1), (cr0, cr1)] = g.covered_cols();
    let mut out = Vec::new();
    for o in 0..g.outputs {
        let own = |c: &usize| g.output_of_col(*c).0 == o;
        let active: Vec<usize> = (first..first + cols).filter(own).collect();
        let covered: Vec<usize> = (cl0..cl1).chain(cr0..cr1).filter(own).collect();
        let pick = |line: &[f64], idx: &[usize]| -> Option<f64> {
            let mut v: Vec<f64> = idx.iter().filter_map(|&c| line.get(c).copied()).collect();
            median(&mut v)
        };
        let mut sig = Vec::new();
        for l in rows - SIGNAL_ROWS..rows {
            sig.push(pick(&leveled(f, g, l, cb_adu)?, &active)?);
        }
        let signal_adu = median(&mut sig)?;
        let mut parallel_adu = Vec::with_capacity(TAIL);
        for j in 0..TAIL {
            let line = leveled(f, g, rows + j, cb_adu)?;
            let base = pick(&line, &covered).unwrap_or(0.0);
            parallel_adu.push(pick(&line, &active)? - base);
        }
        // Serial: only when this output reads past the right end of the active area (a
        // single output reads the whole line from the left).
        let reads_right_edge = g.outputs == 1;
        let (serial_adu, serial_signal_adu) = if reads_right_edge && cr1 - cr0 >= 2 * TAIL {
            let mut tails = vec![Vec::new(); TAIL];
            let mut sigs = Vec::new();
            let mut bases = Vec::new();
            for l in 0..rows {
                let line = leveled(f, g, l, cb_adu)?;
                let base = {
                    let mut v: Vec<f64> = (cr0 + 2 * TAIL..cr1)
                        .filter_map(|c| line.get(c).copied())
                        .collect();
                    median(&mut v).unwrap_or(0.0)
                };
                bases.push(base);
                let mut s: Vec<f64> = (cr0 - SIGNAL_ROWS..cr0)
                    .filter_map(|c| line.get(c).copied())
                    .collect();
                sigs.push(median(&mut s)?);
                for (j, t) in tails.iter_mut().enumerate() {
                    t.push(line.get(cr0 + j).copied()? - base);
                }
            }
            let tail: Option<Vec<f64>> = tails.iter_mut().map(|t| median(t)).collect();
            (tail, median(&mut sigs).unwrap_or(0.0))
        } else {
            (None, 0.0)
        };
        out.push(EdgeResponse {
            output: o,
            signal_adu,
            parallel_adu,
            serial_adu,
            serial_signal_adu,
        });
    }
    Some(out)
}

/// Fits the trap law to the edge responses of the flats, with `gains` (e-/ADU per output)
/// and `read_noise_e` (per output). A flat counts only when its first edge element is above
/// 3 standard errors of its median: `1.25 sqrt(r^2 + E_0) / sqrt(columns)` (the median of
/// that many Gaussian values), so a sensor without measurable CTI gives no law rather than
/// one fitted to noise. `None` with fewer than 2 such flats or signal levels spanning less
/// than a factor 2.
pub fn fit(
    responses: &[EdgeResponse],
    gains: &[f64],
    read_noise_e: &[f64],
    g: &ReadoutGeometry,
) -> Option<EperResult> {
    let columns = f64::from(g.active_cols) / f64::from(g.outputs.max(1));
    let n_par = f64::from(g.active_rows);
    // The right end of the active area is read after this many serial transfers.
    let n_ser = (g.first_active_col() + usize::from(g.active_cols)) as f64;
    let mut pts = Vec::new();
    let (mut tail_sum, mut tail_w) = (vec![0.0; TAIL], 0.0);
    for r in responses {
        let gain = gains.get(usize::from(r.output)).copied()?;
        let q = r.signal_adu * gain;
        let e0 = r.parallel_adu.first().copied()? * gain;
        let read = read_noise_e
            .get(usize::from(r.output))
            .copied()
            .unwrap_or(0.0);
        let se = 1.25 * (read * read + e0.max(0.0)).sqrt() / columns.sqrt();
        if !(q > 0.0 && e0 > 3.0 * se) {
            continue;
        }
        let fs = r
            .serial_adu
            .as_ref()
            .and_then(|t| t.first())
            .map_or(f64::NAN, |e| {
                e * gain / (r.serial_signal_adu * gain) / n_ser
            });
        pts.push((q, e0 / q / n_par, fs));
        // The tail's shape, weighted by the edge signal.
        for (s, e) in tail_sum.iter_mut().zip(&r.parallel_adu) {
            *s += e * gain;
        }
        tail_w += e0;
    }
    let (lo, hi) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    if pts.len() < 2 || hi < 2.0 * lo {
        return None;
    }
    let loglaw = |sel: &dyn Fn(&(f64, f64, f64)) -> f64| -> Option<(f64, f64)> {
        let v: Vec<(f64, f64)> = pts
            .iter()
            .filter(|p| sel(p) > 0.0 && sel(p).is_finite())
            .map(|p| ((p.0 / REFERENCE_E).ln(), sel(p).ln()))
            .collect();
        if v.len() < 2 {
            return None;
        }
        let n = v.len() as f64;
        let (mx, my) = (
            v.iter().map(|p| p.0).sum::<f64>() / n,
            v.iter().map(|p| p.1).sum::<f64>() / n,
        );
        let sxx: f64 = v.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = v.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        Some(((my - slope * mx).exp(), -slope))
    };
    let (eps_par, alpha) = loglaw(&|p| p.1)?;
    // The serial law with the parallel exponent (one trap species): its level alone, the
    // geometric mean of f (q / q_ref)^alpha over the flats.
    let ser: Vec<f64> = pts
        .iter()
        .filter(|p| p.2 > 0.0 && p.2.is_finite())
        .map(|p| (p.2 * (p.0 / REFERENCE_E).powf(alpha)).ln())
        .collect();
    let serial = (ser.len() >= 2).then(|| (ser.iter().sum::<f64>() / ser.len() as f64).exp());
    // Tail t_j = E_j / E_0 = sum_{k > j} w_k: weights are its differences; the trail ends
    // where the tail stops falling (noise), the decay is w_2 / w_1.
    let t: Vec<f64> = tail_sum.iter().map(|s| s / tail_w).collect();
    let mut w: Vec<f64> = t
        .windows(2)
        .map(|p| p[0] - p[1])
        .chain(std::iter::once(*t.last()?))
        .collect();
    let trail = w.iter().position(|x| *x <= 0.02).unwrap_or(w.len()).max(1);
    w.truncate(trail);
    let decay = match (w.first(), w.get(1)) {
        (Some(a), Some(b)) if *a > 0.0 => (b / a).clamp(0.0, 1.0),
        _ => 0.0,
    };
    let mean_delay = t.iter().take(trail).sum::<f64>();
    Some(EperResult {
        traps: ChargeTraps {
            parallel_per_transfer: eps_par,
            serial_per_transfer: serial.unwrap_or(0.0),
            reference_e: REFERENCE_E,
            alpha: alpha.clamp(0.0, 0.99),
            trail_px: trail,
            decay,
        },
        serial_measured: serial.is_some(),
        points: pts,
        mean_delay,
    })
}
