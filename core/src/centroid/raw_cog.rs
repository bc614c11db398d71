//! The tracking path's corrected centre of gravity straight from a window's RAW samples:
//! calibration and CoG power 1 fused, with a given background and an optional pixel-phase
//! curve ([`super::pixcorr`]). It gives what `calibrate_window` + [`super::cog::cog`]
//! (power 1, [`Background::Given`], box anchored on a given pixel) + [`PixCorr::apply`] give,
//! without calibrating any pixel.
//!
//! # Formula
//! The calibration ([`crate::calib::formula`]) is affine in the raw sample inside a *cell*
//! (pixels sharing output amplifier, dark tile and flat tile):
//! ```text
//! e = (d gamma / 16 - D) phi,   d = 16 raw - 16 bias(row, output) - 16 column_bias(col)
//!   = A d - K,                  A = gamma phi / 16,  K = D phi
//! ```
//! (`gamma` the output's gain, `D` the dark term, `phi` the inverse flat). With
//! `F = e - L` (`L` the given level) and a weight `w` of the pixel's offsets from the anchor
//! (`dx`, `dy` in `-h..=h`, `h = side / 2`), every CoG sum is, exactly,
//! ```text
//! sum w F = sum_cells ( A Z_w - (K + L) W_w ),   Z_w = sum_cell w d,  W_w = sum_cell w
//! ```
//! for `w` in `1, dx, dx^2, dy, dy^2`. The raw part of `Z_w` is accumulated per row and
//! *column run* (the box's columns of one cell: one run for a box inside a tile column, two
//! when it crosses a tile edge or the output split) as three running sums, one add each per
//! sample: `P = sum v`, `Q = sum_i P_i = sum u v`, `R = sum_i Q_i = sum u (u + 1) / 2 v`
//! (`u = m - i` for the run's i-th of `m` columns). With `c` the `dx` just past the run,
//! `dx = c - u`, so `sum dx v = c P - Q` and `sum dx^2 v = c^2 P - 2 c Q + 2 R - Q`, per
//! cell, not per pixel; each row adds `P`, `Q`, `R`, `dy P`, `dy^2 P` to its run's cell. The
//! offsets' part (`16 bias` per row and output, `16 column_bias` per column) is subtracted
//! in closed form from sums over the rows and over the columns, which need no raw sample.
//! Only the cell sums meet the calibration constants, in f32: one cell for a box inside one
//! tile, usually 2 or 4 (2x2 tiles) with the 8x8-tiled table, more at the output split.
//! Then, with `S_w = sum w F` and `n` pixels:
//! ```text
//! x = S_dx / S_1                                            (offset from the anchor)
//! sigma_x^2 = [ max(S_dx2 - 2 x S_dx + x^2 S_1, 0)
//!             + var_bg (sum dx^2 - 2 x sum dx + x^2 n) ] / S_1^2
//! SNR = S_1 / sqrt(max(S_1, 0) + n var_bg),   flux = S_1
//! ```
//! The shot-noise term uses `F`, not `max(F, 0)` as [`super::cog`] does: `E[F] = mu`, so
//! `sum (d - x)^2 F` is an unbiased estimate of `sum (d - x)^2 mu` (clamped at 0 because
//! noise can make it negative), where `max(F, 0)` over-estimates the faint wings at low
//! SNR. The position and flux are the general path's; only sigma and SNR differ by that.
//!
//! # Difference to the per-pixel calibrated sums
//! The general path rounds every pixel to 1/64 e- (after truncating the signal term to
//! 2^-16 e-): each calibrated pixel is within
//! [`QUANTISATION_E`](crate::calib::formula::QUANTISATION_E) of the formula's exact
//! value, so its `sum w F` is within `sum |w| QUANTISATION_E` of the exact sum. The fused
//! sums are exact integers (`Z_w`, `W_w`, see below) until the per-cell f32 step: converting
//! `Z_w`, `W_w` and the constants (gain bits, dark bits) to f32 and the products and sums
//! round by at most `2^-24` relative each, about ten roundings in a chain plus one per cell
//! accumulated, so
//! ```text
//! |S_w(fused) - S_w(exact)| <= (10 + cells) 2^-24 M_w,
//! M_w = sum_cells (|A Z_w| + |K W_w|) + |L sum w| <= sum |w| (|A d| + |K| + |L|)
//! ```
//! (the host test `raw_cog` checks this against an f64 evaluation of the formula, and the
//! position against the general path with both bounds added). For a 7x7 box at the bias
//! level plus 20,000 e- the f32 term is ~0.01 e-, below the general path's own rounding.
//!
//! # Integer ranges (no overflow for any 16-bit input)
//! Box side at most [`MAX_BOX_SIDE`] = 9, so `|dx|, |dy| <= 4`, `sum |d| <= 20`,
//! `sum d^2 <= 60` over a side, at most 81 pixels, all in i32:
//! - running sums of a run of `m <= 9` samples over at most 9 rows: `P <= 81 * 65535
//!   < 2^23`, `Q <= 9 P < 2^26`, `R <= 45 P < 2^29`; `|dy P| <= 4 P`, `dy^2 P <= 16 P`;
//! - `|c| <= 5` (`c` is the last column's `dx` plus one), so `c^2 P < 2^28`, `2 |c| Q < 2^30`,
//!   `2 R < 2^30`: the `dx^2` moment's terms and result stay below 2^31; the moments
//!   themselves are below `60 * 9 * 65535 < 2^26`, times 16 below 2^30;
//! - per pixel `|d| = |16 raw - offset| <= 2^20 + 2^15 < 2^21` (raw <= 65535, bias <= 65535
//!   ADU, |column bias| < 2^11 ADU); the offsets' weighted sums are below
//!   `540 * (2^20 + 2^15) < 2^30`, so a cell's `Z_w = sum w d` (`sum |w| <= 9 * 60 = 540`) is
//!   below `540 * 2^21 < 2^31`; `W_w <= 540`.

//! # Cost
//! Split in two ([`RawCogPlan`]): what depends only on the table, the dark scale and the
//! box position (column groups and their column-bias sums, tile rows, the cells' `A` and
//! `K` from the gain, dark and flat look-ups, the defect-list search, the saturation level)
//! is built once per box position; each frame then pays per sample one load and three
//! adds, per row and run the five cell sums (~120 instructions a row of a 7x7 box with the
//! bookkeeping and register spills), per tile row the line levels' bias sums, per cell
//! ~30 integer operations and ten f32 multiply-adds, per star one divide, three square
//! roots (`math::sqrt`) and the curve (two Catmull-Rom evaluations). `cargo m7-bench`
//! (7x7 box crossing 2x2 tiles, curve applied): `centroid_cog1c_raw_planned_7x7` (apply)
//! 2,568 instructions, `raw_cog_plan_7x7` (plan build, in place) 1,308,
//! `centroid_cog1c_raw_7x7` (one-shot [`raw_cog`] = build + apply) 4,028, against 4,655 +
//! 6,805 for `window_calibrate` + `centroid_cog1c_7x7` (general path with a perimeter
//! median); `tracking_frame`, 30 applications: 77,651. What bounds the application (QEMU
//! `-d exec` trace, per call): the fused sums and CoG ~1,970 (of which the row loop ~850:
//! two runs of 3-4 samples a row with their set-up and spilled accumulators; the bias sums
//! and tile-row bookkeeping ~300; the four cells ~370), the curve ~280, the rest (plan
//! check, re-anchoring test, clamps) ~250. An unrolled 7-wide row loop (per-column prefix
//! sums over the rows: 21 accumulators, spilled) and a column-major loop (strided
//! `step_by`) were both slower (2,667 and 3,659) and were not kept.

//! # Re-anchoring
//! The pixel-phase curve holds only while the CoG lies within half a pixel of the anchor
//! (its domain is the anchor pixel's phase). When it lands further, the box is moved once to
//! the CoG's pixel (if it still fits the window unclipped) and the CoG measured again;
//! [`CentroidFlags::NOT_CONVERGED`] when it still lands more than half a pixel off, or when
//! the move would leave the window.
//!
//! # Where it fails (and what it does then)
//! - A listed hot or telegraph pixel inside the box: the fused sums cannot apply its own
//!   dark law or skip it, so the box goes through the general path (`calibrate_window` of
//!   the box, `cog` with the given background, the curve): exact, slower.
//! - A saturated sample (raw >= the table's saturation): [`CentroidFlags::SATURATED`], as
//!   the general path (the value is a lower bound there too).
//! - A box clipped by the window: [`CentroidFlags::EDGE_CLIPPED`], computed on the clipped
//!   box like the general path (truncation bias; the curve was made for the full box).
//! - Flux not positive, bad buffers, an anchor outside the window, a window outside the
//!   active area, a side above [`MAX_BOX_SIDE`]: [`CentroidFlags::DEGENERATE`] with the
//!   anchor pixel as position. Never a panic, never a NaN.
//! - Everything [`super::cog`] and [`super::pixcorr`] list: pixelisation without a curve, a
//!   PSF wider than the curve's, a background level that is wrong (it pulls the CoG towards
//!   the box centre: the level is taken as exact).

use super::cog::{Anchor, CogParams, CogPower, cog};
use super::{
    Background, Centroid, CentroidFlags, CentroidInput, Measured, finish_in, level_to_bits, math,
    sanitize_var,
};
use crate::calib::formula::offset_16ths;
use crate::calib::{FrameCalibration, LineLevels, PixelFlags};
use crate::geometry::Output;
use crate::table::pixcorr::PixCorr;
use crate::units::{ColumnBiasAdu, Electrons};
use crate::window::{Rect, Window};

/// Largest box side the fused path takes (the integer ranges in the module docs hold up to
/// it).
pub const MAX_BOX_SIDE: u8 = 9;
const MB: usize = MAX_BOX_SIDE as usize;
const MB2: usize = MB * MB;

/// A window of raw samples with the levels of its rows.
#[derive(Clone, Copy, Debug)]
pub struct RawWindow<'a> {
    /// Where the window lies on the active area.
    pub rect: Rect,
    /// `rect.len()` raw samples (ADU), row-major.
    pub raw: &'a [u16],
    /// The levels of each row: `levels[r]` for active row `rect.y0 + r`.
    pub levels: &'a [LineLevels],
}

/// Parameters of [`raw_cog`].
#[derive(Clone, Copy, Debug)]
pub struct RawCogParams<'c> {
    /// Box side, px: odd (an even side is rounded up), at most [`MAX_BOX_SIDE`].
    pub box_side: u8,
    /// Background level, e- per pixel (quantised to 1/64 e- as the general path does).
    pub level_e: f32,
    /// Per-pixel background variance (read noise, sky and dark noise), e-^2.
    pub variance_e2: f32,
    /// Pixel-phase curve (power 1, this box, given background) applied to the result.
    pub curve: Option<PixCorr<'c>>,
}

/// What [`raw_cog`] measured and how.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawCog {
    /// The (corrected) centroid, active-area coordinates.
    pub centroid: Centroid,
    /// The box held a listed defect: the general path measured it.
    pub general_path: bool,
    /// The box was moved once to the CoG's pixel.
    pub reanchored: bool,
    /// The pixel the measured box is centred on (after any move), active coordinates.
    pub anchor: (u16, u16),
}

/// A box in active coordinates with its anchor.
#[derive(Clone, Copy, Debug)]
struct BoxAt {
    x0: u16,
    y0: u16,
    w: u16,
    h: u16,
    ax: u16,
    ay: u16,
}

impl BoxAt {
    fn rect(&self) -> Rect {
        Rect {
            x0: self.x0,
            y0: self.y0,
            width: self.w,
            height: self.h,
        }
    }
}

/// A measurement relative to the anchor, before the curve.
#[derive(Clone, Copy, Debug)]
struct Meas {
    ox: f32,
    oy: f32,
    flux_e: f32,
    snr: f32,
    sigma_x: f32,
    sigma_y: f32,
    flags: CentroidFlags,
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
struct ColGroup {
    /// First column's index in the box, and the run's length (both at most [`MB`]).
    i0: u8,
    m: u8,
    /// On output 1.
    out1: bool,
    /// Active column of the first column.
    x: u16,
    /// `dx` of the first column.
    dx_a: i32,
    /// `16 column_bias` summed with weights 1, dx, dx^2 (1/16 ADU).
    cb: [i32; 3],
    /// `sum dx`, `sum dx^2` over the run.
    sdx: [i32; 2],
}

/// A run of box rows in one dark and one flat tile row.
#[derive(Clone, Copy, Debug, Default)]
struct RowRun {
    /// First and one-past-last row index in the box (at most [`MB`]).
    r0: u8,
    r1: u8,
    /// Active row of the first row.
    y: u16,
}

/// A cell's calibration constants: `A` (e- per 1/16 ADU) and `K` (e-), see the module docs.
#[derive(Clone, Copy, Debug, Default)]
struct CellConst {
    a: f32,
    k: f32,
}

/// Cells whose constants a plan holds (a 9x9 box over 8-pixel tiles at the output split has
/// at most 4 column groups x 2 tile rows); a box with more (tiles below 8 pixels) looks its
/// constants up at every application instead (same values, slower).
pub const PLAN_CELLS: usize = 8;

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
struct PlanKey {
    win: Rect,
    anchor: (u16, u16),
    side: u8,
    dark_scale_bits: i32,
    /// A fingerprint of the table: its length, saturation and both gains (a table with the
    /// same four values but other maps is not told apart: the firmware loads one table).
    table_len: usize,
    saturation_adu: u16,
    gain_bits: [u32; 2],
}

/// Everything of the fused CoG (see the module docs) that depends only on the table, the
/// frame's dark scale, the window's position and the box (side, anchor): the box, its
/// column groups with their column-bias sums, its tile rows with their row weights, the
/// cells' constants `A`, `K`, whether it holds a listed defect, the saturation level. Built
/// once per box position ([`RawCogPlan::rebuild`] in place, 1,308 instructions on the M7
/// for a 7x7 box: the table look-ups and the defect-list search), then applied to each
/// frame's raw samples and line levels ([`RawCogPlan::apply`], 2,568). Size: 472 bytes on
/// a 64-bit host, a little less on the M7 (`size_of`; the host test `plan_is_small` keeps it
/// at most 480).
///
/// Staleness: the plan keeps what it was built for (window rectangle, anchor, side, the
/// frame calibration's dark scale and a fingerprint of the table) and `apply` refuses
/// ([`PlanError::Stale`]) any other; the check is a few compares.
#[derive(Clone, Copy, Debug)]
pub struct RawCogPlan {
    key: PlanKey,
    b: BoxAt,
    clipped: bool,
    /// The box holds a listed defect: the general path measures it.
    defects: bool,
    groups: [ColGroup; MB],
    n_groups: u8,
    rows: [RowRun; MB],
    n_rows: u8,
    /// `cells[run * n_groups + group]`, when `n_groups * n_rows <= PLAN_CELLS`.
    cells: [CellConst; PLAN_CELLS],
    cells_held: bool,
    /// The outputs the groups read.
    use_out: [bool; 2],
    /// The weight sums `sum w` of the box, for w in 1, dx, dx^2, dy, dy^2.
    wt: [i32; 5],
}

/// The key of a frame calibration, window, anchor and side.
fn key_of(cal: &FrameCalibration<'_>, win: Rect, anchor: (u16, u16), side: u8) -> PlanKey {
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
fn cell_const(cal: &FrameCalibration<'_>, x: u16, y: u16, out1: bool) -> CellConst {
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

    /// The box side the plan was built for.
    pub fn box_side(&self) -> u8 {
        self.key.side
    }

    /// The anchor the plan was built for.
    pub fn anchor(&self) -> (u16, u16) {
        self.key.anchor
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

    /// The corrected CoG of the plan's box in the raw window `win` (this frame's samples
    /// and line levels), as [`raw_cog`] gives it (bit for bit: `raw_cog` is `new` +
    /// `apply`). [`PlanError::Stale`] when `cal`, `win.rect` or `params.box_side` differ
    /// from the plan's; a window whose buffers do not match its rectangle gives a
    /// [`CentroidFlags::DEGENERATE`] centroid. A re-anchoring move builds the moved box's
    /// plan on the spot (one-shot cost).
    pub fn apply(
        &self,
        cal: &FrameCalibration<'_>,
        win: &RawWindow<'_>,
        params: &RawCogParams<'_>,
    ) -> Result<RawCog, PlanError> {
        let side = (params.box_side / 2).saturating_mul(2).saturating_add(1);
        if self.key != key_of(cal, win.rect, self.key.anchor, side) {
            return Err(PlanError::Stale);
        }
        Ok(self.apply_checked(cal, win, params))
    }

    fn apply_checked(
        &self,
        cal: &FrameCalibration<'_>,
        win: &RawWindow<'_>,
        params: &RawCogParams<'_>,
    ) -> RawCog {
        let side = self.key.side;
        let anchor = self.key.anchor;
        let (ax, ay) = anchor;
        let clip_flag = if self.clipped {
            CentroidFlags::EDGE_CLIPPED
        } else {
            CentroidFlags::empty()
        };
        if !buffers_ok(win) {
            return RawCog {
                centroid: degenerate(ax, ay, side, CentroidFlags::empty()),
                general_path: false,
                reanchored: false,
                anchor,
            };
        }
        let level_bits = level_to_bits(params.level_e);
        let var_bg = sanitize_var(params.variance_e2);
        let mut general_path = false;
        let mut measure = |p: &RawCogPlan| {
            if p.defects {
                general_path = true;
                let level_e = level_bits as i32 as f32 * (1.0 / 64.0);
                general_cog(cal, win, &p.b, side, level_e, var_bg)
            } else {
                fused_cog(cal, p, win, level_bits, var_bg)
            }
        };
        let Some(mut m) = measure(self) else {
            return RawCog {
                centroid: degenerate(ax, ay, side, clip_flag),
                general_path,
                reanchored: false,
                anchor,
            };
        };
        let (mut ax, mut ay) = (ax, ay);
        let mut reanchored = false;
        let far = |m: &Meas| !(m.ox.abs() <= 0.5 && m.oy.abs() <= 0.5);
        let mut flags = clip_flag;
        if far(&m) {
            // Move once to the CoG's pixel; offsets beyond the box are noise: at most h pixels.
            let h = f32::from(side / 2);
            let step = |o: f32| {
                let o = o.clamp(-h, h);
                (if o >= 0.0 { o + 0.5 } else { o - 0.5 }) as i32
            };
            let nx = i32::from(ax) + step(m.ox);
            let ny = i32::from(ay) + step(m.oy);
            let moved = u16::try_from(nx)
                .ok()
                .zip(u16::try_from(ny).ok())
                .and_then(|(nx, ny)| {
                    let mut np = Self::EMPTY;
                    np.rebuild(cal, win.rect, (nx, ny), side).ok()?;
                    Some(np)
                })
                .filter(|p| !p.clipped || self.clipped);
            match moved {
                Some(np) => match measure(&np) {
                    Some(m2) => {
                        (ax, ay) = (np.b.ax, np.b.ay);
                        m = m2;
                        reanchored = true;
                        if far(&m) {
                            flags |= CentroidFlags::NOT_CONVERGED;
                        }
                    }
                    None => flags |= CentroidFlags::NOT_CONVERGED,
                },
                None => flags |= CentroidFlags::NOT_CONVERGED,
            }
        }
        let c = finish(win.rect, ax, ay, side, &m, flags | m.flags);
        let centroid = match &params.curve {
            Some(curve) => curve.apply(c),
            None => c,
        };
        RawCog {
            centroid,
            general_path,
            reanchored,
            anchor: (ax, ay),
        }
    }
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

/// The CoG of the plan's box by the fused sums (see the module docs).
fn fused_cog(
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
        let shot = super::pos(s2 - 2.0 * o * s1 + o * o * s);
        let bg = var_bg * (w2 - 2.0 * o * w1 + o * o * n);
        math::sqrt(super::pos(shot + bg)) * inv
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

/// The general path on the box: calibrate it, `cog` with the given background over the whole
/// box; the result relative to the anchor.
#[inline(never)]
fn general_cog(
    cal: &FrameCalibration<'_>,
    win: &RawWindow<'_>,
    b: &BoxAt,
    side: u8,
    level_e: f32,
    var_bg: f32,
) -> Option<Meas> {
    let rect = b.rect();
    let n = rect.len();
    let mut raw = [0u16; MB2];
    let ww = usize::from(win.rect.width);
    let col_off = usize::from(b.x0 - win.rect.x0);
    let row_off = usize::from(b.y0 - win.rect.y0);
    let bw = usize::from(b.w);
    for (r, dst) in raw.chunks_exact_mut(bw).take(usize::from(b.h)).enumerate() {
        let start = (row_off + r) * ww + col_off;
        dst.copy_from_slice(win.raw.get(start..start + bw)?);
    }
    let levels = win.levels.get(row_off..row_off + usize::from(b.h))?;
    let mut e = [Electrons::ZERO; MB2];
    let mut f = [PixelFlags::empty(); MB2];
    let (raw, e, f) = (raw.get(..n)?, e.get_mut(..n)?, f.get_mut(..n)?);
    cal.calibrate_window(rect, raw, levels, e, f).ok()?;
    let window = Window::new(rect, e)?;
    let input = CentroidInput::new(window).with_pixel_flags(f);
    let c = cog(
        &input,
        &CogParams {
            power: CogPower::One,
            box_side: side,
            anchor: Anchor::WindowCentre,
            background: Background::Given {
                level_e,
                variance_e2: var_bg,
            },
        },
    );
    if c.flags.contains(CentroidFlags::DEGENERATE) {
        return None;
    }
    Some(Meas {
        ox: c.x_px - f32::from(b.ax),
        oy: c.y_px - f32::from(b.ay),
        flux_e: c.flux_e,
        snr: c.snr,
        sigma_x: c.sigma_x_px,
        sigma_y: c.sigma_y_px,
        // The window's own clip flag and LOW_SNR are set again below.
        flags: c.flags & !(CentroidFlags::LOW_SNR | CentroidFlags::CLAMPED),
    })
}

/// The anchor pixel as a degenerate centroid.
fn degenerate(ax: u16, ay: u16, side: u8, flags: CentroidFlags) -> Centroid {
    let half = f32::from(side) * 0.5;
    Centroid {
        x_px: f32::from(ax),
        y_px: f32::from(ay),
        flux_e: 0.0,
        snr: 0.0,
        sigma_x_px: half,
        sigma_y_px: half,
        flags: flags | CentroidFlags::DEGENERATE,
    }
}

/// True when the window's buffers match its rectangle.
fn buffers_ok(win: &RawWindow<'_>) -> bool {
    win.raw.len() == win.rect.len() && win.levels.len() == usize::from(win.rect.height)
}

/// The corrected CoG of the box of `params.box_side` around active pixel `anchor` of the raw
/// window `win` (see the module docs): [`RawCogPlan::new`] then [`RawCogPlan::apply`].
pub fn raw_cog(
    cal: &FrameCalibration<'_>,
    win: &RawWindow<'_>,
    anchor: (u16, u16),
    params: &RawCogParams<'_>,
) -> RawCog {
    let mut plan = RawCogPlan::EMPTY;
    match plan.rebuild(cal, win.rect, anchor, params.box_side) {
        Ok(()) => plan.apply_checked(cal, win, params),
        Err(_) => {
            let side = (params.box_side / 2).saturating_mul(2).saturating_add(1);
            RawCog {
                centroid: degenerate(anchor.0, anchor.1, side, CentroidFlags::empty()),
                general_path: false,
                reanchored: false,
                anchor,
            }
        }
    }
}

/// Active coordinates, clamped to the window (pixel edges), finite values, `LOW_SNR`.
fn finish(win: Rect, ax: u16, ay: u16, side: u8, m: &Meas, flags: CentroidFlags) -> Centroid {
    // The anchor relative to the window's corner (inside it: checked by the box set-up).
    let rel = |a: u16, o: u16| f32::from(a.saturating_sub(o));
    let rel_m = Measured {
        col: rel(ax, win.x0) + m.ox,
        row: rel(ay, win.y0) + m.oy,
        flux_e: m.flux_e,
        snr: m.snr,
        sigma_col: m.sigma_x,
        sigma_row: m.sigma_y,
    };
    finish_in(win, &rel_m, f32::from(side) * 0.5, flags)
        .unwrap_or_else(|| degenerate(ax, ay, side, flags))
}
