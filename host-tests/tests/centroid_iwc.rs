//! The core's Gaussian-windowed centroid against the f64 reference iteration (noise-free,
//! across pixel phases and PSF widths), its systematic error against the truth, its
//! convergence, and its error estimate under noise.
//!
//! `-- --nocapture` prints the systematic RMS error (over phases) and the noise results.

#[path = "common/psf.rs"]
mod psf;

use psf::{
    NOISE_BG_E, NOISE_READ_E, Star, Sweep, WIDTHS_A, Win, crlb_x, mean_std, ref_cog, ref_iwc,
    render, sigma_of_a, standard_monte_carlo, to_electrons,
};
use startrack_core::centroid::iwc::{IwcParams, iwc};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::window::Window;

/// Noise-free IWC with weight sigma `sw(s)` against the f64 fixed point; prints the
/// systematic RMS error against the truth for each width.
fn noise_free(sw: impl Fn(f64) -> f64, label: &str) {
    let sweep = Sweep {
        win: Win::centred(40, 40, 11),
        flux: 1.0e5,
        background: 0.0,
        tol_px: 2e-4,
        forbidden: CentroidFlags::all(),
    };
    let mut worst: f64 = 0.0;
    for a in WIDTHS_A {
        let s = sigma_of_a(a);
        let params = IwcParams {
            weight_sigma_px: sw(s) as f32,
            max_iterations: 30,
            tolerance_px: 2e-5,
            start_box: 5,
            background: Background::Given {
                level_e: 0.0,
                variance_e2: 0.0,
            },
        };
        let r = sweep.run(
            a,
            label,
            |w| iwc(&CentroidInput::new(w), &params),
            |q, _| {
                let start = ref_cog(q, 11, 11, psf::peak(q, 11), 2, 1, 0.0, 0.0, true).unwrap();
                ref_iwc(q, 11, 0.0, start, sw(s), 2000, 1.0)
            },
        );
        worst = worst.max(r.worst_px);
        eprintln!(
            "systematic rms IWC ({label}) a {a:4.2} px: {:.5} px",
            r.systematic_rms_px
        );
    }
    eprintln!("largest |core - f64 reference| ({label}): {worst:.2e} px");
}

#[test]
fn matches_f64_reference_noise_free() {
    noise_free(|s| s, "s_w = s");
}

#[test]
fn matches_f64_reference_noise_free_wide_window() {
    // A window no narrower than 0.8 px: the remedy for undersampled stars.
    noise_free(|s| s.max(0.8), "s_w = max(s, 0.8)");
}

#[test]
fn gives_up_cleanly() {
    // Zero iterations: the starting CoG, converged by definition.
    let win = Win::centred(40, 40, 9);
    let star = Star {
        x: 40.2,
        y: 39.7,
        sigma: sigma_of_a(1.5),
        flux: 1.0e4,
    };
    let e = to_electrons(&render(win, star, 0.0));
    let w = Window::new(win.rect(), &e).unwrap();
    let mut params = IwcParams::new(sigma_of_a(1.5) as f32);
    params.background = Background::Given {
        level_e: 0.0,
        variance_e2: 0.0,
    };
    params.max_iterations = 0;
    let c0 = iwc(&CentroidInput::new(w), &params);
    assert!(c0.flags.is_empty(), "{c0:?}");
    // One iteration with a tolerance no step meets: the last estimate, NOT_CONVERGED.
    params.max_iterations = 1;
    params.tolerance_px = 0.0;
    let c1 = iwc(&CentroidInput::new(w), &params);
    assert!(c1.flags.contains(CentroidFlags::NOT_CONVERGED), "{c1:?}");
    assert!((c1.x_px - 40.2).abs() < (c0.x_px - 40.2).abs() + 1e-3);
}

#[test]
fn error_estimate_matches_scatter() {
    for a in [1.5, 2.5] {
        for (snr, seed) in [(10.0, 31u64), (20.0, 32), (50.0, 33), (100.0, 34)] {
            let s = sigma_of_a(a);
            let params = IwcParams::new(s as f32);
            let mc = standard_monte_carlo(
                a,
                snr,
                (0.2, -0.1),
                seed,
                3000,
                CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED,
            );
            let r = mc.run(|w, _| iwc(&CentroidInput::new(w), &params));
            let (failed, e) = (r.failed, r.estimate_rms());
            let dx = r.dx;
            let (m, sd) = mean_std(&dx);
            let crlb = crlb_x(mc.win, mc.star, NOISE_BG_E, NOISE_READ_E);
            eprintln!(
                "IWC a {a} SNR(5x5) {snr:5.1}: mean error {m:+.4} px, scatter {sd:.4} px, estimate {e:.4} px (ratio {:.3}), CRLB {crlb:.4} (efficiency {:.2}), failed {failed}",
                e / sd,
                crlb / sd
            );
            // Low SNR: a few stars do not converge in 20 iterations (flagged, not counted).
            assert!(
                failed < if snr < 15.0 { 150 } else { 5 },
                "{failed} failures"
            );
            assert!(
                (e / sd - 1.0).abs() < 0.2,
                "a {a} SNR {snr}: estimate {e} vs scatter {sd}"
            );
        }
    }
}
