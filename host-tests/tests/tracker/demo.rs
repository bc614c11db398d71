//! The demo's end-to-end claim: on the simulated sensor, full calibration leaves only noise
//! in the star windows (chi^2 per pixel about 1 against the simulator's truth), while gains
//! and the over-scan bias alone leave the fixed patterns (DSNU, PRNU, column bias) in.

#[test]
fn full_calibration_leaves_only_noise() {
    let r = startrack_homes::demo::run(7, 40).expect("demo runs");
    // Every star of the field is bright enough to be found, and nothing else is: one pair
    // of this field, 5.2 px apart, is found as one detection flagged blended.
    assert_eq!(
        (
            r.stars.len(),
            r.in_blends,
            r.missed,
            r.false_detections,
            r.dropped
        ),
        (39, 1, 0, 0, 0)
    );
    // 40 windows of 49 pixels: the chi^2 per pixel of pure noise has a standard deviation of
    // sqrt(2 / 1960) = 0.032, so 0.85..1.15 is a 4.7-sigma band.
    let full = r.chi2_per_pixel(false);
    let bare = r.chi2_per_pixel(true);
    assert!(
        (0.85..1.15).contains(&full),
        "full calibration chi2/px {full}"
    );
    assert!(bare > 2.0, "gains only chi2/px {bare}");
    // Levels measured on the frame recover the simulated ones.
    assert!((r.mean_bias_adu[0] - 1000.0).abs() < 0.2 && (r.mean_bias_adu[1] - 1100.0).abs() < 0.2);
    // 1033 lines x 32 covered pixels: standard error of the dark scale about 0.1 e-.
    assert!(
        (r.dark_scale_e - r.true_dark_scale_e).abs() < 0.6,
        "{} vs {}",
        r.dark_scale_e,
        r.true_dark_scale_e
    );
}

#[test]
fn reruns_print_identical_numbers() {
    let a = startrack_homes::demo::run(3, 4).unwrap();
    let b = startrack_homes::demo::run(3, 4).unwrap();
    for (x, y) in a.stars.iter().zip(&b.stars) {
        assert_eq!((x.flux_e, x.chi2), (y.flux_e, y.chi2));
    }
}

/// The demo's centroids against the simulator's truth, judged by their own reported sigmas:
/// if each error is normal with the reported sigma, the sum of (error / sigma)^2 over `k`
/// axis measurements is chi^2 with k degrees of freedom (mean k, standard deviation
/// sqrt(2k)). A 5-sigma band on chi^2 / k is then 1 ± 5 sqrt(2 / k): errors much larger than
/// reported (a bias, a wrong window, a lost pixel offset) or sigmas far too large both fail.
#[test]
fn centroid_errors_match_the_reported_sigmas() {
    let r = startrack_homes::demo::run(7, 40).expect("demo runs");
    let (chi2, k) = r.centroid_chi2();
    // Blends and flagged windows are left out; most of the field must remain.
    assert!(k >= 2 * 30, "only {} unflagged stars", k / 2);
    let band = 5.0 * (2.0 / k as f64).sqrt();
    let per_dof = chi2 / k as f64;
    assert!(
        (1.0 - band..1.0 + band).contains(&per_dof),
        "centroid chi2/dof {per_dof:.3} outside 1 ± {band:.3} on {k} axes"
    );
    // The same in RMS terms: the RMS error stays within the RMS of the reported sigmas
    // inflated by the same 5-sigma allowance on a mean of squares.
    let (rms, sigma) = (r.centroid_rms_px(), r.reported_sigma_rms_px());
    assert!(
        rms <= sigma * (1.0 + band).sqrt(),
        "RMS error {rms:.4} px against reported sigma RMS {sigma:.4} px"
    );
}

/// `startrack demo --sky`: the frame of the catalog's stars ends in an attitude within five
/// of its sigmas on each axis, with most stars identified.
#[test]
fn demo_over_the_sky_ends_in_an_attitude_within_its_covariance() {
    let report =
        startrack_homes::demo::run_scene(1, startrack_homes::demo::DemoScene::Sky).unwrap();
    let check = report.attitude.expect("a sky demo checks the attitude");
    let fix = check.fix.expect("an attitude");
    assert!(fix.matched >= 20, "{fix:?}");
    let e = check.error_rad().unwrap();
    for (i, v) in e.iter().enumerate() {
        let sigma = fix.attitude.cov_rad2[i][i].sqrt();
        assert!(
            v.abs() < 5.0 * sigma,
            "axis {i}: {v:e} rad, sigma {sigma:e}"
        );
    }
    // The random-star demo has no attitude to check.
    assert!(startrack_homes::demo::run(1, 3).unwrap().attitude.is_none());
}
