//! The core's width-free Gaussian fit (`gauss_fit_width`): noise-free recovery of position
//! and width, agreement with an f64 implementation of the same estimator, and under noise its
//! pull (error / own sigma), its `chi2_dof` against the chi-square law and the `POOR_FIT`
//! flag on windows the model cannot describe; with a field PSF model's width as a prior
//! (`gauss_fit_width_prior`), the `PSF_MISMATCH` flag on stars the model does not describe.
//!
//! `-- --nocapture` prints the measured numbers.

use startrack_test_support::psf;

use psf::{NOISE_BG_E, NOISE_READ_E, Rng, Star, Win, sigma_of_a};
use startrack_core::centroid::gauss_fit::{
    CHI2_FLAG_Z, PsfFit, WidthFitParams, WidthPrior, chi2_dof_limit, chi2_dof_limit_border,
    gauss_fit_width, gauss_fit_width_prior,
};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::window::Window;

const VAR_BG: f64 = NOISE_BG_E + NOISE_READ_E * NOISE_READ_E;

fn given() -> Background {
    Background::Given {
        level_e: NOISE_BG_E as f32,
        variance_e2: VAR_BG as f32,
    }
}

fn params() -> WidthFitParams {
    WidthFitParams {
        background: given(),
        ..WidthFitParams::new()
    }
}

/// A star of width `a` at a random phase around pixel (40, 50) in an `n x n` window.
fn star_at(rng: &mut Rng, a: f64, flux: f64) -> Star {
    Star {
        x: 40.0 + rng.uniform() - 0.5,
        y: 50.0 + rng.uniform() - 0.5,
        sigma: sigma_of_a(a),
        flux,
    }
}

fn fit_pixels(win: Win, e: &[startrack_core::units::Electrons], p: &WidthFitParams) -> PsfFit {
    gauss_fit_width(&CentroidInput::new(Window::new(win.rect(), e).unwrap()), p)
}

#[test]
fn chi2_limit_matches_the_chi_square_quantiles() {
    // Exact 0.999 quantiles of chi-square (tables; scipy.stats.chi2.ppf(0.999, k)).
    for (dof, q) in [(10u16, 29.588), (21, 46.797), (45, 80.077), (96, 144.567)] {
        let lim = f64::from(chi2_dof_limit(dof, CHI2_FLAG_Z)) * f64::from(dof);
        eprintln!("dof {dof}: limit {lim:.3}, exact {q}");
        // Wilson-Hilferty: 0.6 % high at 10 dof, closer with more.
        let tol = if dof < 20 { 0.007 } else { 0.003 };
        assert!((lim / q - 1.0).abs() < tol, "dof {dof}: {lim} vs {q}");
    }
    assert_eq!(chi2_dof_limit(0, CHI2_FLAG_Z), f32::MAX);
}

#[test]
fn border_chi2_limit_matches_the_f_quantiles() {
    // (border - 1 + d F_0.999(d, border - 1)) / dof with d = dof - border + 1, the exact F
    // quantiles from scipy.stats.f.ppf(0.999, d, border - 1): 5x5 and 7x7 windows (full
    // border, 2 pixels clipped) and 9x9.
    for (dof, border, exact) in [
        (21u16, 16u16, 2.7405),
        (45, 24, 2.4107),
        (45, 22, 2.6145),
        (77, 32, 2.1750),
    ] {
        let lim = f64::from(chi2_dof_limit_border(dof, border, CHI2_FLAG_Z));
        eprintln!("dof {dof}, border {border}: limit {lim:.4}, exact {exact}");
        assert!(
            (lim / exact - 1.0).abs() < 0.02,
            "dof {dof} border {border}: {lim}"
        );
    }
    // A given variance is the chi-square limit; a 3x3 window leaves nothing to test.
    assert_eq!(
        chi2_dof_limit_border(45, 0, CHI2_FLAG_Z),
        chi2_dof_limit(45, CHI2_FLAG_Z)
    );
    assert_eq!(chi2_dof_limit_border(5, 8, CHI2_FLAG_Z), f32::MAX);
}

/// `POOR_FIT` share and failures of `trials` clean stars of width `a`, flux `flux` in an
/// `n x n` window, background the border's median (the flight's).
fn flight_false_flags(n: u16, a: f64, flux: f64, trials: usize, seed: u64) -> (f64, usize) {
    let mut rng = Rng::new(seed);
    let p = WidthFitParams::new();
    let (mut flagged, mut used) = (0usize, 0usize);
    for _ in 0..trials {
        let win = Win::centred(40, 50, n);
        let star = star_at(&mut rng, a, flux);
        let mean = psf::render(win, star, NOISE_BG_E);
        let e = psf::to_electrons(&psf::add_noise(&mean, NOISE_BG_E, VAR_BG, &mut rng));
        let c = fit_pixels(win, &e, &p).centroid;
        if c.flags
            .intersects(CentroidFlags::NOT_CONVERGED | CentroidFlags::DEGENERATE)
        {
            continue;
        }
        used += 1;
        if c.flags.contains(CentroidFlags::POOR_FIT) {
            flagged += 1;
        }
    }
    (flagged as f64 / used.max(1) as f64, trials - used)
}

#[test]
fn clean_stars_rarely_flagged_with_the_border_background() {
    // The border's median and clipped variance (the flight's background): the chi2 limit
    // counts the variance estimate's own error (F, not chi-square) and the wings' refit
    // runs to convergence. Design rate 1e-3: 2000 stars a cell expect 2 flags (Poisson
    // 99.99 % point 9); bound 0.5 % (10 stars). Before: 1.1-1.5 % in 7x7 at a <= 1,
    // 4-65 % at a = 2 px, SNR 100-200. The 7x7 SNR 20 cell keeps ~0.5 %: the held level's
    // own error (shared by all 49 pixels, not in the limit) adds a scaled chi-square(1) to
    // chi2; bound 1 % there (before 1.5 %).
    for (n, a, snr, seed, bound) in [
        (5u16, 1.0, 100.0, 11u64, 0.005),
        (7, 1.0, 100.0, 12, 0.005),
        (7, 1.0, 20.0, 13, 0.01),
        (7, 2.0, 100.0, 15, 0.005),
        (7, 2.0, 200.0, 14, 0.005),
    ] {
        let flux = psf::flux_for_snr(snr, 5.0, VAR_BG);
        let (rate, failed) = flight_false_flags(n, a, flux, 2000, seed);
        eprintln!(
            "{n}x{n} a {a} SNR {snr}, border median: POOR_FIT {:.2} %, failed {failed}",
            100.0 * rate
        );
        assert!(rate <= bound, "{n}x{n} a {a} SNR {snr}: {rate}");
        assert!(failed < 20, "{failed} failures");
    }
}

#[test]
fn recovers_position_and_width_noise_free() {
    let mut worst_pos = 0.0f64;
    let mut worst_a = 0.0f64;
    for n in [5u16, 7] {
        for a in [0.6, 0.8, 1.0, 1.5, 2.0] {
            if n == 5 && a > 1.5 {
                continue; // the 5x5 window holds too little of the wide star's wings
            }
            for ix in 0..5 {
                for iy in 0..5 {
                    let win = Win::centred(40, 50, n);
                    let star = Star {
                        x: 40.0 - 0.45 + 0.2 * f64::from(ix),
                        y: 50.0 - 0.45 + 0.2 * f64::from(iy),
                        sigma: sigma_of_a(a),
                        flux: 1.0e5,
                    };
                    let e = psf::to_electrons(&psf::render(win, star, NOISE_BG_E));
                    let r = fit_pixels(win, &e, &params());
                    let c = r.centroid;
                    assert!(
                        !c.flags.intersects(
                            CentroidFlags::NOT_CONVERGED
                                | CentroidFlags::DEGENERATE
                                | CentroidFlags::POOR_FIT
                        ),
                        "n {n} a {a}: {:?}",
                        c.flags
                    );
                    let err = (f64::from(c.x_px) - star.x)
                        .abs()
                        .max((f64::from(c.y_px) - star.y).abs());
                    worst_pos = worst_pos.max(err);
                    worst_a = worst_a.max((f64::from(r.psf_a_px) / a - 1.0).abs());
                }
            }
        }
    }
    eprintln!(
        "noise-free: worst position error {worst_pos:.2e} px, worst a {worst_a:.2e} relative"
    );
    assert!(worst_pos < 1e-4, "{worst_pos}");
    assert!(worst_a < 1e-4, "{worst_a}");
}

/// The width-free fit in f64: the same model, weights `1 / (max(N P P, 0) + var_bg + 1)`,
/// held background and Gauss-Newton steps, from `start` to a 1e-12 px step. Returns
/// `(x, y, N, s, var_x, var_s, chi2)` window-relative.
fn reference_width_fit(pix: &[f64], n: u16, level: f64, var_bg: f64, start: [f64; 4]) -> [f64; 7] {
    let [mut x, mut y, mut flux, mut s] = start;
    let phi = |u: f64| (-0.5 * u * u).exp() / (2.0 * std::f64::consts::PI).sqrt();
    // Fraction, d/dcentre and d/ds of each pixel.
    let prof = |c: f64, s: f64| -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| {
                let i = f64::from(i);
                let (ul, uh) = ((i - 0.5 - c) / s, (i + 0.5 - c) / s);
                [
                    psf::pixel_frac(i, c, s),
                    (phi(ul) - phi(uh)) / s,
                    (phi(ul) * ul - phi(uh) * uh) / s,
                ]
            })
            .collect()
    };
    let mut out = [0.0; 7];
    for _ in 0..200 {
        let (px, py) = (prof(x, s), prof(y, s));
        let mut a = [[0.0f64; 4]; 4];
        let mut b = [0.0f64; 4];
        let mut chi2 = 0.0;
        for r in 0..usize::from(n) {
            for c in 0..usize::from(n) {
                let ([fx, dx, wx], [fy, dy, wy]) = (px[c], py[r]);
                let star = flux * fx * fy;
                let w = 1.0 / (star.max(0.0) + var_bg + 1.0);
                let j = [
                    flux * dx * fy,
                    flux * fx * dy,
                    fx * fy,
                    flux * (wx * fy + fx * wy),
                ];
                let res = pix[r * usize::from(n) + c] - level - star;
                chi2 += w * res * res;
                for i in 0..4 {
                    b[i] += w * j[i] * res;
                    for k in 0..4 {
                        a[i][k] += w * j[i] * j[k];
                    }
                }
            }
        }
        let inv = invert4(a);
        let step: Vec<f64> = (0..4)
            .map(|i| (0..4).map(|k| inv[i][k] * b[k]).sum())
            .collect();
        out = [x, y, flux, s, inv[0][0], inv[3][3], chi2];
        x += step[0];
        y += step[1];
        flux += step[2];
        s += step[3];
        if step[0].abs() < 1e-12 && step[1].abs() < 1e-12 && step[3].abs() < 1e-12 {
            break;
        }
    }
    out
}

/// Inverse of a symmetric positive-definite 4x4 matrix by Gauss-Jordan elimination.
fn invert4(mut a: [[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut inv = [[0.0; 4]; 4];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    for col in 0..4 {
        let p = a[col][col];
        for k in 0..4 {
            a[col][k] /= p;
            inv[col][k] /= p;
        }
        for r in 0..4 {
            if r != col {
                let f = a[r][col];
                for k in 0..4 {
                    a[r][k] -= f * a[col][k];
                    inv[r][k] -= f * inv[col][k];
                }
            }
        }
    }
    inv
}

#[test]
fn width_fit_matches_an_f64_reference() {
    // The core's f32 fit against the same estimator in f64, on noisy 5x5 and 7x7 windows.
    // Differences: the erfc approximation (~1e-6 of the flux per pixel edge), f32 sums, and
    // the stopping rule (the last step below `tolerance_px`). Bounds with a 1e-6 px
    // tolerance: position and `s` 5e-5 px, error estimates and chi2 within 1 %.
    let mut rng = Rng::new(0x5f1d);
    let (mut worst_pos, mut worst_s, mut worst_sigma, mut worst_chi2) =
        (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut fits = 0;
    let tight = WidthFitParams {
        tolerance_px: 1e-6,
        tolerance_sigmas: 0.0,
        max_iterations: 40,
        ..params()
    };
    for n in [5u16, 7] {
        for a in [0.7, 1.0, 1.5] {
            for flux in [5.0e3, 3.0e4, 3.0e5] {
                for _ in 0..15 {
                    let win = Win::centred(40, 50, n);
                    let star = star_at(&mut rng, a, flux);
                    let mean = psf::render(win, star, NOISE_BG_E);
                    let e = psf::to_electrons(&psf::add_noise(&mean, NOISE_BG_E, VAR_BG, &mut rng));
                    let r = fit_pixels(win, &e, &tight);
                    if r.centroid.flags.contains(CentroidFlags::NOT_CONVERGED) {
                        continue;
                    }
                    let (x0, y0) = (f64::from(win.x0), f64::from(win.y0));
                    let f = reference_width_fit(
                        &psf::to_f64(&e),
                        n,
                        NOISE_BG_E,
                        VAR_BG,
                        [star.x - x0, star.y - y0, flux, star.sigma],
                    );
                    let c = r.centroid;
                    worst_pos = worst_pos
                        .max((f64::from(c.x_px) - x0 - f[0]).abs())
                        .max((f64::from(c.y_px) - y0 - f[1]).abs());
                    worst_s = worst_s.max((f64::from(r.psf_a_px) * 0.31f64.sqrt() - f[3]).abs());
                    worst_sigma = worst_sigma
                        .max((f64::from(c.sigma_x_px) / f[4].sqrt() - 1.0).abs())
                        .max(
                            (f64::from(r.sigma_psf_a_px) * 0.31f64.sqrt() / f[5].sqrt() - 1.0)
                                .abs(),
                        );
                    let dof = f64::from(n * n - 4);
                    worst_chi2 = worst_chi2.max((f64::from(r.chi2_dof) * dof / f[6] - 1.0).abs());
                    fits += 1;
                }
            }
        }
    }
    eprintln!(
        "width fit vs f64 ({fits} fits): position {worst_pos:.2e} px, s {worst_s:.2e} px, \
         sigmas {worst_sigma:.1e} relative, chi2 {worst_chi2:.1e} relative"
    );
    assert!(fits >= 240, "{fits}");
    assert!(worst_pos < 5e-5, "{worst_pos}");
    assert!(worst_s < 5e-5, "{worst_s}");
    assert!(worst_sigma < 0.01, "{worst_sigma}");
    assert!(worst_chi2 < 0.01, "{worst_chi2}");
}

/// Pull RMS of x and y, mean chi2_dof, flagged fraction and failures over `trials` stars of
/// width `a`, flux `flux` on an `n x n` window.
fn monte_carlo(n: u16, a: f64, flux: f64, trials: usize, seed: u64) -> (f64, f64, f64, usize) {
    let mut rng = Rng::new(seed);
    let (mut pull2, mut chi, mut used, mut flagged, mut failed) =
        (0.0, 0.0, 0usize, 0usize, 0usize);
    for _ in 0..trials {
        let win = Win::centred(40, 50, n);
        let star = star_at(&mut rng, a, flux);
        let mean = psf::render(win, star, NOISE_BG_E);
        let e = psf::to_electrons(&psf::add_noise(&mean, NOISE_BG_E, VAR_BG, &mut rng));
        let r = fit_pixels(win, &e, &params());
        let c = r.centroid;
        if c.flags
            .intersects(CentroidFlags::NOT_CONVERGED | CentroidFlags::DEGENERATE)
        {
            failed += 1;
            continue;
        }
        if c.flags.contains(CentroidFlags::POOR_FIT) {
            flagged += 1;
        }
        pull2 += ((f64::from(c.x_px) - star.x) / f64::from(c.sigma_x_px)).powi(2)
            + ((f64::from(c.y_px) - star.y) / f64::from(c.sigma_y_px)).powi(2);
        chi += f64::from(r.chi2_dof);
        used += 1;
    }
    let u = used.max(1) as f64;
    (
        (pull2 / (2.0 * u)).sqrt(),
        chi / u,
        flagged as f64 / u,
        failed,
    )
}

#[test]
fn pulls_chi2_and_false_flags_under_noise() {
    // 1500 stars a cell: the pull RMS has a relative SE of 1/sqrt(4 * 1500) = 1.3 %, the
    // mean chi2_dof (dof 21 or 45) an SE of sqrt(2 / dof / 1500) < 0.8 %. Bounds: pull
    // 0.9-1.1, mean chi2_dof within 5 %, false flags below 0.5 % (1e-3 expected: 1.5 stars).
    for (n, a, snr, seed) in [
        (7u16, 0.7, 20.0, 1u64),
        (7, 1.0, 50.0, 2),
        (7, 1.5, 100.0, 3),
        (5, 1.0, 20.0, 4),
    ] {
        let flux = psf::flux_for_snr(snr, 5.0, VAR_BG);
        let (pull, chi, flagged, failed) = monte_carlo(n, a, flux, 1500, seed);
        eprintln!(
            "{n}x{n} a {a} SNR {snr}: pull RMS {pull:.3}, mean chi2_dof {chi:.3}, POOR_FIT {:.2} %, failed {failed}",
            100.0 * flagged
        );
        assert!((0.9..=1.1).contains(&pull), "pull {pull}");
        assert!((chi - 1.0).abs() < 0.05, "chi2_dof {chi}");
        assert!(flagged < 0.005, "false flags {flagged}");
        assert!(failed < 15, "{failed} failures");
    }
}

#[test]
fn flags_blends_and_cosmic_rays() {
    // A second star of 30 % of the flux 1.5 px away, or a 3,000 e- hit on one pixel next
    // to the peak: the Gaussian cannot describe either, every such window is flagged, with
    // the background given and with the border's (the flight's, whose chi2 limit is wider).
    let mut rng = Rng::new(77);
    let flux = psf::flux_for_snr(50.0, 5.0, VAR_BG);
    let flagged = |win: Win, e: &[startrack_core::units::Electrons], p: &WidthFitParams| {
        fit_pixels(win, e, p)
            .centroid
            .flags
            .contains(CentroidFlags::POOR_FIT)
    };
    let flight = WidthFitParams::new();
    let (mut blends, mut hits, mut blends_border, mut hits_border) = (0, 0, 0, 0);
    for _ in 0..100 {
        let win = Win::centred(40, 50, 7);
        let star = star_at(&mut rng, 1.0, flux);
        let mut mean = psf::render(win, star, NOISE_BG_E);
        let companion = Star {
            x: star.x + 1.5,
            flux: 0.3 * flux,
            ..star
        };
        let second = psf::render(win, companion, 0.0);
        let blend: Vec<f64> = mean.iter().zip(&second).map(|(m, s)| m + s).collect();
        let e = psf::to_electrons(&psf::add_noise(&blend, NOISE_BG_E, VAR_BG, &mut rng));
        blends += usize::from(flagged(win, &e, &params()));
        blends_border += usize::from(flagged(win, &e, &flight));
        mean[3 * 7 + 4] += 3000.0;
        let e = psf::to_electrons(&psf::add_noise(&mean, NOISE_BG_E, VAR_BG, &mut rng));
        hits += usize::from(flagged(win, &e, &params()));
        hits_border += usize::from(flagged(win, &e, &flight));
    }
    eprintln!(
        "POOR_FIT: {blends} / 100 blends, {hits} / 100 cosmic-ray hits (background given); \
         {blends_border} / 100, {hits_border} / 100 (border median)"
    );
    assert!(blends >= 95, "{blends}");
    assert_eq!(hits, 100);
    assert!(blends_border >= 95, "{blends_border}");
    assert_eq!(hits_border, 100);
}

#[test]
fn a_star_the_field_model_does_not_describe_is_flagged_and_fitted_free() {
    // Stars of a = 1.5 px at SNR 50 against a model of a = 1.0 px, scatter 0.02: every one
    // is flagged PSF_MISMATCH and reported as the width-free fit reports it; against a
    // model of their own width, none is, and the width comes out within the scatter.
    let mut rng = Rng::new(78);
    let flux = psf::flux_for_snr(50.0, 5.0, VAR_BG);
    let wrong = WidthPrior {
        a_px: 1.0,
        scatter_px: 0.02,
    };
    let right = WidthPrior { a_px: 1.5, ..wrong };
    let (mut flagged, mut false_flags, mut worst_a) = (0, 0, 0.0f32);
    for _ in 0..100 {
        let win = Win::centred(40, 50, 7);
        let star = star_at(&mut rng, 1.5, flux);
        let mean = psf::render(win, star, NOISE_BG_E);
        let e = psf::to_electrons(&psf::add_noise(&mean, NOISE_BG_E, VAR_BG, &mut rng));
        let input = CentroidInput::new(Window::new(win.rect(), &e).unwrap());
        let free = gauss_fit_width(&input, &params());
        let m = gauss_fit_width_prior(&input, &params(), &wrong);
        if m.centroid.flags.contains(CentroidFlags::PSF_MISMATCH) {
            flagged += 1;
            assert_eq!(m.centroid.x_px, free.centroid.x_px);
            assert_eq!(m.psf_a_px, free.psf_a_px);
        }
        let r = gauss_fit_width_prior(&input, &params(), &right);
        if r.centroid.flags.contains(CentroidFlags::PSF_MISMATCH) {
            false_flags += 1;
        }
        worst_a = worst_a.max((r.psf_a_px - 1.5).abs());
    }
    eprintln!(
        "PSF_MISMATCH: {flagged} / 100 against a wrong model, {false_flags} / 100 against the right one; width within {worst_a:.4} px of the model's"
    );
    assert_eq!(flagged, 100);
    assert!(false_flags <= 1, "{false_flags}");
    // The prior holds the width to a few of the model's scatter.
    assert!(worst_a < 0.1, "{worst_a}");
}
