//! Stars that move during the exposure: the trailed image along a sampled path against the
//! trailed window it generalises, the simulator's trailed stars against its still ones, and
//! the sky scene's trails at a cross-boresight rate and in roll against the truth at
//! mid-exposure (the light's first moment, the trail's length and direction).

use startrack_core::catalog::Catalog;
use startrack_sim::sim::psf::sigma_of_a;
use startrack_sim::sim::{SensorParams, Simulator, Star};
use startrack_sim::sky::field::random_attitude;
use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
use startrack_sim::sky::scene::{SkyScene, committed_catalog};
use startrack_sim::trail::{TrailedImage, TrailedStar, mean_window, path_steps};

use rand::SeedableRng;

/// A straight uniform path through [`TrailedImage`] is [`mean_window`]'s trailed star, pixel
/// for pixel, and the patch holds all of its light.
#[test]
fn a_straight_path_is_the_trailed_window() {
    let star = TrailedStar {
        x_px: 20.3,
        y_px: 15.7,
        flux_e: 1e4,
        trail_dx_px: 6.0,
        trail_dy_px: -3.0,
        psf_sigma_px: 0.8,
    };
    let k = path_steps(star.trail_dx_px.hypot(star.trail_dy_px));
    let path: Vec<[f64; 2]> = (0..k)
        .map(|j| {
            let t = (j as f64 + 0.5) / k as f64 - 0.5;
            [
                star.x_px + t * star.trail_dx_px,
                star.y_px + t * star.trail_dy_px,
            ]
        })
        .collect();
    let img = TrailedImage::along(&path, star.flux_e, star.psf_sigma_px, [64, 64]).unwrap();
    let win = mean_window(64, 64, &star, 0.0);
    for y in 0..64 {
        for x in 0..64 {
            let (a, b) = (img.at(x, y), win[y * 64 + x]);
            assert!((a - b).abs() < 1e-9 * star.flux_e, "({x}, {y}): {a} {b}");
        }
    }
    assert!((img.total_e() - star.flux_e).abs() < 1e-6 * star.flux_e);
    // Clipped to the active area, and refused when it reaches none of it.
    let edge = TrailedImage::along(&[[0.0, 0.0]], 1e4, 0.8, [64, 64]).unwrap();
    assert_eq!((edge.x0, edge.y0), (0, 0));
    // A star on the corner pixel's centre: what lies beyond its outer edges (-0.5 px) is off.
    let inside = 0.5 * (1.0 + libm::erf(0.5 / 0.8 * std::f64::consts::FRAC_1_SQRT_2));
    let expected = 1e4 * inside * inside;
    assert!(
        (edge.total_e() - expected).abs() < 1e-6 * expected,
        "{}",
        edge.total_e()
    );
    assert!(TrailedImage::along(&[[-30.0, 5.0]], 1e4, 0.8, [64, 64]).is_none());
    assert!(TrailedImage::along(&[[f64::NAN, 5.0]], 1e4, 0.8, [64, 64]).is_none());
    assert!(TrailedImage::along(&[], 1e4, 0.8, [64, 64]).is_none());
}

/// A trailed star whose path is one point is the simulator's still star.
#[test]
fn a_still_trail_is_the_still_star() {
    let params = SensorParams {
        noise: false,
        ..SensorParams::default()
    };
    let star = Star {
        x_px: 100.4,
        y_px: 200.8,
        signal_e: 5e4,
        a_px: 1.2,
    };
    let still = Simulator::new(params.clone(), vec![star]);
    let img = TrailedImage::along(
        &[[star.x_px, star.y_px]],
        star.signal_e,
        sigma_of_a(star.a_px),
        [1024, 1024],
    )
    .unwrap();
    let trailed = Simulator {
        trails: vec![img],
        ..Simulator::new(params, Vec::new())
    };
    for y in 190..212 {
        for x in 90..112 {
            let (a, b) = (still.star_e(x, y), trailed.star_e(x, y));
            assert!((a - b).abs() < 1e-9 * star.signal_e, "({x}, {y}): {a} {b}");
        }
    }
}

/// The first and second moments of a trailed image: total, centre, and the variance along
/// the principal axis with its direction (unit vector).
fn moments(img: &TrailedImage) -> (f64, [f64; 2], f64, [f64; 2]) {
    let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
    for j in 0..img.height {
        for i in 0..img.width {
            let m = img.mean_e[j * img.width + i];
            let (x, y) = ((img.x0 + i) as f64, (img.y0 + j) as f64);
            s += m;
            sx += m * x;
            sy += m * y;
        }
    }
    let c = [sx / s, sy / s];
    let (mut xx, mut xy, mut yy) = (0.0, 0.0, 0.0);
    for j in 0..img.height {
        for i in 0..img.width {
            let m = img.mean_e[j * img.width + i] / s;
            let (dx, dy) = ((img.x0 + i) as f64 - c[0], (img.y0 + j) as f64 - c[1]);
            xx += m * dx * dx;
            xy += m * dx * dy;
            yy += m * dy * dy;
        }
    }
    let mean = 0.5 * (xx + yy);
    let diff = (0.25 * (xx - yy).powi(2) + xy * xy).sqrt();
    let angle = 0.5 * (2.0 * xy).atan2(xx - yy);
    (s, c, mean + diff, [angle.cos(), angle.sin()])
}

/// Over the sky at 2 deg/s across the boresight (50 ms exposures) and at 1 deg/s in roll
/// (1 s): each star's light is centred on its mid-exposure position (within 0.01 px), its
/// trail is `|w| T` times the image scale long (within 2 %) and points along the motion
/// (within 1 degree): across the boresight the same near the centre (within 300 px, where
/// the projection's scale changes by under 0.6 %), in roll tangential, its length growing
/// with the distance from the centre. Rendering twice gives the same images.
#[test]
fn sky_trails_follow_the_turn_and_centre_on_mid_exposure() {
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let q0 = random_attitude(&mut rng);
    let a_px = 1.2;
    let sigma2 = sigma_of_a(a_px).powi(2) + 1.0 / 12.0;
    let cases = [
        ([1.2, -1.6, 0.0], 0.1, 0.05, 300.0),
        ([0.0, 0.0, 1.0], 1.0, 1.0, 1000.0),
    ];
    for (rate_deg_s, period_s, exposure_s, r_max) in cases {
        let roll = rate_deg_s[2] != 0.0;
        let rate = rate_deg_s.map(f64::to_radians);
        let motion =
            ExposureMotion::new(RateProfile::constant(rate), period_s, exposure_s).unwrap();
        let scene = SkyScene::ccd47_15deg_moving(q0, motion);
        let frame = 3;
        let trails = scene.trails(&cat, frame, a_px);
        assert_eq!(trails, scene.trails(&cat, frame, a_px));
        let truth = scene.stars(&cat, frame, a_px);
        let f = scene.camera.focal_length_px;
        let c = scene.camera.principal_point_px;
        let mut checked = 0;
        for img in &trails {
            let (total, centre, var_along, dir) = moments(img);
            let star = truth
                .iter()
                .min_by(|a, b| {
                    let d = |s: &Star| (s.x_px - centre[0]).hypot(s.y_px - centre[1]);
                    d(a).total_cmp(&d(b))
                })
                .unwrap();
            // Only stars whole on the active area and well inside the field.
            if (total - star.signal_e).abs() > 1e-6 * star.signal_e
                || !(40.0..984.0).contains(&star.x_px)
                || !(40.0..984.0).contains(&star.y_px)
            {
                continue;
            }
            let err = (star.x_px - centre[0]).hypot(star.y_px - centre[1]);
            assert!(err < 0.01, "{rate_deg_s:?}: centre off by {err} px");
            let (rx, ry) = (star.x_px - c[0], star.y_px - c[1]);
            let r = rx.hypot(ry);
            let (expected_l, expected_dir) = if roll {
                (r * rate[2] * exposure_s, [-ry / r, rx / r])
            } else {
                // Across the boresight the field moves by -w x v: (-wy, wx) f.
                let w = rate[0].hypot(rate[1]);
                (w * f * exposure_s, [-rate[1] / w, rate[0] / w])
            };
            if expected_l < 2.0 || r > r_max {
                continue;
            }
            let l = (12.0 * (var_along - sigma2)).sqrt();
            assert!(
                (l / expected_l - 1.0).abs() < 0.02,
                "{rate_deg_s:?}: star at r {r:.0} px trail {l:.3} px, expected {expected_l:.3}"
            );
            let cos = (dir[0] * expected_dir[0] + dir[1] * expected_dir[1]).abs();
            assert!(
                cos > 1f64.to_radians().cos(),
                "{rate_deg_s:?}: direction {dir:?}"
            );
            checked += 1;
        }
        assert!(
            checked >= 10,
            "{rate_deg_s:?}: only {checked} stars checked"
        );
    }
}
