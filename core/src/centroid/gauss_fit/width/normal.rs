//! The width fit's normal equations at one parameter point ([`normal`]: the weighted sums of
//! `J^T W J` and `J^T W r` over the window, from the separable pixel profiles) and their 4x4
//! `LDL^T` solve ([`Ldl4`]). Cost: per pixel one divide and ten row sums, per row the ten
//! matrix terms; the factor and solve are a few dozen flops.

use super::params::{M, Prior};
use crate::centroid::gauss_fit::Grid;
use crate::centroid::math;
use crate::centroid::prepared::Prepared;

/// The normal equations' sums at one parameter point.
pub(super) struct Normal {
    /// Upper triangle `a00 a01 a02 a03 a11 a12 a13 a22 a23 a33` (order `x, y, N, s`).
    pub(super) a: [f32; 10],
    pub(super) b: [f32; 4],
    /// `sum w r^2`.
    pub(super) chi2: f32,
    /// Usable pixels.
    pub(super) n: u16,
}

impl Normal {
    /// Adds the width's prior.
    pub(super) fn add_prior(&mut self, pr: Prior, s: f32) {
        // The prior as a fifth measurement row `(0, 0, 0, 1)`, residual `s_model - s`, weight
        // `I_p`: not counted in `chi2` (the data's goodness of fit).
        self.a[9] += pr.info;
        self.b[3] += pr.info * (pr.s_model - s);
    }

    /// Holds `s`: its row and column decoupled, a unit pivot and a zero right-hand side
    /// (its step is then 0 and the other parameters' covariance that of the 3-parameter
    /// fit).
    pub(super) fn pin_width(&mut self) {
        let [a00, a01, a02, _, a11, a12, _, a22, _, _] = self.a;
        self.a = [a00, a01, a02, 0.0, a11, a12, 0.0, a22, 0.0, 1.0];
        self.b[3] = 0.0;
    }
}

/// The six profiles along the two axes: fraction, centre and width derivatives.
pub(super) type Profiles = [[f32; M]; 6];

/// The normal equations at `(x, y, n, s)` (`CLEAN`: no excluded pixel; else excluded pixels
/// get weight 0).
pub(super) fn normal<const CLEAN: bool>(
    p: &Prepared<'_>,
    level_e: f32,
    var1: f32,
    (x, y, n, s): (f32, f32, f32, f32),
    prof: &mut Profiles,
) -> Normal {
    let grid = Grid::new(s);
    let wscale = core::f32::consts::SQRT_2 * grid.dscale;
    let [px, dpx, wpx, py, dpy, wpy] = prof;
    let (w, h) = (usize::from(p.width), usize::from(p.height));
    if let (Some(f), Some(d), Some(ws)) = (px.get_mut(..w), dpx.get_mut(..w), wpx.get_mut(..w)) {
        grid.edges
            .pixels_with_width(-0.5 - x, grid.dscale, wscale, f, d, ws);
    }
    if let (Some(f), Some(d), Some(ws)) = (py.get_mut(..h), dpy.get_mut(..h), wpy.get_mut(..h)) {
        grid.edges
            .pixels_with_width(-0.5 - y, grid.dscale, wscale, f, d, ws);
    }
    let mut a = [0.0f32; 10];
    let (mut b0, mut b1, mut b2, mut b3, mut chi2) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    let mut used = 0u16;
    let rows = p
        .pixels
        .chunks_exact(w.max(1))
        .zip(py.iter().zip(dpy.iter().zip(wpy.iter())));
    let mut first = 0usize;
    for (line, (&fy, (&dy, &wy))) in rows {
        let nfy = n * fy;
        let (mut sdd, mut sdf, mut sff, mut sdw, mut sfw) =
            (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let (mut sww, mut sdr, mut sfr, mut swr, mut srr) =
            (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let cols = px.iter().zip(dpx.iter().zip(wpx.iter()));
        for (i, (e, (&fx, (&dx, &wx)))) in line.iter().zip(cols).enumerate() {
            let f = e.to_bits() as f32 * (1.0 / 64.0) - level_e;
            let star = nfy * fx;
            let wt = if CLEAN {
                1.0 / (math::pos(star) + var1)
            } else if p.usable(first + i) {
                used += 1;
                1.0 / (math::pos(star) + var1)
            } else {
                0.0
            };
            let res = f - star;
            let (wd, wf, ww) = (wt * dx, wt * fx, wt * wx);
            sdd += wd * dx;
            sdf += wd * fx;
            sff += wf * fx;
            sdw += wd * wx;
            sfw += wf * wx;
            sww += ww * wx;
            sdr += wd * res;
            sfr += wf * res;
            swr += ww * res;
            srr += wt * res * res;
        }
        first += w;
        let (fy2, fdy, fwy) = (fy * fy, fy * dy, fy * wy);
        let [a00, a01, a02, a03, a11, a12, a13, a22, a23, a33] = &mut a;
        *a00 += fy2 * sdd;
        *a01 += fdy * sdf;
        *a02 += fy2 * sdf;
        *a03 += fy2 * sdw + fwy * sdf;
        *a11 += dy * dy * sff;
        *a12 += fdy * sff;
        *a13 += fdy * sfw + dy * wy * sff;
        *a22 += fy2 * sff;
        *a23 += fy2 * sfw + fwy * sff;
        *a33 += fy2 * sww + 2.0 * fwy * sfw + wy * wy * sff;
        b0 += fy * sdr;
        b1 += dy * sfr;
        b2 += fy * sfr;
        b3 += fy * swr + wy * sfr;
        chi2 += srr;
    }
    if CLEAN {
        used = p.width.saturating_mul(p.height);
    }
    let n2 = n * n;
    let [a00, a01, a02, a03, a11, a12, a13, a22, a23, a33] = a;
    Normal {
        a: [
            a00 * n2,
            a01 * n2,
            a02 * n,
            a03 * n2,
            a11 * n2,
            a12 * n,
            a13 * n2,
            a22,
            a23 * n,
            a33 * n2,
        ],
        b: [b0 * n, b1 * n, b2, b3 * n],
        chi2,
        n: used,
    }
}

/// The `LDL^T` factor of the 4x4 normal matrix: the unit lower triangle and the reciprocal
/// pivots.
pub(super) struct Ldl4 {
    l: [f32; 6],
    id: [f32; 4],
}

impl Ldl4 {
    /// Factors `a` (upper triangle, [`Normal::a`]'s order); `None` unless every pivot is
    /// above `1e-12` of its diagonal element and finite.
    pub(super) fn new(a: [f32; 10]) -> Option<Self> {
        let [a00, a01, a02, a03, a11, a12, a13, a22, a23, a33] = a;
        let ok = |d: f32, aii: f32| d > 1e-12 * aii && d.is_finite() && aii.is_finite();
        if !ok(a00, a00) || a00 <= 0.0 {
            return None;
        }
        let d0 = a00;
        let id0 = 1.0 / d0;
        let (l10, l20, l30) = (a01 * id0, a02 * id0, a03 * id0);
        let d1 = a11 - l10 * a01;
        if !ok(d1, a11) {
            return None;
        }
        let id1 = 1.0 / d1;
        let l21 = (a12 - l20 * a01) * id1;
        let l31 = (a13 - l30 * a01) * id1;
        let d2 = a22 - l20 * a02 - l21 * l21 * d1;
        if !ok(d2, a22) {
            return None;
        }
        let id2 = 1.0 / d2;
        let l32 = (a23 - l30 * a02 - l31 * l21 * d1) * id2;
        let d3 = a33 - l30 * a03 - l31 * l31 * d1 - l32 * l32 * d2;
        if !ok(d3, a33) {
            return None;
        }
        Some(Self {
            l: [l10, l20, l21, l30, l31, l32],
            id: [id0, id1, id2, 1.0 / d3],
        })
    }

    /// Solves `A x = b`.
    pub(super) fn solve(&self, b: [f32; 4]) -> [f32; 4] {
        let [l10, l20, l21, l30, l31, l32] = self.l;
        let [id0, id1, id2, id3] = self.id;
        let [b0, b1, b2, b3] = b;
        let y1 = b1 - l10 * b0;
        let y2 = b2 - l20 * b0 - l21 * y1;
        let y3 = b3 - l30 * b0 - l31 * y1 - l32 * y2;
        let x3 = y3 * id3;
        let x2 = y2 * id2 - l32 * x3;
        let x1 = y1 * id1 - l21 * x2 - l31 * x3;
        let x0 = b0 * id0 - l10 * x1 - l20 * x2 - l30 * x3;
        [x0, x1, x2, x3]
    }

    /// The diagonal of `A^-1`: `sum_k (L^-1)_ki^2 / d_k`.
    pub(super) fn inverse_diagonal(&self) -> [f32; 4] {
        let [l10, l20, l21, l30, l31, l32] = self.l;
        let [id0, id1, id2, id3] = self.id;
        // L^-1 (unit lower): m_ij = -sum_{k=j}^{i-1} l_ik m_kj.
        let m10 = -l10;
        let m20 = -(l20 + l21 * m10);
        let m21 = -l21;
        let m30 = -(l30 + l31 * m10 + l32 * m20);
        let m31 = -(l31 + l32 * m21);
        let m32 = -l32;
        [
            id0 + m10 * m10 * id1 + m20 * m20 * id2 + m30 * m30 * id3,
            id1 + m21 * m21 * id2 + m31 * m31 * id3,
            id2 + m32 * m32 * id3,
            id3,
        ]
    }
}
