//! Stage `tracking_frame`, per frame: the per-frame centroid cost of the tracker's tracking
//! mode with the fused CoG (`core/src/tracker/track.rs`, `CentroidMethod::FusedCog1`) for
//! [`TRACK_STARS`] 7x7 raw windows, each calibrated and centroided by applying its window's
//! `RawCogPlan` (the fused raw-window CoG power 1 in the 7x7 box, `centroid::raw_cog`: the
//! calibration folded into the sums; each star's background given, carried from its last
//! measurement; pixel-phase curve applied).
//!
//! The plans are built beforehand, untimed: the tracker rebuilds a window's plan only when
//! its star moves to another anchor pixel (stage `raw_cog_plan_7x7` in [`crate::window`]
//! gives that cost per move; `centroid_cog1c_raw_7x7` the one-shot plan + apply). Not
//! included: the window capture of the raw lines, the window test and the full-path
//! fallback on flags. The general path (calibrate_window + cog with a perimeter median +
//! curve) is measured by `window_calibrate` and `centroid_cog1c_7x7`. Cost: [`TRACK_STARS`]
//! plan applications, timed once (the inputs take 7 raw lines a star).

use crate::harness::{Bench, Out};
use crate::inputs::{G, Lcg, RAW_COLS, placeholder_levels, raw_line_noisy};
use core::hint::black_box;
use startrack_core::calib::{FrameCalibration, LineLevels};
use startrack_core::centroid::CentroidFlags;
use startrack_core::centroid::raw_cog::{RawCogParams, RawCogPlan, RawWindow};
use startrack_core::window::Rect;

/// Windows of the tracking frame: 30 stars.
pub const TRACK_STARS: usize = 30;

/// Measures and prints `tracking_frame` with the fused path's parameters `raw_params`.
pub fn run(
    out: &mut Out,
    bench: &Bench,
    cal: &FrameCalibration<'_>,
    raw_params: &RawCogParams<'_>,
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    let mut wraw = [[0u16; 49]; TRACK_STARS];
    let mut wlevels = [[placeholder_levels()?; 7]; TRACK_STARS];
    let mut rects = [Rect {
        x0: 0,
        y0: 0,
        width: 7,
        height: 7,
    }; TRACK_STARS];
    let mut line = [0u16; RAW_COLS];
    for (i, ((w, lv), rect)) in wraw
        .iter_mut()
        .zip(wlevels.iter_mut())
        .zip(rects.iter_mut())
        .enumerate()
    {
        let (sx, sy) = (40 + 31 * i, 50 + 29 * i);
        *rect = Rect {
            x0: (sx - 3) as u16,
            y0: (sy - 3) as u16,
            width: 7,
            height: 7,
        };
        let first = G.raw_col_of_x(sx - 3);
        for (r, l) in lv.iter_mut().enumerate() {
            raw_line_noisy(sy - 3 + r, &[(sx, sy)], rng, &mut line);
            *l = LineLevels::measure(&G, &line).map_err(|_| "levels")?;
            w[7 * r..7 * r + 7].copy_from_slice(&line[first..first + 7]);
        }
    }
    let mut ok = true;
    let mut sum = 0.0f32;
    let mut plans = [None; TRACK_STARS];
    for (p, rect) in plans.iter_mut().zip(rects.iter()) {
        *p = RawCogPlan::new(cal, *rect, (rect.x0 + 3, rect.y0 + 3), 7).ok();
    }
    let t_track = bench.measure(|| {
        for (((w, lv), rect), plan) in wraw
            .iter()
            .zip(wlevels.iter())
            .zip(rects.iter())
            .zip(plans.iter())
        {
            let win = RawWindow {
                rect: *rect,
                raw: black_box(w),
                levels: lv,
            };
            match plan.as_ref().map(|p| p.apply(cal, &win, raw_params)) {
                Some(Ok(r)) => {
                    if r.centroid.flags.contains(CentroidFlags::DEGENERATE) {
                        ok = false;
                    }
                    sum += r.centroid.x_px + r.centroid.y_px;
                }
                _ => ok = false,
            }
        }
    });
    black_box(sum);
    if !ok {
        return Err("tracking_frame failed");
    }
    bench.row(out, "tracking_frame", "frame_30_stars", t_track, 1);
    Ok(())
}
