//! Where the trail fit puts a star whose image accelerates during the exposure, against the
//! table the attitude stage corrects a slew's attitudes by
//! (`startrack_core::centroid::trail_fit::accel_offset_fraction`): noise-free trails from
//! the simulator (`startrack_sim::trail`, exactly integrated pixels), the path
//! `v t + a t^2 / 2` cut into 400 equal-time straight pieces, the trail held at its true
//! end-to-end displacement (what the prediction gives), at PSF sigmas 0.67 px (the flight
//! PSF the table was measured at) and 1 px (another width, the same table by the trail's
//! length over the fit's width), 500 to 100,000 e-, at two angles. `-- --nocapture`
//! prints each response.

use startrack_core::centroid::trail_fit::{
    ACCEL_OFFSET_SIGMA, TrailFitParams, accel_offset_fraction, trail_fit,
};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::window::{Rect, Window};
use startrack_sim::trail::{TrailedStar, mean_window};
use startrack_test_support::psf::to_electrons;

const BACKGROUND_E: f64 = 100.0;
/// The acceleration's share of the path, px over the unit exposure: `a T^2 / 24` = 0.02 px,
/// small enough for the fit's response to be linear in it.
const A_PX: f64 = 0.48;

/// The trail fit's offset from the mid-exposure position along the motion, over `a T^2`.
fn response(sigma_px: f64, flux_e: f64, l_px: f64, angle_deg: f64) -> f64 {
    let (c, s) = (angle_deg.to_radians().cos(), angle_deg.to_radians().sin());
    let extent = l_px + A_PX;
    let w = (((extent * c.abs()) + 8.0 * sigma_px + 4.0) as usize) | 1;
    let h = (((extent * s.abs()) + 8.0 * sigma_px + 4.0) as usize) | 1;
    let (cx, cy) = ((w / 2) as f64 + 0.13, (h / 2) as f64 - 0.21);
    let pieces = 400;
    let mut px = vec![BACKGROUND_E; w * h];
    let path = |t: f64| l_px * t + 0.5 * A_PX * t * t;
    for k in 0..pieces {
        let t0 = k as f64 / pieces as f64 - 0.5;
        let t1 = t0 + 1.0 / pieces as f64;
        let (s0, s1) = (path(t0), path(t1));
        let mid = 0.5 * (s0 + s1);
        let star = TrailedStar {
            x_px: cx + mid * c,
            y_px: cy + mid * s,
            flux_e: flux_e / pieces as f64,
            trail_dx_px: (s1 - s0) * c,
            trail_dy_px: (s1 - s0) * s,
            psf_sigma_px: sigma_px,
        };
        for (p, q) in px.iter_mut().zip(mean_window(w, h, &star, 0.0)) {
            *p += q;
        }
    }
    let e = to_electrons(&px);
    let rect = Rect {
        x0: 100,
        y0: 200,
        width: w as u16,
        height: h as u16,
    };
    let params = TrailFitParams {
        fit_background: false,
        background: Background::Given {
            level_e: BACKGROUND_E as f32,
            variance_e2: (BACKGROUND_E + 25.0) as f32,
        },
        ..TrailFitParams::new(sigma_px as f32, (l_px * c) as f32, (l_px * s) as f32)
    };
    let fit = trail_fit(&CentroidInput::new(Window { rect, pixels_e: &e }), &params).centroid;
    assert!(
        !fit.flags
            .intersects(CentroidFlags::NOT_CONVERGED | CentroidFlags::DEGENERATE),
        "sigma {sigma_px} L {l_px}: {:?}",
        fit.flags
    );
    let along = (f64::from(fit.x_px) - 100.0 - cx) * c + (f64::from(fit.y_px) - 200.0 - cy) * s;
    along / A_PX
}

#[test]
fn the_trail_fit_follows_the_offset_table() {
    let mut worst = 0.0f64;
    for sigma_px in [0.67, 1.0] {
        let width = (sigma_px * sigma_px + 1.0 / 12.0f64).sqrt();
        for flux_e in [500.0, 2_000.0, 20_000.0, 100_000.0] {
            for l_px in [0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 14.0] {
                for angle_deg in [0.0, 30.0] {
                    let k = response(sigma_px, flux_e, l_px, angle_deg);
                    let table = accel_offset_fraction(l_px, width);
                    eprintln!(
                        "sigma {sigma_px} px, {flux_e} e-, L {l_px} px, {angle_deg} deg: k {k:.4}, table {table:.4}"
                    );
                    worst = worst.max((k - table).abs());
                    assert!(
                        (k - table).abs() <= ACCEL_OFFSET_SIGMA,
                        "sigma {sigma_px} {flux_e} e- L {l_px} angle {angle_deg}: k {k} against {table}"
                    );
                }
            }
        }
    }
    eprintln!("worst |k - table| {worst:.4} (the stated sigma {ACCEL_OFFSET_SIGMA})");
}

#[test]
fn the_table_starts_at_the_centre_of_light_and_stays_below_the_trail_ends() {
    assert!((accel_offset_fraction(0.0, 0.73) - 1.0 / 24.0).abs() < 1e-12);
    assert!((accel_offset_fraction(f64::NAN, 0.73) - 1.0 / 24.0).abs() < 1e-12);
    assert!((accel_offset_fraction(3.0, 0.0) - 1.0 / 24.0).abs() < 1e-12);
    let mut last = 0.0;
    for i in 1..400 {
        let k = accel_offset_fraction(f64::from(i) * 0.25, 0.73);
        assert!(k > 0.03 && k < 0.125, "L {}: {k}", f64::from(i) * 0.25);
        if i > 60 {
            assert!(k >= last, "rises past the table's dip");
        }
        last = k;
    }
}
