//! Tracking from the attitude: the catalog's stars predicted at the next frame
//! ([`startrack_core::predict`]) against the projected truth, its bad inputs, and the
//! attitude stage taking the tracker's identities ([`Solver::update_with_identities`]),
//! where a false star or a hot pixel in a predicted window must not move the attitude: on
//! the stage's own input, and on the simulated sensor through the whole frame cycle.

use rand::SeedableRng;
use startrack_analysis::sil_rates;
use startrack_core::attitude::{Attitude, Quat, Rate};
use startrack_core::catalog::Catalog;
use startrack_core::predict::{self, PredictConfig, PredictError, PredictFrom, PredictedStars};
use startrack_core::solver::{Solver, SolverConfig};
use startrack_core::tracker::{PredictedStar, Provenance, StarFlags, StarRecord};
use startrack_homes::sil::{self, SilConfig};
use startrack_sim::sim::Star;
use startrack_sim::sky::field::{FieldSpec, random_attitude, render};
use startrack_sim::sky::scene::committed_catalog;

const ARCSEC: f64 = 1.0 / 206_264.806;

/// A fix with a 0.1" cross-boresight and 1" roll sigma at `q`, a rate `w_deg_s` known to
/// 0.05"/s, `interval_s` to the next frame, 100 ms exposures and frames.
fn from(q: Quat, w_deg_s: [f64; 3], interval_s: f64) -> PredictFrom {
    let s2 = |s: f64| (s * ARCSEC) * (s * ARCSEC);
    PredictFrom {
        attitude: Attitude {
            q,
            cov_rad2: [
                [s2(0.1), 0.0, 0.0],
                [0.0, s2(0.1), 0.0],
                [0.0, 0.0, s2(1.0)],
            ],
        },
        rate: Rate {
            w_rad_s: w_deg_s.map(f64::to_radians),
            cov_rad2_s2: [
                [s2(0.05), 0.0, 0.0],
                [0.0, s2(0.05), 0.0],
                [0.0, 0.0, s2(0.5)],
            ],
        },
        scale: 1.0,
        interval_s,
        exposure_s: 0.1,
        period_s: 0.1,
        accel_rad_s2: [0.0; 3],
        velocity_m_s: None,
    }
}

fn predicted(cat: &Catalog<'_>, f: &PredictFrom) -> Result<Vec<PredictedStar>, PredictError> {
    let camera = FieldSpec::ccd47_15deg(0.0).camera;
    let mut out = PredictedStars::new();
    predict::predict(
        cat,
        &camera,
        f,
        [1024, 1024],
        &PredictConfig::flight(7),
        &mut out,
    )?;
    Ok(out.to_vec())
}

/// At 1 deg/s across the boresight the predicted stars are the catalog's stars where the
/// camera sees them at the propagated attitude (to 1e-3 px), as many as the field holds up
/// to 32, spread over the field (every cell of the 4 x 4 grid that holds an eligible star:
/// window on the sensor, no neighbour within 6 px unless 2.5 mag fainter), no two within
/// the blend distance, their trails 6.8 px along the motion.
#[test]
fn predicted_stars_are_the_catalog_stars_where_the_propagated_attitude_puts_them() {
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    for _ in 0..5 {
        let q = random_attitude(&mut rng);
        let f = from(q, [0.0, 1.0, 0.0], 0.1);
        let stars = predicted(&cat, &f).unwrap();
        let q_next = Quat::from_rotation_vector([0.0, 0.1f64.to_radians(), 0.0]) * q;
        let spec = FieldSpec::ccd47_15deg(0.0);
        let truth = render(&cat, q_next, &spec, &mut rng);
        let hp = |t: &startrack_sim::sky::field::FieldStar| {
            t.truth
                .and_then(|i| cat.star(usize::from(i)))
                .map_or(99.0, |s| f64::from(s.hp_mmag) / 1000.0)
        };
        // The predicted windows are 15 px (1 px bound, 6.8 px trail): 7 px from the edges.
        let eligible: Vec<_> = truth
            .iter()
            .filter(|t| {
                let inside = |v: f64| (7.0..=1016.0).contains(&v);
                let alone = truth.iter().all(|o| {
                    o == *t
                        || (o.x_px - t.x_px).hypot(o.y_px - t.y_px) >= 6.0
                        || hp(o) - hp(t) >= 2.5
                });
                inside(t.x_px) && inside(t.y_px) && alone
            })
            .collect();
        assert_eq!(stars.len(), eligible.len().min(32));
        assert!(stars.len() >= 8, "{}", stars.len());
        let cell_of =
            |x: f64, y: f64| ((x / 256.0) as usize).min(3) + 4 * ((y / 256.0) as usize).min(3);
        let mut want = [false; 16];
        for t in &eligible {
            want[cell_of(t.x_px, t.y_px)] = true;
        }
        let mut cells = [false; 16];
        for p in &stars {
            let t = truth
                .iter()
                .find(|t| t.truth == Some(p.catalog))
                .expect("a predicted star in the field");
            let d = (f64::from(p.x_px) - t.x_px).hypot(f64::from(p.y_px) - t.y_px);
            assert!(d < 1e-3, "star {}: {d} px off", p.catalog);
            assert!(p.bound_px >= 1.0 && p.bound_px < 1.1, "{}", p.bound_px);
            // The image's velocity over the 100 ms exposure: 68 px/s along the motion.
            let trail = p.trail_px(0.1);
            assert!((trail.0.abs() - 6.8).abs() < 0.3 && trail.1.abs() < 0.5);
            assert!((p.motion_px.0 - trail.0).abs() < 0.1);
            cells[cell_of(f64::from(p.x_px), f64::from(p.y_px))] = true;
            for o in &stars {
                let d = (o.x_px - p.x_px).hypot(o.y_px - p.y_px);
                assert!(
                    o.catalog == p.catalog || d >= 6.0,
                    "{} {}",
                    o.catalog,
                    p.catalog
                );
            }
        }
        assert_eq!(cells, want);
    }
}

/// NaN or out-of-range inputs are typed errors, an interval past the limit is too old, an
/// empty cone and a field whose stars all fall off the sensor give no star; nothing panics.
#[test]
fn bad_inputs_empty_cones_and_stars_off_the_sensor_predict_nothing() {
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let q = random_attitude(&mut rand_chacha::ChaCha8Rng::seed_from_u64(22));
    let good = from(q, [0.5, 0.0, 0.2], 0.1);
    let bad = [
        PredictFrom {
            attitude: Attitude {
                q: Quat([f64::NAN, 0.0, 0.0, 1.0]),
                ..good.attitude
            },
            ..good
        },
        PredictFrom {
            attitude: Attitude {
                q: Quat([0.0; 4]),
                ..good.attitude
            },
            ..good
        },
        PredictFrom {
            attitude: Attitude {
                cov_rad2: [[f64::INFINITY; 3]; 3],
                ..good.attitude
            },
            ..good
        },
        PredictFrom {
            rate: Rate {
                w_rad_s: [f64::NAN, 0.0, 0.0],
                ..good.rate
            },
            ..good
        },
        PredictFrom {
            interval_s: -0.1,
            ..good
        },
        PredictFrom {
            interval_s: f64::NAN,
            ..good
        },
        PredictFrom { scale: 1.5, ..good },
        PredictFrom {
            exposure_s: f64::NAN,
            ..good
        },
    ];
    for f in &bad {
        assert_eq!(predicted(&cat, f), Err(PredictError::BadInput), "{f:?}");
    }
    let old = PredictFrom {
        interval_s: 1.5,
        ..good
    };
    assert_eq!(predicted(&cat, &old), Err(PredictError::TooOld));
    assert!(!predicted(&cat, &good).unwrap().is_empty());
    // A rate that turns the field right off the sensor during the interval: the stars are
    // still predicted where they will be (a new field), so the prediction is not empty;
    // a camera whose sensor sees 0.05 degree has no star on it.
    let narrow = startrack_core::attitude::Camera::pinhole(1.2e6, [512.0, 512.0]);
    let mut out = PredictedStars::new();
    let n = predict::predict(
        &cat,
        &narrow,
        &good,
        [1024, 1024],
        &PredictConfig::flight(7),
        &mut out,
    );
    assert_eq!(n, Ok(0));
    // An empty cone: a catalog of five stars around the north pole, looked at from the south.
    let list: Vec<startrack_sim::sky::SkyStar> = (0..5)
        .map(|k| startrack_sim::sky::SkyStar {
            hip: k + 1,
            ra_deg: 72.0 * f64::from(k),
            dec_deg: 88.0,
            hp_mag: 3.0,
            bv_mag: 0.5,
        })
        .collect();
    let tiny =
        startrack_sim::sky::build::build(&list, &startrack_sim::sky::build::BuildSpec::fov_15deg())
            .unwrap();
    let tiny = Catalog::parse(&tiny.bytes).unwrap();
    // Camera +z (the boresight) on ICRS -z: a half turn about x.
    let south = from(Quat([0.0, 1.0, 0.0, 0.0]), [0.0; 3], 0.1);
    assert_eq!(predicted(&tiny, &south), Ok(Vec::new()));
}

/// The stars the tracker would report at `q` (brightest first, 0.05 px noise, 0.05 px
/// sigmas) with the predictions they were measured for.
fn tracked(cat: &Catalog<'_>, q: Quat, seed: u64) -> (Vec<StarRecord>, Vec<PredictedStar>) {
    let stars = predicted(cat, &from(q, [0.0; 3], 0.0)).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let spec = FieldSpec::ccd47_15deg(0.05);
    let truth = render(cat, q, &spec, &mut rng);
    let records = stars
        .iter()
        .map(|p| {
            let t = truth.iter().find(|t| t.truth == Some(p.catalog)).unwrap();
            StarRecord {
                x_px: t.x_px as f32,
                y_px: t.y_px as f32,
                flux_e: t.flux_e as f32,
                snr: 200.0,
                sigma_x_px: 0.05,
                sigma_y_px: 0.05,
                cov_xy_px2: 0.0,
                flags: StarFlags::empty(),
                provenance: Provenance::TRACKED,
                psf_a_px: 1.2,
                chi2_dof: 1.0,
            }
        })
        .collect();
    (records, stars)
}

fn solver<'c>(cat: &Catalog<'c>) -> Solver<'c> {
    let camera = FieldSpec::ccd47_15deg(0.0).camera;
    Solver::new(*cat, SolverConfig::for_camera(camera, 0.05))
}

/// The attitude stage takes the predicted identities (no search: every star identified),
/// and a false star or a hot pixel measured in a predicted window (the brightest star's
/// position taken by a spike 0.6 px off it, inside its 1 px bound; another star's by one
/// 2.5 px off, outside it; a third star replaced by a false star with its identity) does
/// not move the attitude: it is within 1 % of its own sigma of the attitude without those
/// three stars, which are not among the matches.
#[test]
fn a_false_star_or_a_hot_pixel_in_a_predicted_window_does_not_move_the_attitude() {
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
    for k in 0..5 {
        let q = random_attitude(&mut rng);
        let (records, ids) = tracked(&cat, q, 100 + k);
        assert!(records.len() >= 20);
        let mut s = solver(&cat);
        // The prior: a lost-in-space fix of the same stars.
        s.update(&records, 0).unwrap();
        let clean = s
            .update_with_identities(&records, ids.iter().map(Some), 100_000, None)
            .0
            .unwrap();
        assert_eq!(usize::from(s.identified()), records.len());
        assert_eq!(clean.matched as usize, records.len());
        let e = clean.attitude.q.error_vector(q);
        assert!(e[0].hypot(e[1]) < 5.0 * clean.attitude.boresight_sigma_rad());

        let mut spoiled = records.clone();
        spoiled[0].x_px += 0.6;
        spoiled[1].y_px -= 2.5;
        spoiled[2].x_px += 40.0;
        spoiled[2].y_px -= 17.0;
        let mut s = solver(&cat);
        s.update(&records, 0).unwrap();
        let fix = s
            .update_with_identities(&spoiled, ids.iter().map(Some), 100_000, None)
            .0
            .unwrap();
        // The same three stars left out of a clean list: the attitude it should be.
        let mut s = solver(&cat);
        s.update(&records, 0).unwrap();
        let without = s
            .update_with_identities(&records[3..], ids[3..].iter().map(Some), 100_000, None)
            .0
            .unwrap();
        assert_eq!(usize::from(fix.matched), records.len() - 3);
        let d = fix.attitude.q.error_vector(without.attitude.q);
        let sigma = without.attitude.boresight_sigma_rad();
        assert!(d[0].hypot(d[1]) < 0.01 * sigma, "{d:?} against {sigma}");
        assert!(
            d[2].abs() < 0.01 * without.attitude.roll_sigma_rad(),
            "{d:?}"
        );
    }
}

/// Identities that disagree with the stars (every star given another's) are no solution by
/// identity: the stage searches and finds the right attitude, never a wrong one.
#[test]
fn wrong_identities_send_the_stage_to_its_search() {
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let q = random_attitude(&mut rand_chacha::ChaCha8Rng::seed_from_u64(24));
    let (records, ids) = tracked(&cat, q, 7);
    // Each star given its neighbour's identity, with a bound wide enough to pass the gate.
    let shuffled: Vec<PredictedStar> = (0..ids.len())
        .map(|i| PredictedStar {
            x_px: records[i].x_px,
            y_px: records[i].y_px,
            ..ids[(i + 1) % ids.len()]
        })
        .collect();
    let mut s = solver(&cat);
    s.update(&records, 0).unwrap();
    let fix = s
        .update_with_identities(&records, shuffled.iter().map(Some), 100_000, None)
        .0
        .unwrap();
    assert_eq!(s.identified(), 0);
    let e = fix.attitude.q.error_vector(q);
    assert!(e.iter().all(|v| v.abs() < 1e-4), "{e:?}");
}

/// The SIL over a still sky (seed 100 of the rate table) for 8 frames, with `false_stars`
/// beside the catalog's from frame 3 (the windows are the catalog's from frame 2).
fn still_sky(false_stars: Vec<Star>) -> sil::SilReport {
    let case = sil_rates::RateCase {
        motion: "cross",
        rate_deg_s: 0.0,
    };
    let config = SilConfig {
        false_stars,
        false_stars_from: 3,
        ..sil_rates::config(&case, 100, 8)
    };
    sil::run(&config).unwrap()
}

/// On the simulated sensor: a hot pixel's spike (50,000 e- in a 0.3 px PSF) 0.7 px from one
/// catalog star, inside its prediction's bound, and a false star brighter than another
/// catalog star 2.5 px from it, outside the bound but inside its window, both from the
/// fourth frame on, when the windows are already the catalog's. In each of those frames
/// both stars are measured (a fit the PSF does not describe), neither keeps its identity
/// (two fewer identified stars than without the spoilers), and the attitude from the others
/// is within 5 of its sigmas of the truth on each axis. (Present from power-on, the spike
/// stops lost in space altogether: no attitude, not a wrong one.)
#[test]
fn a_hot_pixel_or_a_false_star_on_the_sensor_does_not_move_the_attitude() {
    let clean = still_sky(Vec::new());
    // Two bright catalog stars of the field, clear of the edges.
    let mut truth: Vec<Star> = clean.frames[3]
        .truth
        .iter()
        .filter(|t| (100.0..924.0).contains(&t.x_px) && (100.0..924.0).contains(&t.y_px))
        .copied()
        .collect();
    truth.sort_by(|a, b| b.signal_e.total_cmp(&a.signal_e));
    let (a, b) = (truth[0], truth[1]);
    let spoilers = vec![
        Star {
            x_px: a.x_px + 0.7,
            y_px: a.y_px,
            signal_e: 50_000.0,
            a_px: 0.3,
        },
        Star {
            x_px: b.x_px,
            y_px: b.y_px + 2.5,
            signal_e: 2.0 * b.signal_e,
            a_px: 1.2,
        },
    ];
    let spoiled = still_sky(spoilers);
    for (c, s) in clean.frames.iter().zip(&spoiled.frames).skip(3) {
        let n = s.summary.frame;
        assert!(s.predicted_windows >= 20, "frame {n}");
        let (ca, sa) = (c.attitude.as_ref().unwrap(), s.attitude.as_ref().unwrap());
        assert!(ca.identified >= 20, "frame {n}: {}", ca.identified);
        // Both spoiled stars are measured (flagged, a fit the PSF does not describe) and
        // neither keeps its identity in the attitude.
        assert!(
            sa.identified + 2 <= ca.identified,
            "frame {n}: {} {}",
            sa.identified,
            ca.identified
        );
        let spoiled_stars = s.stars.iter().filter(|m| {
            let near = |t: &Star| {
                (f64::from(m.star.x_px) - t.x_px).hypot(f64::from(m.star.y_px) - t.y_px) < 3.0
            };
            near(&a) || near(&b)
        });
        assert_eq!(spoiled_stars.count(), 2, "frame {n}");
        let sf = sa.fix.as_ref().unwrap();
        let e = sa.error_rad().unwrap();
        for i in 0..3 {
            let sigma = sf.attitude.cov_rad2[i][i].sqrt();
            assert!(e[i].abs() < 5.0 * sigma, "frame {n}: axis {i} {e:?}");
        }
    }
}

/// Any value of any input (attitude, covariances, rate, scale, times, velocity, as raw f64
/// bits: NaN, infinities, denormals, huge): the prediction returns, never panics, and every
/// star it gives is valid, on the sensor with its whole window, and at most 32.
#[test]
fn any_input_predicts_valid_stars_or_an_error() {
    use proptest::prelude::*;
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let any = || {
        prop_oneof![
            4 => -1.0f64..1.0,
            1 => any::<u64>().prop_map(f64::from_bits),
        ]
    };
    let mut runner = proptest::test_runner::TestRunner::new(proptest::test_runner::Config {
        cases: 300,
        ..Default::default()
    });
    runner
        .run(
            &(
                proptest::array::uniform4(any()),
                proptest::array::uniform3(any()),
                proptest::array::uniform3(any()),
                any(),
                any(),
                any(),
            ),
            |(q, cov, w, scale, interval, exposure)| {
                let s2 = |s: f64| [[s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]];
                let f = PredictFrom {
                    attitude: Attitude {
                        q: Quat(q),
                        cov_rad2: s2(cov[0] * 1e-10),
                    },
                    rate: Rate {
                        w_rad_s: w,
                        cov_rad2_s2: s2(cov[1] * 1e-10),
                    },
                    scale: 1.0 + 0.05 * scale,
                    interval_s: interval,
                    exposure_s: exposure,
                    period_s: 0.1,
                    accel_rad_s2: w,
                    velocity_m_s: (scale > 0.5).then_some(w.map(|c| c * 3.0e5)),
                };
                if let Ok(stars) = predicted(&cat, &f) {
                    prop_assert!(stars.len() <= 32);
                    for p in &stars {
                        prop_assert!(p.is_valid());
                        let side = startrack_core::tracker::predicted_window_side(
                            7,
                            p.bound_px,
                            p.trail_px(exposure as f32),
                        );
                        let half = f32::from(side / 2);
                        prop_assert!(p.x_px >= half && p.x_px <= 1023.0 - half, "{p:?}");
                        prop_assert!(p.y_px >= half && p.y_px <= 1023.0 - half, "{p:?}");
                    }
                }
                Ok(())
            },
        )
        .unwrap();
}

/// With the observer's velocity (the attitude of the ICRF, aberration removed) each star is
/// predicted where the camera sees it, its catalog direction aberrated (to 1e-3 px): at
/// 300 km/s, the velocity command's limit, up to 4 px from where the ICRF direction falls.
#[test]
fn an_icrf_attitude_predicts_the_aberrated_stars() {
    let bytes = committed_catalog().unwrap();
    let cat = Catalog::parse(&bytes).unwrap();
    let q = random_attitude(&mut rand_chacha::ChaCha8Rng::seed_from_u64(25));
    let v = [3.0e5, -1.0e5, 0.5e5];
    let f = PredictFrom {
        velocity_m_s: Some(v),
        ..from(q, [0.0; 3], 0.1)
    };
    let camera = FieldSpec::ccd47_15deg(0.0).camera;
    let stars = predicted(&cat, &f).unwrap();
    let still = predicted(&cat, &from(q, [0.0; 3], 0.1)).unwrap();
    assert!(stars.len() >= 8);
    let mut largest = 0.0f64;
    for p in &stars {
        let s = cat.star(usize::from(p.catalog)).unwrap();
        let seen = startrack_core::attitude::aberrate(s.dir, v);
        let want = camera
            .project_of(q.rotate(seen), f64::from(s.bv_mmag) / 1000.0)
            .unwrap();
        let d = (f64::from(p.x_px) - want[0]).hypot(f64::from(p.y_px) - want[1]);
        assert!(d < 1e-3, "star {}: {d} px", p.catalog);
        if let Some(o) = still.iter().find(|o| o.catalog == p.catalog) {
            largest = largest.max(f64::from((o.x_px - p.x_px).hypot(o.y_px - p.y_px)));
        }
    }
    assert!(largest > 1.0 && largest < 5.0, "{largest}");
}
