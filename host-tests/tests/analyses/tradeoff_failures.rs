//! Failure-map cells pinned on each side of a boundary (host-tests/analysis/src/tradeoff/failures.rs
//! defines the cells): the plain power-2 CoG 5x5 (pixelisation) is biased below a ~ 1 px
//! and not at 2 px; every method fails at SNR 1; the Gauss fit passes at SNR 30, a = 1 px; an
//! uncorrected hot pixel and a close pair break it, their absence does not; a PSF-width
//! mismatch breaks the fit told the width, not the width-free fit.
//!
//! Tolerances from the trial count N (x and y pooled): an RMS has a relative standard error
//! of 1/sqrt(4 N) ([`rms_relative_se`] of 2N); a detection rate p one of sqrt(p (1 - p) / N).
//! Each assertion keeps its quantity 4 standard errors away from the limit. The systematic
//! error is a bounded function of the uniform pixel phase, whose RMS varies less between
//! samples than a Gaussian's: the same RMS margin is conservative for it.

use startrack_analysis::accuracy::{Method, rms_relative_se};
use startrack_analysis::tradeoff::failures::{
    BIAS_LIMIT_PX, DETECT_LIMIT, FailCell, Perturb, RMS_OVER_CRLB_LIMIT, Scene, Stats, run_scene,
};
use startrack_analysis::tradeoff::methods;
use startrack_core::table::pixcorr::CogPower;

const N: usize = 400;

fn cell(method: Method, a_px: f64, snr: f64, perturb: Perturb) -> Stats {
    let cells: Vec<FailCell> = run_scene(&[method], &Scene { a_px, snr, perturb }, 0, N, 11);
    let s = cells[0].stats.expect("the method applies");
    eprintln!(
        "{} a {a_px} SNR {snr} {perturb:?}: bias {:.4} px, rms/crlb {:.3}, detect {:.3}, {:?}",
        method.name(),
        s.bias_px,
        s.rms_px / s.crlb_px,
        s.detect_rate,
        s.reasons()
    );
    s
}

/// 4 relative standard errors of an RMS over N stars.
fn rms_margin() -> f64 {
    4.0 * rms_relative_se(2 * N)
}

fn detect_margin(p: f64) -> f64 {
    // At least the error of p = 1 - 1/N, so that a rate of exactly 1 still has a margin.
    let p = p.clamp(1.0 / N as f64, 1.0 - 1.0 / N as f64);
    4.0 * (p * (1.0 - p) / N as f64).sqrt()
}

fn biased(s: &Stats) -> bool {
    s.bias_px * (1.0 - rms_margin()) > BIAS_LIMIT_PX
}

fn unbiased(s: &Stats) -> bool {
    s.bias_px * (1.0 + rms_margin()) < BIAS_LIMIT_PX
}

fn passes(s: &Stats) -> bool {
    unbiased(s)
        && s.rms_px * (1.0 + rms_margin()) < RMS_OVER_CRLB_LIMIT * s.crlb_px
        && s.detect_rate - detect_margin(s.detect_rate) > DETECT_LIMIT
}

#[test]
fn plain_power_2_cog_is_biased_below_one_pixel_not_at_two() {
    let m = Method::Cog {
        power: CogPower::Two,
        box_side: 5,
        corrected: false,
    };
    let small = cell(m, 0.6, 100.0, Perturb::None);
    assert!(biased(&small), "{} at a = 0.6", m.name());
    assert!(small.fails());
    let wide = cell(m, 2.0, 100.0, Perturb::None);
    assert!(unbiased(&wide), "{} at a = 2", m.name());
}

#[test]
fn every_method_fails_at_snr_1() {
    for m in methods() {
        let cells = run_scene(
            &[m],
            &Scene {
                a_px: 1.0,
                snr: 1.0,
                perturb: Perturb::None,
            },
            0,
            N,
            11,
        );
        let Some(s) = cells[0].stats else { continue };
        assert!(
            s.detect_rate + detect_margin(s.detect_rate) < DETECT_LIMIT,
            "{}: detect {}",
            m.name(),
            s.detect_rate
        );
    }
}

#[test]
fn gauss_fit_passes_at_snr_30_a_1() {
    let s = cell(Method::GaussFit { window: 5 }, 1.0, 30.0, Perturb::None);
    assert!(passes(&s));
}

#[test]
fn a_hot_pixel_and_a_close_pair_break_the_gauss_fit() {
    let fit = Method::GaussFit { window: 5 };
    assert!(passes(&cell(fit, 1.5, 30.0, Perturb::HotPixel(0.0))));
    assert!(biased(&cell(fit, 1.5, 30.0, Perturb::HotPixel(3000.0))));
    assert!(passes(&cell(fit, 1.5, 30.0, Perturb::Pair(6.0))));
    assert!(biased(&cell(fit, 1.5, 30.0, Perturb::Pair(1.0))));
}

#[test]
fn a_width_mismatch_breaks_the_fit_told_the_width_not_the_width_free_fit() {
    // Configured for a = 1.5 px: the Gauss fit passes on a 1.5 px star and fails on a 0.6 px
    // one (RMS over 2x the bound).
    let fit = Method::GaussFit { window: 5 };
    assert!(passes(&cell(fit, 1.5, 30.0, Perturb::TrueWidth(1.5))));
    let narrow = cell(fit, 1.5, 30.0, Perturb::TrueWidth(0.6));
    assert!(narrow.rms_px * (1.0 - rms_margin()) > RMS_OVER_CRLB_LIMIT * narrow.crlb_px);
    // The width-free fit is told no width: the same stars give the same cell whatever the
    // configured a, and it passes on both.
    let free = Method::GaussFitWidth { window: 7 };
    for true_a in [0.6, 1.5] {
        let a = cell(free, 1.5, 30.0, Perturb::TrueWidth(true_a));
        let b = cell(free, 0.8, 30.0, Perturb::TrueWidth(true_a));
        assert_eq!(a, b, "true a {true_a}");
        assert!(passes(&a), "true a {true_a}");
    }
}
