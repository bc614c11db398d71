//! Host benchmarks of the core's stages, the same stages `cargo m7-bench` counts on
//! the Cortex-M7, on a simulated CCD47-20 frame (1072 x 1033 raw, 8x8-tiled table, 60
//! stars):
//!
//! - `frame/scan_detect`: the whole frame streamed line by line as the firmware does it:
//!   levels, the dark-scale accumulation, and the pre-filtered calibrate-and-detect scan
//!   (`ScanDetector`, background every 64 rows). Its throughput line (`thrpt`, in Melem/s
//!   of raw samples) is the full-frame Mpx/s figure of the README.
//! - `frame/calibrated_detect`: the same with every active pixel calibrated and fed to
//!   `LineDetector` (the reference path), for comparison.
//! - `line_calibrate` (1024 px), `window_calibrate` (7x7), `centroid_cog1_7x7`,
//!   `centroid_gauss_fit_7x7`, `centroid_gauss_fit_given_bg_5x5` (the near-CRLB fit as
//!   `startrack accuracy` runs it), `centroid_cog1c_raw_7x7` (the fused raw-window corrected
//!   CoG, one-shot), `tracking_frame` (the firmware's tracking: 30 windows, each a
//!   `RawCogPlan` built beforehand and applied to the frame's raw samples).
//!
//! Run: `cargo bench -p startrack-host --bench stages` (one group: append its name).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::centroid::cog::{CogParams, cog};
use startrack_core::centroid::gauss_fit::{GaussFitParams, gauss_fit};
use startrack_core::centroid::raw_cog::{RawCogParams, RawCogPlan, RawWindow, raw_cog};
use startrack_core::centroid::{Background, CentroidInput};
use startrack_core::detect::{DetectConfig, LineDetector, ScanDetector};
use startrack_core::table::CalibTable;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::{PixCorr, PixCorrBackground};
use startrack_core::units::{Electrons, Kelvin};
use startrack_core::window::{Rect, Window};
use startrack_sim::pixcorr::{CurveSpec, build_curve};
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator, Star};
use std::hint::black_box;

struct Frame {
    table: Vec<u8>,
    lines: Vec<Vec<u16>>,
    stars: Vec<Star>,
    params: SensorParams,
    dark_scale_e: Electrons,
}

fn frame() -> Frame {
    let params = SensorParams {
        seed: 21,
        ..SensorParams::default()
    };
    let stars = startrack_homes::demo::star_field(21, 60, &params);
    let sim = Simulator::new(params.clone(), stars.clone());
    let g = params.geometry;
    let table = sim.truth_table_tiled(TruthSections::ALL, 3).unwrap();
    let parsed = CalibTable::parse(&table).unwrap();
    let mut est = DarkScaleEstimator::new();
    let mut lines = Vec::new();
    for y in 0..usize::from(g.lines) {
        let mut line = vec![0u16; g.line_len()];
        sim.render_line(y, &mut line);
        let lv = LineLevels::measure(&g, &line).unwrap();
        est.add_line(&parsed, &line, &lv).unwrap();
        lines.push(line);
    }
    Frame {
        table,
        lines,
        stars,
        params,
        dark_scale_e: est.estimate().unwrap(),
    }
}

fn calibration<'t>(f: &Frame, table: CalibTable<'t>) -> FrameCalibration<'t> {
    FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: f.dark_scale_e,
            exposure_ms: 1000,
            temperature_k: Kelvin::from_num(293),
        },
    )
}

fn stages(c: &mut Criterion) {
    let f = frame();
    let g = f.params.geometry;
    let table = CalibTable::parse(&f.table).unwrap();
    let cal = calibration(&f, table);
    let levels: Vec<LineLevels> = f
        .lines
        .iter()
        .map(|l| LineLevels::measure(&g, l).unwrap())
        .collect();
    let active_rows = usize::from(g.active_rows);
    let width = usize::from(g.active_cols);

    let mut group = c.benchmark_group("frame");
    group.sample_size(10);
    group.throughput(Throughput::Elements(
        (g.line_len() * usize::from(g.lines)) as u64,
    ));
    group.bench_function("scan_detect", |b| {
        b.iter(|| {
            let mut est = DarkScaleEstimator::new();
            let mut scan = Box::new(ScanDetector::<256>::new(cal, DetectConfig::default(), 64));
            for (y, line) in f.lines.iter().enumerate() {
                let lv = LineLevels::measure(&g, line).unwrap();
                est.add_line(&table, line, &lv).unwrap();
                if y < active_rows {
                    scan.push_raw_line(y as u16, line, &lv).unwrap();
                }
            }
            scan.finish();
            black_box((scan.candidates().len(), est.estimate()))
        })
    });
    group.bench_function("calibrated_detect", |b| {
        let mut e = vec![Electrons::ZERO; width];
        let mut fl = vec![PixelFlags::empty(); width];
        b.iter(|| {
            let mut est = DarkScaleEstimator::new();
            let mut det = Box::new(
                LineDetector::<256>::new(DetectConfig::default(), g.active_cols, g.active_rows)
                    .with_background_stride(64),
            );
            for (y, line) in f.lines.iter().enumerate() {
                let lv = LineLevels::measure(&g, line).unwrap();
                est.add_line(&table, line, &lv).unwrap();
                if y < active_rows {
                    cal.calibrate_span(y as u16, 0, line, &lv, &mut e, &mut fl)
                        .unwrap();
                    det.push_line(y as u16, &e, &fl).unwrap();
                }
            }
            det.finish();
            black_box((det.candidates().len(), est.estimate()))
        })
    });
    group.finish();

    let mut e = vec![Electrons::ZERO; width];
    let mut fl = vec![PixelFlags::empty(); width];
    let mut group = c.benchmark_group("line");
    group.throughput(Throughput::Elements(width as u64));
    group.bench_function("line_calibrate", |b| {
        b.iter(|| {
            cal.calibrate_span(
                100,
                0,
                black_box(&f.lines[100]),
                &levels[100],
                &mut e,
                &mut fl,
            )
            .unwrap()
        })
    });
    group.finish();

    // 7x7 windows around the simulated stars away from the edges.
    let windows: Vec<(Rect, Vec<u16>, Vec<LineLevels>)> = f
        .stars
        .iter()
        .filter(|s| s.x_px > 10.0 && s.y_px > 10.0 && s.x_px < 1010.0 && s.y_px < 1010.0)
        .take(30)
        .map(|s| {
            let (x0, y0) = (s.x_px.round() as u16 - 3, s.y_px.round() as u16 - 3);
            let rect = Rect {
                x0,
                y0,
                width: 7,
                height: 7,
            };
            let raw = (y0..y0 + 7)
                .flat_map(|y| {
                    let l = &f.lines[usize::from(y)];
                    (x0..x0 + 7).map(move |x| l[g.raw_col_of_x(usize::from(x))])
                })
                .collect();
            let lv = levels[usize::from(y0)..usize::from(y0) + 7].to_vec();
            (rect, raw, lv)
        })
        .collect();
    assert_eq!(windows.len(), 30, "not enough stars inside the frame");
    let calibrate = |w: &(Rect, Vec<u16>, Vec<LineLevels>)| {
        let mut we = [Electrons::ZERO; 49];
        let mut wf = [PixelFlags::empty(); 49];
        cal.calibrate_window(w.0, &w.1, &w.2, &mut we, &mut wf)
            .unwrap();
        (we, wf)
    };
    c.bench_function("window_calibrate_7x7", |b| {
        b.iter(|| calibrate(black_box(&windows[0])))
    });
    let (we, wf) = calibrate(&windows[0]);
    let input = CentroidInput::new(Window::new(windows[0].0, &we).unwrap()).with_pixel_flags(&wf);
    c.bench_function("centroid_cog1_7x7", |b| {
        b.iter(|| cog(black_box(&input), &CogParams::new(CogPower::One, 7)))
    });
    c.bench_function("centroid_gauss_fit_7x7", |b| {
        b.iter(|| gauss_fit(black_box(&input), &GaussFitParams::new(1.0)))
    });
    c.bench_function("centroid_gauss_fit_given_bg_5x5", |b| {
        let (we5, _) = calibrate(&windows[0]);
        // The central 5x5 of the window, as the M7 bench cuts it.
        let c5: Vec<Electrons> = (1..6)
            .flat_map(|r| we5[7 * r + 1..7 * r + 6].to_vec())
            .collect();
        let r5 = Rect {
            x0: windows[0].0.x0 + 1,
            y0: windows[0].0.y0 + 1,
            width: 5,
            height: 5,
        };
        let input5 = CentroidInput::new(Window::new(r5, &c5).unwrap());
        let params = GaussFitParams {
            fit_background: false,
            background: Background::Given {
                level_e: 0.0,
                variance_e2: 40.0,
            },
            ..GaussFitParams::new(1.0)
        };
        b.iter(|| gauss_fit(black_box(&input5), &params))
    });
    // The fused tracking path with a given-background curve (a = 1.2 px, box 7).
    let curve = build_curve(&CurveSpec {
        a_px: 1.2,
        box_side: 7,
        power: CogPower::One,
        background: PixCorrBackground::Given,
        knots: 33,
    })
    .unwrap();
    let (curve, _) = PixCorr::parse(&curve.bytes).unwrap();
    let params = RawCogParams {
        box_side: 7,
        level_e: 0.0,
        variance_e2: 40.0,
        curve: Some(curve),
    };
    let raw_windows: Vec<(RawWindow<'_>, (u16, u16))> = windows
        .iter()
        .map(|w| {
            let rw = RawWindow {
                rect: w.0,
                raw: &w.1,
                levels: &w.2,
            };
            (rw, (w.0.x0 + 3, w.0.y0 + 3))
        })
        .collect();
    c.bench_function("centroid_cog1c_raw_7x7", |b| {
        let (rw, anchor) = &raw_windows[0];
        b.iter(|| raw_cog(&cal, black_box(rw), *anchor, &params))
    });
    let plans: Vec<RawCogPlan> = raw_windows
        .iter()
        .map(|(rw, anchor)| RawCogPlan::new(&cal, rw.rect, *anchor, 7).unwrap())
        .collect();
    c.bench_function("tracking_frame_30_stars", |b| {
        b.iter(|| {
            let mut s = 0.0f32;
            for ((rw, _), plan) in raw_windows.iter().zip(&plans) {
                if let Ok(r) = plan.apply(&cal, black_box(rw), &params) {
                    s += r.centroid.x_px + r.centroid.y_px;
                }
            }
            s
        })
    });
}

criterion_group!(benches, stages);
criterion_main!(benches);
