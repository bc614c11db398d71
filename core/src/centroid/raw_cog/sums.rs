//! The fused sums of the raw CoG: one frame's raw samples and line levels become the box's
//! background-subtracted moments `S_w = sum w F` (w in 1, dx, dx^2, dy, dy^2) without
//! calibrating a pixel, then its centroid offset, error, flux and SNR (the formula of
//! [`super`]).
//!
//! Per row and column group the samples go into three running sums (`P`, `Q`, `R`); per
//! tile row each group's sums meet its cell's constants in f32 ([`flush`]); the offsets
//! (line bias, column bias) are subtracted in closed form from sums over rows and columns.
//!
//! # Cost
//! Per sample one load and three adds; per row and run the five cell sums (~120
//! instructions a row of a 7x7 box with the bookkeeping and register spills); per tile row
//! the line levels' bias sums; per cell ~30 integer operations and ten f32 multiply-adds;
//! per star one divide and three square roots. Of `centroid_cog1c_raw_planned_7x7`'s ~2,600
//! instructions (`cargo m7-bench`) the fused sums and CoG take ~2,000.

use super::RawWindow;
use super::plan::{CellConst, ColGroup, MB, RawCogPlan, cell_const};
use crate::calib::FrameCalibration;
use crate::calib::formula::offset_16ths;
use crate::centroid::CentroidFlags;
use crate::centroid::math::{self, pos};
use crate::geometry::Output;
use crate::units::ColumnBiasAdu;

/// A measurement relative to the anchor, before the curve.
#[derive(Clone, Copy, Debug)]
pub(super) struct Meas {
    pub(super) ox: f32,
    pub(super) oy: f32,
    pub(super) flux_e: f32,
    pub(super) snr: f32,
    pub(super) sigma_x: f32,
    pub(super) sigma_y: f32,
    pub(super) flags: CentroidFlags,
}

/// Raw sums of one column group over the rows of the current tile row: the prefix sums of
/// [`row_sums`] (`P = sum v`, `Q = sum u v`, `R = sum u (u + 1) / 2 v` with `u = m - i` for
/// the run's i-th column) added over rows, and `sum dy P`, `sum dy^2 P`.
#[derive(Clone, Copy, Default)]
struct GroupAcc {
    p: i32,
    q: i32,
    r: i32,
    yp: i32,
    yyp: i32,
}

impl GroupAcc {
    /// Adds one row's run sums at row offset `dy` (`dy2 = dy^2`).
    #[inline(always)]
    fn add(&mut self, p: i32, q: i32, r: i32, dy: i32, dy2: i32) {
        self.p += p;
        self.q += q;
        self.r += r;
        self.yp += dy * p;
        self.yyp += dy2 * p;
    }
}

/// `(P, Q, R)` of a run of samples (see [`GroupAcc`]): three adds a sample, no multiply;
/// `sum dx v` and `sum dx^2 v` follow per cell in closed form.
#[inline(always)]
fn row_sums(seg: &[u16]) -> (i32, i32, i32) {
    let (mut p, mut q, mut r) = (0i32, 0i32, 0i32);
    for v in seg {
        p += i32::from(*v);
        q += p;
        r += q;
    }
    (p, q, r)
}

/// The fused moments `S_w = sum w (e - level_e)` (e-) of the plan's box, with the weight
/// sums `sum w`, and whether a sample is saturated. `None` for buffers that do not match.
fn fused_sums(
    cal: &FrameCalibration<'_>,
    plan: &RawCogPlan,
    win: &RawWindow<'_>,
    level_e: f32,
) -> Option<([f32; 5], bool)> {
    let b = &plan.b;
    let bw = usize::from(b.w);
    let ww = usize::from(win.rect.width);
    let dy0 = i32::from(b.y0) - i32::from(b.ay);
    let groups = plan.groups.get(..usize::from(plan.n_groups))?;
    let runs = plan.rows.get(..usize::from(plan.n_rows))?;
    let sat = plan.key.saturation_adu;
    let mut saturated = false;
    let mut e = [0f32; 5];
    let col_off = usize::from(b.x0 - win.rect.x0);
    let row_off = usize::from(b.y0 - win.rect.y0);
    let levels = win.levels.get(row_off..row_off + usize::from(b.h))?;
    let raw = win.raw.get(row_off * ww + col_off..)?;
    let [use0, use1] = plan.use_out;
    // The column split of two groups (the box's width for one).
    let split = match groups {
        [_] => bw,
        [_, g2] => usize::from(g2.i0),
        _ => 0,
    };
    for (k, run) in runs.iter().enumerate() {
        let (ra, rb) = (usize::from(run.r0), usize::from(run.r1));
        // Offsets (16 bias per output) of the tile row's rows.
        let (mut bias0, mut bias1) = ([0i32; 3], [0i32; 3]);
        let mut rw = [0i32; 3];
        let add = |acc: &mut [i32; 3], v: i32, dy: i32, dy2: i32| {
            acc[0] += v;
            acc[1] += dy * v;
            acc[2] += dy2 * v;
        };
        for (lv, dy) in levels.get(ra..rb)?.iter().zip(dy0 + ra as i32..) {
            let dy2 = dy * dy;
            if use0 {
                add(
                    &mut bias0,
                    offset_16ths(lv.bias(Output(0)), ColumnBiasAdu::ZERO),
                    dy,
                    dy2,
                );
            }
            if use1 {
                add(
                    &mut bias1,
                    offset_16ths(lv.bias(Output(1)), ColumnBiasAdu::ZERO),
                    dy,
                    dy2,
                );
            }
            add(&mut rw, 1, dy, dy2);
        }
        let bias = [bias0, bias1];
        let rows = raw.get(ra * ww..)?.chunks(ww.max(1)).take(rb - ra);
        let cells = if plan.cells_held {
            plan.cells.get(k * groups.len()..)
        } else {
            None
        };
        if split > 0 {
            // One or two column groups: both runs' sums in registers.
            let [mut a1, mut a2] = [GroupAcc::default(); 2];
            for (row, dy) in rows.zip(dy0 + ra as i32..) {
                let (left, right) = row.get(..bw)?.split_at_checked(split)?;
                let (p1, q1, s1) = row_sums(left);
                let (p2, q2, s2) = row_sums(right);
                // A sample at or above saturation makes its run's sum reach it: test the
                // samples only then.
                if p1 + p2 >= i32::from(sat) {
                    saturated |= left.iter().chain(right).any(|v| *v >= sat);
                }
                let dy2 = dy * dy;
                a1.add(p1, q1, s1, dy, dy2);
                a2.add(p2, q2, s2, dy, dy2);
            }
            flush(
                cal,
                groups,
                &[a1, a2],
                cells,
                (run.y, rw),
                &bias,
                level_e,
                &mut e,
            );
        } else {
            let mut acc = [GroupAcc::default(); MB];
            for (row, dy) in rows.zip(dy0 + ra as i32..) {
                let row = row.get(..bw)?;
                for (gr, a) in groups.iter().zip(acc.iter_mut()) {
                    let i0 = usize::from(gr.i0);
                    let seg = row.get(i0..i0 + usize::from(gr.m))?;
                    let (p, q, r) = row_sums(seg);
                    if p >= i32::from(sat) {
                        saturated |= seg.iter().any(|v| *v >= sat);
                    }
                    a.add(p, q, r, dy, dy * dy);
                }
            }
            flush(
                cal,
                groups,
                &acc,
                cells,
                (run.y, rw),
                &bias,
                level_e,
                &mut e,
            );
        }
    }
    Some((e, saturated))
}

/// Ends one tile row of the box: each column group's raw sums become the cell's
/// `Z_w = sum w d` (offsets subtracted in closed form), then its background-subtracted
/// moments `A Z_w - (K + L) W_w` are added to `e` (`L` = `level_e`); `y` is the tile row's
/// first active row, `rw` its row weights (rows, `sum dy`, `sum dy^2`). The cells'
/// constants come from the plan (`cells`, this tile row's first) or, when it does not hold
/// them, from the table.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn flush(
    cal: &FrameCalibration<'_>,
    groups: &[ColGroup],
    acc: &[GroupAcc],
    cells: Option<&[CellConst]>,
    (y, rw): (u16, [i32; 3]),
    bias: &[[i32; 3]; 2],
    level_e: f32,
    e: &mut [f32; 5],
) {
    let [n_r, sdy, sdy2] = rw;
    for (k, (gr, a)) in groups.iter().zip(acc.iter()).enumerate() {
        let [b1, bdy, bdy2] = if gr.out1 { bias[1] } else { bias[0] };
        let m = i32::from(gr.m);
        // Raw moments of the cell from the prefix sums (u = m - i, dx = c - u).
        let c = gr.dx_a + m;
        let su2 = 2 * a.r - a.q;
        let raw_x = c * a.p - a.q;
        let raw_xx = c * c * a.p - 2 * c * a.q + su2;
        // Offsets: 16 (bias(row) + column_bias(col)) summed with each weight.
        let [cb0, cbx, cbxx] = gr.cb;
        let [sdx, sdx2] = gr.sdx;
        let z = [
            16 * a.p - (m * b1 + n_r * cb0),
            16 * raw_x - (sdx * b1 + n_r * cbx),
            16 * raw_xx - (sdx2 * b1 + n_r * cbxx),
            16 * a.yp - (m * bdy + sdy * cb0),
            16 * a.yyp - (m * bdy2 + sdy2 * cb0),
        ];
        let w = [m * n_r, sdx * n_r, sdx2 * n_r, m * sdy, m * sdy2];
        let cc = match cells.and_then(|c| c.get(k)) {
            Some(cc) => *cc,
            None => cell_const(cal, gr.x, y, gr.out1),
        };
        let kl = cc.k + level_e;
        for (ei, (zv, wv)) in e.iter_mut().zip(z.iter().zip(w.iter())) {
            *ei += cc.a * *zv as f32 - kl * *wv as f32;
        }
    }
}

/// The CoG of the plan's box by the fused sums (see [`super`]).
pub(super) fn fused_cog(
    cal: &FrameCalibration<'_>,
    plan: &RawCogPlan,
    win: &RawWindow<'_>,
    level_bits: i64,
    var_bg: f32,
) -> Option<Meas> {
    // The level is within i32 bits (level_to_bits saturates there).
    let l = level_bits as i32 as f32 * (1.0 / 64.0);
    let ([s, sx, sxx, sy, syy], saturated) = fused_sums(cal, plan, win, l)?;
    let [n, wx, wxx, wy, wyy] = plan.wt.map(|v| v as f32);
    // No star: the flux is not positive (or not a number).
    if s.is_nan() || s <= 0.0 {
        return None;
    }
    let inv = 1.0 / s;
    let ox = sx * inv;
    let oy = sy * inv;
    let axis = |o: f32, s1: f32, s2: f32, w1: f32, w2: f32| {
        let shot = pos(s2 - 2.0 * o * s1 + o * o * s);
        let bg = var_bg * (w2 - 2.0 * o * w1 + o * o * n);
        math::sqrt(pos(shot + bg)) * inv
    };
    let snr = s / math::sqrt(s + n * var_bg).max(f32::MIN_POSITIVE);
    let mut flags = CentroidFlags::empty();
    if saturated {
        flags |= CentroidFlags::SATURATED;
    }
    Some(Meas {
        ox,
        oy,
        flux_e: s,
        snr,
        sigma_x: axis(ox, sx, sxx, wx, wxx),
        sigma_y: axis(oy, sy, syy, wy, wyy),
        flags,
    })
}
