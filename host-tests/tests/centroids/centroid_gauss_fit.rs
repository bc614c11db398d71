//! The core's pixel-integrated Gaussian fit: noise-free recovery of the true position across
//! pixel phases and PSF widths (the model is exact, so the truth is the reference), and under
//! noise its bias, its error estimate, and its efficiency against the Cramer-Rao bound.
//!
//! `-- --nocapture` prints the measured errors.

use startrack_test_support::psf;

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

/// The held-background fit in f64: the same model, weights `1 / (max(N P P, 0) + var_bg + 1)`
/// and Gauss-Newton steps as the core, iterated from the truth to a 1e-12 px step. Returns
/// `(x, y, N, var_x, var_y)` window-relative.
fn reference_held_fit(
    pix: &[f64],
    n: u16,
    level: f64,
    var_bg: f64,
    s: f64,
    start: (f64, f64, f64),
) -> [f64; 5] {
    let (mut x, mut y, mut flux) = start;
    let phi = |u: f64| (-0.5 * u * u).exp() / (2.0 * std::f64::consts::PI).sqrt();
    let prof = |c: f64| -> (Vec<f64>, Vec<f64>) {
        (0..n)
            .map(|i| {
                let i = f64::from(i);
                (
                    psf::pixel_frac(i, c, s),
                    (phi((i - 0.5 - c) / s) - phi((i + 0.5 - c) / s)) / s,
                )
            })
            .unzip()
    };
    let mut cov = [0.0; 3];
    for _ in 0..100 {
        let ((fx, dx), (fy, dy)) = (prof(x), prof(y));
        let mut a = [[0.0f64; 3]; 3];
        let mut b = [0.0f64; 3];
        for r in 0..usize::from(n) {
            for c in 0..usize::from(n) {
                let star = flux * fx[c] * fy[r];
                let w = 1.0 / (star.max(0.0) + var_bg + 1.0);
                let j = [flux * dx[c] * fy[r], flux * fx[c] * dy[r], fx[c] * fy[r]];
                let res = pix[r * usize::from(n) + c] - level - star;
                for i in 0..3 {
                    b[i] += w * j[i] * res;
                    for k in 0..3 {
                        a[i][k] += w * j[i] * j[k];
                    }
                }
            }
        }
        // Inverse by cofactors (3x3, f64).
        let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
        let inv = |i: usize, k: usize| {
            let (r0, r1) = ([1, 0, 0][k], [2, 2, 1][k]);
            let (c0, c1) = ([1, 0, 0][i], [2, 2, 1][i]);
            let m = a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0];
            if (i + k).is_multiple_of(2) {
                m / det
            } else {
                -m / det
            }
        };
        let step: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|k| inv(i, k) * b[k]).sum())
            .collect();
        cov = [inv(0, 0), inv(1, 1), inv(2, 2)];
        x += step[0];
        y += step[1];
        flux += step[2];
        if step[0].abs() < 1e-12 && step[1].abs() < 1e-12 {
            break;
        }
    }
    [x, y, flux, cov[0], cov[1]]
}

#[test]
fn held_background_fit_matches_an_f64_reference() {
    // The fast held-background path (3 parameters, separable sums, LDL^T, `EdgeGrid`
    // recurrence) against the same estimator in f64. Differences come from the erfc
    // approximation (<= 1.5e-6 of the flux per pixel edge: a model error of that order,
    // worth ~1e-5 px at these fluxes), the f32 sums (~1e-6 relative) and, for the default
    // tolerance, the stopping rule (the last applied step is below 1e-4 px and the error
    // after it is a fraction of that step). Bounds: 3e-5 px with a 1e-6 px tolerance, and
    // 1e-4 px + 3e-5 px with the default; the error estimate within 1 %.
    let (bg, read) = (NOISE_BG_E, NOISE_READ_E);
    let var_bg = bg + read * read;
    let mut rng = psf::Rng::new(0x6f17);
    let (mut worst_tight, mut worst_default, mut worst_sigma) = (0.0f64, 0.0f64, 0.0f64);
    let mut fits = 0;
    for n in [5u16, 7] {
        for a in [0.7, 1.0, 1.5, 2.0] {
            for snr_flux in [3.0e3, 3.0e4, 3.0e5] {
                for _ in 0..20 {
                    let s = sigma_of_a(a);
                    let win = Win::centred(40, 50, n);
                    let star = psf::Star {
                        x: 40.0 + rng.uniform() - 0.5,
                        y: 50.0 + rng.uniform() - 0.5,
                        sigma: s,
                        flux: snr_flux,
                    };
                    let mean = psf::render(win, star, bg);
                    let e = psf::to_electrons(&psf::add_noise(&mean, bg, var_bg, &mut rng));
                    let pix = psf::to_f64(&e);
                    let w = startrack_core::window::Window::new(win.rect(), &e).unwrap();
                    let background = Background::Given {
                        level_e: bg as f32,
                        variance_e2: var_bg as f32,
                    };
                    let base = GaussFitParams {
                        fit_background: false,
                        background,
                        ..GaussFitParams::new(s as f32)
                    };
                    let tight = GaussFitParams {
                        tolerance_px: 1e-6,
                        max_iterations: 30,
                        ..base
                    };
                    let c_tight = gauss_fit(&CentroidInput::new(w), &tight);
                    let c_default = gauss_fit(&CentroidInput::new(w), &base);
                    if c_tight.flags.contains(CentroidFlags::NOT_CONVERGED)
                        || c_default.flags.contains(CentroidFlags::NOT_CONVERGED)
                    {
                        continue;
                    }
                    let (x0, y0) = (f64::from(win.x0), f64::from(win.y0));
                    let r = reference_held_fit(
                        &pix,
                        n,
                        bg,
                        var_bg,
                        s,
                        (star.x - x0, star.y - y0, snr_flux),
                    );
                    let err = |c: &startrack_core::centroid::Centroid| {
                        (f64::from(c.x_px) - x0 - r[0])
                            .abs()
                            .max((f64::from(c.y_px) - y0 - r[1]).abs())
                    };
                    worst_tight = worst_tight.max(err(&c_tight));
                    worst_default = worst_default.max(err(&c_default));
                    worst_sigma = worst_sigma
                        .max((f64::from(c_default.sigma_x_px) / r[3].sqrt() - 1.0).abs())
                        .max((f64::from(c_default.sigma_y_px) / r[4].sqrt() - 1.0).abs());
                    fits += 1;
                }
            }
        }
    }
    eprintln!(
        "held fit vs f64 ({fits} fits): tolerance 1e-6 {worst_tight:.2e} px, default \
         {worst_default:.2e} px, sigma {worst_sigma:.1e} relative"
    );
    assert!(fits >= 400, "{fits}");
    assert!(worst_tight < 3e-5, "{worst_tight}");
    assert!(worst_default < 1.3e-4, "{worst_default}");
    assert!(worst_sigma < 0.01, "{worst_sigma}");
}
