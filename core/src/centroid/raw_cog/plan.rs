//! The plan of one box position: everything of the fused CoG (see [`super`]) that depends
//! only on the table, the frame's dark scale, the window's position and the box, worked out
//! once so that each frame pays only for its raw samples and line levels.
//!
//! The box is cut into column groups (runs of columns on one output, in one dark and one
//! flat tile column) with their column-bias sums, and into tile rows with their row
//! weights; each group and tile row is a cell whose calibration constants `A`, `K` come from
//! the gain, dark and flat look-ups. The plan also records whether the box holds a listed
//! defect (then the general path measures it) and what it was built for, so that an
//! application to another window, anchor, side, table or dark scale is refused as stale.
//!
//! # Cost
//! Built in place by [`RawCogPlan::rebuild`]: ~1,300 instructions on the M7 for a 7x7 box
//! (`raw_cog_plan_7x7` of `cargo m7-bench`), the table look-ups and the defect-list search.
//! Size 472 bytes on a 64-bit host (the host test `plan_is_small` keeps it at most 480).

use crate::calib::FrameCalibration;
use crate::geometry::Output;
use crate::window::Rect;

/// Largest box side the fused path takes (the integer ranges in the [`super`] docs hold up
/// to it).
pub const MAX_BOX_SIDE: u8 = 9;
/// [`MAX_BOX_SIDE`] as an array length, and its square.
pub(super) const MB: usize = MAX_BOX_SIDE as usize;
pub(super) const MB2: usize = MB * MB;

/// A box in active coordinates with its anchor.
#[derive(Clone, Copy, Debug)]
pub(super) struct BoxAt {
    pub(super) x0: u16,
    pub(super) y0: u16,
    pub(super) w: u16,
    pub(super) h: u16,
    pub(super) ax: u16,
    pub(super) ay: u16,
}

impl BoxAt {
    pub(super) fn rect(&self) -> Rect {
        Rect {
            x0: self.x0,
            y0: self.y0,
            width: self.w,
            height: self.h,
        }
    }
}

/// The side-`side` box around (ax, ay) clipped to `win`; `None` when the anchor is outside.
fn box_around(win: Rect, ax: u16, ay: u16, side: u8) -> Option<(BoxAt, bool)> {
    if !win.contains(ax, ay) {
        return None;
    }
    let h = u16::from(side / 2);
    let x0 = ax.saturating_sub(h).max(win.x0);
    let y0 = ay.saturating_sub(h).max(win.y0);
    // The window's end fits u32; the box's end is at most ax + h + 1.
    let xe = (u32::from(ax) + u32::from(h) + 1).min(u32::from(win.x0) + u32::from(win.width));
    let ye = (u32::from(ay) + u32::from(h) + 1).min(u32::from(win.y0) + u32::from(win.height));
    let w = (xe - u32::from(x0)) as u16;
    let hh = (ye - u32::from(y0)) as u16;
    let clipped = w != 2 * h + 1 || hh != 2 * h + 1;
    Some((
        BoxAt {
            x0,
            y0,
            w,
            h: hh,
            ax,
            ay,
        },
        clipped,
    ))
}

/// A run of box columns with equal calibration constants except the column bias: one
/// output, one dark tile column, one flat tile column.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct ColGroup {
    /// First column's index in the box, and the run's length (both at most [`MB`]).
    pub(super) i0: u8,
    pub(super) m: u8,
    /// On output 1.
    pub(super) out1: bool,
    /// Active column of the first column.
    pub(super) x: u16,
    /// `dx` of the first column.
    pub(super) dx_a: i32,
    /// `16 column_bias` summed with weights 1, dx, dx^2 (1/16 ADU).
    pub(super) cb: [i32; 3],
    /// `sum dx`, `sum dx^2` over the run.
    pub(super) sdx: [i32; 2],
}

/// A run of box rows in one dark and one flat tile row.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct RowRun {
    /// First and one-past-last row index in the box (at most [`MB`]).
    pub(super) r0: u8,
    pub(super) r1: u8,
    /// Active row of the first row.
    pub(super) y: u16,
}

/// A cell's calibration constants: `A` (e- per 1/16 ADU) and `K` (e-), see [`super`].
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct CellConst {
    pub(super) a: f32,
    pub(super) k: f32,
}

/// Cells whose constants a plan holds (a 9x9 box over 8-pixel tiles at the output split has
/// at most 4 column groups x 2 tile rows); a box with more (tiles below 8 pixels) looks its
/// constants up at every application instead (same values, slower).
pub(crate) const PLAN_CELLS: usize = 8;

/// Why a [`RawCogPlan`] cannot be built or applied.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PlanError {
    /// A box side above [`MAX_BOX_SIDE`], an anchor outside the window, or a window not on
    /// the active area.
    BadInput,
    /// The plan was built for another window position, anchor, box side, table or dark scale
    /// than the application's: build a new one.
    Stale,
}

/// What a plan was built for; an application checks it against its own inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct PlanKey {
    pub(super) win: Rect,
    pub(super) anchor: (u16, u16),
    pub(super) side: u8,
    pub(super) dark_scale_bits: i32,
    /// A fingerprint of the table: its length, saturation and both gains (a table with the
    /// same four values but other maps is not told apart: the firmware loads one table).
    pub(super) table_len: usize,
    pub(super) saturation_adu: u16,
    pub(super) gain_bits: [u32; 2],
}

/// Everything of the fused CoG (see [`super`]) that depends only on the table, the
/// frame's dark scale, the window's position and the box (side, anchor): the box, its
/// column groups with their column-bias sums, its tile rows with their row weights, the
/// cells' constants `A`, `K`, whether it holds a listed defect, the saturation level. Built
/// once per box position ([`RawCogPlan::rebuild`] in place, ~1,300 instructions on the M7
/// for a 7x7 box: the table look-ups and the defect-list search), then applied to each
/// frame's raw samples and line levels ([`RawCogPlan::apply`], ~2,600). Size: 472 bytes on
/// a 64-bit host, a little less on the M7 (`size_of`; the host test `plan_is_small` keeps it
/// at most 480).
///
/// Staleness: the plan keeps what it was built for (window rectangle, anchor, side, the
/// frame calibration's dark scale and a fingerprint of the table) and `apply` refuses
/// ([`PlanError::Stale`]) any other; the check is a few compares.
#[derive(Clone, Copy, Debug)]
pub struct RawCogPlan {
    pub(super) key: PlanKey,
    pub(super) b: BoxAt,
    pub(super) clipped: bool,
    /// The box holds a listed defect: the general path measures it.
    pub(super) defects: bool,
    pub(super) groups: [ColGroup; MB],
    pub(super) n_groups: u8,
    pub(super) rows: [RowRun; MB],
    pub(super) n_rows: u8,
    /// `cells[run * n_groups + group]`, when `n_groups * n_rows <= PLAN_CELLS`.
    pub(super) cells: [CellConst; PLAN_CELLS],
    pub(super) cells_held: bool,
    /// The outputs the groups read.
    pub(super) use_out: [bool; 2],
    /// The weight sums `sum w` of the box, for w in 1, dx, dx^2, dy, dy^2.
    pub(super) wt: [i32; 5],
}

/// The key of a frame calibration, window, anchor and side.
pub(super) fn key_of(
    cal: &FrameCalibration<'_>,
    win: Rect,
    anchor: (u16, u16),
    side: u8,
) -> PlanKey {
    let t = cal.table();
    PlanKey {
        win,
        anchor,
        side,
        dark_scale_bits: cal.dark_scale_bits(),
        table_len: t.len_bytes(),
        saturation_adu: t.saturation_adu(),
        gain_bits: [t.gain(Output(0)).to_bits(), t.gain(Output(1)).to_bits()],
    }
}

/// True when `r` lies in the active area (and is not empty).
fn rect_ok(cal: &FrameCalibration<'_>, r: Rect) -> bool {
    let g = cal.table().geometry();
    !r.is_empty()
        && u32::from(r.x0) + u32::from(r.width) <= u32::from(g.active_cols)
        && u32::from(r.y0) + u32::from(r.height) <= u32::from(g.active_rows)
}

/// A cell's constants at active pixel (x, y) on output 1 or 0.
#[inline(always)]
pub(super) fn cell_const(cal: &FrameCalibration<'_>, x: u16, y: u16, out1: bool) -> CellConst {
    let t = cal.table();
    let gain = t.gain(Output(u8::from(out1)));
    let flat = t.flat_inv(x, y).to_bits() as f32;
    // The dark term's two factors in f32 (an i64 product would convert through a call).
    let dark = f32::from(t.dark_rel(x, y).to_bits()) * cal.dark_scale_bits() as f32;
    // A = gain_bits flat_bits 2^-46 (e- per 1/16 ADU), K = dark_16 flat_bits 2^-30 (e-)
    // with dark_16 = 16 dark_rel_bits dark_scale_bits.
    CellConst {
        a: gain.to_bits() as f32 * flat * (1.0 / 70_368_744_177_664.0),
        k: dark * flat * (1.0 / 67_108_864.0),
    }
}

impl RawCogPlan {
    /// The plan of the `box_side` box (odd; an even side is rounded up) around active pixel
    /// `anchor` of a window at `win` (clipped to it), for this table and dark scale.
    pub fn new(
        cal: &FrameCalibration<'_>,
        win: Rect,
        anchor: (u16, u16),
        box_side: u8,
    ) -> Result<Self, PlanError> {
        let mut p = Self::EMPTY;
        p.rebuild(cal, win, anchor, box_side)?;
        Ok(p)
    }

    /// A plan of nothing (every application is stale): storage to [`Self::rebuild`].
    pub const EMPTY: Self = Self {
        key: PlanKey {
            win: Rect {
                x0: 0,
                y0: 0,
                width: 0,
                height: 0,
            },
            anchor: (0, 0),
            side: 0,
            dark_scale_bits: 0,
            table_len: 0,
            saturation_adu: 0,
            gain_bits: [0; 2],
        },
        b: BoxAt {
            x0: 0,
            y0: 0,
            w: 0,
            h: 0,
            ax: 0,
            ay: 0,
        },
        clipped: false,
        defects: false,
        groups: [ColGroup {
            i0: 0,
            m: 0,
            out1: false,
            x: 0,
            dx_a: 0,
            cb: [0; 3],
            sdx: [0; 2],
        }; MB],
        n_groups: 0,
        rows: [RowRun { r0: 0, r1: 0, y: 0 }; MB],
        n_rows: 0,
        cells: [CellConst { a: 0.0, k: 0.0 }; PLAN_CELLS],
        cells_held: false,
        use_out: [false; 2],
        wt: [0; 5],
    };

    /// [`Self::new`] in place (no copy of the plan: what the firmware does when a tracked
    /// star moves to another anchor pixel). On an error the plan is left stale for every
    /// input ([`Self::EMPTY`]'s key).
    pub fn rebuild(
        &mut self,
        cal: &FrameCalibration<'_>,
        win: Rect,
        anchor: (u16, u16),
        box_side: u8,
    ) -> Result<(), PlanError> {
        self.key = Self::EMPTY.key;
        let side = (box_side / 2).saturating_mul(2).saturating_add(1);
        if side > MAX_BOX_SIDE || !rect_ok(cal, win) {
            return Err(PlanError::BadInput);
        }
        let (b, clipped) = box_around(win, anchor.0, anchor.1, side).ok_or(PlanError::BadInput)?;
        self.fill(cal, b, clipped).ok_or(PlanError::BadInput)?;
        self.key = key_of(cal, win, anchor, side);
        Ok(())
    }

    /// True when the plan was built for this calibration, window position, anchor and side
    /// (`apply` would take it).
    pub fn is_for(
        &self,
        cal: &FrameCalibration<'_>,
        win: Rect,
        anchor: (u16, u16),
        box_side: u8,
    ) -> bool {
        let side = (box_side / 2).saturating_mul(2).saturating_add(1);
        self.key == key_of(cal, win, anchor, side)
    }

    #[inline(never)]
    fn fill(&mut self, cal: &FrameCalibration<'_>, b: BoxAt, clipped: bool) -> Option<()> {
        let t = cal.table();
        let g = t.geometry();
        let shift =
            |m: Option<crate::table::MapView<'_>>| m.map_or(16, |m| m.header().tile_log2.min(16));
        let (dl, fl) = (shift(t.dark_map()), shift(t.flat_map()));
        let bw = usize::from(b.w);
        let dx0 = i32::from(b.x0) - i32::from(b.ax);
        let dy0 = i32::from(b.y0) - i32::from(b.ay);
        let split = if g.outputs == 2 {
            (g.line_len() / 2).saturating_sub(g.first_active_col())
        } else {
            usize::MAX
        };
        // x < 2^16 and the shifts are at most 16: the next tile edge is below 2^17.
        let next_edge = |x: usize, l: u8| ((x >> l) + 1) << l;
        // Column groups (runs ending at a dark or flat tile edge or the output split), with
        // their column-bias sums.
        let groups = &mut self.groups;
        let mut n_groups = 0usize;
        let (x_start, x_end) = (usize::from(b.x0), usize::from(b.x0) + bw);
        let mut x = x_start;
        while x < x_end {
            let mut stop = x_end.min(next_edge(x, dl)).min(next_edge(x, fl));
            if x < split {
                stop = stop.min(split);
            }
            let i0 = x - x_start;
            let dx_a = dx0 + i0 as i32;
            let (mut cb, mut sdx) = ([0i32; 3], [0i32; 2]);
            for (xc, dx) in (x..stop).zip(dx_a..) {
                let c = i32::from(t.column_bias(g.raw_col_of_x(xc)).to_bits());
                cb[0] += c;
                cb[1] += dx * c;
                cb[2] += dx * dx * c;
                sdx[0] += dx;
                sdx[1] += dx * dx;
            }
            // Box columns are below 2^16 and at most MB of them (so at most MB runs).
            *groups.get_mut(n_groups)? = ColGroup {
                i0: i0 as u8,
                m: (stop - x) as u8,
                out1: x >= split,
                x: x as u16,
                dx_a,
                cb,
                sdx,
            };
            n_groups += 1;
            x = stop;
        }
        // Tile rows (computed in usize: a shift of 16, no map, would overflow a u16).
        let rows = &mut self.rows;
        let mut n_rows = 0usize;
        let y_end = usize::from(b.y0) + usize::from(b.h);
        let mut r0 = 0usize;
        let mut wt_rows = [0i32; 3];
        while r0 < usize::from(b.h) {
            let y = usize::from(b.y0) + r0;
            let stop = y_end.min(next_edge(y, dl)).min(next_edge(y, fl));
            // stop - b.y0 <= b.h <= MB; stop > y, so r1 > r0.
            let r1 = stop - usize::from(b.y0);
            for dy in (dy0 + r0 as i32..).take(r1 - r0) {
                wt_rows[0] += 1;
                wt_rows[1] += dy;
                wt_rows[2] += dy * dy;
            }
            *rows.get_mut(n_rows)? = RowRun {
                r0: r0 as u8,
                r1: r1 as u8,
                y: y as u16,
            };
            n_rows += 1;
            r0 = r1;
        }
        self.cells_held = n_groups * n_rows <= PLAN_CELLS;
        if self.cells_held {
            let gs = self.groups.get(..n_groups)?;
            let rs = self.rows.get(..n_rows)?;
            for (c, (rr, gr)) in self
                .cells
                .iter_mut()
                .zip(rs.iter().flat_map(|r| gs.iter().map(move |g| (r, g))))
            {
                *c = cell_const(cal, gr.x, rr.y, gr.out1);
            }
        }
        let gs = self.groups.get(..n_groups)?;
        let (sdx, sdx2) = gs
            .iter()
            .fold((0, 0), |(a, b), g| (a + g.sdx[0], b + g.sdx[1]));
        let [h, sdy, sdy2] = wt_rows;
        let w = bw as i32;
        self.use_out = [gs.iter().any(|g| !g.out1), gs.iter().any(|g| g.out1)];
        self.wt = [w * h, h * sdx, h * sdx2, w * sdy, w * sdy2];
        self.n_groups = n_groups as u8;
        self.n_rows = n_rows as u8;
        self.b = b;
        self.clipped = clipped;
        self.defects = cal.rect_has_defects(b.rect());
        Some(())
    }
}
