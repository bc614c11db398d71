//! Figures 5 and 6: the paper's dark non-uniformity experiment through the core, and our
//! dark pre-calculation's improvement (the required numbers).
//!
//! Monte Carlo tolerances, with n = TRIALS trials per point:
//! - a detection rate q has binomial standard error sqrt(q (1 - q) / n) (at most 0.016 for
//!   n = 1000); "falls" means by more than 3 combined standard errors;
//! - an RMS over n roughly Gaussian errors has relative standard error 1/sqrt(2n) (2.2 % at
//!   n = 1000); the two DSNU points of a ratio use the same star positions, phases and photon
//!   draws, so their ratio scatters less than the sqrt(2) x 2.2 % = 3.2 % of independent
//!   points. The required bound (<= 1.1) sits 3 of those above the expected ratio (~1.01:
//!   the measured map adds (250 + 25) / 32 e-^2 to 275 e-^2 per pixel), so a pass is not luck.

use startrack_analysis::figures::fig5::{DarkMethod, Fig5Params, Fig5Point, run};

const TRIALS: usize = 1000;

fn experiment() -> Vec<Fig5Point> {
    let p = Fig5Params {
        snr0: vec![5.0, 10.0],
        dsnu: vec![0.0, 0.125, 0.25],
        trials: TRIALS,
        dark_frames: 32,
        a_px: 1.5,
        seed: 11,
    };
    run(&p, false).points
}

fn get(points: &[Fig5Point], snr0: f64, dsnu: f64, power: u8, method: DarkMethod) -> Fig5Point {
    *points
        .iter()
        .find(|q| q.snr0 == snr0 && q.dsnu == dsnu && q.power == power && q.method == method)
        .unwrap()
}

fn binomial_se(q: f64) -> f64 {
    (q * (1.0 - q) / TRIALS as f64)
        .sqrt()
        .max(0.5 / TRIALS as f64)
}

#[test]
fn precalc_removes_the_dsnu_penalty_and_perimeter_shows_the_paper_effect() {
    let pts = experiment();
    for q in &pts {
        eprintln!(
            "SNR {:>4} DSNU {:.3} pow {} {:>9}: rms {:.4} px, detected {:.3}, mean SNR {:.2}",
            q.snr0,
            q.dsnu,
            q.power,
            q.method.name(),
            q.rms_px,
            q.detect_rate,
            q.mean_snr
        );
    }
    let rel_se = 1.0 / (2.0 * TRIALS as f64).sqrt();
    for snr0 in [5.0, 10.0] {
        for power in [1u8, 2] {
            // Precalc: the error at DSNU 0.25 is at most 1.1x the error without DSNU.
            let e0 = get(&pts, snr0, 0.0, power, DarkMethod::Precalc).rms_px;
            let e25 = get(&pts, snr0, 0.25, power, DarkMethod::Precalc).rms_px;
            assert!(
                e25 <= 1.1 * e0,
                "precalc SNR {snr0} pow {power}: {e25} vs {e0} (MC rel. se {rel_se:.3})"
            );
        }
        // Perimeter (the paper): the detection rate falls with DSNU.
        let d: Vec<f64> = [0.0, 0.125, 0.25]
            .iter()
            .map(|&s| get(&pts, snr0, s, 1, DarkMethod::Perimeter).detect_rate)
            .collect();
        for w in d.windows(2) {
            let se = (binomial_se(w[0]).powi(2) + binomial_se(w[1]).powi(2)).sqrt();
            assert!(w[1] < w[0] - 3.0 * se, "perimeter SNR {snr0}: {d:?}");
        }
    }
    // Precalc: an SNR-5 star is still detected at least 95 % of the time at every DSNU.
    for dsnu in [0.0, 0.125, 0.25] {
        let q = get(&pts, 5.0, dsnu, 1, DarkMethod::Precalc).detect_rate;
        assert!(q >= 0.95, "precalc SNR 5 DSNU {dsnu}: detected {q}");
    }
    // Perimeter at high SNR: the error grows with DSNU (the paper: 0.1 -> 0.3 px at SNR 10),
    // by far more than the Monte Carlo scatter (relative se 1/sqrt(2 n_detected)).
    for power in [1u8, 2] {
        let a = get(&pts, 10.0, 0.0, power, DarkMethod::Perimeter);
        let b = get(&pts, 10.0, 0.25, power, DarkMethod::Perimeter);
        let se_b = 1.0 / (2.0 * b.detect_rate * TRIALS as f64).sqrt();
        assert!(
            b.rms_px * (1.0 - 3.0 * se_b) > 2.0 * a.rms_px * (1.0 + 3.0 * rel_se),
            "perimeter SNR 10 pow {power}: {} -> {}",
            a.rms_px,
            b.rms_px
        );
    }
}
