//! The telegraph search of `calib frames` (`calib_frames::rts`) on synthetic series: its
//! false-alarm rate on stacks of pure Gaussian noise (the design: at most 2e-5 per pixel,
//! 20 per million; the target 100 per million), its thresholds against the distributions
//! they come from, and what it finds of two-level pixels with steps of 5 sigmas and dwells
//! of a few frames.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use startrack_core::geometry::{ReadoutGeometry, Segment};
use startrack_lab::calib_frames::rts::{
    FALSE_ALARM_PER_TEST, SeriesAccum, chi_square_upper_quantile, normal_tail,
    scan_threshold_sigma, variance_threshold_ratio,
};
use startrack_sim::fits::RawFrame;

/// A readout of 400 lines of the test-128 layout: 128 active and 32 covered pixels a line.
fn geometry() -> ReadoutGeometry {
    ReadoutGeometry {
        overscan_px: 8,
        covered_px: 16,
        active_cols: 128,
        active_rows: 400,
        lines: 400,
        outputs: 2,
    }
}

/// Read noise of the synthetic frames, ADU (gain 1 e-/ADU, no dark).
const SIGMA_ADU: f64 = 4.0;
const BIAS_ADU: f64 = 1000.0;

/// `frames` frames of Gaussian noise, plus `steps` (pixel index, step ADU, state per frame).
fn series(seed: u64, frames: usize, steps: &[(usize, f64, Vec<bool>)]) -> SeriesAccum {
    let g = geometry();
    let n = usize::from(g.lines) * g.line_len();
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, SIGMA_ADU).unwrap();
    let mut acc = SeriesAccum::new(&g);
    for k in 0..frames {
        let mut data: Vec<f64> = (0..n).map(|_| BIAS_ADU + normal.sample(&mut r)).collect();
        for (i, step, states) in steps {
            if states[k] {
                data[*i] += step;
            }
        }
        let f = RawFrame {
            lines: usize::from(g.lines),
            cols: g.line_len(),
            data_adu: data
                .iter()
                .map(|v| v.round().clamp(0.0, 65535.0) as u16)
                .collect(),
        };
        acc.add(&f, &vec![0.0; g.line_len()]);
    }
    acc
}

fn searched_pixels(g: &ReadoutGeometry) -> usize {
    (0..usize::from(g.lines) * g.line_len())
        .filter(|i| {
            matches!(
                g.segment(i % g.line_len()),
                Some(Segment::Active | Segment::Covered)
            )
        })
        .count()
}

/// Variance of the rounded noise, ADU^2, as the bias pairs measure it.
fn bias_var() -> f64 {
    SIGMA_ADU * SIGMA_ADU + 1.0 / 12.0
}

#[test]
fn pure_gaussian_stacks_give_at_most_100_false_per_million() {
    let g = geometry();
    let pixels = searched_pixels(&g);
    // 64 000 searched pixels x (30 + 100 frames): at the design's 2e-5 per pixel, 1.3 false
    // are expected per stack; 100 per million would be 6.4 per stack.
    let mut total = 0usize;
    for (seed, frames) in [(1u64, 30usize), (2, 100)] {
        let acc = series(seed, frames, &[]);
        let found = acc.telegraph(&[1.0, 1.0], &[bias_var(), bias_var()]);
        println!(
            "{frames} frames of pure noise: {} of {pixels} pixels flagged ({:.1} per million)",
            found.len(),
            1e6 * found.len() as f64 / pixels as f64
        );
        total += found.len();
    }
    let per_million = 1e6 * total as f64 / (2 * pixels) as f64;
    assert!(per_million <= 100.0, "{per_million} per million");
}

#[test]
fn thresholds_follow_their_distributions() {
    // Wilson-Hilferty against the chi-square tail summed exactly for even degrees:
    // P(chi2_2m > x) = exp(-x/2) sum_{k<m} (x/2)^k / k!.
    for nu in [10u32, 30, 100] {
        let x = chi_square_upper_quantile(f64::from(nu), 1e-5);
        let h = x / 2.0;
        let (mut term, mut sum) = (1.0f64, 0.0f64);
        for k in 0..nu / 2 {
            if k > 0 {
                term *= h / f64::from(k);
            }
            sum += term;
        }
        let tail = (-h).exp() * sum;
        println!("chi-square {nu} degrees: quantile {x:.3} at 1e-5, exact tail there {tail:.3e}");
        assert!((tail / 1e-5 - 1.0).abs() < 0.3, "{nu}: {tail}");
    }
    // The scan's union bound: 2 (n - 1) Q(a)^2 = p.
    let a = scan_threshold_sigma(100, FALSE_ALARM_PER_TEST);
    let q = normal_tail(a);
    assert!((2.0 * 99.0 * q * q / FALSE_ALARM_PER_TEST - 1.0).abs() < 1e-6);
    assert!(variance_threshold_ratio(100, FALSE_ALARM_PER_TEST) > 1.5);
}

/// A two-state chain of `frames` frames with mean dwells `high` and `low`.
fn chain(r: &mut ChaCha8Rng, frames: usize, high: f64, low: f64) -> Vec<bool> {
    let mut s = r.random::<f64>() < high / (high + low);
    (0..frames)
        .map(|_| {
            let now = s;
            if r.random::<f64>() < if s { 1.0 / high } else { 1.0 / low } {
                s = !s;
            }
            now
        })
        .collect()
}

#[test]
fn steps_of_5_sigma_with_dwells_of_a_few_frames_are_found() {
    let g = geometry();
    let len = g.line_len();
    let mut r = ChaCha8Rng::seed_from_u64(9);
    let frames = 100;
    // 600 pixels spread over the readout, each with its mean dwells.
    let dwells = [
        (2.0, 2.0),
        (2.0, 10.0),
        (2.0, 40.0),
        (5.0, 5.0),
        (20.0, 20.0),
        (40.0, 2.0),
    ];
    let mut steps = Vec::new();
    for k in 0..600usize {
        let line = (k * 7) % usize::from(g.lines);
        let col = g.first_active_col() + (k * 13) % usize::from(g.active_cols);
        let (h, l) = dwells[k % dwells.len()];
        steps.push((
            line * len + col,
            5.0 * SIGMA_ADU,
            chain(&mut r, frames, h, l),
        ));
    }
    steps.sort_by_key(|s| s.0);
    steps.dedup_by_key(|s| s.0);
    let acc = series(3, frames, &steps);
    let found = acc.telegraph(&[1.0, 1.0], &[bias_var(), bias_var()]);
    // The series shows a pixel when it holds each state for two frames in a row.
    let shows = |st: &[bool]| {
        let run = |v: bool| st.windows(2).any(|w| w[0] == v && w[1] == v);
        run(true) && run(false)
    };
    let shown: Vec<&(usize, f64, Vec<bool>)> = steps.iter().filter(|s| shows(&s.2)).collect();
    let hit = shown
        .iter()
        .filter(|s| found.contains(&(s.0 % len, s.0 / len)))
        .count();
    let false_found = found
        .iter()
        .filter(|(c, l)| !steps.iter().any(|s| s.0 == l * len + c))
        .count();
    println!(
        "5-sigma steps: {hit} of {} shown found ({} planted); {false_found} false",
        shown.len(),
        steps.len()
    );
    assert!(shown.len() >= 400);
    assert!(hit as f64 >= 0.9 * shown.len() as f64);
    assert!(false_found <= 3);
}

#[test]
fn a_cosmic_ray_hit_in_one_frame_is_not_a_telegraph_pixel() {
    let g = geometry();
    let len = g.line_len();
    let i = 10 * len + g.first_active_col() + 5;
    let mut states = vec![false; 30];
    states[12] = true;
    let acc = series(4, 30, &[(i, 400.0, states)]);
    let found = acc.telegraph(&[1.0, 1.0], &[bias_var(), bias_var()]);
    assert!(!found.contains(&(i % len, i / len)));
}
