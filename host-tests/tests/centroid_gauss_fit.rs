//! The core's pixel-integrated Gaussian fit: noise-free recovery of the true position across
//! pixel phases and PSF widths (the model is exact, so the truth is the reference), and under
//! noise its bias, its error estimate, and its efficiency against the Cramer-Rao bound.
//!
//! `-- --nocapture` prints the measured errors.

#[path = "common/psf.rs"]
mod psf;

use psf::{
    Rng, Star, Win, add_noise, crlb_x, flux_for_snr, mean_std, render, sigma_of_a, to_electrons,
};
use startrack_core::centroid::gauss_fit::{GaussFitParams, gauss_fit};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::window::Window;

const WIDTHS_A: [f64; 7] = [0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0];

fn phases() -> impl Iterator<Item = f64> {
    (0..10).map(|i| -0.45 + 0.1 * f64::from(i))
}

#[test]
fn recovers_the_true_position_noise_free() {
    let win = Win::centred(60, 70, 11);
    for fit_background in [false, true] {
        for a in WIDTHS_A {
            let s = sigma_of_a(a);
            let (mut worst, mut worst_flux): (f64, f64) = (0.0, 0.0);
            for px in phases() {
                for py in phases() {
                    let star = Star {
                        x: 60.0 + px,
                        y: 70.0 + py,
                        sigma: s,
                        flux: 1.0e5,
                    };
                    let e = to_electrons(&render(win, star, 200.0));
                    let params = GaussFitParams {
                        psf_sigma_px: s as f32,
                        max_iterations: 10,
                        tolerance_px: 1e-5,
                        start_box: 5,
                        fit_background,
                        background: Background::PerimeterMean,
                    };
                    let c = gauss_fit(
                        &CentroidInput::new(Window::new(win.rect(), &e).unwrap()),
                        &params,
                    );
                    assert!(
                        !c.flags
                            .intersects(CentroidFlags::DEGENERATE | CentroidFlags::CLAMPED),
                        "a {a} ({px},{py}): {c:?}"
                    );
                    let err = (f64::from(c.x_px) - star.x)
                        .abs()
                        .max((f64::from(c.y_px) - star.y).abs());
                    worst = worst.max(err);
                    if fit_background {
                        worst_flux = worst_flux.max((f64::from(c.flux_e) / star.flux - 1.0).abs());
                    }
                    assert!(
                        err < 1e-3,
                        "fit_bg {fit_background} a {a} ({px},{py}): {c:?} vs ({}, {})",
                        star.x,
                        star.y
                    );
                }
            }
            if fit_background {
                eprintln!(
                    "fit_background true  a {a:4.2}: worst |error| {worst:.2e} px, worst flux error {worst_flux:.1e}"
                );
            } else {
                // The perimeter mean holds the wings of a wide star: a background bias.
                eprintln!("fit_background false a {a:4.2}: worst |error| {worst:.2e} px");
            }
        }
    }
}

#[test]
fn noise_bias_error_estimate_and_efficiency() {
    const BG: f64 = 100.0;
    const READ: f64 = 5.0;
    const VAR_BG: f64 = BG + READ * READ;
    let win = Win::centred(100, 100, 9);
    for a in [1.0, 2.0] {
        for (snr, seed) in [(10.0, 41u64), (20.0, 42), (50.0, 43), (100.0, 44)] {
            let s = sigma_of_a(a);
            let star = Star {
                x: 100.3,
                y: 99.8,
                sigma: s,
                flux: flux_for_snr(snr, 5.0, VAR_BG),
            };
            let mean = render(win, star, BG);
            let mut rng = Rng::new(seed);
            let (mut dx, mut est) = (vec![], vec![]);
            let params = GaussFitParams::new(s as f32);
            let mut failed = 0;
            for _ in 0..3000 {
                let e = to_electrons(&add_noise(&mean, BG, VAR_BG, &mut rng));
                let c = gauss_fit(
                    &CentroidInput::new(Window::new(win.rect(), &e).unwrap()),
                    &params,
                );
                if c.flags
                    .intersects(CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED)
                {
                    failed += 1;
                    continue;
                }
                dx.push(f64::from(c.x_px) - star.x);
                est.push(f64::from(c.sigma_x_px).powi(2));
            }
            let (m, sd) = mean_std(&dx);
            let se = sd / (dx.len() as f64).sqrt();
            let e = (est.iter().sum::<f64>() / est.len() as f64).sqrt();
            let crlb = crlb_x(win, star, BG, READ);
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
