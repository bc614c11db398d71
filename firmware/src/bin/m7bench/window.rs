//! Stages of one star's 7x7 window, per window or star, averaged over [`WINDOW_REPS`]
//! windows at different positions: `window_calibrate` (the window's 49 raw samples to
//! electrons, `FrameCalibration::calibrate_window`), the fused raw-window corrected CoG
//! one-shot (`centroid_cog1c_raw_7x7`, `_5x5`: `centroid::raw_cog`, calibration included)
//! and split as tracking runs it (`raw_cog_plan_7x7`, the plan of a box, rebuilt when the
//! star moves to another anchor pixel; `centroid_cog1c_raw_planned_7x7`, its application to
//! a frame's raw window), then the centroid methods of [`crate::centroid`] on the calibrated
//! window. The run fails if the fused path flags a clean star or the plan
//! disagrees with the one-shot. Cost: [`WINDOW_REPS`] windows, 7 raw lines each.

use crate::centroid::CentroidTimes;
use crate::harness::{Bench, Out};
use crate::inputs::{G, Lcg, RAW_COLS, placeholder_levels, raw_line};
use core::hint::black_box;
use startrack_core::calib::{FrameCalibration, LineLevels, PixelFlags};
use startrack_core::centroid::raw_cog::{RawCogParams, RawCogPlan, RawWindow, raw_cog};
use startrack_core::table::pixcorr::PixCorr;
use startrack_core::units::Electrons;
use startrack_core::window::Rect;

/// Windows measured, each around its own star.
pub const WINDOW_REPS: usize = 32;

/// Measures and prints the window stages: the fused path with `raw_params` (7x7) and
/// `raw_params5` (5x5), the general path's corrected CoG with `curve`.
pub fn run(
    out: &mut Out,
    bench: &Bench,
    cal: &FrameCalibration<'_>,
    raw_params: &RawCogParams<'_>,
    raw_params5: &RawCogParams<'_>,
    curve: &PixCorr<'_>,
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    let mut t_cog1c_raw = 0u64;
    let mut t_cog1c_raw5 = 0u64;
    let mut t_raw_plan = 0u64;
    let mut t_raw_planned = 0u64;
    let mut t_window = 0u64;
    let mut t_centroid = CentroidTimes::new();
    for rep in 0..WINDOW_REPS {
        let (sx, sy) = (64 + 29 * rep, 80 + 23 * rep);
        let mut lines = [[0u16; RAW_COLS]; 7];
        let mut levels = [placeholder_levels()?; 7];
        for (r, (l, lv)) in lines.iter_mut().zip(levels.iter_mut()).enumerate() {
            raw_line(sy - 3 + r, (sx, sy), rng, l);
            *lv = LineLevels::measure(&G, l).map_err(|_| "levels")?;
        }
        let rect = Rect {
            x0: (sx - 3) as u16,
            y0: (sy - 3) as u16,
            width: 7,
            height: 7,
        };
        let first = G.raw_col_of_x(sx - 3);
        let mut wraw = [0u16; 49];
        for (r, l) in lines.iter().enumerate() {
            wraw[7 * r..7 * r + 7].copy_from_slice(&l[first..first + 7]);
        }
        let mut we = [Electrons::ZERO; 49];
        let mut wf = [PixelFlags::empty(); 49];
        let mut r = Ok(PixelFlags::empty());
        t_window += bench.measure(|| {
            r = cal.calibrate_window(rect, black_box(&wraw), &levels, &mut we, &mut wf);
        });
        r.map_err(|_| "calibrate_window failed")?;
        // The fused path: raw window and levels to the corrected centroid, calibration
        // included ("window_calibrate + corrected CoG 7x7" as one stage).
        let rw = RawWindow {
            rect,
            raw: &wraw,
            levels: &levels,
        };
        let rw = black_box(&rw);
        let mut fused = None;
        t_cog1c_raw += bench.measure(|| {
            fused = Some(raw_cog(cal, rw, (sx as u16, sy as u16), raw_params));
        });
        let mut fused5 = None;
        t_cog1c_raw5 += bench.measure(|| {
            fused5 = Some(raw_cog(cal, rw, (sx as u16, sy as u16), raw_params5));
        });
        let fused5 = fused5.ok_or("raw_cog 5x5")?;
        if fused5.centroid.flags.bits() != 0 || fused5.general_path {
            return Err("raw_cog 5x5 flagged a clean star");
        }
        let fused = fused.ok_or("raw_cog")?;
        if fused.centroid.flags.bits() != 0 || fused.general_path {
            return Err("raw_cog flagged a clean star");
        }
        // The same box as a plan (built once per box move) and its application per frame.
        let anchor = (sx as u16, sy as u16);
        // Rebuilt in place, as the firmware keeps a plan per tracking window.
        let mut plan = RawCogPlan::EMPTY;
        let mut built = Err(());
        t_raw_plan += bench.measure(|| {
            built = plan
                .rebuild(cal, black_box(rect), anchor, 7)
                .map_err(|_| ());
        });
        built.map_err(|_| "raw_cog plan")?;
        let plan = black_box(&plan);
        let mut planned = None;
        t_raw_planned += bench.measure(|| {
            planned = Some(plan.apply(cal, rw, raw_params));
        });
        let planned = planned
            .ok_or("raw_cog planned")?
            .map_err(|_| "raw_cog planned")?;
        if planned != fused {
            return Err("raw_cog plan + apply differs from the one-shot");
        }
        t_centroid.add_window(bench, rect, &we, &wf, curve)?;
    }
    let reps = WINDOW_REPS as u64;
    bench.row(out, "window_calibrate", "window_7x7", t_window, reps);
    t_centroid.print_corrected(out, bench, reps);
    bench.row(out, "centroid_cog1c_raw_7x7", "star", t_cog1c_raw, reps);
    bench.row(out, "centroid_cog1c_raw_5x5", "star", t_cog1c_raw5, reps);
    // The fused path split as tracking runs it: the plan of a box (built when
    // the star moves to another anchor pixel) and its application to a frame's raw window.
    bench.row(out, "raw_cog_plan_7x7", "box", t_raw_plan, reps);
    bench.row(
        out,
        "centroid_cog1c_raw_planned_7x7",
        "star",
        t_raw_planned,
        reps,
    );
    t_centroid.print_methods(out, bench, reps)
}
