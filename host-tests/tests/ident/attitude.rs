//! The q-method attitude and its covariance: conventions on known cases, and Monte Carlo
//! over fields rendered from the catalog at random attitudes (seeded): boresight and roll
//! errors against the bound from the centroid sigmas, and the normalised error squared.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use startrack_core::attitude::{self, AttitudeError, Camera, Observation, Quat};
use startrack_core::catalog::Catalog;
use startrack_sim::sky::build::default_catalog;
use startrack_sim::sky::field::{self, FieldSpec};

fn camera() -> Camera {
    FieldSpec::ccd47_15deg(0.0).camera
}

#[test]
fn identity_attitude_puts_icrs_z_on_the_principal_point_and_x_along_columns() {
    let cam = camera();
    let q = Quat::IDENTITY;
    let p = cam.project(q.rotate([0.0, 0.0, 1.0])).unwrap_or_default();
    assert!(
        (p[0] - 511.5).abs() < 1e-9 && (p[1] - 511.5).abs() < 1e-9,
        "{p:?}"
    );
    let d = [0.01, 0.0, 1.0];
    let p = cam.project(q.rotate(d)).unwrap_or_default();
    assert!(p[0] > 511.5 + 30.0 && (p[1] - 511.5).abs() < 1e-9, "{p:?}");
    // A rotation of +90 degrees about z (Hamilton, scalar first) takes ICRS +x to camera +y:
    // the star moves to increasing row.
    let q = Quat::from_axis_angle([0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_2);
    let p = cam.project(q.rotate(d)).unwrap_or_default();
    assert!(p[1] > 511.5 + 30.0 && (p[0] - 511.5).abs() < 1e-6, "{p:?}");
    assert!((q.0[0] - q.0[3]).abs() < 1e-12 && q.0[3] > 0.0);
}

#[test]
fn pixel_direction_round_trips_with_distortion() {
    let mut cam = camera();
    cam.k1 = -0.05;
    for (x, y) in [(0.0, 0.0), (1023.0, 17.5), (511.5, 511.5), (300.25, 900.75)] {
        let p = cam.project(cam.direction(x, y)).unwrap_or_default();
        assert!(
            (p[0] - x).abs() < 1e-6 && (p[1] - y).abs() < 1e-6,
            "{x},{y} -> {p:?}"
        );
    }
}

#[test]
fn noise_free_observations_give_the_attitude_exactly_even_at_180_degrees() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let dirs = [
        [0.1, 0.0, 1.0],
        [-0.05, 0.08, 1.0],
        [0.02, -0.1, 1.0],
        [0.0, 0.0, 1.0],
    ]
    .map(|v: [f64; 3]| {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / n)
    });
    let mut qs: Vec<Quat> = (0..200).map(|_| field::random_attitude(&mut rng)).collect();
    // Rotations of exactly 180 degrees, where QUEST-style solvers are singular.
    qs.push(Quat([0.0, 1.0, 0.0, 0.0]));
    qs.push(Quat([0.0, 0.0, 0.0, 1.0]));
    qs.push(Quat([0.0, 0.6, 0.8, 0.0]));
    for q in qs {
        let obs: Vec<Observation> = dirs
            .iter()
            .map(|&camera| Observation {
                camera,
                icrs: q.rotate_inv(camera),
                sigma_rad: 1e-4,
            })
            .collect();
        let a = attitude::solve(&obs).unwrap_or_else(|e| panic!("{e}"));
        let e = a.q.error_vector(q);
        let err = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
        assert!(err < 1e-10, "q {:?}: error {err:e} rad", q.0);
        assert!(a.q.0[0] >= 0.0);
    }
}

#[test]
fn bad_or_degenerate_observations_are_refused() {
    let o = Observation {
        camera: [0.0, 0.0, 1.0],
        icrs: [0.0, 0.0, 1.0],
        sigma_rad: 1e-4,
    };
    assert_eq!(attitude::solve(&[o]), Err(AttitudeError::TooFewStars));
    assert_eq!(attitude::solve(&[o, o, o]), Err(AttitudeError::Degenerate));
    let mut bad = o;
    bad.camera = [f64::NAN, 0.0, 1.0];
    assert_eq!(
        attitude::solve(&[o, bad]),
        Err(AttitudeError::BadObservation)
    );
    bad = o;
    bad.sigma_rad = 0.0;
    assert_eq!(
        attitude::solve(&[o, bad]),
        Err(AttitudeError::BadObservation)
    );
}

struct Stats {
    fields: usize,
    bore_rms_over_bound: f64,
    roll_rms_over_bound: f64,
    nees_mean: f64,
    roll_over_bore: f64,
}

fn monte_carlo(fields: usize, sigma_px: f64, seed: u64) -> Stats {
    let bytes = default_catalog().unwrap_or_else(|e| panic!("{e}")).bytes;
    let cat = Catalog::parse(&bytes).unwrap_or_else(|e| panic!("{e}"));
    let spec = FieldSpec::ccd47_15deg(sigma_px);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut e_b2, mut p_b, mut e_r2, mut p_r, mut nees, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    while n < fields {
        let q = field::random_attitude(&mut rng);
        let stars = field::render(&cat, q, &spec, &mut rng);
        let meas = field::measured(&stars, &spec.camera, sigma_px);
        let obs: Vec<Observation> = stars
            .iter()
            .zip(&meas)
            .filter_map(|(s, m)| {
                Some(Observation {
                    camera: m.dir,
                    icrs: cat.dir(s.truth?.into())?,
                    sigma_rad: m.sigma_rad,
                })
            })
            .collect();
        if obs.len() < 3 {
            continue;
        }
        let a = attitude::solve(&obs).unwrap_or_else(|e| panic!("{e}"));
        let e = a.q.error_vector(q);
        e_b2 += e[0] * e[0] + e[1] * e[1];
        p_b += a.cov_rad2[0][0] + a.cov_rad2[1][1];
        e_r2 += e[2] * e[2];
        p_r += a.cov_rad2[2][2];
        nees += a.nees(e).unwrap_or(f64::NAN);
        n += 1;
    }
    Stats {
        fields: n,
        bore_rms_over_bound: (e_b2 / p_b).sqrt(),
        roll_rms_over_bound: (e_r2 / p_r).sqrt(),
        nees_mean: nees / n as f64,
        roll_over_bore: (p_r / p_b).sqrt(),
    }
}

/// Errors within 1.1x the bound and NEES at 3: over 2000 fields the mean NEES (chi-square
/// with 3 degrees of freedom) has a standard deviation of sqrt(6 / 2000) = 0.055, so +-0.2
/// is 3.6 sigma; an RMS over its bound has a relative standard deviation near
/// 1 / sqrt(2 * 2000 * dof) and stays within +-0.1 at any plausible spread of bounds.
#[test]
fn errors_match_the_covariance_in_monte_carlo() {
    for sigma_px in [0.1, 0.3] {
        let s = monte_carlo(2000, sigma_px, 1400 + (sigma_px * 10.0) as u64);
        println!(
            "sigma {sigma_px} px, {} fields: boresight RMS / bound {:.3}, roll RMS / bound {:.3}, NEES mean {:.3}, roll bound / boresight bound {:.1}",
            s.fields, s.bore_rms_over_bound, s.roll_rms_over_bound, s.nees_mean, s.roll_over_bore
        );
        assert!((0.9..=1.1).contains(&s.bore_rms_over_bound));
        assert!((0.9..=1.1).contains(&s.roll_rms_over_bound));
        assert!((s.nees_mean - 3.0).abs() <= 0.2, "NEES {}", s.nees_mean);
    }
}

/// Stellar aberration: an observer at 30 km/s (Earth's orbit) sees a star 90 degrees from
/// its apex moved towards the apex by v/c = 20.6 arcsec; a star at the apex does not move.
#[test]
fn aberration_moves_stars_towards_the_apex_by_v_over_c() {
    let v = [30_000.0, 0.0, 0.0];
    let star = [0.0, 0.0, 1.0];
    let seen = attitude::aberrate(star, v);
    let shift = attitude::angle_between(star, seen);
    let expected = (30_000.0 / attitude::C_M_PER_S).atan();
    assert!(
        (shift - expected).abs() < 1e-12,
        "{shift:e} vs {expected:e}"
    );
    assert!((shift.to_degrees() * 3600.0 - 20.64).abs() < 0.01);
    assert!(seen[0] > 0.0, "towards the apex: {seen:?}");
    let apex = attitude::aberrate([1.0, 0.0, 0.0], v);
    assert!(attitude::angle_between(apex, [1.0, 0.0, 0.0]) < 1e-15);
}

/// Stars trailed alike, `sigma_along_px` along a trail at `angle_rad` to the rows and
/// `sigma_across_px` across it, over `fields` random fields of 20 stars: the q-method's
/// attitude refined with each star's 2x2 covariance ([`attitude::refine`]); the mean NEES
/// per axis (1 each when the covariance says what the errors are) and the RMS
/// cross-boresight error over its bound, of the refined attitude and of the q-method's with
/// the larger sigma a star.
fn trailed_monte_carlo(
    fields: usize,
    sigma_along_px: f64,
    sigma_across_px: f64,
    angle_rad: f64,
    seed: u64,
) -> ([f64; 3], f64, [f64; 3]) {
    use rand::RngExt;
    use rand_distr::{Distribution, StandardNormal};
    let cam = camera();
    let f = cam.focal_length_px;
    let (c, s) = (angle_rad.cos(), angle_rad.sin());
    // The pixel covariance: R diag(along^2, across^2) R^T.
    let (va, vc) = (sigma_along_px.powi(2), sigma_across_px.powi(2));
    let cov_px = [
        va * c * c + vc * s * s,
        va * s * s + vc * c * c,
        (va - vc) * s * c,
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut nees, mut nees_q) = ([0.0; 3], [0.0; 3]);
    let (mut e2, mut b2) = (0.0, 0.0);
    for _ in 0..fields {
        let q = field::random_attitude(&mut rng);
        let mut obs = Vec::new();
        let mut iso = Vec::new();
        while obs.len() < 20 {
            let (x, y): (f64, f64) = (
                rng.random_range(10.0..1014.0),
                rng.random_range(10.0..1014.0),
            );
            let truth = cam.direction(x, y);
            let (n1, n2): (f64, f64) = (
                StandardNormal.sample(&mut rng),
                StandardNormal.sample(&mut rng),
            );
            let (da, dc) = (n1 * sigma_along_px, n2 * sigma_across_px);
            // A focal length 1 + 2e-4 times the model's: stars 0.1 px out at 500 px.
            let (xs, ys) = (511.5 + (x - 511.5) * 1.0002, 511.5 + (y - 511.5) * 1.0002);
            let b = cam.direction(xs + da * c - dc * s, ys + da * s + dc * c);
            let k = b[2] / f;
            obs.push(attitude::ImageObservation {
                camera: b,
                icrs: q.rotate_inv(truth),
                cov_rad2: cov_px.map(|v| v * k * k),
            });
            iso.push(Observation {
                camera: b,
                icrs: q.rotate_inv(truth),
                sigma_rad: sigma_along_px.max(sigma_across_px) * b[2].powf(1.5) / f,
            });
        }
        let start = attitude::solve(&iso).unwrap();
        let a = attitude::refine(start.q, &obs).unwrap();
        let e = a.q.error_vector(q);
        let eq = start.q.error_vector(q);
        for i in 0..3 {
            nees[i] += e[i] * e[i] / a.cov_rad2[i][i];
            nees_q[i] += eq[i] * eq[i] / start.cov_rad2[i][i];
        }
        e2 += e[0] * e[0] + e[1] * e[1];
        b2 += a.cov_rad2[0][0] + a.cov_rad2[1][1];
    }
    let n = fields as f64;
    (nees.map(|v| v / n), (e2 / b2).sqrt(), nees_q.map(|v| v / n))
}

/// Stars trailed alike (0.1 px along, 0.02 px across, trails along the rows, at 30 and 45
/// degrees to them), the focal length 2e-4 off: the q-method's attitude with the larger sigma
/// a star puts the along-trail sigma on both axes (the axis the trails do not cross gets a
/// bound far too wide, NEES below 0.65 on one axis at least), while refined with each star's
/// 2x2 covariance ([`attitude::refine`]) every axis's mean NEES is within 0.85-1.15 (2000
/// fields: chi-square with one degree of freedom, the mean's standard deviation 0.032) and
/// the RMS cross-boresight error within 0.9-1.1 of its bound.
#[test]
fn refined_attitude_of_trailed_stars_has_its_covariance() {
    for angle in [0.0f64, 30.0, 45.0] {
        let (nees, ratio, nees_q) = trailed_monte_carlo(2000, 0.1, 0.02, angle.to_radians(), 77);
        eprintln!(
            "trails at {angle} degrees: NEES per axis {nees:.3?}, error / bound {ratio:.3}; the q-method with the larger sigma {nees_q:.3?}"
        );
        assert!(nees.iter().all(|v| (0.85..=1.15).contains(v)), "{nees:?}");
        assert!((0.9..=1.1).contains(&ratio), "{ratio}");
        assert!(nees_q.iter().any(|v| *v < 0.65), "{nees_q:?}");
    }
}

/// Noise-free stars: the refinement takes an attitude 20 arcsec off (and a focal length
/// 1e-3 off) to the truth within 1e-9 rad, and refuses what it cannot use.
#[test]
fn refinement_recovers_the_attitude_and_refuses_bad_input() {
    let cam = camera();
    let f = cam.focal_length_px;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let q = field::random_attitude(&mut rng);
    let obs: Vec<attitude::ImageObservation> = [
        (100.0, 200.0),
        (900.0, 150.0),
        (500.0, 800.0),
        (300.0, 600.0),
        (700.0, 450.0),
    ]
    .iter()
    .map(|&(x, y)| {
        let truth = cam.direction(x, y);
        let b = cam.direction(511.5 + (x - 511.5) * 1.001, 511.5 + (y - 511.5) * 1.001);
        let k = b[2] / f;
        attitude::ImageObservation {
            camera: b,
            icrs: q.rotate_inv(truth),
            cov_rad2: [0.01, 0.0004, 0.001].map(|v| v * k * k),
        }
    })
    .collect();
    let start = Quat::from_rotation_vector([1e-4, -5e-5, 3e-5]) * q;
    let a = attitude::refine(start, &obs).unwrap();
    let a = attitude::refine(a.q, &obs).unwrap();
    let e = a.q.error_vector(q);
    assert!(e.iter().all(|v| v.abs() < 1e-9), "{e:?}");
    assert_eq!(
        attitude::refine(q, &obs[..1]),
        Err(AttitudeError::TooFewStars)
    );
    let mut bad = obs.clone();
    bad[2].cov_rad2 = [1e-10, 1e-10, 1e-10];
    assert_eq!(
        attitude::refine(q, &bad),
        Err(AttitudeError::BadObservation)
    );
    bad[2] = obs[2];
    bad[2].camera = [f64::NAN, 0.0, 1.0];
    assert_eq!(
        attitude::refine(q, &bad),
        Err(AttitudeError::BadObservation)
    );
}
