//! CTI by EPER (`calib_frames::eper`) against the simulator's trap law: flats of a small
//! single-output readout with 9 extra store lines (the CCD47-20's count), at five signal
//! levels, two frames each. Tolerances: the edge elements are medians over 128 columns (rows)
//! of ~5 e- read noise plus the shot noise of the trail, a standard error of ~0.6 e- on a
//! first edge element of 15-300 e-; over 10 flats the fitted per-transfer fraction is good to
//! a few per cent and the exponent to a few hundredths. The bounds below are 2-3 times that.

use startrack_core::geometry::ReadoutGeometry;
use startrack_lab::calib_frames::eper::{edge_response, fit};
use startrack_lab::calib_frames::labset::LabSet;
use startrack_lab::cti::CTI_FIT_FLUXES_E;
use startrack_lab::cti::CtiExperiment;
use startrack_sim::fits::RawFrame;
use startrack_sim::sim::effects::ChargeTraps;

/// The trap law of the test sensor: strong enough to be seen over 128 transfers.
const TRUTH: ChargeTraps = ChargeTraps {
    parallel_per_transfer: 2.0e-4,
    serial_per_transfer: 1.2e-4,
    reference_e: 1000.0,
    alpha: 0.5,
    trail_px: 3,
    decay: 0.5,
};

fn labset() -> LabSet {
    LabSet {
        geometry: ReadoutGeometry {
            overscan_px: 8,
            covered_px: 16,
            active_cols: 128,
            active_rows: 128,
            lines: 137,
            outputs: 1,
        },
        flat_exposures_s: vec![0.2, 0.5, 1.0, 2.0, 4.0],
        traps: Some(TRUTH),
        ..LabSet::small(11)
    }
}

#[test]
fn eper_recovers_the_trap_law() {
    let set = labset();
    let g = set.geometry;
    let t0 = std::time::Instant::now();
    let mut responses = Vec::new();
    let truth_sensor = set.sensor();
    let cb: Vec<f64> = (0..g.line_len())
        .map(|c| truth_sensor.column_bias_adu(c))
        .collect();
    for (i, &t) in set.flat_exposures_s.iter().enumerate() {
        for k in 0..2u32 {
            let s = set.frame_sensor(10 + 2 * i as u32 + k, t, set.flat_temperature_k, true);
            let (lines, len) = (usize::from(g.lines), g.line_len());
            let mut data_adu = vec![0u16; lines * len];
            for (l, line) in data_adu.chunks_exact_mut(len).enumerate() {
                s.render_line(l, line);
            }
            let f = RawFrame {
                lines,
                cols: len,
                data_adu,
            };
            responses.extend(edge_response(&f, &g, &cb).expect("9 extra lines"));
        }
    }
    let gains = [set.sensor().params.gain_e_per_adu[0]];
    let read = [set.sensor().params.read_noise_e];
    let e = fit(&responses, &gains, &read, &g).expect("fits");
    // The same flats without traps: no edge response above the noise, no law.
    let clean = LabSet {
        traps: None,
        ..labset()
    };
    let mut none = Vec::new();
    for (i, &t) in clean.flat_exposures_s.iter().enumerate() {
        let s = clean.frame_sensor(10 + 2 * i as u32, t, clean.flat_temperature_k, true);
        let (lines, len) = (usize::from(g.lines), g.line_len());
        let mut data_adu = vec![0u16; lines * len];
        for (l, line) in data_adu.chunks_exact_mut(len).enumerate() {
            s.render_line(l, line);
        }
        let f = RawFrame {
            lines,
            cols: len,
            data_adu,
        };
        none.extend(edge_response(&f, &g, &cb).expect("9 extra lines"));
    }
    assert_eq!(fit(&none, &gains, &read, &g), None);
    println!("rendered and measured 10 flats in {:?}", t0.elapsed());
    for p in &e.points {
        println!(
            "signal {:>7.0} e-: parallel {:.3e}, serial {:.3e} per transfer",
            p.0, p.1, p.2
        );
    }
    let m = e.traps;
    println!(
        "EPER: parallel {:.3e} (truth {:.1e}), serial {:.3e} (truth {:.1e}), alpha {:.3} (truth {}), trail {} decay {:.3} (truth {} {}), mean delay {:.3}",
        m.parallel_per_transfer,
        TRUTH.parallel_per_transfer,
        m.serial_per_transfer,
        TRUTH.serial_per_transfer,
        m.alpha,
        TRUTH.alpha,
        m.trail_px,
        m.decay,
        TRUTH.trail_px,
        TRUTH.decay,
        e.mean_delay
    );
    assert!(e.serial_measured);
    assert!((m.parallel_per_transfer / TRUTH.parallel_per_transfer - 1.0).abs() < 0.10);
    assert!((m.serial_per_transfer / TRUTH.serial_per_transfer - 1.0).abs() < 0.15);
    assert!((m.alpha - TRUTH.alpha).abs() < 0.08);
    assert_eq!(m.trail_px, TRUTH.trail_px);
    assert!((m.decay - TRUTH.decay).abs() < 0.15);
    assert!((e.mean_delay - TRUTH.mean_delay()).abs() < 0.15);

    // The table's centroid coefficients from the measured law against those from the truth,
    // for the flight method on the CCD47-20.
    let coeffs = |traps: ChargeTraps| {
        let x = CtiExperiment::flight(traps);
        x.fit(&x.bias_grid(&CTI_FIT_FLUXES_E, &x.positions(4)))
            .expect("fit")
    };
    let (got, want) = (coeffs(m), coeffs(TRUTH));
    let shift = |c: &startrack_core::table::CtiCoeffs, f: f32| {
        CtiExperiment::flight(TRUTH)
            .correction(c)
            .shift_px(f, 300.0, 1000.0)
    };
    for f in [600.0f32, 5000.0, 40_000.0] {
        let (a, b) = (shift(&got, f), shift(&want, f));
        println!(
            "shift at (300, 1000), {f} e-: from EPER ({:.4}, {:.4}) px, from the truth ({:.4}, {:.4}) px",
            a.0, a.1, b.0, b.1
        );
        assert!((a.1 / b.1 - 1.0).abs() < 0.12, "{a:?} {b:?}");
        assert!((a.0 / b.0 - 1.0).abs() < 0.20, "{a:?} {b:?}");
    }
}

#[test]
fn a_two_output_set_measures_the_parallel_law_only() {
    let set = LabSet {
        geometry: ReadoutGeometry {
            outputs: 2,
            ..labset().geometry
        },
        ..labset()
    };
    let g = set.geometry;
    let s = set.frame_sensor(5, 2.0, set.flat_temperature_k, true);
    let (lines, len) = (usize::from(g.lines), g.line_len());
    let mut data_adu = vec![0u16; lines * len];
    for (l, line) in data_adu.chunks_exact_mut(len).enumerate() {
        s.render_line(l, line);
    }
    let f = RawFrame {
        lines,
        cols: len,
        data_adu,
    };
    let cb: Vec<f64> = (0..len).map(|c| s.column_bias_adu(c)).collect();
    let r = edge_response(&f, &g, &cb).expect("measures");
    assert_eq!(r.len(), 2);
    assert!(
        r.iter()
            .all(|e| e.serial_adu.is_none() && e.parallel_adu[0] > 0.0)
    );
    // Without extra lines there is no edge to measure.
    let short = ReadoutGeometry { lines: 130, ..g };
    let f2 = RawFrame {
        lines: 130,
        cols: len,
        data_adu: f.data_adu[..130 * len].to_vec(),
    };
    assert_eq!(edge_response(&f2, &short, &cb), None);
}
