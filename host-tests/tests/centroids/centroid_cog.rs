//! Noise-free tests of the core's centre of gravity against the f64 reference: pixel phases
//! over the central pixel, PSF widths a = 0.5..3 px, boxes 3..9, both powers, given and
//! perimeter backgrounds, and the extremes of the calibrated range.
//!
//! `cargo test -p startrack-host --test centroids centroid_cog:: -- --nocapture` also prints the
//! systematic (pixelisation + truncation) error against the true position, the paper's
//! Figures 1 and 4.

use startrack_test_support::psf;

use psf::{Star, Sweep, WIDTHS_A, Win, phases, ref_cog, render, sigma_of_a, to_electrons, to_f64};
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::units::Electrons;
use startrack_core::window::Window;

const BOXES: [u8; 4] = [3, 5, 7, 9];

fn power_of(p: CogPower) -> u8 {
    match p {
        CogPower::One => 1,
        CogPower::Two => 2,
    }
}

#[test]
fn matches_f64_reference_noise_free() {
    let win = Win::centred(100, 200, 11);
    let sweep = Sweep {
        win,
        flux: 1.0e5,
        background: 0.0,
        tol_px: 1e-4,
        forbidden: CentroidFlags::DEGENERATE | CentroidFlags::CLAMPED | CentroidFlags::LOW_SNR,
    };
    let mut worst: f64 = 0.0;
    for power in [CogPower::One, CogPower::Two] {
        for side in BOXES {
            let params = CogParams {
                power,
                box_side: side,
                anchor: Anchor::Peak,
                background: Background::Given {
                    level_e: 0.0,
                    variance_e2: 0.0,
                },
            };
            for a in WIDTHS_A {
                let r = sweep.run(
                    a,
                    &format!("{power:?} box {side}"),
                    |w| cog(&CentroidInput::new(w), &params),
                    |q, _| {
                        ref_cog(
                            q,
                            win.w,
                            win.h,
                            psf::peak(q, win.w),
                            u16::from(side / 2),
                            power_of(power),
                            0.0,
                            0.0,
                            true,
                        )
                        .unwrap()
                    },
                );
                worst = worst.max(r.worst_px);
                eprintln!(
                    "systematic rms {power:?} box {side} a {a:4.2} px: {:.4} px",
                    r.systematic_rms_px
                );
            }
        }
    }
    eprintln!("largest |core - f64 reference|: {worst:.2e} px");
}

#[test]
fn perimeter_background_mean_and_median() {
    // A 9x9 window around a 7x7 box, star a = 1.5 px on 250 e- of background.
    let win = Win::centred(50, 60, 9);
    for (bgmode, is_median) in [
        (Background::PerimeterMean, false),
        (Background::PerimeterMedian, true),
    ] {
        for px in phases() {
            let star = Star {
                x: 50.0 + px,
                y: 60.0 - 0.5 * px,
                sigma: sigma_of_a(1.5),
                flux: 2.0e4,
            };
            let e = to_electrons(&render(win, star, 250.0));
            let q = to_f64(&e);
            let mut border = psf::border(&q, 9);
            border.sort_by(f64::total_cmp);
            let bg = if is_median {
                0.5 * (border[15] + border[16])
            } else {
                border.iter().sum::<f64>() / border.len() as f64
            };
            let w = Window::new(win.rect(), &e).unwrap();
            for power in [CogPower::One, CogPower::Two] {
                let params = CogParams {
                    power,
                    box_side: 7,
                    anchor: Anchor::Peak,
                    background: bgmode,
                };
                let c = cog(&CentroidInput::new(w), &params);
                // The core rounds the level to 1/64 e- and uses the measured border variance.
                let var_bg = if is_median {
                    0.0
                } else {
                    startrack_core::centroid::estimate_background(&CentroidInput::new(w), bgmode)
                        .unwrap()
                        .variance_e2 as f64
                };
                let var_level = if is_median { 0.0 } else { var_bg / 32.0 };
                let (rx, ry) = ref_cog(
                    &q,
                    9,
                    9,
                    psf::peak(&q, 9),
                    3,
                    power_of(power),
                    bg,
                    var_bg + var_level,
                    true,
                )
                .unwrap();
                let tol = 2e-4;
                assert!(
                    (f64::from(c.x_px) - rx - 46.0).abs() < tol,
                    "{bgmode:?} {power:?} {px}: {} vs {}",
                    c.x_px,
                    rx + 46.0
                );
                assert!(
                    (f64::from(c.y_px) - ry - 56.0).abs() < tol,
                    "{bgmode:?} {power:?} {px}: {} vs {}",
                    c.y_px,
                    ry + 56.0
                );
                // Against the truth: background removed, 7x7 box of a 1.5 px star.
                assert!(
                    (f64::from(c.x_px) - star.x).abs() < 0.02,
                    "{} vs {}",
                    c.x_px,
                    star.x
                );
            }
        }
    }
}

#[test]
fn extremes_of_the_calibrated_range() {
    // A star whose peak is at the top of the calibrated range, on zero and on the most
    // negative background (so that pixel - background reaches 2^26 e-).
    let win = Win::centred(20, 20, 9);
    for (bg, peak) in [(0.0, 33_000_000.0), (-33_554_000.0, 33_554_000.0)] {
        let sigma = sigma_of_a(1.0);
        let frac0 = psf::pixel_frac(20.0, 20.2, sigma) * psf::pixel_frac(20.0, 19.9, sigma);
        let star = Star {
            x: 20.2,
            y: 19.9,
            sigma,
            flux: (peak - bg) / frac0,
        };
        let e = to_electrons(&render(win, star, bg));
        let q = to_f64(&e);
        let w = Window::new(win.rect(), &e).unwrap();
        for power in [CogPower::One, CogPower::Two] {
            for side in [3u8, 5, 7] {
                let params = CogParams {
                    power,
                    box_side: side,
                    anchor: Anchor::Peak,
                    background: Background::Given {
                        level_e: bg as f32,
                        variance_e2: 0.0,
                    },
                };
                let c = cog(&CentroidInput::new(w), &params);
                let (rx, ry) = ref_cog(
                    &q,
                    9,
                    9,
                    psf::peak(&q, 9),
                    u16::from(side / 2),
                    power_of(power),
                    bg,
                    0.0,
                    true,
                )
                .unwrap();
                assert!(c.flags.is_empty(), "{:?}", c.flags);
                assert!(
                    (f64::from(c.x_px) - rx - 16.0).abs() < 1e-3,
                    "{power:?} {side}: {} vs {}",
                    c.x_px,
                    rx + 16.0
                );
                assert!(
                    (f64::from(c.y_px) - ry - 16.0).abs() < 1e-3,
                    "{power:?} {side}: {} vs {}",
                    c.y_px,
                    ry + 16.0
                );
                assert!(c.snr.is_finite() && c.snr > 1000.0 && c.sigma_x_px.is_finite());
            }
        }
    }
    // Every pixel at the maximum (and at the minimum): flat, degenerate, finite.
    for v in [Electrons::MAX, Electrons::MIN] {
        let e = vec![v; 81];
        let w = Window::new(win.rect(), &e).unwrap();
        for power in [CogPower::One, CogPower::Two] {
            for bgmode in [
                Background::PerimeterMean,
                Background::PerimeterMedian,
                Background::Given {
                    level_e: 0.0,
                    variance_e2: 0.0,
                },
            ] {
                let c = cog(
                    &CentroidInput::new(w),
                    &CogParams {
                        power,
                        box_side: 9,
                        anchor: Anchor::Peak,
                        background: bgmode,
                    },
                );
                assert!(
                    c.x_px.is_finite()
                        && c.y_px.is_finite()
                        && c.flux_e.is_finite()
                        && c.snr.is_finite()
                );
                assert!((16.0..=24.0).contains(&c.x_px) && (16.0..=24.0).contains(&c.y_px));
                if !matches!(bgmode, Background::Given { .. }) || v == Electrons::MIN {
                    assert!(
                        c.flags.contains(CentroidFlags::DEGENERATE),
                        "{v} {bgmode:?} {power:?}: {c:?}"
                    );
                    assert_eq!((c.x_px, c.y_px), (20.0, 20.0));
                }
            }
        }
    }
}
