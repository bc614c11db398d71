//! The core's pixel-integrated Gaussian fit: noise-free recovery of the true position across
//! pixel phases and PSF widths (the model is exact, so the truth is the reference), and under
//! noise its bias, its error estimate, and its efficiency against the Cramer-Rao bound.
//!
//! `-- --nocapture` prints the measured errors.

#[path = "common/psf.rs"]
mod psf;

use psf::{
    NOISE_BG_E, NOISE_READ_E, Sweep, WIDTHS_A, Win, crlb_x, mean_std, sigma_of_a,
    standard_monte_carlo,
};
use startrack_core::centroid::gauss_fit::{GaussFitParams, gauss_fit};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};

#[test]
fn recovers_the_true_position_noise_free() {
    // The model is exact, so the reference is the truth itself.
    let sweep = Sweep {
        win: Win::centred(60, 70, 11),
        flux: 1.0e5,
        background: 200.0,
        tol_px: 1e-3,
        forbidden: CentroidFlags::DEGENERATE | CentroidFlags::CLAMPED,
    };
    let (x0, y0) = (f64::from(sweep.win.x0), f64::from(sweep.win.y0));
    for fit_background in [false, true] {
        for a in WIDTHS_A {
            let s = sigma_of_a(a);
            let params = GaussFitParams {
                psf_sigma_px: s as f32,
                max_iterations: 10,
                tolerance_px: 1e-5,
                start_box: 5,
                fit_background,
                background: Background::PerimeterMean,
            };
            let worst_flux = std::cell::Cell::new(0.0f64);
            let r = sweep.run(
                a,
                &format!("fit_bg {fit_background}"),
                |w| {
                    let c = gauss_fit(&CentroidInput::new(w), &params);
                    let flux_err = (f64::from(c.flux_e) / sweep.flux - 1.0).abs();
                    worst_flux.set(worst_flux.get().max(flux_err));
                    c
                },
                |_, star| (star.x - x0, star.y - y0),
            );
            if fit_background {
                eprintln!(
                    "fit_background true  a {a:4.2}: worst |error| {:.2e} px, worst flux error {:.1e}",
                    r.worst_px,
                    worst_flux.get()
                );
            } else {
                // The perimeter mean holds the wings of a wide star: a background bias.
                eprintln!(
                    "fit_background false a {a:4.2}: worst |error| {:.2e} px",
                    r.worst_px
                );
            }
        }
    }
}

#[test]
fn noise_bias_error_estimate_and_efficiency() {
    for a in [1.0, 2.0] {
        for (snr, seed) in [(10.0, 41u64), (20.0, 42), (50.0, 43), (100.0, 44)] {
            let s = sigma_of_a(a);
            let params = GaussFitParams::new(s as f32);
            let mc = standard_monte_carlo(
                a,
                snr,
                (0.3, -0.2),
                seed,
                3000,
                CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED,
            );
            let r = mc.run(|w, _| gauss_fit(&CentroidInput::new(w), &params));
            let (dx, failed, e) = (&r.dx, r.failed, r.estimate_rms());
            let (m, sd) = mean_std(dx);
            let se = sd / (dx.len() as f64).sqrt();
            let crlb = crlb_x(mc.win, mc.star, NOISE_BG_E, NOISE_READ_E);
            eprintln!(
                "fit a {a} SNR(5x5) {snr:5.1}: mean error {m:+.4} px (SE {se:.4}), scatter {sd:.4} px, estimate {e:.4} px (ratio {:.3}), CRLB {crlb:.4} (efficiency {:.2}), failed {failed}",
                e / sd,
                crlb / sd
            );
            assert!(
                failed < if snr < 15.0 { 60 } else { 5 },
                "{failed} failures"
            );
            assert!(
                (e / sd - 1.0).abs() < 0.2,
                "a {a} SNR {snr}: estimate {e} vs scatter {sd}"
            );
            assert!(
                m.abs() < 4.0 * se + 2e-3,
                "a {a} SNR {snr}: bias {m} (SE {se})"
            );
            if snr >= 20.0 {
                assert!(crlb / sd > 0.8, "a {a} SNR {snr}: efficiency {}", crlb / sd);
            }
        }
    }
}
