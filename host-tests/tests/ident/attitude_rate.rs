//! The angular-rate filter (`core/src/attitude/rate.rs`) in Monte Carlo: attitudes of a
//! spacecraft turning at a constant rate, 10 a second, each with a known Gaussian error (1"
//! and 1.2" across the boresight, 7" in roll, with a correlation, about what the SIL's sky
//! gives), seeded. Over many runs at each rate the rate's error has the covariance the
//! filter states (mean normalised error squared at 3), and the error against the bound is
//! printed. A step in the attitude restarts the window; odd input never panics.

use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use startrack_core::attitude::{Attitude, Quat, RATE_WINDOW, RateFilter};

const ARCSEC: f64 = 4.848_136_811e-6;

/// The attitudes' covariance (rad^2) and its Cholesky factor.
fn noise() -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
    let (sx, sy, sz, rho) = (1.0 * ARCSEC, 1.2 * ARCSEC, 7.0 * ARCSEC, 0.3);
    let cov = [
        [sx * sx, rho * sx * sy, 0.0],
        [rho * sx * sy, sy * sy, 0.0],
        [0.0, 0.0, sz * sz],
    ];
    let l = [
        [sx, 0.0, 0.0],
        [rho * sy, sy * (1.0 - rho * rho).sqrt(), 0.0],
        [0.0, 0.0, sz],
    ];
    (cov, l)
}

/// Mean NEES of the rate over `runs` windows at rate `w` (rad/s), the RMS error and the RMS
/// 1-sigma bound per axis (arcsec/s).
fn monte_carlo(w: [f64; 3], runs: usize, seed: u64) -> (f64, [f64; 3], [f64; 3]) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (cov, l) = noise();
    let (mut nees, mut err2, mut bound2) = (0.0, [0.0; 3], [0.0; 3]);
    let period_us = 100_000u64;
    for run in 0..runs {
        let q0 = startrack_sim::sky::field::random_attitude(&mut rng);
        let mut f = RateFilter::new(0.0);
        let mut last = None;
        // One more than the window: the first attitude has left it.
        for k in 0..=RATE_WINDOW as u64 {
            let t = (k as f64) * period_us as f64 * 1e-6;
            let truth = Quat::from_rotation_vector(w.map(|c| c * t)) * q0;
            let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
            let e: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| l[i][j] * z[j]).sum());
            let q = Quat::from_rotation_vector(e) * truth;
            let a = Attitude { q, cov_rad2: cov };
            last = f.push(1_000_000 + run as u64 + k * period_us, &a);
            if k == 0 {
                assert_eq!(last, None, "one attitude gives no rate");
            } else {
                assert!(
                    last.is_some(),
                    "run {run}: attitude {k} restarted the window"
                );
            }
        }
        assert_eq!(f.len(), RATE_WINDOW);
        let r = last.expect("a rate");
        let e: [f64; 3] = std::array::from_fn(|i| r.w_rad_s[i] - w[i]);
        nees += r.nees(e).expect("invertible");
        for (i, ei) in e.iter().enumerate() {
            err2[i] += ei * ei;
            bound2[i] += r.cov_rad2_s2[i][i];
        }
    }
    let n = runs as f64;
    let rms = |v: [f64; 3]| v.map(|x| (x / n).sqrt() / ARCSEC);
    (nees / n, rms(err2), rms(bound2))
}

#[test]
fn rate_error_matches_its_covariance_at_constant_rates() {
    let deg = 1f64.to_radians();
    for (k, (name, w)) in [
        ("at rest", [0.0, 0.0, 0.0]),
        ("1 deg/s across", [deg, 0.0, 0.0]),
        ("1 deg/s roll", [0.0, 0.0, deg]),
        ("3 deg/s", [2.0 * deg, -2.0 * deg, 0.6 * deg]),
    ]
    .into_iter()
    .enumerate()
    {
        let runs = 600;
        let (nees, rms, bound) = monte_carlo(w, runs, 40 + k as u64);
        println!(
            "{name}: mean NEES {nees:.2}; RMS rate error x {:.2} y {:.2} z {:.2} arcsec/s, bound {:.2} {:.2} {:.2}",
            rms[0], rms[1], rms[2], bound[0], bound[1], bound[2]
        );
        // The mean of 600 chi-squared(3) draws: 3 with a standard deviation of 0.10.
        assert!((2.65..3.35).contains(&nees), "{name}: mean NEES {nees}");
        for (i, (r, b)) in rms.iter().zip(bound).enumerate() {
            assert!(
                (r / b - 1.0).abs() < 0.12,
                "{name}: axis {i}: RMS {r} against bound {b}"
            );
        }
    }
}

#[test]
fn a_step_restarts_the_window_and_odd_input_gives_no_rate() {
    let (cov, _) = noise();
    let q0 = Quat::from_axis_angle([0.0, 0.6, 0.8], 1.0);
    let w = [0.01, 0.0, 0.0];
    let mut f = RateFilter::new(0.0);
    let at = |t: f64| Attitude {
        q: Quat::from_rotation_vector(w.map(|c| c * t)) * q0,
        cov_rad2: cov,
    };
    for k in 0..5u64 {
        f.push(k * 100_000, &at(k as f64 * 0.1));
    }
    assert_eq!(f.len(), 5);
    // A 60" step across the boresight: the fit does not predict it, the window restarts.
    let stepped = Attitude {
        q: Quat::from_rotation_vector([60.0 * ARCSEC, 0.0, 0.0]) * at(0.5).q,
        cov_rad2: cov,
    };
    assert_eq!(f.push(500_000, &stepped), None);
    assert_eq!(f.len(), 1);
    // The same time again, or an earlier one: a restart, not a rate.
    assert_eq!(f.push(500_000, &at(0.5)), None);
    assert_eq!(f.push(400_000, &at(0.4)), None);
    // A covariance that cannot be inverted: no rate, nothing kept.
    let singular = Attitude {
        q: at(0.6).q,
        cov_rad2: [[0.0; 3]; 3],
    };
    assert_eq!(f.push(600_000, &singular), None);
    assert!(f.is_empty());
    // An attitude more than 2 s after the others leaves them behind.
    f.push(700_000, &at(0.7));
    f.push(800_000, &at(0.8));
    assert_eq!(f.len(), 2);
    f.push(3_000_000, &at(3.0));
    assert_eq!(f.len(), 1);
}

proptest! {
    #[test]
    fn the_filter_never_panics(steps in proptest::collection::vec(
        (any::<u32>(), proptest::array::uniform4(-2.0f64..2.0), proptest::array::uniform3(any::<f64>())), 0..24)) {
        let mut f = RateFilter::new(0.0);
        for (t, q, d) in steps {
            let a = Attitude {
                q: Quat(q),
                cov_rad2: [[d[0], 0.0, 0.0], [0.0, d[1], 0.0], [0.0, 0.0, d[2]]],
            };
            if let Some(r) = f.push(u64::from(t), &a) {
                prop_assert!(r.w_rad_s.iter().all(|v| v.is_finite()));
            }
        }
    }
}

/// Attitudes of a slew at a constant angular acceleration, 20 a second with the noise
/// above: once the window has 4 attitudes the filter measures the acceleration within its
/// covariance, its rate is the one at the newest attitude (no lag), and no attitude restarts
/// the window.
#[test]
fn a_constant_acceleration_is_measured_and_the_rate_does_not_lag() {
    let (cov, l) = noise();
    let deg = 1f64.to_radians();
    let alpha = [2.0 * deg, -deg, 0.5 * deg];
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let q0 = Quat::from_axis_angle([0.0, 0.6, 0.8], 1.0);
    let mut f = RateFilter::new(5.0 * deg);
    let (mut nees_a, mut nees_w, mut n) = (0.0, 0.0, 0.0);
    for k in 0..40u64 {
        let t = k as f64 * 0.05;
        let truth = Quat::from_rotation_vector(alpha.map(|a| 0.5 * a * t * t)) * q0;
        let z: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut rng));
        let e: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| l[i][j] * z[j]).sum());
        let a = Attitude {
            q: Quat::from_rotation_vector(e) * truth,
            cov_rad2: cov,
        };
        let r = f.push(k * 50_000, &a);
        assert_eq!(f.len(), (k as usize + 1).min(RATE_WINDOW), "attitude {k}");
        let acc = f.acceleration();
        if k >= 3 {
            let ea: [f64; 3] = std::array::from_fn(|i| acc.alpha_rad_s2[i] - alpha[i]);
            let inv = invert(acc.cov_rad2_s4);
            nees_a += quad(&inv, ea);
            let r = r.expect("a rate");
            let ew: [f64; 3] = std::array::from_fn(|i| r.w_rad_s[i] - alpha[i] * t);
            nees_w += r.nees(ew).expect("invertible");
            n += 1.0;
        } else {
            assert_eq!(
                acc.alpha_rad_s2, [0.0; 3],
                "attitude {k}: nothing measured yet"
            );
        }
    }
    println!(
        "acceleration NEES {:.2}, rate NEES {:.2}",
        nees_a / n,
        nees_w / n
    );
    assert!(nees_a / n < 6.0, "acceleration NEES {}", nees_a / n);
    assert!(nees_w / n < 6.0, "rate NEES {}", nees_w / n);
}

fn invert(m: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let [[a, b, c], [d, e, f], [g, h, i]] = m;
    let det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
    [
        [
            (e * i - f * h) / det,
            (c * h - b * i) / det,
            (b * f - c * e) / det,
        ],
        [
            (f * g - d * i) / det,
            (a * i - c * g) / det,
            (c * d - a * f) / det,
        ],
        [
            (d * h - e * g) / det,
            (b * g - a * h) / det,
            (a * e - b * d) / det,
        ],
    ]
}

fn quad(m: &[[f64; 3]; 3], v: [f64; 3]) -> f64 {
    (0..3)
        .map(|i| (0..3).map(|j| v[i] * m[i][j] * v[j]).sum::<f64>())
        .sum()
}
