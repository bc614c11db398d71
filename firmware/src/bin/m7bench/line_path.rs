//! Stages of the line path, per line of the full readout: `line_levels_measure` (each
//! output's bias from its over-scan), `dark_scale_add_line` (the covered columns' dark
//! accumulated for the frame's dark scale) and `line_calibrate` (every active pixel of a line
//! to electrons, per pixel). Inputs: [`LINES`] raw lines with one star, calibrated with the
//! bench's table. Cost: [`LINES`] x 1072 samples through three core stages.

use crate::harness::{Bench, Out};
use crate::inputs::{ACTIVE, G, Lcg, RAW_COLS, raw_line};
use core::hint::black_box;
use startrack_core::calib::{DarkScaleEstimator, FrameCalibration, LineLevels, PixelFlags};
use startrack_core::table::CalibTable;
use startrack_core::units::Electrons;

/// Lines measured.
pub const LINES: usize = 16;

/// Measures and prints the three line stages.
pub fn run(
    out: &mut Out,
    bench: &Bench,
    table: &CalibTable<'_>,
    cal: &FrameCalibration<'_>,
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    let mut raw = [0u16; RAW_COLS];
    let mut e = [Electrons::ZERO; ACTIVE];
    let mut flags = [PixelFlags::empty(); ACTIVE];
    let mut est = DarkScaleEstimator::new();
    let (mut t_levels, mut t_dark, mut t_span) = (0u64, 0u64, 0u64);
    for i in 0..LINES {
        let y = 96 + 13 * i;
        raw_line(y, (500, 100), rng, &mut raw);
        let mut levels = None;
        t_levels += bench.measure(|| {
            levels = Some(LineLevels::measure(&G, black_box(&raw)));
        });
        let levels = levels
            .ok_or("no levels")?
            .map_err(|_| "LineLevels::measure failed")?;
        let mut r = Ok(());
        t_dark += bench.measure(|| {
            r = est.add_line(table, black_box(&raw), &levels);
        });
        r.map_err(|_| "add_line failed")?;
        let mut r = Ok(PixelFlags::empty());
        t_span += bench.measure(|| {
            r = cal.calibrate_span(y as u16, 0, black_box(&raw), &levels, &mut e, &mut flags);
        });
        r.map_err(|_| "calibrate_span failed")?;
        black_box(&e);
    }
    let n = LINES as u64;
    bench.row(out, "line_calibrate", "pixel", t_span, n * ACTIVE as u64);
    bench.row(out, "line_levels_measure", "line", t_levels, n);
    bench.row(out, "dark_scale_add_line", "line", t_dark, n);
    black_box(est.estimate());
    Ok(())
}
