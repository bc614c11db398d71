//! Cortex-M7 cost harness: runs the core on deterministic synthetic inputs on QEMU's
//! `mps2-an500` board and prints, over semihosting, the instructions each stage takes per
//! unit as CSV (`stage,unit,instructions_per_unit`), then exits 0 (or 1 on any error). Run it
//! with `.ci/m7-bench` (or `cargo m7-bench`); `host-tests/m7-costs.csv` is its committed
//! output and `firmware/m7bench-budgets.csv` the budgets CI holds it to.
//!
//! - [`harness`]: SysTick ticks converted to instructions by a calibration loop, semihosting
//!   output and exit;
//! - [`inputs`]: the calibration table, raw lines with stars and noise, pixel-phase curves;
//! - the stage families, in the order they print: [`line_path`] (levels, dark scale, line
//!   calibration), [`scan`] (the streaming scan), [`track`] (a tracking frame), [`window`]
//!   (a star window's calibration and the fused raw-window CoG), [`centroid`] (the
//!   centroid methods on calibrated windows), [`tracker`] (the tracker application's
//!   acquisition and tracking frames, every line) and [`ident`] (star identification and
//!   attitude, lost in space and tracking).
//!
//! Cost: QEMU runs the whole bench in well under a second of host time; `cargo m7-bench`'s
//! time is the release build (fat LTO). Uses neither embassy nor defmt; linked with its own
//! memory map and the start-up code below (see `build.rs`).

#![no_std]
#![no_main]

mod centroid;
mod harness;
mod ident;
mod inputs;
mod line_path;
// The firmware's MDMA node builder, timed as the board runs it.
#[path = "../../board/stm32h743/mdma_list.rs"]
#[allow(dead_code, reason = "the bench uses the node builder, not every item")]
mod mdma_list;
mod scan;
mod sequencer;
mod track;
mod tracker;
mod window;

use core::arch::asm;
use core::fmt::Write;

use fixed::types::U16F16;
use harness::{Bench, Out, exit, systick_handler};
use inputs::{Lcg, s_curve_bytes, write_bench_table};
use startrack_core::calib::{FrameCalibration, FrameConditions};
use startrack_core::centroid::raw_cog::RawCogParams;
use startrack_core::table::CalibTable;
use startrack_core::table::pixcorr::{PixCorr, PixCorrBackground};
use startrack_core::units::Electrons;

// ---------------------------------------------------------------------------------------------
// Start-up: the bench's own vector table and reset handler (linked by `m7bench.x`, written by
// build.rs), so that it needs neither cortex-m-rt's `link.x` (and a `memory.x`) nor a device
// crate.

unsafe extern "C" {
    static mut __m7_sbss: u32;
    static mut __m7_ebss: u32;
    static mut __m7_sdata: u32;
    static mut __m7_edata: u32;
    static __m7_sidata: u32;
}

/// A fault or an unexpected exception: report failure.
unsafe extern "C" fn fault() {
    exit(false)
}

/// Exceptions 1 to 15 (the initial stack pointer, word 0, is written by the linker script).
#[unsafe(link_section = ".m7bench.vectors")]
#[unsafe(no_mangle)]
#[used]
static M7BENCH_VECTORS: [Option<unsafe extern "C" fn()>; 15] = [
    Some(m7bench_reset_vector), // Reset
    Some(fault),                // NMI
    Some(fault),                // HardFault
    Some(fault),                // MemManage
    Some(fault),                // BusFault
    Some(fault),                // UsageFault
    None,
    None,
    None,
    None,
    Some(fault), // SVCall
    Some(fault), // DebugMonitor
    None,
    Some(fault),           // PendSV
    Some(systick_handler), // SysTick
];

unsafe extern "C" fn m7bench_reset_vector() {
    // SAFETY: runs once, first, before any Rust code that touches statics or the FPU.
    unsafe {
        let mut p = &raw mut __m7_sbss;
        while p < &raw mut __m7_ebss {
            p.write_volatile(0);
            p = p.add(1);
        }
        let (mut d, mut s) = (&raw mut __m7_sdata, &raw const __m7_sidata);
        while d < &raw mut __m7_edata {
            d.write_volatile(s.read_volatile());
            d = d.add(1);
            s = s.add(1);
        }
        // Full access to the FPU (CP10, CP11): the target is hard-float.
        let cpacr = 0xE000_ED88 as *mut u32;
        cpacr.write_volatile(cpacr.read_volatile() | (0xF << 20));
        asm!("dsb", "isb", options(nomem, nostack));
    }
    main()
}

// ---------------------------------------------------------------------------------------------

fn main() -> ! {
    let mut out = Out::new();
    if let Err(what) = run(&mut out) {
        let _ = writeln!(out, "# m7bench error: {what}");
        exit(false)
    }
    exit(true)
}

fn run(out: &mut Out) -> Result<(), &'static str> {
    let mut rng = Lcg(0x5eed);
    let mut table_buf = [0u8; 64 * 1024];
    let len = write_bench_table(&mut rng, &mut table_buf)?;
    let table = CalibTable::parse(&table_buf[..len]).map_err(|_| "table does not parse")?;
    let cal = FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: Electrons::from_num(12.5),
            exposure_ms: 200,
            temperature_k: U16F16::from_num(258),
        },
    );

    let bench = Bench::calibrate(out)?;
    line_path::run(out, &bench, &table, &cal, &mut rng)?;
    scan::run(out, &bench, &cal, &mut rng)?;

    // The pixel-phase curves the stages apply (power 1; the knots do not change the cost):
    // the tracking path's (box 7, given background), its 5x5 twin (the trade-off chart's
    // corrected 5x5 CoG) and the general path's (box 7, perimeter median).
    let track_curve_bytes = s_curve_bytes(7, PixCorrBackground::Given);
    let curve5_bytes = s_curve_bytes(5, PixCorrBackground::Given);
    let median_curve_bytes = s_curve_bytes(7, PixCorrBackground::PerimeterMedian);
    let (track_curve, _) =
        PixCorr::parse(&track_curve_bytes).map_err(|_| "pixel-phase curve (given)")?;
    let (curve_given5, _) =
        PixCorr::parse(&curve5_bytes).map_err(|_| "pixel-phase curve (given, 5x5)")?;
    let (curve, _) = PixCorr::parse(&median_curve_bytes).map_err(|_| "pixel-phase curve")?;
    // The fused path's parameters: each star's background given, the curve applied.
    let raw_params = RawCogParams {
        box_side: 7,
        level_e: 10.0,
        variance_e2: 40.0,
        curve: Some(track_curve),
    };
    let raw_params5 = RawCogParams {
        box_side: 5,
        curve: Some(curve_given5),
        ..raw_params
    };

    track::run(out, &bench, &cal, &raw_params, &mut rng)?;
    window::run(
        out,
        &bench,
        &cal,
        &raw_params,
        &raw_params5,
        &curve,
        &mut rng,
    )?;
    sequencer::run(out, &bench)?;
    // Last, so that its draws do not change the other stages' inputs.
    tracker::run(out, &bench, &table, &mut rng)?;
    // Its own generator: the identification fields do not move the other stages' inputs.
    ident::run(out, &bench, &mut Lcg(0x1d_5eed))
}
