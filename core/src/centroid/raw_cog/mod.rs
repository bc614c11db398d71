//! The tracking path's corrected centre of gravity straight from a window's RAW samples:
//! calibration and CoG power 1 fused, with a given background and an optional pixel-phase
//! curve ([`super::pixcorr`]). It gives what `calibrate_window` + [`super::cog::cog`]
//! (power 1, [`Background::Given`](super::Background::Given), box anchored on a given pixel) + [`PixCorr::apply`] give,
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
//! ~2,600 instructions, `raw_cog_plan_7x7` (plan build, in place) ~1,300,
//! `centroid_cog1c_raw_7x7` (one-shot [`raw_cog`] = build + apply) ~4,000, against ~4,700 +
//! ~6,800 for `window_calibrate` + `centroid_cog1c_7x7` (general path with a perimeter
//! median); `tracking_frame`, 30 applications: ~78,000 (exact counts: docs/speed.md). What bounds the application (QEMU
//! `-d exec` trace, per call): the fused sums and CoG ~2,000 (of which the row loop ~850:
//! two runs of 3-4 samples a row with their set-up and spilled accumulators; the bias sums
//! and tile-row bookkeeping ~300; the four cells ~370), the curve ~280, the rest (plan
//! check, re-anchoring test, clamps) ~250. The row loop is the fastest of the three
//! layouts measured: an unrolled 7-wide row loop (per-column prefix sums over the rows: 21
//! accumulators, spilled) and a column-major loop (strided `step_by`) cost ~2,700 and
//! ~3,700.

//! # Re-anchoring
//! The pixel-phase curve holds only while the CoG lies within half a pixel of the anchor
//! (its domain is the anchor pixel's phase). When it lands further, the box is moved once to
//! the CoG's pixel (if it still fits the window unclipped) and the CoG measured again;
//! [`CentroidFlags::NOT_CONVERGED`](super::CentroidFlags::NOT_CONVERGED) when it still lands more than half a pixel off, or when
//! the move would leave the window.
//!
//! # Where it fails (and what it does then)
//! - A listed hot or telegraph pixel inside the box: the fused sums cannot apply its own
//!   dark law or skip it, so the box goes through the general path (`calibrate_window` of
//!   the box, `cog` with the given background, the curve): exact, slower.
//! - A saturated sample (raw >= the table's saturation): [`CentroidFlags::SATURATED`](super::CentroidFlags::SATURATED), as
//!   the general path (the value is a lower bound there too).
//! - A box clipped by the window: [`CentroidFlags::EDGE_CLIPPED`](super::CentroidFlags::EDGE_CLIPPED), computed on the clipped
//!   box like the general path (truncation bias; the curve was made for the full box).
//! - Flux not positive, bad buffers, an anchor outside the window, a window outside the
//!   active area, a side above [`MAX_BOX_SIDE`]: [`CentroidFlags::DEGENERATE`](super::CentroidFlags::DEGENERATE) with the
//!   anchor pixel as position. Never a panic, never a NaN.
//! - Everything [`super::cog`] and [`super::pixcorr`] list: pixelisation without a curve, a
//!   PSF wider than the curve's, a background level that is wrong (it pulls the CoG towards
//!   the box centre: the level is taken as exact).

mod apply;
mod plan;
mod sums;

pub use apply::raw_cog;
pub use plan::{MAX_BOX_SIDE, PlanError, RawCogPlan};

use super::Centroid;
use crate::calib::LineLevels;
use crate::table::pixcorr::PixCorr;
use crate::window::Rect;

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
