//! The core's 3-point parabolic peak fit against the f64 reference (noise-free, across pixel
//! phases and PSF widths), its systematic error against the truth, and its error estimate
//! under noise.
//!
//! `-- --nocapture` prints the systematic RMS error (over phases) and the noise results.

#[path = "common/psf.rs"]
mod psf;

use psf::{
    MonteCarlo, Star, Sweep, WIDTHS_A, Win, flux_for_snr, mean_std, ref_quad3, render, sigma_of_a,
    to_electrons,
};
use startrack_core::centroid::quadratic::{QuadraticParams, quadratic};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::window::Window;

/// Reference fit on the quantised window values (window-relative).
fn reference(q: &[f64], w: usize) -> (f64, f64) {
    let (pc, pr) = psf::peak(q, w as u16);
    let (pc, pr) = (usize::from(pc), usize::from(pr));
    let at = |c: usize, r: usize| q[r * w + c];
    let fit = |a: f64, b: f64, c: f64| ref_quad3(a, b, c).clamp(-0.5, 0.5);
    (
        pc as f64 + fit(at(pc - 1, pr), at(pc, pr), at(pc + 1, pr)),
        pr as f64 + fit(at(pc, pr - 1), at(pc, pr), at(pc, pr + 1)),
    )
}

#[test]
fn matches_f64_reference_noise_free() {
    let sweep = Sweep {
        win: Win::centred(500, 30, 7),
        flux: 5.0e4,
        background: 0.0,
        tol_px: 1e-4,
        forbidden: CentroidFlags::DEGENERATE | CentroidFlags::PEAK_AT_EDGE,
    };
    let mut worst: f64 = 0.0;
    let params = QuadraticParams {
        background: Background::Given {
            level_e: 0.0,
            variance_e2: 0.0,
        },
    };
    for a in WIDTHS_A {
        let r = sweep.run(
            a,
            "parabolic",
            |w| quadratic(&CentroidInput::new(w), &params),
            |q, _| reference(q, 7),
        );
        worst = worst.max(r.worst_px);
        eprintln!("systematic rms a {a:4.2} px: {:.4} px", r.systematic_rms_px);
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
    let params = QuadraticParams {
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

#[test]
fn error_estimate_matches_scatter() {
    const BG: f64 = 100.0;
    const VAR_BG: f64 = 125.0;
    let win = Win::centred(100, 100, 7);
    {
        for (snr, seed) in [(20.0, 21u64), (50.0, 22), (100.0, 23)] {
            let star = Star {
                x: 100.2,
                y: 99.9,
                sigma: sigma_of_a(1.5),
                flux: flux_for_snr(snr, 3.0, VAR_BG),
            };
            let params = QuadraticParams {
                background: Background::PerimeterMean,
            };
            let r = MonteCarlo {
                win,
                star,
                background: BG,
                var_bg: VAR_BG,
                trials: 4000,
                seed,
                fail_flags: CentroidFlags::empty(),
            }
            .run(|w, _| {
                let c = quadratic(&CentroidInput::new(w), &params);
                assert!(!c.flags.contains(CentroidFlags::DEGENERATE), "{c:?}");
                c
            });
            let (dx, e) = (&r.dx, r.estimate_rms());
            let (m, s) = mean_std(dx);
            eprintln!(
                "SNR(3x3) {snr:5.1}: mean error {m:+.4} px, scatter {s:.4} px, estimate {e:.4} px (ratio {:.3})",
                e / s
            );
            assert!(
                (e / s - 1.0).abs() < 0.2,
                "SNR {snr}: estimate {e} vs scatter {s}"
            );
        }
    }
}
