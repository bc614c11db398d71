//! The tracker's angular rate and acceleration: a small filter over its last attitudes
//! ([`RateFilter`]), the rate with its covariance it gives ([`Rate`]), as the attitude
//! report carries it, and the angular acceleration ([`Acceleration`]) the attitude stage
//! needs while a slew's rate changes.
//!
//! The filter keeps the last [`RATE_WINDOW`] attitudes no older than
//! [`RateFilter::MAX_SPAN_US`] before the newest, each with its covariance, and fits them by
//! weighted least squares: with the newest attitude `q_r` as reference, each attitude's
//! rotation from it, `theta_i = log(q_i q_r^-1)` (camera frame, rad), is modelled as
//! `a + w dt_i + alpha dt_i^2 / 2 + e_i` (`dt_i = t_i - t_r`), where `e_i` is the attitude's
//! error of covariance `P_i` and `a` takes up the reference's own error. Two models are
//! fitted: the constant rate (`alpha` = 0, six unknowns) and, from 4 attitudes, the constant
//! acceleration (nine). The rate reported is the constant-rate fit's unless the
//! acceleration's Wald statistic `alpha^T C_alpha^-1 alpha` exceeds
//! [`RateFilter::ACCEL_CHI2`]: the quadratic fit's
//! rate at the newest attitude is four times noisier at the window's end, and the constant
//! rate's lags a changing rate by `alpha (t_r - t_mean)`, a quarter of a second's
//! acceleration for 12 attitudes 49 ms apart. The acceleration ([`RateFilter::acceleration`])
//! is the quadratic fit's whenever there is one, significant or not, with its covariance.
//! Each fit's covariance is its normal matrix's inverse: exact for independent Gaussian
//! attitude errors and a motion about fixed camera axes, to first order in the errors
//! otherwise (the frames of attitudes 0.5 s apart at 2 deg/s differ by 1 degree; the
//! covariance is not rotated between them).
//!
//! An attitude that the chosen fit does not predict (its normalised residual squared above
//! [`RateFilter::GATE_CHI2`], a slew's start or end, a wrong fix) restarts the window from
//! it, so a stale rate is never reported: the next report then has no rate until a second
//! attitude.
//!
//! Cost: per attitude, one quaternion product and logarithm per kept attitude for each fit,
//! a 6x6 and a 9x9 normal matrix built and inverted through its Cholesky factor (a few
//! thousand flops), and under 4 attitudes the constant rate's bias from an acceleration
//! (three more right-hand sides); the gate reuses the last push's fit. 12 x 112 bytes of
//! window and about 900 bytes of the last fit. No allocation, no panic. `cargo m7-bench`'s `rate_filter_push`
//! counts a push into a full window.

use super::{Attitude, Quat, dot, inverse3, mat_vec};

/// Attitudes the rate filter keeps.
pub const RATE_WINDOW: usize = 12;

/// An angular rate and its covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rate {
    /// Angular rate of the camera frame against ICRS, in the camera frame, rad/s (x, y across
    /// the boresight, z roll): `q(t + dt) = exp(w dt) q(t)`.
    pub w_rad_s: [f64; 3],
    /// Its covariance, rad^2/s^2.
    pub cov_rad2_s2: [[f64; 3]; 3],
}

impl Rate {
    /// Magnitude of the rate, rad/s.
    pub fn magnitude_rad_s(&self) -> f64 {
        libm::sqrt(self.w_rad_s.iter().map(|v| v * v).sum())
    }

    /// The normalised error squared `e^T P^-1 e` of a rate error `e` (rad/s); its mean is 3
    /// when the covariance is consistent.
    pub fn nees(&self, e: [f64; 3]) -> Option<f64> {
        let inv = inverse3(&self.cov_rad2_s2)?;
        Some(dot(e, mat_vec(&inv, e)))
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Sample {
    time_us: u64,
    q: Quat,
    /// The inverse of the attitude's covariance, rad^-2.
    info: [[f64; 3]; 3],
}

/// An angular acceleration and its covariance, in the camera frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Acceleration {
    /// Angular acceleration, rad/s^2, in the rate's convention: `q(t + dt) =
    /// exp(w dt + alpha dt^2 / 2) q(t)`.
    pub alpha_rad_s2: [f64; 3],
    /// Its covariance, rad^2/s^4.
    pub cov_rad2_s4: [[f64; 3]; 3],
}

impl Acceleration {
    /// The attitude at mid-exposure from `attitude`, measured on stars integrated over
    /// `integration_s` s whose centroids sit `k a T^2` past their mid-exposure positions
    /// (`a` the image's acceleration; `k` = `offset_fraction`, 1/24 for the centre of
    /// light, more for long trails: [`crate::centroid::trail_fit::accel_offset_fraction`],
    /// known to `offset_fraction_sigma`). The stars' attitude is then `exp(k alpha T^2)`
    /// turned from the one at mid-exposure, and is turned back. The attitude's covariance
    /// gains the acceleration's, scaled by `(k T^2)^2`, and `k`'s own uncertainty,
    /// `(sigma_k T^2)^2 alpha alpha^T` (the acceleration comes from earlier attitudes'
    /// differences, so it is independent of this frame's error). At 5 deg/s^2 and 39 ms the
    /// turn is 1.1 to 2.4 arcsec.
    #[inline(never)]
    pub fn mid_exposure(
        &self,
        attitude: &Attitude,
        integration_s: f64,
        offset_fraction: f64,
        offset_fraction_sigma: f64,
    ) -> Attitude {
        let t2 = integration_s * integration_s;
        let k = offset_fraction * t2;
        let sk = offset_fraction_sigma * t2;
        if !(k.is_finite() && sk.is_finite()) {
            return *attitude;
        }
        let a = self.alpha_rad_s2;
        let mut cov = attitude.cov_rad2;
        for ((row, arow), ai) in cov.iter_mut().zip(self.cov_rad2_s4).zip(a) {
            for ((x, y), aj) in row.iter_mut().zip(arow).zip(a) {
                *x += k * k * y + sk * sk * ai * aj;
            }
        }
        Attitude {
            q: Quat::from_rotation_vector(a.map(|v| -v * k)) * attitude.q,
            cov_rad2: cov,
        }
    }
}

/// The angular-rate filter over the last attitudes (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct RateFilter {
    samples: heapless::Deque<Sample, RATE_WINDOW>,
    /// The last push's quadratic fit's acceleration (`None` under 4 attitudes).
    acceleration: Option<Acceleration>,
    /// The last push's chosen fit and its bias from an unmeasured acceleration, which the
    /// next attitude is gated by (`None` under 2 attitudes).
    gate: Option<Gate>,
    /// The platform's largest angular acceleration, rad/s^2: what is assumed of an
    /// acceleration the window cannot yet estimate.
    max_accel_rad_s2: f64,
}

type M3 = [[f64; 3]; 3];

/// Unknowns of the largest fit: intercept, rate, acceleration, three axes each.
const MAX_UNKNOWNS: usize = 9;

/// A square matrix of the fits' size.
type MN = [[f64; MAX_UNKNOWNS]; MAX_UNKNOWNS];

/// `m[i][j]`, 0 outside.
fn at<const K: usize>(m: &[[f64; K]; K], i: usize, j: usize) -> f64 {
    m.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0)
}

/// `m[i][j] += v` (nothing outside).
fn add_at<const K: usize>(m: &mut [[f64; K]; K], i: usize, j: usize, v: f64) {
    if let Some(x) = m.get_mut(i).and_then(|r| r.get_mut(j)) {
        *x += v;
    }
}

/// `v[i]`, 0 outside.
fn vat<const K: usize>(v: &[f64; K], i: usize) -> f64 {
    v.get(i).copied().unwrap_or(0.0)
}

/// `v[i] += x` (nothing outside).
fn vadd<const K: usize>(v: &mut [f64; K], i: usize, x: f64) {
    if let Some(e) = v.get_mut(i) {
        *e += x;
    }
}

/// A polynomial fit of the window: `terms` of 2 (constant rate) or 3 (constant
/// acceleration), the coefficients `c[k]` of `dt^k / k!` and their covariance, the newest
/// attitude the reference.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fit {
    terms: usize,
    c: [[f64; 3]; 3],
    cov: MN,
}

impl Fit {
    /// The block `(j, k)` of the coefficients' covariance.
    fn block(&self, j: usize, k: usize) -> M3 {
        core::array::from_fn(|r| core::array::from_fn(|c| at(&self.cov, 3 * j + r, 3 * k + c)))
    }

    /// The rate at the reference and its covariance.
    fn rate(&self) -> Rate {
        let [_, w, _] = self.c;
        Rate {
            w_rad_s: w,
            cov_rad2_s2: self.block(1, 1),
        }
    }

    /// The acceleration and its covariance (zero for the constant-rate fit).
    fn acceleration(&self) -> Acceleration {
        let [_, _, alpha] = self.c;
        Acceleration {
            alpha_rad_s2: alpha,
            cov_rad2_s4: self.block(2, 2),
        }
    }

    /// The fit's rotation `dt` s from the reference and its covariance.
    #[inline(never)]
    fn predict(&self, dt: f64) -> ([f64; 3], M3) {
        let g = basis(dt);
        let mut mean = [0.0; 3];
        let mut cov = [[0.0; 3]; 3];
        for (j, (gj, cj)) in g.iter().zip(self.c).enumerate().take(self.terms) {
            for (m, c) in mean.iter_mut().zip(cj) {
                *m += gj * c;
            }
            for (k, gk) in g.iter().enumerate().take(self.terms) {
                let b = self.block(j, k);
                for (row, brow) in cov.iter_mut().zip(b) {
                    for (x, y) in row.iter_mut().zip(brow) {
                        *x += gj * gk * y;
                    }
                }
            }
        }
        (mean, cov)
    }

    /// The acceleration's Wald statistic (`None` for the constant-rate fit or a singular
    /// block).
    fn wald(&self) -> Option<f64> {
        (self.terms == 3).then_some(())?;
        let a = self.acceleration();
        let inv = inverse3(&a.cov_rad2_s4)?;
        Some(dot(a.alpha_rad_s2, mat_vec(&inv, a.alpha_rad_s2)))
    }
}

/// What the next attitude is gated by: the chosen fit, and for the constant rate with the
/// platform's bound, what a unit acceleration does to its intercept and rate.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Gate {
    fit: Fit,
    bias: Option<(M3, M3)>,
}

/// The model's basis at `dt`: `1, dt, dt^2 / 2`.
fn basis(dt: f64) -> [f64; 3] {
    [1.0, dt, 0.5 * dt * dt]
}

/// Adds `D D^T max^2 / 3` to `cov`: what `D alpha` spreads by for an acceleration `alpha`
/// uniform within `+-max` on each axis.
fn add_spread(cov: &mut M3, d: &M3, max: f64) {
    let v = max * max / 3.0;
    for (row, di) in cov.iter_mut().zip(d) {
        for (x, dj) in row.iter_mut().zip(d) {
            *x += v * dot(*di, *dj);
        }
    }
}

fn sub_v(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = a;
    let [u, v, w] = b;
    [x - u, y - v, z - w]
}

/// The inverse of the leading `n x n` block of the symmetric positive-definite `m` by its
/// Cholesky factor (`None` when not positive definite or not finite).
#[inline(never)]
fn inverse_spd(m: &MN, n: usize) -> Option<MN> {
    let mut l = [[0.0; MAX_UNKNOWNS]; MAX_UNKNOWNS];
    for j in 0..n {
        let d = at(m, j, j) - (0..j).map(|k| at(&l, j, k) * at(&l, j, k)).sum::<f64>();
        if !(d.is_finite() && d > 0.0) {
            return None;
        }
        let ljj = libm::sqrt(d);
        add_at(&mut l, j, j, ljj);
        for i in j + 1..n {
            let s = at(m, i, j) - (0..j).map(|k| at(&l, i, k) * at(&l, j, k)).sum::<f64>();
            add_at(&mut l, i, j, s / ljj);
        }
    }
    let mut inv = [[0.0; MAX_UNKNOWNS]; MAX_UNKNOWNS];
    for col in 0..n {
        // L y = e_col, then L^T x = y.
        let mut y = [0.0; MAX_UNKNOWNS];
        for i in 0..n {
            let e = if i == col { 1.0 } else { 0.0 };
            let s = e - (0..i).map(|k| at(&l, i, k) * vat(&y, k)).sum::<f64>();
            vadd(&mut y, i, s / at(&l, i, i));
        }
        let mut x = [0.0; MAX_UNKNOWNS];
        for i in (0..n).rev() {
            let s = vat(&y, i) - (i + 1..n).map(|k| at(&l, k, i) * vat(&x, k)).sum::<f64>();
            vadd(&mut x, i, s / at(&l, i, i));
        }
        for (i, v) in x.iter().enumerate().take(n) {
            add_at(&mut inv, i, col, *v);
        }
    }
    inv.iter().flatten().all(|v| v.is_finite()).then_some(inv)
}

impl RateFilter {
    /// The newest attitude's oldest companion in the fit, us.
    pub const MAX_SPAN_US: u64 = 2_000_000;
    /// Normalised residual squared (3 degrees of freedom) above which a new attitude restarts
    /// the window: 1.4 in 10^6 consistent attitudes exceed it (chi-squared of 3 degrees).
    pub const GATE_CHI2: f64 = 30.0;
    /// The acceleration's Wald statistic above which the rate is the constant-acceleration
    /// fit's: the gate's level, exceeded by 1.4 in 10^6 windows of a constant rate (a window
    /// chosen so is one whose noise looks like an acceleration, and its rate is the worse
    /// for it). A slew's acceleration passes it at once: at 0.05 deg/s^2 over 12 attitudes
    /// 49 ms apart the statistic is about 900 with the SIL's attitude errors.
    pub const ACCEL_CHI2: f64 = 30.0;

    /// An empty filter for a platform whose angular acceleration is at most
    /// `max_accel_rad_s2` on each axis (0: assumed constant rate until the window shows
    /// otherwise; a value that is not finite or negative is taken as 0).
    pub const fn new(max_accel_rad_s2: f64) -> Self {
        Self {
            samples: heapless::Deque::new(),
            acceleration: None,
            gate: None,
            max_accel_rad_s2: if max_accel_rad_s2.is_finite() && max_accel_rad_s2 > 0.0 {
                max_accel_rad_s2
            } else {
                0.0
            },
        }
    }

    /// Forgets every attitude.
    pub fn clear(&mut self) {
        self.samples.clear();
        self.acceleration = None;
        self.gate = None;
    }

    /// Attitudes in the window.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the window is empty.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The angular acceleration the last push's window gives, from 4 attitudes; under 4,
    /// none measured: zero, with the platform's bound as a uniform spread on each axis
    /// (variance `max^2 / 3`).
    pub fn acceleration(&self) -> Acceleration {
        self.acceleration.unwrap_or_else(|| {
            let v = self.max_accel_rad_s2 * self.max_accel_rad_s2 / 3.0;
            Acceleration {
                alpha_rad_s2: [0.0; 3],
                cov_rad2_s4: [[v, 0.0, 0.0], [0.0, v, 0.0], [0.0, 0.0, v]],
            }
        })
    }

    /// Adds the attitude at `time_us` (the counter, us) and returns the rate fitted to the
    /// window, or `None` with fewer than two attitudes. An attitude not after the newest,
    /// with a covariance that is not invertible, or far from the fit's prediction restarts
    /// the window.
    #[inline(never)]
    pub fn push(&mut self, time_us: u64, attitude: &Attitude) -> Option<Rate> {
        self.acceleration = None;
        let Some(info) = inverse3(&attitude.cov_rad2) else {
            self.clear();
            return None;
        };
        let s = Sample {
            time_us,
            q: attitude.q,
            info,
        };
        let newest = self.samples.back().map(|b| b.time_us);
        if newest.is_some_and(|t| time_us <= t) {
            self.clear();
        }
        while self
            .samples
            .front()
            .is_some_and(|f| time_us.saturating_sub(f.time_us) > Self::MAX_SPAN_US)
        {
            self.samples.pop_front();
        }
        if self.samples.len() >= 2 && !self.predicts(&s, attitude) {
            self.clear();
        }
        if self.samples.is_full() {
            self.samples.pop_front();
        }
        // Cannot fail: a place was made above.
        let _ = self.samples.push_back(s);
        let Some((fit, quadratic)) = self.chosen() else {
            self.gate = None;
            return None;
        };
        self.acceleration = quadratic.map(|q| q.acceleration());
        let bias = self.unmeasured_bias(&fit);
        self.gate = Some(Gate { fit, bias });
        let mut rate = fit.rate();
        if quadratic.is_none() {
            // A constant rate fitted under an acceleration the window cannot measure yet
            // lags the newest attitude's: by `B alpha`, `alpha` within the platform's bound.
            if let Some((_, b1)) = bias {
                add_spread(&mut rate.cov_rad2_s2, &b1, self.max_accel_rad_s2);
            }
        }
        Some(rate)
    }

    /// What a unit acceleration along each camera axis, not in the constant-rate `fit`,
    /// does to its intercept and rate: the fit's coefficients for the attitudes
    /// `alpha dt_i^2 / 2` (column `k` for the unit acceleration about axis `k`). `None`
    /// for a fit of the acceleration (it has no such bias) or no platform bound.
    #[inline(never)]
    fn unmeasured_bias(&self, fit: &Fit) -> Option<(M3, M3)> {
        if fit.terms != 2 || self.max_accel_rad_s2 == 0.0 {
            return None;
        }
        let r = self.samples.back()?;
        let (mut b0, mut b1) = ([[0.0; 3]; 3], [[0.0; 3]; 3]);
        for k in 0..3 {
            let mut rhs = [0.0; MAX_UNKNOWNS];
            for s in &self.samples {
                let dt = (s.time_us as f64 - r.time_us as f64) * 1e-6;
                let [_, _, g2] = basis(dt);
                // info * (e_k dt^2 / 2): column k of the information, scaled.
                for (row, i_row) in s.info.iter().enumerate() {
                    let v = vat(i_row, k) * g2;
                    vadd(&mut rhs, row, v);
                    vadd(&mut rhs, 3 + row, dt * v);
                }
            }
            for row in 0..3 {
                let b0v = (0..6).map(|c| at(&fit.cov, row, c) * vat(&rhs, c)).sum();
                let b1v = (0..6)
                    .map(|c| at(&fit.cov, 3 + row, c) * vat(&rhs, c))
                    .sum();
                add_at(&mut b0, row, k, b0v);
                add_at(&mut b1, row, k, b1v);
            }
        }
        Some((b0, b1))
    }

    /// The fit the rate comes from (the constant rate's unless the acceleration is
    /// significant) and the quadratic fit when there is one.
    #[inline(never)]
    fn chosen(&self) -> Option<(Fit, Option<Fit>)> {
        let quadratic = if self.samples.len() >= 4 {
            self.fit(3)
        } else {
            None
        };
        match quadratic {
            // The constant rate's fit is not needed (its normal matrix is the quadratic's
            // leading block: positive definite whenever the quadratic's is).
            Some(q) if q.wald().is_some_and(|w| w > Self::ACCEL_CHI2) => Some((q, Some(q))),
            q => Some((self.fit(2)?, q)),
        }
    }

    /// Whether the last push's chosen fit predicts `s` within the gate.
    #[inline(never)]
    fn predicts(&self, s: &Sample, attitude: &Attitude) -> bool {
        let Some(Gate { fit, bias }) = self.gate else {
            return true;
        };
        let Some(r) = self.samples.back() else {
            return true;
        };
        let dt = (s.time_us as f64 - r.time_us as f64) * 1e-6;
        let theta = s.q.error_vector(r.q);
        let (pred, pred_cov) = fit.predict(dt);
        let e = sub_v(theta, pred);
        let mut cov = attitude.cov_rad2;
        if let Some((b0, b1)) = bias {
            // The constant rate's prediction misses an acceleration by
            // `(B0 + dt B1 - dt^2 / 2) alpha`.
            let d: M3 = core::array::from_fn(|i| {
                core::array::from_fn(|k| {
                    at(&b0, i, k) + dt * at(&b1, i, k) - if i == k { 0.5 * dt * dt } else { 0.0 }
                })
            });
            add_spread(&mut cov, &d, self.max_accel_rad_s2);
        }
        for (row, prow) in cov.iter_mut().zip(pred_cov) {
            for (x, y) in row.iter_mut().zip(prow) {
                *x += y;
            }
        }
        inverse3(&cov).is_none_or(|inv| dot(e, mat_vec(&inv, e)) <= Self::GATE_CHI2)
    }

    /// The weighted least-squares fit of `terms` (2 or 3) coefficients per axis to the
    /// window, the newest attitude the reference (`None` with fewer than `terms` attitudes,
    /// or singular).
    #[inline(never)]
    fn fit(&self, terms: usize) -> Option<Fit> {
        if self.samples.len() < terms || !(2..=3).contains(&terms) {
            return None;
        }
        let r = self.samples.back()?;
        let n = 3 * terms;
        let mut normal = [[0.0; MAX_UNKNOWNS]; MAX_UNKNOWNS];
        let mut rhs = [0.0; MAX_UNKNOWNS];
        for s in &self.samples {
            let dt = (s.time_us as f64 - r.time_us as f64) * 1e-6;
            let g = basis(dt);
            let wt = mat_vec(&s.info, s.q.error_vector(r.q));
            for (j, gj) in g.iter().enumerate().take(terms) {
                for (row, (i_row, w)) in s.info.iter().zip(wt).enumerate() {
                    vadd(&mut rhs, 3 * j + row, gj * w);
                    for (k, gk) in g.iter().enumerate().take(terms) {
                        for (col, v) in i_row.iter().enumerate() {
                            add_at(&mut normal, 3 * j + row, 3 * k + col, gj * gk * v);
                        }
                    }
                }
            }
        }
        let cov = inverse_spd(&normal, n)?;
        let mut c = [[0.0; 3]; 3];
        for (i, row) in cov.iter().enumerate().take(n) {
            let v = row.iter().zip(rhs).take(n).map(|(a, b)| a * b).sum();
            add_at(&mut c, i / 3, i % 3, v);
        }
        c.iter()
            .flatten()
            .all(|v| v.is_finite())
            .then_some(Fit { terms, c, cov })
    }
}
