//! The tracker's angular rate: a small filter over its last attitudes ([`RateFilter`]) and
//! the rate with its covariance it gives ([`Rate`]), as the attitude report carries it.
//!
//! The filter keeps the last [`RATE_WINDOW`] attitudes no older than
//! [`RateFilter::MAX_SPAN_US`] before the newest, each with its covariance, and fits a
//! constant rate by weighted least squares: with the newest attitude `q_r` as reference,
//! each attitude's rotation from it, `theta_i = log(q_i q_r^-1)` (camera frame, rad), is
//! modelled as `a + w (t_i - t_r) + e_i`, where `e_i` is the attitude's error of covariance
//! `P_i` and `a` takes up the reference's own error. The six normal equations are solved in
//! 3x3 blocks (the rate is the Schur complement's solution), and the rate's covariance is
//! that complement's inverse: exact for independent Gaussian attitude errors and a constant
//! rate about a camera axis, to first order in the errors otherwise (the frames of
//! attitudes 0.5 s apart at 2 deg/s differ by 1 degree; the covariance is not rotated
//! between them).
//!
//! An attitude that the fit does not predict (its normalised residual squared above
//! [`RateFilter::GATE_CHI2`], a slew's start, a wrong fix) restarts the window from it, so a
//! stale rate is never reported: the next report then has no rate until a second attitude.
//!
//! Cost: per attitude, one quaternion product and logarithm per kept attitude, three 3x3
//! inversions and a few hundred flops; 12 x 112 bytes of state. No allocation, no panic.

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

/// The angular-rate filter over the last attitudes (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RateFilter {
    samples: heapless::Deque<Sample, RATE_WINDOW>,
}

type M3 = [[f64; 3]; 3];

/// A fit of the window: intercept and rate, and their covariances.
struct Fit {
    a: [f64; 3],
    rate: Rate,
    cov_aa: M3,
    cov_aw: M3,
}

fn add(a: &M3, b: &M3) -> M3 {
    let mut o = *a;
    for (ro, rb) in o.iter_mut().zip(b) {
        for (x, y) in ro.iter_mut().zip(rb) {
            *x += y;
        }
    }
    o
}

fn sub_m(a: &M3, b: &M3) -> M3 {
    add(a, &scale(b, -1.0))
}

fn scale(a: &M3, s: f64) -> M3 {
    a.map(|r| r.map(|v| v * s))
}

fn transpose(m: &M3) -> M3 {
    let [[a, b, c], [d, e, f], [g, h, i]] = *m;
    [[a, d, g], [b, e, h], [c, f, i]]
}

fn mul(a: &M3, b: &M3) -> M3 {
    let bt = transpose(b);
    a.map(|row| bt.map(|col| dot(row, col)))
}

fn sub_v(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    let [x, y, z] = a;
    let [u, v, w] = b;
    [x - u, y - v, z - w]
}

impl RateFilter {
    /// The newest attitude's oldest companion in the fit, us.
    pub const MAX_SPAN_US: u64 = 2_000_000;
    /// Normalised residual squared (3 degrees of freedom) above which a new attitude restarts
    /// the window: 1.4 in 10^6 consistent attitudes exceed it (chi-squared of 3 degrees).
    pub const GATE_CHI2: f64 = 30.0;

    /// An empty filter.
    pub const fn new() -> Self {
        Self {
            samples: heapless::Deque::new(),
        }
    }

    /// Forgets every attitude.
    pub fn clear(&mut self) {
        self.samples.clear();
    }

    /// Attitudes in the window.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the window is empty.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Adds the attitude at `time_us` (the counter, us) and returns the rate fitted to the
    /// window, or `None` with fewer than two attitudes. An attitude not after the newest,
    /// with a covariance that is not invertible, or far from the fit's prediction restarts
    /// the window.
    pub fn push(&mut self, time_us: u64, attitude: &Attitude) -> Option<Rate> {
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
        self.fit().map(|f| f.rate)
    }

    /// Whether the fit of the window predicts `s` within the gate.
    fn predicts(&self, s: &Sample, attitude: &Attitude) -> bool {
        let Some(fit) = self.fit() else {
            return true;
        };
        let (a, rate) = (fit.a, fit.rate);
        let Some(r) = self.samples.back() else {
            return true;
        };
        let dt = (s.time_us as f64 - r.time_us as f64) * 1e-6;
        let theta = s.q.error_vector(r.q);
        let mut pred = a;
        for (p, w) in pred.iter_mut().zip(rate.w_rad_s) {
            *p += w * dt;
        }
        let e = sub_v(theta, pred);
        // The residual's covariance: the attitude's and the prediction's,
        // Caa + dt (Caw + Cwa) + dt^2 Cww.
        let cross = add(&fit.cov_aw, &transpose(&fit.cov_aw));
        let pred_cov = add(
            &add(&fit.cov_aa, &scale(&cross, dt)),
            &scale(&rate.cov_rad2_s2, dt * dt),
        );
        let cov = add(&attitude.cov_rad2, &pred_cov);
        inverse3(&cov).is_none_or(|inv| dot(e, mat_vec(&inv, e)) <= Self::GATE_CHI2)
    }

    /// The weighted least-squares intercept (rad) and rate of the window, the newest attitude
    /// the reference, with their covariances.
    fn fit(&self) -> Option<Fit> {
        if self.samples.len() < 2 {
            return None;
        }
        let r = self.samples.back()?;
        let zero = [[0.0; 3]; 3];
        let (mut na, mut nb, mut nd) = (zero, zero, zero);
        let (mut r1, mut r2) = ([0.0; 3], [0.0; 3]);
        for s in &self.samples {
            let dt = (s.time_us as f64 - r.time_us as f64) * 1e-6;
            let theta = s.q.error_vector(r.q);
            let wt = mat_vec(&s.info, theta);
            na = add(&na, &s.info);
            nb = add(&nb, &scale(&s.info, dt));
            nd = add(&nd, &scale(&s.info, dt * dt));
            for ((x, y), v) in r1.iter_mut().zip(r2.iter_mut()).zip(wt) {
                *x += v;
                *y += v * dt;
            }
        }
        let na_inv = inverse3(&na)?;
        let b_ainv = mul(&nb, &na_inv);
        let schur = sub_m(&nd, &mul(&b_ainv, &nb));
        let cov = inverse3(&schur)?;
        let w = mat_vec(&cov, sub_v(r2, mat_vec(&b_ainv, r1)));
        let a = mat_vec(&na_inv, sub_v(r1, mat_vec(&nb, w)));
        let ok = w.iter().chain(cov.iter().flatten()).all(|v| v.is_finite());
        // Block inverse: Caw = -A^-1 B S^-1, Caa = A^-1 + A^-1 B S^-1 B A^-1.
        let ainv_b = mul(&na_inv, &nb);
        let cov_aw = scale(&mul(&ainv_b, &cov), -1.0);
        let cov_aa = add(&na_inv, &mul(&mul(&ainv_b, &cov), &transpose(&ainv_b)));
        ok.then_some(Fit {
            a,
            rate: Rate {
                w_rad_s: w,
                cov_rad2_s2: cov,
            },
            cov_aa,
            cov_aw,
        })
    }
}
