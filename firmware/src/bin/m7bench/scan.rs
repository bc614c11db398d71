//! Stage `scan_detect`, per pixel: the streaming calibrate-and-detect with the raw
//! pre-filter (`ScanDetector::push_raw_line`) over [`SCAN_LINES`] consecutive rows holding
//! [`SCAN_STARS`], on near-Gaussian noise, with a background row calibrated whole every
//! [`SCAN_BG_STRIDE`] rows. Each line's levels are measured outside the timing (their own
//! stage in [`crate::line_path`]). The run fails unless the scan finds exactly the stars. Cost:
//! [`SCAN_LINES`] x 1024 active pixels through the scan; a `#` line reports how many were
//! calibrated and the background rows' share of the time.

use crate::harness::{Bench, Out};
use crate::inputs::{ACTIVE, G, Lcg, RAW_COLS, raw_line_noisy};
use core::fmt::Write;
use core::hint::black_box;
use startrack_core::calib::{FrameCalibration, LineLevels};
use startrack_core::detect::{DetectConfig, ScanDetector};

/// Rows of the streaming scan bench (two background rows at stride 64).
pub const SCAN_LINES: usize = 128;
/// Background stride of the scan bench: whole lines are calibrated every this many rows.
pub const SCAN_BG_STRIDE: u16 = 64;
/// Stars in the scan bench's rows.
pub const SCAN_STARS: [(usize, usize); 10] = [
    (40, 10),
    (150, 20),
    (300, 33),
    (420, 47),
    (512, 60),
    (600, 70),
    (700, 85),
    (800, 95),
    (900, 110),
    (1000, 120),
];

/// Measures and prints `scan_detect`.
pub fn run(
    out: &mut Out,
    bench: &Bench,
    cal: &FrameCalibration<'_>,
    rng: &mut Lcg,
) -> Result<(), &'static str> {
    let mut raw = [0u16; RAW_COLS];
    let mut scan = ScanDetector::<64>::new(*cal, DetectConfig::default(), SCAN_BG_STRIDE);
    let (mut t_scan, mut t_bg_rows) = (0u64, 0u64);
    let mut r = Ok(());
    for y in 0..SCAN_LINES {
        raw_line_noisy(y, &SCAN_STARS, rng, &mut raw);
        let levels = LineLevels::measure(&G, &raw).map_err(|_| "levels")?;
        let t = bench.measure(|| {
            r = scan.push_raw_line(y as u16, black_box(&raw), &levels);
        });
        t_scan += t;
        if scan.detector().background_due(y as u16) || y == 0 {
            t_bg_rows += t;
        }
        r.map_err(|_| "push_raw_line failed")?;
    }
    t_scan += bench.measure(|| scan.finish());
    let found = scan.candidates().len();
    if found != SCAN_STARS.len() {
        let _ = writeln!(out, "# scan found {found} of {} stars", SCAN_STARS.len());
        for c in scan.candidates() {
            let _ = writeln!(
                out,
                "# {} {} {} {} {:?}",
                c.x_px, c.y_px, c.flux_e, c.pixels, c.flags
            );
        }
        return Err("scan_detect did not find exactly the stars");
    }
    let _ = writeln!(
        out,
        "# scan_detect: {} of {} pixels calibrated, {} candidates; background rows \
         (calibrated whole) {} % of the time",
        scan.calibrated_px(),
        SCAN_LINES * ACTIVE,
        found,
        t_bg_rows * 100 / t_scan.max(1)
    );
    bench.row(
        out,
        "scan_detect",
        "pixel",
        t_scan,
        (SCAN_LINES * ACTIVE) as u64,
    );
    Ok(())
}
