//! Charge traps: the simulator's parallel and serial trap law, the centroid bias it causes
//! for the flight method (Gauss fit, 7x7, a = 1.2 px) against signal and transfer distance,
//! and the core's correction from fitted coefficients (`startrack_core::calib::cti`).
//!
//! Monte Carlo tolerances: the paired residual of each cell has a standard error measured
//! from its own pairs; the bound on the residual is checked with 3 of those added (RMS over
//! the cells), so a correction just at the target fails rather than passes by luck.

use startrack_test_support::table_fixtures;

use startrack_test_support::field as common_field;

use startrack_host::cli::calib_models::{CTI_SNRS, CalibCtiArgs, cti_trials, measure_cti};
use startrack_lab::cti::{CtiExperiment, DEFAULT_TRAPS, McCell, summarize};
use startrack_sim::sim::effects::ChargeTraps;
use startrack_sim::sim::{Effects, SensorParams, Simulator, Star};

fn sim(traps: Option<ChargeTraps>, star: Star) -> Simulator {
    Simulator::new(
        SensorParams {
            noise: false,
            dark_mean_e: 0.0,
            prnu: 0.0,
            effects: Effects {
                traps,
                ..Effects::default()
            },
            ..SensorParams::default()
        },
        vec![star],
    )
}

#[test]
fn traps_conserve_charge_and_trail_away_from_each_output() {
    let traps = ChargeTraps {
        parallel_per_transfer: 2e-4,
        serial_per_transfer: 2e-4,
        ..DEFAULT_TRAPS
    };
    for (x, left) in [(200.0, true), (800.0, false)] {
        let star = Star {
            x_px: x,
            y_px: 600.0,
            signal_e: 5000.0,
            a_px: 1.2,
        };
        let (plain, trapped) = (sim(None, star), sim(Some(traps), star));
        let g = plain.params.geometry;
        let (mut s0, mut s1, mut mx0, mut mx1, mut my0, mut my1) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for y in 590..615 {
            for xi in (x as usize - 10)..(x as usize + 11) {
                let col = g.raw_col_of_x(xi);
                let a = plain.expected_e(col, y).0;
                let b = trapped.expected_e(col, y).0;
                s0 += a;
                s1 += b;
                mx0 += a * xi as f64;
                mx1 += b * xi as f64;
                my0 += a * y as f64;
                my1 += b * y as f64;
            }
        }
        // Everything deferred is released inside the box (trails of 3 px).
        assert!((s0 - s1).abs() < 1e-9 * s0, "{s0} {s1}");
        let (dx, dy) = (mx1 / s1 - mx0 / s0, my1 / s1 - my0 / s0);
        println!("star at x {x}: photocentre moved ({dx:+.4}, {dy:+.4}) px");
        // Parallel trails into later lines; serial away from the output's amplifier.
        assert!(dy > 0.01, "{dy}");
        assert!(if left { dx > 0.005 } else { dx < -0.005 }, "{dx}");
    }
}

#[test]
fn bias_grows_with_transfers_and_falls_with_signal() {
    let e = CtiExperiment::flight(DEFAULT_TRAPS);
    let b = |f: f64, x: f64, y: f64| e.noiseless_bias(f, x, y).expect("fits");
    // Parallel: proportional to the rows crossed, to a few per cent.
    let (near, mid, far) = (
        b(2000.0, 300.3, 100.2),
        b(2000.0, 300.3, 500.2),
        b(2000.0, 300.3, 1000.2),
    );
    let per_row = |p: &startrack_lab::cti::BiasPoint| p.bias_y_px / p.transfers_par;
    println!(
        "bias_y at rows 100 / 500 / 1000, 2000 e-: {:.4} / {:.4} / {:.4} px",
        near.bias_y_px, mid.bias_y_px, far.bias_y_px
    );
    assert!(
        near.bias_y_px > 0.0 && mid.bias_y_px > near.bias_y_px && far.bias_y_px > mid.bias_y_px
    );
    assert!((per_row(&far) / per_row(&mid) - 1.0).abs() < 0.05);
    // Fainter stars lose a larger share of their charge.
    let (faint, bright) = (b(500.0, 300.3, 1000.2), b(40_000.0, 300.3, 1000.2));
    println!(
        "bias_y at row 1000: {:.4} px at 500 e-, {:.4} px at 40,000 e-",
        faint.bias_y_px, bright.bias_y_px
    );
    assert!(faint.bias_y_px > 1.5 * bright.bias_y_px);
    // Serial: away from each amplifier, more for the columns far from it.
    let (l_near, l_far) = (b(2000.0, 20.3, 300.2), b(2000.0, 480.3, 300.2));
    let (r_far, r_near) = (b(2000.0, 540.3, 300.2), b(2000.0, 1000.3, 300.2));
    assert!(l_far.bias_x_px > l_near.bias_x_px && l_near.bias_x_px > 0.0);
    assert!(r_far.bias_x_px < r_near.bias_x_px && r_near.bias_x_px < 0.0);
}

fn check_removed(cells: &[McCell], what: &str) {
    for snr in CTI_SNRS {
        let v: Vec<McCell> = cells.iter().filter(|c| c.snr == snr).copied().collect();
        let (bias, res, se) = summarize(&v);
        println!(
            "{what}: SNR {snr:>3}: CTI bias RMS {bias:.5} px, residual {res:.5} px ({:.1} %, standard error {se:.5} px)",
            100.0 * res / bias
        );
        assert!(
            res + 3.0 * se <= 0.10 * bias,
            "{what} SNR {snr}: {res} + 3 x {se} vs {bias}"
        );
    }
    let (bias, res, se) = summarize(cells);
    println!(
        "{what}: all cells: CTI bias RMS {bias:.5} px, residual {res:.5} px: {:.1} % removed",
        100.0 * (1.0 - res / bias)
    );
    assert!(res + 3.0 * se <= 0.10 * bias);
}

/// `startrack calib cti`'s measurement: the coefficients fitted on a 4 x 4 grid of positions
/// and 8 fluxes, checked by the paired Monte Carlo on a 5 x 5 grid (off the fitting one) at
/// SNR 10, 20, 50, 100 and 200.
#[test]
fn correction_removes_at_least_90_percent_of_the_bias() {
    let (run, _) = measure_cti(&CalibCtiArgs {
        out_dir: std::path::PathBuf::new(),
        traps: None,
        seed: 7,
    })
    .expect("measures");
    println!("fitted: {:?}", run.coeffs);
    println!("{}", run.summary);
    let cells = run.cells;
    assert_eq!(cells.len(), CTI_SNRS.len() * 25);
    assert!(cells.iter().all(|c| c.used + 2 >= cti_trials(c.snr)));
    check_removed(&cells, "flight Gauss fit 7x7");
    // The bias is worth correcting: at SNR 10 on the far rows it is several times the
    // residual target.
    let far = cells
        .iter()
        .filter(|c| c.snr == 10.0 && c.y_px > 1000.0)
        .map(|c| c.bias_px.1)
        .fold(0.0, f64::max);
    assert!(far > 0.02, "{far}");
}

/// The tracker applies the table's CTI section to every star it reports: the same frame
/// processed with and without the section gives the same stars, each moved by exactly the
/// core's shift for its flux and position (the acquisition frame, `startrack process`'s path).
#[test]
fn the_tracker_applies_the_table_coefficients() {
    use startrack_core::calib::cti::CtiCorrection;
    use startrack_core::table::{CalibTable, SectionKind};
    use startrack_core::tracker::TrackerConfig;
    use startrack_homes::demo::render_frame;
    use startrack_homes::home::{HOST_CAPACITY, process_frame};
    use table_fixtures::{RawSection, RawTable, cti_coeffs, enc_cti};

    let (sim, plain) = common_field::field(5, 30);
    let g = sim.params.geometry;
    let coeffs = cti_coeffs(&g);
    let mut raw_table = RawTable::decompose(&plain);
    raw_table.sections.push(RawSection::new(
        SectionKind::Cti,
        enc_cti(g.outputs, &coeffs),
    ));
    let with = raw_table.build();
    let config = TrackerConfig {
        max_stars: HOST_CAPACITY as u16,
        ..TrackerConfig::FLIGHT
    };
    let frame = render_frame(&sim);
    let run = |bytes: &[u8]| {
        process_frame(
            CalibTable::parse(bytes).expect("parses"),
            &frame,
            config,
            None,
        )
        .expect("processes")
        .stars
    };
    let (a, b) = (run(&plain), run(&with));
    assert_eq!(a.len(), b.len());
    assert!(a.len() >= 20, "{}", a.len());
    let corr = CtiCorrection::new(coeffs, g, config.psf_sigma_px());
    let mut moved = 0usize;
    for (s, t) in a.iter().zip(&b) {
        let (dx, dy) = corr.shift_px(s.flux_e, s.x_px, s.y_px);
        assert_eq!((s.flux_e, s.flags), (t.flux_e, t.flags));
        assert!((t.x_px - (s.x_px - dx)).abs() < 1e-4, "{s:?} {t:?} {dx}");
        assert!((t.y_px - (s.y_px - dy)).abs() < 1e-4, "{s:?} {t:?} {dy}");
        moved += usize::from(dy.abs() > 1e-3);
    }
    // The fixture's coefficients move most stars measurably.
    assert!(moved * 2 > a.len(), "{moved} of {}", a.len());
}
