//! The width-free Gauss fit as the flight configuration and `startrack process` run it
//! (7x7 window, border-median background, width not told) against the Cramer-Rao bound, on
//! stars of every width in 0.6-2 px: the "width unknown" target RMS / CRLB <= 1.1 at
//! SNR >= 10, where CRLB is the bound of a star whose width is known.
//!
//! Below a = 0.8 px no estimator that does not know the width can meet that target: the
//! bound with the width unknown (`crlb_x_width_free_px`, the 4-parameter Fisher matrix) is
//! 1.29x the known-width bound at a = 0.6, SNR 30 (1.55x at SNR 10, 1.08x at SNR 100). There
//! the test holds the fit to 1.1x the width-unknown bound instead; the known-width target is
//! met with the width from a field PSF model: the same fit with the model's width as a prior
//! (scatter 0.02 px, each star's model width off by a seeded error of that RMS) is held to
//! it at every width.
//!
//! A small seeded Monte Carlo (600 stars a cell): an RMS over 2 x 600 errors has a relative
//! standard error of 1 / sqrt(2 x 1200) = 2.0 %, so a cell passes at 1.1 x (1 + 3 SE). The
//! documented table (docs/accuracy.md) uses 2000 stars a cell: `startrack accuracy
//! --width-unknown`. `-- --nocapture` prints the cells.

use startrack_analysis::accuracy::{MODEL_SCATTER_A_PX, Method, Noise, rms_relative_se, run_cell};

const WIDTHS: [f64; 5] = [0.6, 0.8, 1.0, 1.5, 2.0];
const SNRS: [f64; 3] = [10.0, 30.0, 100.0];

#[test]
fn width_free_fit_is_near_the_bound_for_every_width() {
    let noise = Noise {
        trials: 600,
        seed: 11,
        ..Noise::default()
    };
    let fit = Method::GaussFitWidth { window: 7 };
    let limit = 1.1 * (1.0 + 3.0 * rms_relative_se(2 * noise.trials));
    let mut cells = Vec::new();
    for a in WIDTHS {
        for snr in SNRS {
            let c = run_cell(fit, a, snr, &noise).expect("the fit needs no curve");
            eprintln!(
                "a {a} SNR {snr}: RMS / CRLB {:.3}, / width-free CRLB {:.3} (bounds' ratio {:.3}), pull {:.3}, failed {}",
                c.efficiency_ratio(),
                c.rms_px / c.crlb_width_free_px,
                c.crlb_width_free_px / c.crlb_px,
                c.pull_rms,
                c.failures
            );
            cells.push(c);
        }
    }
    for c in &cells {
        let (a, snr) = (c.a_px, c.snr);
        let bound = if a >= 0.8 {
            c.crlb_px
        } else {
            c.crlb_width_free_px
        };
        assert!(
            c.rms_px / bound <= limit,
            "a {a} SNR {snr}: {}",
            c.rms_px / bound
        );
        // Failures (not converged, flagged): at most 1 %; at SNR 10, 2 % (a >= 0.8) and
        // 7 % (a = 0.6: the width barely shows in the noise).
        let most = match (a < 0.8, snr < 20.0) {
            (true, true) => 7,
            (false, true) => 2,
            _ => 1,
        };
        assert!(
            c.failures * 100 <= most * noise.trials,
            "a {a} SNR {snr}: {} failed",
            c.failures
        );
    }
}

#[test]
fn with_the_field_model_the_fit_is_near_the_known_width_bound_for_every_width() {
    let noise = Noise {
        trials: 600,
        seed: 14,
        ..Noise::default()
    };
    let fit = Method::GaussFitWidthModel {
        window: 7,
        scatter_a_px: MODEL_SCATTER_A_PX,
    };
    let limit = 1.1 * (1.0 + 3.0 * rms_relative_se(2 * noise.trials));
    for a in WIDTHS {
        for snr in SNRS {
            let c = run_cell(fit, a, snr, &noise).expect("the fit needs no curve");
            eprintln!(
                "model: a {a} SNR {snr}: RMS / CRLB {:.3}, / CRLB with the prior {:.3}, pull {:.3}, mismatched {}, failed {}",
                c.efficiency_ratio(),
                c.rms_px / c.crlb_width_free_px,
                c.pull_rms,
                c.psf_mismatch,
                c.failures
            );
            assert!(
                c.efficiency_ratio() <= limit,
                "a {a} SNR {snr}: {}",
                c.efficiency_ratio()
            );
            // A model as good as its scatter: PSF_MISMATCH is the 1e-3 tail (at most 1 %).
            assert!(
                c.psf_mismatch * 100 <= noise.trials,
                "a {a} SNR {snr}: {} mismatched",
                c.psf_mismatch
            );
            assert!(
                c.failures * 100 <= noise.trials,
                "a {a} SNR {snr}: {} failed",
                c.failures
            );
        }
    }
}

#[test]
fn an_assumed_width_is_far_from_the_bound_on_other_widths() {
    // What the width-free fit is for: the fit told a = 1.2 px (the flight configuration's
    // former width) on narrow stars at high SNR.
    let noise = Noise {
        trials: 600,
        seed: 12,
        ..Noise::default()
    };
    let assumed = Method::GaussFitAssumed {
        window: 7,
        a_px: 1.2,
    };
    let c = run_cell(assumed, 0.6, 100.0, &noise).unwrap();
    let w = run_cell(Method::GaussFitWidth { window: 7 }, 0.6, 100.0, &noise).unwrap();
    eprintln!(
        "a 0.6 SNR 100: assumed a 1.2 {:.2} x CRLB, width-free {:.2}",
        c.efficiency_ratio(),
        w.efficiency_ratio()
    );
    assert!(c.efficiency_ratio() > 1.5 * w.efficiency_ratio());
}

#[test]
fn sigmas_hold_or_are_flagged() {
    // The width-free fit's pull (error / own sigma) is 0.9-1.1 in a cell, or its stars carry
    // SIGMA_UNRELIABLE (at least 95 % of them); from a = 0.8 px it holds in every cell, and
    // with the field model in every cell with no flag. 600 stars: the pull's relative SE is
    // 2 %, so "holds" is 0.9-1.1 widened by 3 SE.
    let noise = Noise {
        trials: 600,
        seed: 13,
        ..Noise::default()
    };
    let se = rms_relative_se(2 * noise.trials);
    let (lo, hi) = (0.9 * (1.0 - 3.0 * se), 1.1 * (1.0 + 3.0 * se));
    let fit = Method::GaussFitWidth { window: 7 };
    let mut flagged_cells = 0;
    for a in WIDTHS {
        for snr in SNRS {
            let c = run_cell(fit, a, snr, &noise).unwrap();
            let used = c.trials - c.failures;
            let share = c.sigma_flagged as f64 / used as f64;
            eprintln!(
                "a {a} SNR {snr}: pull {:.3}, flagged {:.1} %",
                c.pull_rms,
                100.0 * share
            );
            if !(lo..=hi).contains(&c.pull_rms) {
                assert!(
                    share >= 0.95,
                    "a {a} SNR {snr}: pull {} with {share} flagged",
                    c.pull_rms
                );
                flagged_cells += 1;
            }
            if a >= 0.8 {
                assert!(
                    (lo..=hi).contains(&c.pull_rms),
                    "a {a} SNR {snr}: pull {}",
                    c.pull_rms
                );
            }
            if a >= 1.0 && snr >= 30.0 {
                assert_eq!(
                    c.sigma_flagged, 0,
                    "a {a} SNR {snr}: flagged where the sigma holds"
                );
            }
            let m = run_cell(
                Method::GaussFitWidthModel {
                    window: 7,
                    scatter_a_px: MODEL_SCATTER_A_PX,
                },
                a,
                snr,
                &noise,
            )
            .unwrap();
            eprintln!("model: a {a} SNR {snr}: pull {:.3}", m.pull_rms);
            assert!(
                (lo..=hi).contains(&m.pull_rms),
                "model: a {a} SNR {snr}: pull {}",
                m.pull_rms
            );
            assert_eq!(m.sigma_flagged, 0, "model: a {a} SNR {snr}: flagged");
        }
    }
    assert!(
        flagged_cells >= 1,
        "the table has cells where the sigma fails"
    );
    // The CoG rule: the plain 3x3 CoG of power 1 (pulls up to 18) is always flagged, the
    // corrected 7x7 one on an a = 1 star never.
    let plain = Method::Cog {
        power: startrack_core::table::pixcorr::CogPower::One,
        box_side: 3,
        corrected: false,
    };
    let c = run_cell(plain, 2.0, 100.0, &noise).unwrap();
    eprintln!(
        "cog1 3x3 a 2 SNR 100: pull {:.2}, flagged {}",
        c.pull_rms, c.sigma_flagged
    );
    assert!(c.pull_rms > 5.0);
    assert_eq!(c.sigma_flagged, c.trials - c.failures);
    let corrected = Method::Cog {
        power: startrack_core::table::pixcorr::CogPower::One,
        box_side: 7,
        corrected: true,
    };
    let c = run_cell(corrected, 1.0, 30.0, &noise).unwrap();
    assert!((lo..=hi).contains(&c.pull_rms), "{}", c.pull_rms);
    assert_eq!(c.sigma_flagged, 0);
}
