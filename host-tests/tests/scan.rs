//! The raw pre-filtered scan (`detect::prefilter::ScanDetector`) against the calibrated path
//! (`LineDetector` fed every calibrated line, same background stride): the candidates must be
//! identical, bit for bit, on simulated CCD47-20 frames, including maps with a large spread
//! of dark, flat and column bias; and the scan must calibrate only a small part of a quiet
//! frame (otherwise it is no faster).

use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::detect::{DetectConfig, LineDetector, ScanDetector};
use startrack_core::table::CalibTable;
use startrack_core::units::{Electrons, Kelvin};
use startrack_host::sim::truth::TruthSections;
use startrack_host::sim::{SensorParams, Simulator};

struct Frame {
    table: Vec<u8>,
    lines: Vec<(Vec<u16>, LineLevels)>,
    dark_scale_e: Electrons,
    params: SensorParams,
}

fn frame(params: SensorParams, n_stars: usize, tile_log2: u8) -> Frame {
    let stars = startrack_host::demo::star_field(params.seed, n_stars, &params);
    let sim = Simulator::new(params.clone(), stars);
    let g = params.geometry;
    let table = sim
        .truth_table_tiled(TruthSections::ALL, tile_log2)
        .unwrap();
    let parsed = CalibTable::parse(&table).unwrap();
    let mut lines = Vec::new();
    let mut est = DarkScaleEstimator::new();
    let mut line = vec![0u16; g.line_len()];
    for y in 0..usize::from(g.lines) {
        sim.render_line(y, &mut line);
        let lv = LineLevels::measure(&g, &line).unwrap();
        est.add_line(&parsed, &line, &lv).unwrap();
        lines.push((line.clone(), lv));
    }
    Frame {
        table,
        lines,
        dark_scale_e: est.estimate().unwrap(),
        params,
    }
}

/// Runs both paths; returns (reference candidates, scan candidates, calibrated fraction).
fn both(f: &Frame, stride: u16) -> (LineDetector<256>, ScanDetector<'_, 256>, f64) {
    let g = f.params.geometry;
    let table = CalibTable::parse(&f.table).unwrap();
    let cal = FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: f.dark_scale_e,
            exposure_ms: 1000,
            temperature_k: Kelvin::from_num(293),
        },
    );
    let mut reference =
        LineDetector::<256>::new(DetectConfig::default(), g.active_cols, g.active_rows)
            .with_background_stride(stride);
    let mut scan = ScanDetector::<256>::new(cal, DetectConfig::default(), stride);
    let mut e = vec![Electrons::ZERO; usize::from(g.active_cols)];
    let mut fl = vec![PixelFlags::empty(); e.len()];
    for (y, (raw, lv)) in f.lines.iter().enumerate().take(usize::from(g.active_rows)) {
        cal.calibrate_span(y as u16, 0, raw, lv, &mut e, &mut fl)
            .unwrap();
        reference.push_line(y as u16, &e, &fl).unwrap();
        scan.push_raw_line(y as u16, raw, lv).unwrap();
    }
    reference.finish();
    scan.finish();
    let total = f64::from(g.active_cols) * f64::from(g.active_rows);
    let frac = f64::from(scan.calibrated_px()) / total;
    (reference, scan, frac)
}

fn sorted(c: &[startrack_core::detect::Detection]) -> Vec<startrack_core::detect::Detection> {
    let mut v = c.to_vec();
    v.sort_by_key(|a| (a.peak_y, a.peak_x));
    v
}

#[test]
fn scan_equals_calibrated_path_on_simulated_frames() {
    for (seed, stride) in [(3u64, 1u16), (5, 8), (7, 64)] {
        let f = frame(
            SensorParams {
                seed,
                ..SensorParams::default()
            },
            60,
            3,
        );
        let (reference, scan, frac) = both(&f, stride);
        assert!(
            reference.candidates().len() >= 40,
            "seed {seed}: only {} candidates",
            reference.candidates().len()
        );
        assert_eq!(
            sorted(reference.candidates()),
            sorted(scan.candidates()),
            "seed {seed} stride {stride}"
        );
        assert_eq!(reference.dropped(), scan.detector().dropped());
        assert_eq!(reference.dropped_pixels(), scan.detector().dropped_pixels());
        println!(
            "seed {seed} stride {stride}: {} candidates, {:.2} % of the pixels calibrated",
            scan.candidates().len(),
            100.0 * frac
        );
        // The background rows alone are 1/stride of the frame (1.6 % at 64); the pre-filter
        // passes the star pixels and the ~1 % of noise samples above 2.5 sigma, with the
        // spans between them.
        if stride == 64 {
            assert!(frac < 0.10, "calibrated {frac}");
        }
    }
}

#[test]
fn scan_equals_calibrated_path_with_large_map_spread() {
    // Per-pixel maps with strong dark non-uniformity, flat variation and column bias: the
    // chunk bounds are loose, most chunks go to the exact path, and the result must not
    // change.
    let f = frame(
        SensorParams {
            seed: 9,
            dsnu: 0.5,
            prnu: 0.05,
            column_bias_sigma_adu: 40.0,
            dark_mean_e: 400.0,
            ..SensorParams::default()
        },
        40,
        0,
    );
    let (reference, scan, frac) = both(&f, 16);
    assert_eq!(sorted(reference.candidates()), sorted(scan.candidates()));
    println!(
        "large spread: {:.2} % of the pixels calibrated",
        100.0 * frac
    );
}
