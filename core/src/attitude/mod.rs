//! Attitude from identified stars: Davenport's q-method in f64, and the attitude's 3x3
//! covariance from each star's direction sigma.
//!
//! Each observation pairs a measured camera-frame unit vector `b_i` with its catalog ICRS
//! unit vector `r_i` and the 1-sigma angular error of `b_i`, `sigma_i` (rad, isotropic across
//! the line of sight). The attitude `A` maximises Wahba's gain `sum w_i b_i . A r_i` with
//! `w_i = 1 / sigma_i^2`: it is the eigenvector of Davenport's 4x4 matrix `K` with the largest
//! eigenvalue, found here by cyclic Jacobi rotations (at most `MAX_SWEEPS` (12) sweeps of six
//! rotations; each sweep about 300 flops).
//!
//! Why the q-method with Jacobi: it is exact and has no singular rotation, so it needs no
//! reference rotation (QUEST and ESOQ2 solve the characteristic equation and divide by a
//! term that vanishes at 180 degrees, which is why they carry one); it stays accurate in a
//! narrow field where `K`'s two largest eigenvalues are close (the eigenvector error is
//! `eps / gap`, about 1e-13 for a 15 degree field in f64), and its cost is a few thousand
//! flops, small beside identification.
//!
//! Covariance: `P = (sum w_i (I - b_i b_i^T))^-1` (Shuster), rad^2, of the small rotation
//! vector `e` (camera frame) with `A_est = exp(e) A_true`: `P[0][0]`, `P[1][1]` are the
//! cross-boresight variances, `P[2][2]` the roll variance. It is exact to first order in
//! the sigmas; `startrack-host`'s Monte Carlo tests check it (errors against the bound, the
//! normalised error squared at 3).
//!
//! Anisotropic errors: a trailed star is known worse along its trail than across it, and
//! the q-method's one weight a star cannot say so. [`refine`] takes the q-method's attitude
//! one Gauss-Newton step further with each star's whole 2x2 image-plane covariance
//! ([`ImageObservation`]), the focal-length scale fitted beside it as identification fits
//! it, and gives that weighted fit's covariance (with isotropic errors and the scale held,
//! Shuster's). Cost: about 100 flops a star and a 3x3 inverse.
//!
//! Stellar aberration: [`aberrate`] moves a catalog direction by the observer's velocity
//! (first order in v/c, the residual below 1 mas at orbital speeds); the attitude stage
//! refits an identified attitude with the matched catalog directions moved so
//! ([`crate::solver::Solver::update_at_velocity`]).

mod camera;
mod quat;
mod rate;

pub use camera::{Camera, CameraError};
pub use quat::{Quat, angle_between};
pub(crate) use quat::{cross, dot, mat_vec, norm};
pub use rate::{Acceleration, RATE_WINDOW, Rate, RateFilter};

/// Most Jacobi sweeps; a 4x4 converges to f64 precision in 5-6.
pub(crate) const MAX_SWEEPS: usize = 12;

/// Speed of light, m/s.
pub const C_M_PER_S: f64 = 299_792_458.0;

/// One identified star.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Measured direction, camera frame, unit vector.
    pub camera: [f64; 3],
    /// Catalog direction, ICRS, unit vector.
    pub icrs: [f64; 3],
    /// 1-sigma angular error of `camera` in each axis across the line of sight, rad (> 0).
    pub sigma_rad: f64,
}

/// An attitude and its covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Attitude {
    /// ICRS to camera, Hamilton, scalar first, `w >= 0`.
    pub q: Quat,
    /// Covariance of the error rotation vector in the camera frame, rad^2 (x, y across the
    /// boresight, z roll).
    pub cov_rad2: [[f64; 3]; 3],
}

impl Attitude {
    /// 1-sigma cross-boresight error bound, rad: `sqrt(P_xx + P_yy)`.
    pub fn boresight_sigma_rad(&self) -> f64 {
        libm::sqrt(self.cov_rad2[0][0] + self.cov_rad2[1][1])
    }

    /// 1-sigma roll error bound, rad: `sqrt(P_zz)`.
    pub fn roll_sigma_rad(&self) -> f64 {
        libm::sqrt(self.cov_rad2[2][2])
    }

    /// The normalised error squared `e^T P^-1 e` of an error vector `e` (rad, camera frame);
    /// its mean over many fields is 3 when the covariance is consistent.
    pub fn nees(&self, e: [f64; 3]) -> Option<f64> {
        let inv = inverse3(&self.cov_rad2)?;
        Some(dot(e, mat_vec(&inv, e)))
    }
}

/// Why no attitude was computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum AttitudeError {
    /// Fewer than two observations.
    TooFewStars,
    /// An observation is not finite, not a unit vector, or has a sigma that is not positive.
    BadObservation,
    /// The directions do not fix the rotation (all parallel): no unique attitude, singular
    /// covariance.
    Degenerate,
}

impl core::fmt::Display for AttitudeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::TooFewStars => "attitude needs two stars or more",
            Self::BadObservation => "attitude: an observation is not a finite unit vector",
            Self::Degenerate => "attitude: the stars do not fix the rotation",
        })
    }
}

impl core::error::Error for AttitudeError {}

/// The attitude that best fits `obs` (Wahba's problem, weights `1 / sigma^2`) and its
/// covariance.
pub fn solve(obs: &[Observation]) -> Result<Attitude, AttitudeError> {
    if obs.len() < 2 {
        return Err(AttitudeError::TooFewStars);
    }
    let mut b = [[0.0f64; 3]; 3];
    let mut info = [[0.0f64; 3]; 3];
    let mut w_max = 0.0f64;
    for o in obs {
        let ok = |v: [f64; 3]| v.iter().all(|c| c.is_finite()) && (norm(v) - 1.0).abs() < 1e-6;
        if !(ok(o.camera) && ok(o.icrs) && o.sigma_rad > 0.0 && o.sigma_rad.is_finite()) {
            return Err(AttitudeError::BadObservation);
        }
        let w = 1.0 / (o.sigma_rad * o.sigma_rad);
        w_max = w_max.max(w);
        for (r, (br, ir)) in b.iter_mut().zip(info.iter_mut()).enumerate() {
            let bc = o.camera.get(r).copied().unwrap_or(0.0);
            for (c, (bv, iv)) in br.iter_mut().zip(ir.iter_mut()).enumerate() {
                *bv += w * bc * o.icrs.get(c).copied().unwrap_or(0.0);
                let delta = if r == c { 1.0 } else { 0.0 };
                *iv += w * (delta - bc * o.camera.get(c).copied().unwrap_or(0.0));
            }
        }
    }
    let cov_rad2 = inverse3(&info).ok_or(AttitudeError::Degenerate)?;
    // A weight scale keeps K's entries near 1 whatever the sigmas.
    let s = 1.0 / (w_max * obs.len() as f64);
    let b = b.map(|r| r.map(|v| v * s));
    let sigma = b[0][0] + b[1][1] + b[2][2];
    let z = [b[1][2] - b[2][1], b[2][0] - b[0][2], b[0][1] - b[1][0]];
    // Davenport's K for the vector-first quaternion (qv, q4) with A = (q4^2 - |qv|^2) I +
    // 2 qv qv^T - 2 q4 [qv x].
    let mut k = [[0.0f64; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            let v = b.get(r).and_then(|row| row.get(c)).copied().unwrap_or(0.0)
                + b.get(c).and_then(|row| row.get(r)).copied().unwrap_or(0.0)
                - if r == c { sigma } else { 0.0 };
            set4(&mut k, r, c, v);
        }
        set4(&mut k, r, 3, z.get(r).copied().unwrap_or(0.0));
        set4(&mut k, 3, r, z.get(r).copied().unwrap_or(0.0));
    }
    set4(&mut k, 3, 3, sigma);
    let (vals, vecs) = jacobi4(k);
    let best = (0..4)
        .max_by(|&i, &j| get4(&vals, i).total_cmp(&get4(&vals, j)))
        .unwrap_or(0);
    let col = |r: usize| {
        vecs.get(r)
            .and_then(|row| row.get(best))
            .copied()
            .unwrap_or(0.0)
    };
    // A = R(q) for the Hamilton quaternion (q4, -qv).
    let q = Quat([col(3), -col(0), -col(1), -col(2)])
        .normalized()
        .ok_or(AttitudeError::Degenerate)?;
    Ok(Attitude { q, cov_rad2 })
}

/// One identified star with the 2x2 covariance of its image-plane error, for [`refine`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageObservation {
    /// Measured direction, camera frame, unit vector.
    pub camera: [f64; 3],
    /// Catalog direction, ICRS, unit vector.
    pub icrs: [f64; 3],
    /// Covariance of the star's image-plane position error along the camera's x and y axes,
    /// scaled to the direction: the pixel covariance times `(z / f)^2` (`z` the direction's
    /// boresight component, `f` the focal length, px), `[xx, yy, xy]`, rad^2. A pinhole
    /// moves the direction by `(z / f) (I - b b^T) (dx, dy, 0)` for a pixel error `(dx, dy)`.
    pub cov_rad2: [f64; 3],
}

/// The attitude `start` refined by one Gauss-Newton step of the weighted least squares of
/// `obs`, each star weighted by the inverse of its 2x2 image-plane covariance, with the
/// focal-length scale fitted beside it, and that fit's covariance of the attitude (the
/// marginal one, the scale's uncertainty included, as identification's).
///
/// With `b` a star's measured direction, `p = start r` its catalog direction in the camera
/// frame and `d = b - p`, a small rotation `delta` (`A = exp(delta) start`) moves `p` by
/// `delta x p`, and a focal length `1 + s` times the model's moves `b` by `T (b_x, b_y) s`.
/// The star's error is `T eta`, `T = (I - b b^T) E`, `E = (e_x, e_y)`, `eta` of covariance
/// `S`: in `eta`'s coordinates its residual is `a = G^-1 T^T d` (`G = T^T T`) and the model
/// `a = G^-1 U^T delta + beta s`, `U = [b x] E`, `beta = (b_x, b_y)`. The normal equations
/// of `theta = (delta, s)` are `sum H^T S^-1 H theta = sum H^T S^-1 a`, `H = (G^-1 U^T,
/// beta)`; the attitude's covariance is the inverse of the Schur complement of the scale,
/// `P = (F_aa - f_as f_as^T / f_ss)^-1`. With isotropic errors and the scale held it is
/// Shuster's `(sum w (I - b b^T))^-1`. One step from the q-method's attitude is the weighted
/// fit's to second order in its error (the problem is linear in `theta` to first).
/// Errors: [`AttitudeError::TooFewStars`] below two stars, [`AttitudeError::BadObservation`]
/// for a direction that is not a finite unit vector or a covariance that is not positive
/// definite, [`AttitudeError::Degenerate`] when the stars do not fix the rotation and scale.
#[inline(never)]
pub fn refine(start: Quat, obs: &[ImageObservation]) -> Result<Attitude, AttitudeError> {
    if obs.len() < 2 {
        return Err(AttitudeError::TooFewStars);
    }
    // The normal equations' blocks: attitude (aa), attitude-scale (as), scale (ss).
    let mut f_aa = [[0.0f64; 3]; 3];
    let mut f_as = [0.0f64; 3];
    let mut f_ss = 0.0f64;
    let mut g_a = [0.0f64; 3];
    let mut g_s = 0.0f64;
    for o in obs {
        let ok = |v: [f64; 3]| v.iter().all(|c| c.is_finite()) && (norm(v) - 1.0).abs() < 1e-6;
        let [sxx, syy, sxy] = o.cov_rad2;
        let det_s = sxx * syy - sxy * sxy;
        if !(ok(o.camera)
            && ok(o.icrs)
            && sxx > 0.0
            && syy > 0.0
            && det_s > 0.0
            && det_s.is_finite())
        {
            return Err(AttitudeError::BadObservation);
        }
        let [bx, by, bz] = o.camera;
        let p = start.rotate(o.icrs);
        let d = [bx - p[0], by - p[1], bz - p[2]];
        // G and its inverse (det = bz^2 > 0 for a direction in front of the camera).
        let (g00, g11, g01) = (1.0 - bx * bx, 1.0 - by * by, -bx * by);
        let det_g = g00 * g11 - g01 * g01;
        if det_g.is_nan() || det_g <= 0.0 {
            return Err(AttitudeError::BadObservation);
        }
        let gi = [[g11 / det_g, -g01 / det_g], [-g01 / det_g, g00 / det_g]];
        let si = [[syy / det_s, -sxy / det_s], [-sxy / det_s, sxx / det_s]];
        // a = G^-1 T^T d; the rows of V = U G^-1 (U's rows: (0, -bz), (bz, 0), (-by, bx)).
        let bd = dot(o.camera, d);
        let a = mul2v(&gi, [d[0] - bx * bd, d[1] - by * bd]);
        let v = [[0.0, -bz], [bz, 0.0], [-by, bx]].map(|u| {
            [
                u[0] * gi[0][0] + u[1] * gi[1][0],
                u[0] * gi[0][1] + u[1] * gi[1][1],
            ]
        });
        let beta = [bx, by];
        let (si_a, si_beta) = (mul2v(&si, a), mul2v(&si, beta));
        f_ss += dot2(beta, si_beta);
        g_s += dot2(beta, si_a);
        for (((vr, fr), fa), ga) in v
            .iter()
            .zip(f_aa.iter_mut())
            .zip(f_as.iter_mut())
            .zip(g_a.iter_mut())
        {
            let vs = mul2v(&si, *vr);
            *fa += dot2(vs, beta);
            *ga += dot2(vs, a);
            for (fk, vk) in fr.iter_mut().zip(v.iter()) {
                *fk += dot2(vs, *vk);
            }
        }
    }
    // The scale taken out (its Schur complement); a field that cannot fix it keeps it held.
    if f_ss > 0.0 && f_ss.is_finite() {
        let k = 1.0 / f_ss;
        for ((fr, ga), fa) in f_aa.iter_mut().zip(g_a.iter_mut()).zip(f_as) {
            for (fk, fb) in fr.iter_mut().zip(f_as) {
                *fk -= fa * fb * k;
            }
            *ga -= fa * g_s * k;
        }
    }
    let cov_rad2 = inverse3(&f_aa).ok_or(AttitudeError::Degenerate)?;
    let delta = mat_vec(&cov_rad2, g_a);
    let q = (Quat::from_rotation_vector(delta) * start)
        .normalized()
        .ok_or(AttitudeError::Degenerate)?;
    Ok(Attitude { q, cov_rad2 })
}

/// `m v` of a 2x2 and a 2-vector.
fn mul2v(m: &[[f64; 2]; 2], v: [f64; 2]) -> [f64; 2] {
    [
        m[0][0] * v[0] + m[0][1] * v[1],
        m[1][0] * v[0] + m[1][1] * v[1],
    ]
}

fn dot2(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// The direction `dir` (unit) as seen by an observer moving at `velocity_m_per_s` (ICRS,
/// barycentric): `(u + v/c) / |u + v/c|`, first order in v/c.
pub fn aberrate(dir: [f64; 3], velocity_m_per_s: [f64; 3]) -> [f64; 3] {
    let u = [
        dir[0] + velocity_m_per_s[0] / C_M_PER_S,
        dir[1] + velocity_m_per_s[1] / C_M_PER_S,
        dir[2] + velocity_m_per_s[2] / C_M_PER_S,
    ];
    let n = norm(u);
    if n > 0.0 && n.is_finite() {
        u.map(|c| c / n)
    } else {
        dir
    }
}

fn get4(v: &[f64; 4], i: usize) -> f64 {
    v.get(i).copied().unwrap_or(0.0)
}

fn at4(m: &[[f64; 4]; 4], r: usize, c: usize) -> f64 {
    m.get(r).and_then(|row| row.get(c)).copied().unwrap_or(0.0)
}

fn set4(m: &mut [[f64; 4]; 4], r: usize, c: usize, v: f64) {
    if let Some(x) = m.get_mut(r).and_then(|row| row.get_mut(c)) {
        *x = v;
    }
}

/// Eigenvalues and eigenvectors (columns) of a symmetric 4x4, by cyclic Jacobi rotations.
fn jacobi4(mut a: [[f64; 4]; 4]) -> ([f64; 4], [[f64; 4]; 4]) {
    let mut v = [[0.0f64; 4]; 4];
    for i in 0..4 {
        set4(&mut v, i, i, 1.0);
    }
    const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];
    for _ in 0..MAX_SWEEPS {
        let off: f64 = PAIRS
            .iter()
            .map(|&(p, q)| {
                let x = at4(&a, p, q);
                x * x
            })
            .sum();
        let diag: f64 = (0..4)
            .map(|i| {
                let x = at4(&a, i, i);
                x * x
            })
            .sum();
        if off <= 1e-32 * diag || off == 0.0 {
            break;
        }
        for &(p, q) in &PAIRS {
            let apq = at4(&a, p, q);
            if apq == 0.0 {
                continue;
            }
            let theta = (at4(&a, q, q) - at4(&a, p, p)) / (2.0 * apq);
            let t = 1.0 / (theta.abs() + libm::sqrt(theta * theta + 1.0));
            let t = if theta < 0.0 { -t } else { t };
            let c = 1.0 / libm::sqrt(t * t + 1.0);
            let s = t * c;
            for k in 0..4 {
                let (akp, akq) = (at4(&a, k, p), at4(&a, k, q));
                set4(&mut a, k, p, c * akp - s * akq);
                set4(&mut a, k, q, s * akp + c * akq);
            }
            for k in 0..4 {
                let (apk, aqk) = (at4(&a, p, k), at4(&a, q, k));
                set4(&mut a, p, k, c * apk - s * aqk);
                set4(&mut a, q, k, s * apk + c * aqk);
            }
            for k in 0..4 {
                let (vkp, vkq) = (at4(&v, k, p), at4(&v, k, q));
                set4(&mut v, k, p, c * vkp - s * vkq);
                set4(&mut v, k, q, s * vkp + c * vkq);
            }
        }
    }
    (
        [at4(&a, 0, 0), at4(&a, 1, 1), at4(&a, 2, 2), at4(&a, 3, 3)],
        v,
    )
}

/// Inverse of a 3x3 by its adjugate; `None` when it is singular to f64 precision.
pub(crate) fn inverse3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let [[a, b, c], [d, e, f], [g, h, i]] = *m;
    let co = [
        [e * i - f * h, c * h - b * i, b * f - c * e],
        [f * g - d * i, a * i - c * g, c * d - a * f],
        [d * h - e * g, b * g - a * h, a * e - b * d],
    ];
    let det = a * co[0][0] + b * co[1][0] + c * co[2][0];
    let scale = m.iter().flatten().map(|x| x.abs()).fold(0.0f64, f64::max);
    if !det.is_finite() || det.abs() <= 1e-13 * scale * scale * scale {
        return None;
    }
    Some(co.map(|r| r.map(|x| x / det)))
}
