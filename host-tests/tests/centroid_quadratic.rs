//! The core's 3-point peak fits against the f64 reference (noise-free, across pixel phases and
//! PSF widths), their systematic error against the truth, and their error estimate under noise.
//!
//! `-- --nocapture` prints the systematic RMS error (over phases) and the noise results.

#[path = "common/psf.rs"]
mod psf;

use psf::{
    Rng, Star, Win, add_noise, flux_for_snr, mean_std, ref_quad3, render, sigma_of_a, to_electrons,
    to_f64,
};
use startrack_core::centroid::quadratic::{QuadraticKind, QuadraticParams, quadratic};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::window::Window;

const WIDTHS_A: [f64; 7] = [0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0];

fn phases() -> impl Iterator<Item = f64> {
    (0..10).map(|i| -0.45 + 0.1 * f64::from(i))
}

/// Reference fit on the quantised window values (window-relative).
fn reference(q: &[f64], w: usize, kind: QuadraticKind) -> (f64, f64) {
    let (pc, pr) = psf::peak(q, w as u16);
    let (pc, pr) = (usize::from(pc), usize::from(pr));
    let at = |c: usize, r: usize| q[r * w + c];
    let fit = |a: f64, b: f64, c: f64| {
        let log = kind == QuadraticKind::Gaussian && a > 0.0 && c > 0.0;
        ref_quad3(a, b, c, log).clamp(-0.5, 0.5)
    };
    (
        pc as f64 + fit(at(pc - 1, pr), at(pc, pr), at(pc + 1, pr)),
        pr as f64 + fit(at(pc, pr - 1), at(pc, pr), at(pc, pr + 1)),
    )
}

#[test]
fn matches_f64_reference_noise_free() {
    let win = Win::centred(500, 30, 7);
    let mut worst: f64 = 0.0;
    for kind in [QuadraticKind::Parabolic, QuadraticKind::Gaussian] {
        for a in WIDTHS_A {
            let mut sys_sq = 0.0;
            let mut n = 0.0;
            for px in phases() {
                for py in phases() {
                    let star = Star {
                        x: 500.0 + px,
                        y: 30.0 + py,
                        sigma: sigma_of_a(a),
                        flux: 5.0e4,
                    };
                    let e = to_electrons(&render(win, star, 0.0));
                    let q = to_f64(&e);
                    let params = QuadraticParams {
                        kind,
                        background: Background::Given {
                            level_e: 0.0,
                            variance_e2: 0.0,
                        },
                    };
                    let c = quadratic(
                        &CentroidInput::new(Window::new(win.rect(), &e).unwrap()),
                        &params,
                    );
                    let (rx, ry) = reference(&q, 7, kind);
                    let (rx, ry) = (rx + f64::from(win.x0), ry + f64::from(win.y0));
                    let err = (f64::from(c.x_px) - rx)
                        .abs()
                        .max((f64::from(c.y_px) - ry).abs());
                    worst = worst.max(err);
                    assert!(
                        err < 1e-4,
                        "{kind:?} a {a} ({px},{py}): core ({}, {}) ref ({rx}, {ry})",
                        c.x_px,
                        c.y_px
                    );
                    assert!(
                        !c.flags
                            .intersects(CentroidFlags::DEGENERATE | CentroidFlags::PEAK_AT_EDGE),
                        "{c:?}"
                    );
                    sys_sq += (rx - star.x).powi(2);
                    n += 1.0;
                }
            }
            eprintln!(
                "systematic rms {kind:?} a {a:4.2} px: {:.4} px",
                (sys_sq / n).sqrt()
            );
        }
    }
    eprintln!("largest |core - f64 reference|: {worst:.2e} px");
}

#[test]
fn peak_on_the_border_keeps_the_pixel_centre() {
    let win = Win {
        x0: 0,
        y0: 10,
        w: 4,
        h: 5,
    };
    let star = Star {
        x: 0.1,
        y: 12.2,
        sigma: sigma_of_a(1.0),
        flux: 1e4,
    };
    let e = to_electrons(&render(win, star, 0.0));
    for kind in [QuadraticKind::Parabolic, QuadraticKind::Gaussian] {
        let params = QuadraticParams {
            kind,
            background: Background::Given {
                level_e: 0.0,
                variance_e2: 0.0,
            },
        };
        let c = quadratic(
            &CentroidInput::new(Window::new(win.rect(), &e).unwrap()).with_clipped(true),
            &params,
        );
        assert!(
            c.flags
                .contains(CentroidFlags::PEAK_AT_EDGE | CentroidFlags::EDGE_CLIPPED),
            "{c:?}"
        );
        assert_eq!(c.x_px, 0.0);
        assert!((f64::from(c.y_px) - 12.2).abs() < 0.1, "{c:?}");
    }
}

#[test]
fn error_estimate_matches_scatter() {
    const BG: f64 = 100.0;
    const VAR_BG: f64 = 125.0;
    let win = Win::centred(100, 100, 7);
    for kind in [QuadraticKind::Parabolic, QuadraticKind::Gaussian] {
        for (snr, seed) in [(20.0, 21u64), (50.0, 22), (100.0, 23)] {
            let star = Star {
                x: 100.2,
                y: 99.9,
                sigma: sigma_of_a(1.5),
                flux: flux_for_snr(snr, 3.0, VAR_BG),
            };
            let mean = render(win, star, BG);
            let mut rng = Rng::new(seed);
            let (mut dx, mut est) = (vec![], vec![]);
            let params = QuadraticParams {
                kind,
                background: Background::PerimeterMean,
            };
            for _ in 0..4000 {
                let e = to_electrons(&add_noise(&mean, BG, VAR_BG, &mut rng));
                let c = quadratic(
                    &CentroidInput::new(Window::new(win.rect(), &e).unwrap()),
                    &params,
                );
                assert!(!c.flags.contains(CentroidFlags::DEGENERATE), "{c:?}");
                dx.push(f64::from(c.x_px) - star.x);
                est.push(f64::from(c.sigma_x_px).powi(2));
            }
            let (m, s) = mean_std(&dx);
            let e = (est.iter().sum::<f64>() / est.len() as f64).sqrt();
            eprintln!(
                "{kind:?} SNR(3x3) {snr:5.1}: mean error {m:+.4} px, scatter {s:.4} px, estimate {e:.4} px (ratio {:.3})",
                e / s
            );
            assert!(
                (e / s - 1.0).abs() < 0.2,
                "{kind:?} SNR {snr}: estimate {e} vs scatter {s}"
            );
        }
    }
}
