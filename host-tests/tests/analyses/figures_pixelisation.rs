//! Figures 1-4 against an independent exact f64 computation, and the paper's qualitative
//! claims about them.
//!
//! The reference uses the self-contained erf of `common/psf.rs` (not `libm`, which the
//! figures use) and the closed form of a noise-free CoG of a separable image: for a star at
//! phase `p` in an n x n box centred on pixel 0, the x estimate is
//! `sum_i i P_i(p)^k / sum_i P_i(p)^k` (k = power, `P_i` the pixel fraction of eq. 3), since
//! the y factors cancel. The RMS over a grid of positions over both axes, pooled over x and y,
//! is then the 1-D RMS over the same phases.
//!
//! Tolerance against the core: the core returns positions as f32 around x = 100 px, whose
//! spacing is 7.6e-6 px, and sums in f32 (relative 6e-8 per term over <= 49 terms), so each
//! shift carries up to ~1e-5 px of rounding: 2e-5 px absolute plus 1e-3 relative. The power-2
//! core also subtracts the noise-variance term `F` from `F^2` (module `cog`), a relative
//! 1/F ~ 1e-6 change at the 10^6 e- signal, inside that tolerance.

use startrack_test_support::psf;

use startrack_analysis::figures::{Effort, Written};
use startrack_analysis::figures::{csv, fig1, fig2, fig3, log_space, phases, systematic};

/// Reference shift (estimate - truth) of a noise-free CoG, 1-D.
fn ref_shift(a_px: f64, n: u8, power: u8, p: f64) -> f64 {
    let s = psf::sigma_of_a(a_px);
    let h = i32::from(n / 2);
    let (mut num, mut den) = (0.0, 0.0);
    for i in -h..=h {
        let w = psf::pixel_frac(f64::from(i), p, s).powi(i32::from(power));
        num += f64::from(i) * w;
        den += w;
    }
    num / den - p
}

/// Reference RMS over the midpoint grid of `m` phases.
fn ref_rms(a_px: f64, n: u8, power: u8, m: usize) -> f64 {
    let ph = phases(m);
    (ph.iter()
        .map(|&p| ref_shift(a_px, n, power, p).powi(2))
        .sum::<f64>()
        / m as f64)
        .sqrt()
}

/// The core's value is within the rounding tolerance (module doc) of the reference; `what`
/// names the point in a failure.
fn assert_close(core: f64, reference: f64, what: std::fmt::Arguments<'_>) {
    assert!(
        (core - reference).abs() <= 2e-5 + 1e-3 * reference.abs(),
        "{what}: core {core} reference {reference}"
    );
}

#[test]
fn fig1_and_fig4_match_the_exact_reference() {
    let (n_a, m) = (16, 10);
    for power in [1u8, 2] {
        let rows = fig1::rows(power, n_a, m);
        assert_eq!(rows.len(), n_a * fig1::WINDOWS.len());
        for r in &rows {
            assert_close(
                r.rms_px,
                ref_rms(r.a_px, r.window, power, m),
                format_args!("power {power} window {} a {}", r.window, r.a_px),
            );
        }
    }
}

#[test]
fn the_grid_rms_approaches_the_continuous_average() {
    // The figures average over a grid of positions; the definition is the average over the
    // continuous central pixel. The midpoint rule's error on m cells is estimated by
    // Richardson from m and 2m (|M_m - I| ~ 4/3 |M_m - M_2m|); the core's grid value must
    // lie within twice that (plus the rounding tolerance) of the integral by Simpson's rule
    // on 4000 cells.
    let m = 20;
    for a in [0.3, 0.5, 2.0, 4.0] {
        let s2 = |p: f64| ref_shift(a, 5, 1, p).powi(2);
        let k = 4000;
        let h = 1.0 / k as f64;
        let integral: f64 = (0..=k)
            .map(|i| {
                let w = if i == 0 || i == k {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                w * s2(-0.5 + i as f64 * h)
            })
            .sum::<f64>()
            * h
            / 3.0;
        let mm = ref_rms(a, 5, 1, m).powi(2);
        let m2 = ref_rms(a, 5, 1, 2 * m).powi(2);
        let bound = 2.0 * 4.0 / 3.0 * (mm - m2).abs();
        let core = systematic::rms_shift(a, 5, 1, m).powi(2);
        assert!(
            (core - integral).abs() <= bound + 4e-5 * core.sqrt() + 1e-9,
            "a {a}: core grid {core} integral {integral} bound {bound}"
        );
    }
}

#[test]
fn fig1_five_by_five_has_its_minimum_near_one_pixel() {
    let rows = fig1::rows(1, 30, 10);
    for w in fig1::WINDOWS {
        let curve: Vec<_> = rows.iter().filter(|r| r.window == w).collect();
        let min = curve
            .iter()
            .min_by(|a, b| a.rms_px.total_cmp(&b.rms_px))
            .copied()
            .copied()
            .unwrap();
        // A U-shaped curve: pixelisation on the left, truncation on the right.
        let first = curve.first().unwrap().rms_px;
        let last = curve.last().unwrap().rms_px;
        assert!(
            first > 10.0 * min.rms_px && last > 10.0 * min.rms_px,
            "{w}: {curve:?}"
        );
        if w == 5 {
            assert!(
                (0.7..=1.6).contains(&min.a_px),
                "5x5 minimum at a = {} px",
                min.a_px
            );
        }
    }
    // A bigger box truncates later: its minimum lies at a larger image.
    let argmin = |w: u8| {
        rows.iter()
            .filter(|r| r.window == w)
            .min_by(|a, b| a.rms_px.total_cmp(&b.rms_px))
            .unwrap()
            .a_px
    };
    assert!(argmin(3) < argmin(5) && argmin(5) < argmin(7));
}

#[test]
fn fig4_power_two_pixelises_more_and_truncates_less() {
    let a = log_space(0.25, 8.0, 20);
    let p1 = fig1::rows(1, 20, 10);
    let p2 = fig1::rows(2, 20, 10);
    let at = |rows: &[fig1::RmsRow], w: u8, a_px: f64| {
        rows.iter()
            .find(|r| r.window == w && (r.a_px - a_px).abs() < 1e-12)
            .unwrap()
            .rms_px
    };
    // Small images (a ~ 0.5 px): more pixelisation error with squared weights.
    let small = a.iter().copied().find(|v| *v > 0.45).unwrap();
    assert!(at(&p2, 5, small) > at(&p1, 5, small));
    // Large images (a ~ 2.5 px): less truncation error with squared weights.
    let large = a.iter().copied().find(|v| *v > 2.4).unwrap();
    assert!(at(&p2, 5, large) < at(&p1, 5, large));
}

#[test]
fn fig2_and_fig3_match_the_exact_reference_and_the_paper_shapes() {
    let n = 41;
    for a_values in [&fig2::LARGE_A_PX[..], &fig3::SMALL_A_PX[..]] {
        let rows = fig2::rows(a_values, n);
        assert_eq!(rows.len(), n * a_values.len());
        for r in &rows {
            assert_close(
                r.shift_px,
                ref_shift(r.a_px, fig2::WINDOW, 1, r.true_x_px),
                format_args!("a {} x {}", r.a_px, r.true_x_px),
            );
        }
    }
    // Large images: the box pulls the estimate towards its centre (shift against x).
    for r in fig2::rows(&[3.0], n) {
        if r.true_x_px.abs() > 0.05 {
            assert!(r.shift_px * r.true_x_px < 0.0, "{r:?}");
        }
    }
    // The smallest image sticks to the pixel centre: shift ~ -x near the middle.
    for r in fig2::rows(&[0.25], n) {
        if r.true_x_px.abs() > 0.1 && r.true_x_px.abs() < 0.3 {
            assert!(
                (r.shift_px + r.true_x_px).abs() < 0.5 * r.true_x_px.abs(),
                "{r:?}"
            );
        }
    }
}

#[test]
fn csv_files_have_the_required_columns_and_a_parameter_header() {
    let dir = std::env::temp_dir().join(format!("startrack-figs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut w = Written::default();
    fig1::write(&dir, Effort::Quick, &mut w).unwrap();
    fig2::write(&dir, Effort::Quick, &mut w).unwrap();
    fig3::write(&dir, Effort::Quick, &mut w).unwrap();
    startrack_analysis::figures::fig4::write(&dir, Effort::Quick, &mut w).unwrap();
    for (name, cols) in [
        ("fig1.csv", "a_px,window,rms_px"),
        ("fig2.csv", "a_px,true_x_px,shift_px"),
        ("fig3.csv", "a_px,true_x_px,shift_px"),
        ("fig4.csv", "a_px,window,rms_px"),
    ] {
        let text = std::fs::read_to_string(dir.join(name)).unwrap();
        let (header, columns, rows) = csv::read_csv(&text);
        assert!(!header.is_empty(), "{name}");
        assert_eq!(columns.join(","), cols, "{name}");
        assert!(rows.len() >= 20, "{name}");
        for r in rows {
            assert_eq!(r.len(), 3);
            assert!(r.iter().all(|v| v.parse::<f64>().is_ok_and(f64::is_finite)));
        }
    }
    // fig1: at least 20 a values per window, 0.25..8 px.
    let (_, _, rows) = csv::read_csv(&std::fs::read_to_string(dir.join("fig1.csv")).unwrap());
    let a: Vec<f64> = rows
        .iter()
        .filter(|r| r[1] == "5")
        .map(|r| r[0].parse().unwrap())
        .collect();
    assert!(a.len() >= 20 && (a[0] - 0.25).abs() < 1e-9 && (a[a.len() - 1] - 8.0).abs() < 1e-9);
    // A PNG per figure where a font is installed (.ci/run installs one).
    if startrack_analysis::figures::plot::ensure_font().is_ok() {
        for f in ["fig1.png", "fig2.png", "fig3.png", "fig4.png"] {
            let bytes = std::fs::read(dir.join(f)).unwrap();
            assert!(bytes.starts_with(b"\x89PNG") && bytes.len() > 10_000, "{f}");
        }
    } else {
        assert_eq!(w.skipped_png.len(), 4);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
