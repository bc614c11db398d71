//! Degenerate and hostile windows for every centroid method: a flag, finite outputs and a
//! position inside the window, never a panic; and a property test over arbitrary windows.

use startrack_test_support::psf;

use proptest::prelude::*;
use psf::{Star, Win, render, sigma_of_a, to_electrons};
use startrack_core::calib::PixelFlags;
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::gauss_fit::{GaussFitParams, gauss_fit};
use startrack_core::centroid::{Background, Centroid, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};

const BACKGROUNDS: [Background; 4] = [
    Background::PerimeterMean,
    Background::PerimeterMedian,
    Background::Given {
        level_e: 0.0,
        variance_e2: 0.0,
    },
    Background::Given {
        level_e: f32::NAN,
        variance_e2: f32::INFINITY,
    },
];

/// Every method with a spread of parameters.
fn all_methods(input: &CentroidInput<'_>) -> Vec<(String, Centroid)> {
    let mut out = vec![];
    for bg in BACKGROUNDS {
        for power in [CogPower::One, CogPower::Two] {
            for side in [0u8, 1, 3, 4, 5, 9, 255] {
                for anchor in [Anchor::Peak, Anchor::WindowCentre] {
                    let p = CogParams {
                        power,
                        box_side: side,
                        anchor,
                        background: bg,
                    };
                    out.push((format!("{p:?}"), cog(input, &p)));
                }
            }
        }
        for (s, iters, fit_background) in [
            (1.0, 8, true),
            (0.0, 3, false),
            (f32::NAN, 255, true),
            (1e30, 1, true),
        ] {
            let p = GaussFitParams {
                psf_sigma_px: s,
                max_iterations: iters,
                tolerance_px: 1e-4,
                start_box: 5,
                fit_background,
                background: bg,
            };
            out.push((format!("{p:?}"), gauss_fit(input, &p)));
        }
    }
    out
}

/// Finite outputs, position inside the window's extent (pixel edges).
fn check(rect: Rect, name: &str, c: &Centroid) {
    for v in [c.x_px, c.y_px, c.flux_e, c.snr, c.sigma_x_px, c.sigma_y_px] {
        assert!(v.is_finite(), "{name}: {c:?}");
    }
    assert!(c.sigma_x_px >= 0.0 && c.sigma_y_px >= 0.0, "{name}: {c:?}");
    if !rect.is_empty() {
        let (x0, y0) = (f32::from(rect.x0), f32::from(rect.y0));
        assert!(
            c.x_px >= x0 - 0.5 && c.x_px <= x0 + f32::from(rect.width) - 0.5,
            "{name}: {rect:?} {c:?}"
        );
        assert!(
            c.y_px >= y0 - 0.5 && c.y_px <= y0 + f32::from(rect.height) - 0.5,
            "{name}: {rect:?} {c:?}"
        );
    }
    if c.flags.contains(CentroidFlags::DEGENERATE) {
        let cx = f32::from(rect.x0) + f32::from(rect.width.saturating_sub(1) / 2);
        let cy = f32::from(rect.y0) + f32::from(rect.height.saturating_sub(1) / 2);
        assert_eq!(
            (c.x_px, c.y_px),
            (cx, cy),
            "{name}: degenerate not at the centre pixel"
        );
    }
}

fn rect(w: u16, h: u16) -> Rect {
    Rect {
        x0: 300,
        y0: 400,
        width: w,
        height: h,
    }
}

/// Runs every method on `pixels` and asserts that each result is flagged `must`.
fn expect_all(r: Rect, pixels: &[Electrons], flags: &[PixelFlags], must: CentroidFlags) {
    let w = Window {
        rect: r,
        pixels_e: pixels,
    };
    for (name, c) in all_methods(&CentroidInput::new(w).with_pixel_flags(flags)) {
        check(r, &name, &c);
        assert!(
            c.flags.intersects(must),
            "{name}: expected {must:?}, got {c:?}"
        );
    }
}

#[test]
fn flat_zero_negative_windows_are_degenerate() {
    let r = rect(7, 7);
    for v in [0.0, 250.0, -3.0, -33_554_432.0] {
        // Flat: the background methods see nothing; a given background of 0 sees a flat
        // positive window (a position at the centre) or a negative one (degenerate).
        let px = vec![Electrons::from_num(v); 49];
        let w = Window {
            rect: r,
            pixels_e: &px,
        };
        for (name, c) in all_methods(&CentroidInput::new(w)) {
            check(r, &name, &c);
            if v <= 0.0 || name.contains("Perimeter") {
                assert!(
                    c.flags.contains(CentroidFlags::DEGENERATE),
                    "{v} {name}: {c:?}"
                );
            } else {
                // By symmetry the centre pixel (iterative methods: up to f32 rounding).
                assert!(
                    (c.x_px - 303.0).abs() < 1e-3 && (c.y_px - 403.0).abs() < 1e-3,
                    "{name}: {c:?}"
                );
            }
        }
    }
    // All negative but not flat (a gradient: after a perimeter background, a faint "star" on
    // one side, its peak in a corner; every method must flag it: no star, too faint, not
    // converged, or a box clipped by the window edge).
    let px: Vec<Electrons> = (0..49).map(|i| Electrons::from_num(-100 - i)).collect();
    expect_all(
        r,
        &px,
        &[],
        CentroidFlags::DEGENERATE
            | CentroidFlags::LOW_SNR
            | CentroidFlags::NOT_CONVERGED
            | CentroidFlags::EDGE_CLIPPED,
    );
}

#[test]
fn empty_mismatched_and_oversized_windows() {
    let px = vec![Electrons::from_num(5); 40 * 40];
    for (r, n) in [
        (rect(0, 0), 0),
        (rect(0, 5), 0),
        (rect(5, 5), 24),
        (rect(40, 40), 1600),
        (rect(5, 5), 26),
    ] {
        expect_all(r, &px[..n], &[], CentroidFlags::DEGENERATE);
    }
    // Flags of the wrong length.
    expect_all(
        rect(3, 3),
        &px[..9],
        &[PixelFlags::empty(); 4],
        CentroidFlags::DEGENERATE,
    );
}

#[test]
fn one_by_one_and_clipped_three_by_two() {
    let px = [Electrons::from_num(1000)];
    let r = rect(1, 1);
    for (name, c) in all_methods(&CentroidInput::new(Window {
        rect: r,
        pixels_e: &px,
    })) {
        check(r, &name, &c);
        // The perimeter is the pixel itself: nothing left; a given background: one pixel.
        assert!(
            c.flags.contains(CentroidFlags::DEGENERATE) || (c.x_px, c.y_px) == (300.0, 400.0),
            "{name}: {c:?}"
        );
    }
    // A star at the corner of the active area, its window clipped to 3x2.
    let win = Win {
        x0: 0,
        y0: 0,
        w: 3,
        h: 2,
    };
    let star = Star {
        x: 0.3,
        y: 0.2,
        sigma: sigma_of_a(1.0),
        flux: 1e4,
    };
    let e = to_electrons(&render(win, star, 0.0));
    let w = Window::new(win.rect(), &e).unwrap();
    for (name, c) in all_methods(&CentroidInput::new(w).with_clipped(true)) {
        check(win.rect(), &name, &c);
        assert!(
            c.flags.contains(CentroidFlags::EDGE_CLIPPED),
            "{name}: {c:?}"
        );
    }
}

#[test]
fn excluded_and_saturated_pixels() {
    let win = Win::centred(300, 400, 7);
    let r = win.rect();
    // A flat window whose only bright pixel is an excluded hot pixel (value 0 by calibration).
    let mut px = vec![Electrons::from_num(100); 49];
    let mut flags = vec![PixelFlags::empty(); 49];
    px[24] = Electrons::ZERO;
    flags[24] = PixelFlags::HOT_EXCLUDED;
    expect_all(r, &px, &flags, CentroidFlags::EXCLUDED_PIXEL);
    for (name, c) in all_methods(
        &CentroidInput::new(Window {
            rect: r,
            pixels_e: &px,
        })
        .with_pixel_flags(&flags),
    ) {
        if name.contains("Perimeter") {
            assert!(c.flags.contains(CentroidFlags::DEGENERATE), "{name}: {c:?}");
        }
    }
    // A star with an excluded pixel next to its peak, and a saturated core.
    let star = Star {
        x: 300.1,
        y: 399.8,
        sigma: sigma_of_a(1.5),
        flux: 1e5,
    };
    let mut px = to_electrons(&render(win, star, 50.0));
    let mut flags = vec![PixelFlags::empty(); 49];
    px[25] = Electrons::ZERO;
    flags[25] = PixelFlags::TELEGRAPH;
    flags[24] = PixelFlags::SATURATED;
    let input = CentroidInput::new(Window {
        rect: r,
        pixels_e: &px,
    })
    .with_pixel_flags(&flags);
    for (name, c) in all_methods(&input) {
        check(r, &name, &c);
        assert!(
            c.flags
                .contains(CentroidFlags::EXCLUDED_PIXEL | CentroidFlags::SATURATED),
            "{name}: {c:?}"
        );
    }
    // Every pixel excluded.
    let flags = vec![PixelFlags::TELEGRAPH; 49];
    expect_all(r, &px, &flags, CentroidFlags::DEGENERATE);
}

fn arb_flags() -> impl Strategy<Value = PixelFlags> {
    prop_oneof![
        8 => Just(PixelFlags::empty()),
        1 => (0u8..16).prop_map(PixelFlags::from_bits_truncate),
    ]
}

fn arb_window() -> impl Strategy<Value = (Rect, Vec<Electrons>, Vec<PixelFlags>)> {
    (
        0u16..=9,
        0u16..=9,
        any::<u16>(),
        any::<u16>(),
        any::<bool>(),
    )
        .prop_flat_map(|(w, h, x0, y0, with_flags)| {
            let n = usize::from(w) * usize::from(h);
            let values = prop_oneof![
                2 => any::<i32>(),
                2 => -2000i32..64_000,
                1 => Just(i32::MAX),
                1 => Just(i32::MIN),
            ];
            let nf = if with_flags { n } else { 0 };
            (
                Just(Rect {
                    x0,
                    y0,
                    width: w,
                    height: h,
                }),
                proptest::collection::vec(values.prop_map(Electrons::from_bits), n),
                proptest::collection::vec(arb_flags(), nf),
            )
        })
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig::with_cases(400)))]

    #[test]
    fn any_window_gives_finite_position_inside((r, px, flags) in arb_window(), clipped in any::<bool>()) {
        let input = CentroidInput::new(Window { rect: r, pixels_e: &px }).with_pixel_flags(&flags).with_clipped(clipped);
        for (name, c) in all_methods(&input) {
            check(r, &name, &c);
            prop_assert_eq!(clipped, c.flags.contains(CentroidFlags::EDGE_CLIPPED) && clipped);
        }
    }
}

/// Every method with its usual parameters on `input`.
fn usual_methods(
    input: &CentroidInput<'_>,
    background: Background,
    sigma: f32,
) -> Vec<(&'static str, Centroid)> {
    vec![
        (
            "cog 1",
            cog(
                input,
                &CogParams {
                    power: CogPower::One,
                    box_side: 9,
                    anchor: Anchor::Peak,
                    background,
                },
            ),
        ),
        (
            "cog 2",
            cog(
                input,
                &CogParams {
                    power: CogPower::Two,
                    box_side: 9,
                    anchor: Anchor::Peak,
                    background,
                },
            ),
        ),
        (
            "gauss fit",
            gauss_fit(
                input,
                &GaussFitParams {
                    background,
                    ..GaussFitParams::new(sigma)
                },
            ),
        ),
    ]
}

#[test]
fn every_method_at_the_calibrated_maximum() {
    // A star whose peak pixel is at the top of the calibrated range, on the most negative
    // background: pixel - background reaches 2^26 e-, power-2 sums and normal equations their
    // largest values. Each method must give what it gives for the same star 1000 times fainter
    // (its own systematic error aside).
    let win = Win::centred(300, 400, 9);
    let sigma = sigma_of_a(1.5);
    let (bg, peak) = (-33_554_000.0, 33_554_000.0);
    let frac0 = psf::pixel_frac(300.0, 300.2, sigma) * psf::pixel_frac(400.0, 399.9, sigma);
    let star = Star {
        x: 300.2,
        y: 399.9,
        sigma,
        flux: (peak - bg) / frac0,
    };
    let e = to_electrons(&render(win, star, bg));
    let faint = to_electrons(&render(
        win,
        Star {
            flux: star.flux * 1e-3,
            ..star
        },
        0.0,
    ));
    let given = |level_e: f64| Background::Given {
        level_e: level_e as f32,
        variance_e2: 0.0,
    };
    let bright = usual_methods(
        &CentroidInput::new(Window::new(win.rect(), &e).unwrap()),
        given(bg),
        sigma as f32,
    );
    let faint = usual_methods(
        &CentroidInput::new(Window::new(win.rect(), &faint).unwrap()),
        given(0.0),
        sigma as f32,
    );
    for ((name, c), (_, f)) in bright.into_iter().zip(faint) {
        check(win.rect(), name, &c);
        let bad = CentroidFlags::DEGENERATE | CentroidFlags::NOT_CONVERGED | CentroidFlags::CLAMPED;
        assert!(
            !c.flags.intersects(bad) && !f.flags.intersects(bad),
            "{name}: {c:?} {f:?}"
        );
        assert!(
            (c.x_px - f.x_px).abs() < 1e-3 && (c.y_px - f.y_px).abs() < 1e-3,
            "{name}: {c:?} vs {f:?}"
        );
        let err = (f64::from(c.x_px) - star.x)
            .abs()
            .max((f64::from(c.y_px) - star.y).abs());
        assert!(err < 0.01, "{name}: {c:?} vs {star:?}");
        assert!(c.snr > 1000.0, "{name}: {c:?}");
    }
}
