//! The colour correction in the attitude: fields rendered through optics with lateral colour
//! (each star shifted by its B-V), identified on uncorrected directions, then refit with
//! `ident::colour_corrected` from the catalog's B-V. Without centroid noise the corrected
//! attitude is exact and the uncorrected one carries the colour's systematic error; with
//! 0.1 px noise the corrected attitude's errors are at its covariance (NEES near 3). A
//! field where identification confused the two stars of a close double (within 2 px) is
//! counted and left out; any other confusion fails the test.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use startrack_core::attitude::{Camera, angle_between};
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig};
use startrack_sim::sky::build::default_catalog;
use startrack_sim::sky::field::{self, FieldSpec};

/// The simulated optics of `startrack optics case` (lateral colour 2.5e-4 per mag).
fn optics() -> Camera {
    startrack_lab::optics::simulated_truth()
}

/// Identification's centroid sigma: at least 0.1 px, so that its 5-sigma cut keeps the
/// stars the uncorrected colour moves by up to a few tenths of a px.
const IDENT_SIGMA_MIN_PX: f64 = 0.1;

/// Attitude errors (rad) of each field without and with the colour correction, the mean
/// NEES of the corrected attitudes, and the fields with a misidentified star (left out).
fn errors(sigma_px: f64, fields: usize) -> (Vec<f64>, Vec<f64>, f64, usize) {
    let built = default_catalog().expect("catalog");
    let cat = Catalog::parse(&built.bytes).expect("parses");
    let cam = optics();
    let spec = FieldSpec {
        camera: cam,
        ..FieldSpec::ccd47_15deg(sigma_px)
    };
    let ident_sigma = sigma_px.max(IDENT_SIGMA_MIN_PX);
    let cfg = IdentConfig::for_camera(cam.focal_length_px, ident_sigma);
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let (mut plain, mut corrected, mut nees) = (Vec::new(), Vec::new(), 0.0);
    let (mut solved, mut misidentified) = (0u32, 0usize);
    for _ in 0..fields {
        let q = field::random_attitude(&mut rng);
        let stars = field::render(&cat, q, &spec, &mut rng);
        let meas = field::measured(&stars, &cam, ident_sigma);
        let sol = ident::lost_in_space(&cat, &meas, &cfg).expect("solves");
        let mut wrong = 0;
        for m in &sol.matches {
            let truth = stars.get(usize::from(m.star)).and_then(|s| s.truth);
            if truth == Some(m.catalog) {
                continue;
            }
            // Only a close double may be confused: the two catalog stars within 2 px.
            let sep_px = truth
                .and_then(|t| Some((cat.dir(t.into())?, cat.dir(m.catalog.into())?)))
                .map_or(f64::INFINITY, |(a, b)| {
                    angle_between(a, b) * cam.focal_length_px
                });
            assert!(
                sep_px < 2.0,
                "{truth:?} identified as {}, {sep_px} px apart",
                m.catalog
            );
            wrong += 1;
        }
        if wrong > 0 {
            // A double closer than the noise resolves, matched to its neighbour: counted,
            // and its field left out of the errors (they measure the colour correction).
            misidentified += 1;
            continue;
        }
        let px: Vec<[f64; 2]> = stars.iter().map(|s| [s.x_px, s.y_px]).collect();
        let att = ident::colour_corrected(&cat, &cam, &px, ident_sigma, &sol).expect("refits");
        let e0 = sol.attitude.q.error_vector(q);
        let e1 = att.q.error_vector(q);
        plain.push(e0.iter().map(|c| c * c).sum::<f64>().sqrt());
        corrected.push(e1.iter().map(|c| c * c).sum::<f64>().sqrt());
        nees += att.nees(e1).unwrap_or(f64::INFINITY);
        solved += 1;
    }
    (plain, corrected, nees / f64::from(solved), misidentified)
}

#[test]
fn colour_correction_removes_the_colour_error_of_the_attitude() {
    let (plain, corrected, _, wrong) = errors(0.0, 50);
    assert_eq!(wrong, 0);
    let worst = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    let rms = |v: &[f64]| (v.iter().map(|e| e * e).sum::<f64>() / v.len() as f64).sqrt();
    println!(
        "no noise, 50 fields: attitude error uncorrected RMS {:.3e} rad (worst {:.3e}), colour-corrected RMS {:.3e} rad (worst {:.3e})",
        rms(&plain),
        worst(&plain),
        rms(&corrected),
        worst(&corrected)
    );
    // Exact to the undistortion's tolerance (1e-12 normalised) and rounding.
    assert!(worst(&corrected) < 1e-10, "{}", worst(&corrected));
    assert!(rms(&plain) > 1e3 * rms(&corrected).max(1e-13));
}

#[test]
fn colour_corrected_attitude_is_consistent_with_its_covariance() {
    let (_, c, nees, wrong) = errors(0.1, 300);
    println!(
        "0.1 px, 300 fields: mean NEES of the colour-corrected attitude {nees:.3} over {} fields ({wrong} with a close double misidentified, left out)",
        c.len()
    );
    // The mean of about 300 chi-square(3) draws: 3 +- 0.14 (1 sigma); 4 sigma allowed.
    assert!((nees - 3.0).abs() < 0.57, "{nees}");
}
