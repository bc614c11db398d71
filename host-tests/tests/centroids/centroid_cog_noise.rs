//! Monte Carlo tests of the core's centre of gravity under noise: the variance-subtracted
//! power-2 CoG is unbiased, and the propagated error estimate matches the measured scatter.
//!
//! Noise: Gaussian with the variance of shot noise (star and background) plus read noise,
//! from a seeded splitmix64 (deterministic). `-- --nocapture` prints the measured RMS, the
//! estimated sigma, and the efficiency against the Cramer-Rao bound.

use startrack_test_support::psf;

use psf::{
    McResult, MonteCarlo, Star, Win, crlb_x, flux_for_snr, mean_std, ref_cog, render, sigma_of_a,
};
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;

const BG_E: f64 = 100.0;
const READ_E: f64 = 5.0;
const VAR_BG: f64 = BG_E + READ_E * READ_E;
const TRIALS: usize = 4000;

/// The core's results and, on the same data, plain eq. 6 (no variance subtraction) in f64.
struct Run {
    core: McResult,
    /// Plain eq. 6 estimates minus the true x.
    naive_dx: Vec<f64>,
}

fn run(snr: f64, power: CogPower, background: Background, seed: u64) -> (Run, Star, Win) {
    let win = Win::centred(100, 100, 9);
    let star = Star {
        x: 100.3,
        y: 99.85,
        sigma: sigma_of_a(2.0),
        flux: flux_for_snr(snr, 5.0, VAR_BG),
    };
    let params = CogParams {
        power,
        box_side: 5,
        anchor: Anchor::WindowCentre,
        background,
    };
    let mut naive_dx = Vec::new();
    let core = MonteCarlo {
        win,
        star,
        background: BG_E,
        var_bg: VAR_BG,
        trials: TRIALS,
        seed,
        fail_flags: CentroidFlags::empty(),
    }
    .run(|w, q| {
        let c = cog(&CentroidInput::new(w), &params);
        assert!(
            !c.flags
                .intersects(CentroidFlags::DEGENERATE | CentroidFlags::CLAMPED),
            "SNR {snr}: {c:?}"
        );
        if let Some((nx, _)) = ref_cog(q, 9, 9, (4, 4), 2, 2, BG_E, 0.0, false) {
            naive_dx.push(nx + f64::from(win.x0) - star.x);
        }
        c
    });
    (Run { core, naive_dx }, star, win)
}

/// The noise-free expectation of the estimator: its formula on the mean image with `E[w]`
/// (power 1: mu, power 2: mu^2), background level `bg`.
fn expected_x(win: Win, star: Star, power: CogPower, bg: f64) -> f64 {
    let mean = render(win, star, BG_E);
    let p = if power == CogPower::One { 1 } else { 2 };
    ref_cog(&mean, 9, 9, (4, 4), 2, p, bg, 0.0, false)
        .unwrap()
        .0
        + f64::from(win.x0)
        - star.x
}

/// The noise-free perimeter mean (the expectation of the measured level).
fn perimeter_mean(win: Win, star: Star) -> f64 {
    let border = psf::border(&render(win, star, BG_E), 9);
    border.iter().sum::<f64>() / border.len() as f64
}

#[test]
fn power_two_with_variance_subtraction_is_unbiased() {
    for (snr, seed) in [(20.0, 1u64), (50.0, 2), (100.0, 3)] {
        for (bgmode, name) in [
            (
                Background::Given {
                    level_e: BG_E as f32,
                    variance_e2: VAR_BG as f32,
                },
                "given",
            ),
            (Background::PerimeterMean, "perimeter mean"),
        ] {
            let (r, star, win) = run(snr, CogPower::Two, bgmode, seed);
            let bg = if name == "given" {
                BG_E
            } else {
                perimeter_mean(win, star)
            };
            let want = expected_x(win, star, CogPower::Two, bg);
            let (m, s) = mean_std(&r.core.dx);
            let se = s / (TRIALS as f64).sqrt();
            let (nm, _) = mean_std(&r.naive_dx);
            eprintln!(
                "SNR {snr:5.1} {name:15}: mean error {m:+.5} px (expected {want:+.5}, SE {se:.5}); plain eq. 6 {nm:+.5} px"
            );
            assert!(
                (m - want).abs() < 3.5 * se,
                "SNR {snr} {name}: bias {} px, SE {se}",
                m - want
            );
            if name == "given" && snr <= 20.0 {
                // The test has the power to see the bias the subtraction removes.
                assert!(
                    (nm - want).abs() > 5.0 * se,
                    "plain eq. 6 bias {} not detected",
                    nm - want
                );
            }
        }
    }
}

#[test]
fn error_estimate_matches_scatter() {
    for power in [CogPower::One, CogPower::Two] {
        for (snr, seed) in [(10.0, 11u64), (20.0, 12), (50.0, 13), (100.0, 14)] {
            for bgmode in [Background::PerimeterMean, Background::PerimeterMedian] {
                let (r, star, win) = run(snr, power, bgmode, seed);
                let (_, measured) = mean_std(&r.core.dx);
                let est = r.core.estimate_rms();
                let (snr_m, _) = mean_std(&r.core.snr);
                let crlb = crlb_x(win, star, BG_E, READ_E);
                eprintln!(
                    "{power:?} SNR {snr:5.1} ({bgmode:?}, measured SNR {snr_m:6.1}): scatter {measured:.4} px, estimate {est:.4} px (ratio {:.3}), CRLB {crlb:.4} px (efficiency {:.2})",
                    est / measured,
                    crlb / measured
                );
                assert!(
                    (est / measured - 1.0).abs() < 0.2,
                    "{power:?} SNR {snr} {bgmode:?}: estimate {est} vs scatter {measured}"
                );
                // The reported SNR against the flux's actual signal-to-scatter (eq. 8 plus the
                // background level's error, which a 32-pixel perimeter makes significant).
                let (fm, fs) = mean_std(&r.core.flux);
                assert!(
                    (snr_m / (fm / fs) - 1.0).abs() < 0.2,
                    "reported SNR {snr_m}, flux/scatter {}",
                    fm / fs
                );
            }
        }
    }
}
