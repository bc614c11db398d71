//! The bright-object flags on a Moon built another way: this file's own Moon and its own
//! blooming, added to the second sky's frames ([`super::sil_second_sky`], its own stars and
//! rotation) and run through the same simulated sensor and the flight frame cycle, so the
//! claim that the flags name the Moon, that no star is taken from it and that the flag
//! clears when it leaves does not rest on the SIL's bright-object generator alone.
//!
//! The Moon here: a uniform disc (the Moon's limb darkening is slight) of the mean angular
//! diameter 0.518 degree (31.1 arcmin; the Astronomical Almanac's mean, 1,737.4 km at
//! 384,400 km), 17.6 px in radius at the camera's 3,889 px focal length; full, visual
//! magnitude -12.74 (Allen's Astrophysical Quantities, 4th ed., section 12.2), taken as Hp,
//! through the photometric constant the stars share (`sky::field::FLUX_E_AT_MAG0`);
//! at a phase the disc's lit part is cut by a straight terminator (the limb's ellipse
//! taken as a chord, an overestimate of the lit part this test does not lean on). Each
//! pixel's share of the disc comes from 8 x 8 sub-samples. Blooming, this file's own rule
//! for a CCD without an anti-blooming drain: in each column the charge above the full well
//! leaves its pixel and fills the nearest pixels below the well along the column, half up
//! and half down, and a column holding more than its pixels can spills it off the ends.
//! Every position is on each of the sensor's two outputs (their gains and biases differ:
//! the right output's full well reads 63,600 ADU, under the ADC's top).

use super::sil_second_sky::run_with;
use startrack_analysis::sil_rates;
use startrack_core::tracker::Obstructions;
use startrack_sim::sim::SensorParams;
use startrack_sim::sky::field::FLUX_E_AT_MAG0;
use startrack_sim::sky::scene::REFERENCE_EXPOSURE_S;
use startrack_sim::trail::TrailedImage;

/// The Moon's visual magnitude at full phase (Allen, 4th ed., 12.2).
const FULL_MOON_MAG: f64 = -12.74;
/// The Moon's mean angular radius, rad (31.1 arcmin diameter).
const MOON_RADIUS_RAD: f64 = 0.259 * core::f64::consts::PI / 180.0;
/// The camera's focal length, px (the 15 degree field on 1,024 px).
const FOCAL_PX: f64 = 3889.0;
/// The flight exposure, s (the second sky's).
const EXPOSURE_S: f64 = 0.039;

/// The Moon's light on the active area at `centre_px` and phase angle `phase_deg` (0 full,
/// the terminator a chord perpendicular to +x, the lit side towards +x), bloomed, as one
/// patch of whole columns (mean electrons before the flat).
fn moon(centre_px: [f64; 2], phase_deg: f64, params: &SensorParams) -> Option<TrailedImage> {
    let g = params.geometry;
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    let r = MOON_RADIUS_RAD * FOCAL_PX;
    // The lit fraction of the disc's face, (1 + cos phase) / 2; the terminator a chord at
    // `x_t` from the centre leaving that fraction of the disc's area on the +x side.
    let lit = 0.5 * (1.0 + phase_deg.to_radians().cos());
    let area_on_right = |x_t: f64| {
        let u = (x_t / r).clamp(-1.0, 1.0);
        (u.acos() - u * (1.0 - u * u).sqrt()) / core::f64::consts::PI
    };
    let (mut lo, mut hi) = (-r, r);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if area_on_right(mid) > lit {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let x_t = 0.5 * (lo + hi);
    let flux_e =
        FLUX_E_AT_MAG0 * 10f64.powf(-0.4 * FULL_MOON_MAG) * EXPOSURE_S / REFERENCE_EXPOSURE_S;
    let per_area_e = flux_e / (core::f64::consts::PI * r * r);
    let x0 = (centre_px[0] - r - 1.0).floor().max(0.0) as usize;
    let x1 = ((centre_px[0] + r + 1.0).ceil().max(0.0) as usize).min(cols);
    if x0 >= x1 {
        return None;
    }
    let width = x1 - x0;
    let mut e = vec![0.0; width * rows];
    const SUB: usize = 8;
    for y in 0..rows {
        if (y as f64 - centre_px[1]).abs() > r + 1.0 {
            continue;
        }
        for x in x0..x1 {
            let mut inside = 0;
            for i in 0..SUB {
                for j in 0..SUB {
                    let dx = x as f64 - 0.5 + (i as f64 + 0.5) / SUB as f64 - centre_px[0];
                    let dy = y as f64 - 0.5 + (j as f64 + 0.5) / SUB as f64 - centre_px[1];
                    inside += usize::from(dx * dx + dy * dy <= r * r && dx >= x_t);
                }
            }
            e[y * width + (x - x0)] = per_area_e * inside as f64 / (SUB * SUB) as f64;
        }
    }
    // A bloomed pixel holds a full well whatever its response, but this light is added
    // before the sensor's flat: filled to 1.25 wells (PRNU 2 %: 12 sigmas), the sensor's
    // clip at the well leaves every full pixel exactly full, as charge would.
    let well = 1.25 * params.full_well_e;
    for c in 0..width {
        let mut col: Vec<f64> = (0..rows).map(|y| e[y * width + c]).collect();
        bloom(&mut col, well);
        for (y, v) in col.into_iter().enumerate() {
            e[y * width + c] = v;
        }
    }
    Some(TrailedImage {
        x0,
        y0: 0,
        width,
        height: rows,
        mean_e: e,
    })
}

/// This file's blooming: each pixel's charge above `well` moves along the column, half
/// up and half down, into the nearest pixels with room; what reaches an end is lost.
fn bloom(col: &mut [f64], well: f64) {
    let n = col.len();
    for y in 0..n {
        let excess = col[y] - well;
        if excess <= 0.0 {
            continue;
        }
        col[y] = well;
        for (dir, mut share) in [(-1i64, 0.5 * excess), (1, 0.5 * excess)] {
            let mut k = y as i64 + dir;
            while share > 0.0 && (0..n as i64).contains(&k) {
                let room = (well - col[k as usize]).max(0.0);
                let put = room.min(share);
                col[k as usize] += put;
                share -= put;
                k += dir;
            }
        }
    }
}

#[test]
fn blooming_keeps_the_charge_within_the_well_and_along_the_column() {
    let mut col = vec![0.0; 20];
    col[10] = 5.5;
    bloom(&mut col, 1.0);
    assert!(col.iter().all(|v| *v <= 1.0 + 1e-12));
    assert!((col.iter().sum::<f64>() - 5.5).abs() < 1e-12);
    // The pixel keeps its well; 2.25 goes each way: two full pixels and a quarter.
    assert_eq!(col.iter().filter(|v| **v > 0.0).count(), 7);
    let mut full = vec![3.0; 5];
    bloom(&mut full, 1.0);
    assert!(full.iter().all(|v| (*v - 1.0).abs() < 1e-12), "{full:?}");
}

/// The second sky at rest (seed 7, 14 frames at the flight timing) with this file's Moon in
/// the field for the first 10 frames, full at (300, 420) px (the left output), then gone;
/// and again at a phase of 90 degrees at (700, 600) px (the right output). In every frame: an attitude (the Moon's columns
/// leave most of the stars), none wrong; while the Moon is in the field the frame says
/// Moon and not Earth; from the second frame after it leaves, no obstruction.
#[test]
fn the_flags_name_a_moon_from_another_generator() {
    for (centre, phase_deg) in [([300.0, 420.0], 0.0), ([700.0, 600.0], 90.0)] {
        let frames = run_with(7, [0.0; 3], 14, &|k, params| {
            if k < 10 {
                moon(centre, phase_deg, params).into_iter().collect()
            } else {
                Vec::new()
            }
        });
        for (k, f) in frames.iter().enumerate() {
            let (e, sc, sr) = f
                .fix
                .unwrap_or_else(|| panic!("Moon at {centre:?}: frame {k} has no attitude"));
            assert!(
                !sil_rates::is_wrong(e, sc, sr),
                "Moon at {centre:?}: frame {k} wrong: {e:?}"
            );
            eprintln!(
                "Moon at {centre:?}, phase {phase_deg} deg: frame {k}: {:?}, {:?}, probe row's saturated run {:?}",
                f.obstructions, f.summary.mode, f.summary.probe_saturated_cols
            );
            if k < 10 {
                assert!(
                    f.obstructions.contains(Obstructions::MOON)
                        && !f.obstructions.contains(Obstructions::EARTH),
                    "Moon at {centre:?}: frame {k}: {:?}",
                    f.obstructions
                );
            } else if k >= 11 {
                assert!(
                    f.obstructions.is_empty(),
                    "Moon gone: frame {k}: {:?}",
                    f.obstructions
                );
            }
        }
    }
}
