//! Cortex-M7 cost harness (issue 5): runs the core on deterministic synthetic inputs on QEMU's
//! `mps2-an500` board and prints, over semihosting, the instructions each stage takes per
//! unit as CSV (`stage,unit,instructions_per_unit`), then exits 0 (or 1 on any error).
//!
//! Counting: QEMU does not model the DWT cycle counter, so the bench times with SysTick on the
//! core clock while QEMU runs with `-icount shift=N` (every instruction advances virtual time
//! by 2^N ns). SysTick ticks are converted to instructions with a calibration loop of known
//! instruction count measured in the same run, so the numbers do not depend on N or on the
//! board's clock; the results are *instructions*, not cycles (QEMU models no pipeline, cache
//! or wait states). Run it with `.ci/m7-bench` (or `cargo m7-bench`).
//!
//! Uses neither embassy nor defmt; linked with its own memory map (see `build.rs`).

#![no_std]
#![no_main]

use core::arch::asm;
use core::fmt::Write;
use core::hint::black_box;
use core::sync::atomic::{AtomicU32, Ordering};

use fixed::types::{U0F16, U8F8, U16F16};
use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::centroid::cog::{CogParams, CogPower, cog};
use startrack_core::centroid::gauss_fit::{GaussFitParams, gauss_fit};
use startrack_core::centroid::pixcorr::{CurveHeader, PixCorr, PixCorrBackground};
use startrack_core::centroid::raw_cog::{RawCogParams, RawCogPlan, RawWindow, raw_cog};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::detect::{DetectConfig, ScanDetector};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{
    CalibTable, HotPixel, HotPolicy, MapHeader, MapSpec, TableSpec, write_table,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, Electrons, FlatInv, GainEPerAdu};
use startrack_core::window::{Rect, Window};

// ---------------------------------------------------------------------------------------------
// Semihosting (ARM semihosting v2: `bkpt 0xAB`, operation in r0, argument in r1).

const SYS_WRITE0: u32 = 0x04;
const SYS_EXIT: u32 = 0x18;
const ADP_STOPPED_APPLICATION_EXIT: u32 = 0x2_0026;
const ADP_STOPPED_RUN_TIME_ERROR_UNKNOWN: u32 = 0x2_0023;

fn semihost(op: u32, arg: u32) -> u32 {
    let r: u32;
    // SAFETY: a semihosting call: the debugger (QEMU) reads r0/r1 and the memory r1 points
    // to, and writes r0; no other state changes.
    unsafe { asm!("bkpt 0xAB", inout("r0") op => r, in("r1") arg, options(nostack)) };
    r
}

/// Exits QEMU: status 0 on success, 1 otherwise (AArch32 SYS_EXIT carries only the reason).
fn exit(ok: bool) -> ! {
    let reason = if ok {
        ADP_STOPPED_APPLICATION_EXIT
    } else {
        ADP_STOPPED_RUN_TIME_ERROR_UNKNOWN
    };
    loop {
        semihost(SYS_EXIT, reason);
    }
}

/// Line-buffered writer to the host's stdout (SYS_WRITE0 of a NUL-terminated buffer).
struct Out {
    buf: [u8; 160],
    len: usize,
}

impl Out {
    const fn new() -> Self {
        Self {
            buf: [0; 160],
            len: 0,
        }
    }

    fn flush(&mut self) {
        if self.len > 0 {
            self.buf[self.len] = 0;
            semihost(SYS_WRITE0, self.buf.as_ptr() as u32);
            self.len = 0;
        }
    }
}

impl Write for Out {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for &b in s.as_bytes() {
            if self.len + 1 >= self.buf.len() {
                self.flush();
            }
            self.buf[self.len] = b;
            self.len += 1;
            if b == b'\n' {
                self.flush();
            }
        }
        Ok(())
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    let mut out = Out::new();
    let _ = writeln!(out, "# m7bench panicked: {info}");
    exit(false)
}

// ---------------------------------------------------------------------------------------------
// Start-up: the bench's own vector table and reset handler (linked by `m7bench.x`, written by
// build.rs), so that it needs neither cortex-m-rt's `link.x` (whose `INCLUDE memory.x` would
// find the STM32H743 map in the workspace root) nor a device crate.

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
// SysTick as a tick counter extended by its wrap interrupt.

const SYST_CSR: *mut u32 = 0xE000_E010 as *mut u32;
const SYST_RVR: *mut u32 = 0xE000_E014 as *mut u32;
const SYST_CVR: *mut u32 = 0xE000_E018 as *mut u32;
const RELOAD: u32 = 0x00FF_FFFF;

static WRAPS: AtomicU32 = AtomicU32::new(0);

unsafe extern "C" fn systick_handler() {
    WRAPS.fetch_add(1, Ordering::Relaxed);
}

fn systick_start() {
    // SAFETY: the SysTick registers of the Cortex-M7's System Control Space, owned by this
    // program alone.
    unsafe {
        SYST_RVR.write_volatile(RELOAD);
        SYST_CVR.write_volatile(0);
        // Enable, interrupt on wrap, processor clock.
        SYST_CSR.write_volatile(0b111);
        // The counter reads 0 until its first reload: wait for it.
        while SYST_CVR.read_volatile() == 0 {}
    }
}

/// Ticks since start: wraps x 2^24 + (RELOAD - current value), read consistently.
#[inline(always)]
fn ticks() -> u64 {
    loop {
        let w0 = WRAPS.load(Ordering::SeqCst);
        // SAFETY: as in `systick_start`.
        let v = unsafe { SYST_CVR.read_volatile() };
        let w1 = WRAPS.load(Ordering::SeqCst);
        if w0 == w1 {
            return u64::from(w0) * u64::from(RELOAD + 1) + u64::from(RELOAD - v);
        }
    }
}

/// Ticks `f` takes, minus the cost of an empty measurement.
#[inline(never)]
fn measure(overhead: u64, mut f: impl FnMut()) -> u64 {
    let t0 = ticks();
    f();
    let t1 = ticks();
    (t1 - t0).saturating_sub(overhead)
}

/// `k` iterations of `nop; subs; bne`: 3k instructions.
#[inline(never)]
fn known_loop(k: u32) {
    // SAFETY: a register-only loop.
    unsafe {
        asm!(
            "2:",
            "nop",
            "subs {0}, {0}, #1",
            "bne 2b",
            inout(reg) k => _,
            options(nomem, nostack),
        )
    };
}

/// Converts ticks to instructions with the calibration (`cal_ticks` for `cal_instr`
/// instructions), as a value x100 (two decimals), rounded.
fn instr_x100(ticks: u64, units: u64, cal_ticks: u64, cal_instr: u64) -> u64 {
    let num = u128::from(ticks) * u128::from(cal_instr) * 100;
    let den = u128::from(cal_ticks) * u128::from(units);
    ((num + den / 2) / den) as u64
}

// ---------------------------------------------------------------------------------------------
// Deterministic synthetic inputs.

const G: ReadoutGeometry = ReadoutGeometry::CCD47_20_DUAL;
const RAW_COLS: usize = 1072;
const ACTIVE: usize = 1024;
const TILE_LOG2: u8 = 3;
const TILES: usize = MapHeader::for_area(ACTIVE as u16, ACTIVE as u16, TILE_LOG2).tiles();
const BIAS_ADU: u32 = 1000;

/// A 32-bit LCG (Numerical Recipes constants): deterministic noise.
struct Lcg(u32);

impl Lcg {
    fn next(&mut self) -> u32 {
        self.0 = self.0.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        self.0 >> 8
    }
}

/// exp(-k^2 / 2) x 1000 for k = -3..=3: a Gaussian PSF of sigma 1 px, separable.
const PSF_1000: [u32; 7] = [11, 135, 607, 1000, 607, 135, 11];
/// Peak of a star, ADU above bias.
const STAR_PEAK_ADU: u32 = 20_000;

/// Raw line of active row `y`: bias, noise of +-8 ADU, and a star centred on active (sx, sy).
fn raw_line(y: usize, star: (usize, usize), rng: &mut Lcg, out: &mut [u16; RAW_COLS]) {
    let first_active = usize::from(G.overscan_px + G.covered_px);
    for (col, v) in out.iter_mut().enumerate() {
        let mut s = BIAS_ADU + rng.next() % 17;
        if col >= first_active && col < first_active + ACTIVE {
            let x = col - first_active;
            let (dx, dy) = (x.abs_diff(star.0), y.abs_diff(star.1));
            if dx <= 3 && dy <= 3 {
                let wx = PSF_1000[3 + dx];
                let wy = PSF_1000[3 + dy];
                s += STAR_PEAK_ADU * wx / 1000 * wy / 1000;
            }
        }
        *v = s as u16;
    }
}

/// Raw line of active row `y` for the scan: bias, near-Gaussian noise (sum of four uniform
/// 0..=15 ADU draws: sigma 9.2 ADU, a tail like a Gaussian's to 3.5 sigma, so the 2.5-sigma
/// join threshold passes ~0.6 % of the samples as real noise does) and the stars of `stars`.
fn raw_line_noisy(y: usize, stars: &[(usize, usize)], rng: &mut Lcg, out: &mut [u16; RAW_COLS]) {
    let first_active = usize::from(G.overscan_px + G.covered_px);
    for (col, v) in out.iter_mut().enumerate() {
        // The LCG's top bits: its low bits have short periods (bits 8..11 repeat every 4096
        // draws, about one line), which made correlated noise peaks.
        let mut s = BIAS_ADU + (0..4).map(|_| rng.next() >> 20).sum::<u32>();
        if col >= first_active && col < first_active + ACTIVE {
            let x = col - first_active;
            for star in stars {
                let (dx, dy) = (x.abs_diff(star.0), y.abs_diff(star.1));
                if dx <= 3 && dy <= 3 {
                    s += STAR_PEAK_ADU * PSF_1000[3 + dx] / 1000 * PSF_1000[3 + dy] / 1000;
                }
            }
        }
        *v = s.min(65_535) as u16;
    }
}

// ---------------------------------------------------------------------------------------------

const LINES: usize = 16;
/// Rows of the streaming scan bench (two background rows at stride 64).
const SCAN_LINES: usize = 128;
/// Background stride of the scan bench: whole lines are calibrated every this many rows.
const SCAN_BG_STRIDE: u16 = 64;
/// Stars in the scan bench's rows.
const SCAN_STARS: [(usize, usize); 10] = [
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
/// Windows of the tracking-frame bench (issue 5: 30 stars).
const TRACK_STARS: usize = 30;
const WINDOW_REPS: usize = 32;

fn main() -> ! {
    let mut out = Out::new();
    if let Err(what) = run(&mut out) {
        let _ = writeln!(out, "# m7bench error: {what}");
        exit(false)
    }
    exit(true)
}

fn run(out: &mut Out) -> Result<(), &'static str> {
    // The calibration table: CCD47-20, both outputs, per-column bias, 8x8-tiled dark and
    // flat maps (the README's flashed table), hot and telegraph pixels.
    let gains = [GainEPerAdu::from_num(1.5), GainEPerAdu::from_num(1.625)];
    let mut column_bias = [ColumnBiasAdu::ZERO; RAW_COLS];
    for (i, c) in column_bias.iter_mut().enumerate() {
        *c = ColumnBiasAdu::from_bits((i as i16 % 37) - 18);
    }
    let mut dark = [DarkRel::ONE; TILES];
    let mut flat = [FlatInv::ONE; TILES];
    let mut rng = Lcg(0x5eed);
    for (d, f) in dark.iter_mut().zip(flat.iter_mut()) {
        *d = DarkRel::from_bits(56 + (rng.next() % 17) as u8);
        *f = FlatInv::from_bits(15_800 + (rng.next() % 1_200) as u16);
    }
    let hot_at = |x: u16, y: u16, policy| HotPixel {
        x,
        y,
        rate_e_per_s: U16F16::from_num(40),
        doubling_k: U8F8::from_num(6.5),
        policy,
    };
    let hot = [
        hot_at(300, 100, HotPolicy::Correct),
        hot_at(513, 101, HotPolicy::Correct),
        hot_at(514, 300, HotPolicy::Exclude),
        hot_at(100, 700, HotPolicy::Correct),
    ];
    let telegraph = [(40u16, 200u16), (900, 640)];
    let spec = TableSpec {
        geometry: G,
        saturation_adu: 65_000,
        gains: &gains,
        column_bias: Some(&column_bias),
        dark_rel: Some(MapSpec {
            tile_log2: TILE_LOG2,
            tiles: &dark,
        }),
        flat_inv: Some(MapSpec {
            tile_log2: TILE_LOG2,
            tiles: &flat,
        }),
        hot_ref_k: U16F16::from_num(263),
        hot: &hot,
        telegraph: &telegraph,
    };
    let mut table_buf = [0u8; 64 * 1024];
    let len = write_table(&spec, &mut table_buf).map_err(|_| "write_table failed")?;
    let table = CalibTable::parse(&table_buf[..len]).map_err(|_| "table does not parse")?;
    let cal = FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: Electrons::from_num(12.5),
            exposure_ms: 200,
            temperature_k: U16F16::from_num(258),
        },
    );

    systick_start();
    let overhead = (0..8)
        .map(|_| measure(0, || {}))
        .min()
        .ok_or("no overhead")?;
    // Calibration: a loop of known instruction count.
    const CAL_K: u32 = 100_000;
    let cal_instr = 3 * u64::from(CAL_K);
    let cal_ticks = measure(overhead, || known_loop(black_box(CAL_K)));
    let cal_ticks_half = measure(overhead, || known_loop(black_box(CAL_K / 2)));
    if cal_ticks == 0 {
        return Err("SysTick does not count (QEMU without -icount?)");
    }
    let _ = writeln!(
        out,
        "# systick calibration: {} instructions = {} ticks; {} instructions = {} ticks; \
         ticks per 1000 instructions = {}",
        cal_instr,
        cal_ticks,
        cal_instr / 2,
        cal_ticks_half,
        cal_ticks * 1000 / cal_instr
    );
    let _ = writeln!(out, "stage,unit,instructions_per_unit");
    let row = |out: &mut Out, stage: &str, unit: &str, ticks: u64, units: u64| {
        let v = instr_x100(ticks, units, cal_ticks, cal_instr);
        let _ = writeln!(out, "{stage},{unit},{}.{:02}", v / 100, v % 100);
    };

    // Line path: levels, dark-scale accumulation, calibration of the whole active line.
    let mut raw = [0u16; RAW_COLS];
    let mut e = [Electrons::ZERO; ACTIVE];
    let mut flags = [PixelFlags::empty(); ACTIVE];
    let mut est = DarkScaleEstimator::new();
    let (mut t_levels, mut t_dark, mut t_span) = (0u64, 0u64, 0u64);
    for i in 0..LINES {
        let y = 96 + 13 * i;
        raw_line(y, (500, 100), &mut rng, &mut raw);
        let mut levels = None;
        t_levels += measure(overhead, || {
            levels = Some(LineLevels::measure(&G, black_box(&raw)));
        });
        let levels = levels
            .ok_or("no levels")?
            .map_err(|_| "LineLevels::measure failed")?;
        let mut r = Ok(());
        t_dark += measure(overhead, || {
            r = est.add_line(&table, black_box(&raw), &levels);
        });
        r.map_err(|_| "add_line failed")?;
        let mut r = Ok(PixelFlags::empty());
        t_span += measure(overhead, || {
            r = cal.calibrate_span(y as u16, 0, black_box(&raw), &levels, &mut e, &mut flags);
        });
        r.map_err(|_| "calibrate_span failed")?;
        black_box(&e);
    }
    let n = LINES as u64;
    row(out, "line_calibrate", "pixel", t_span, n * ACTIVE as u64);
    row(out, "line_levels_measure", "line", t_levels, n);
    row(out, "dark_scale_add_line", "line", t_dark, n);

    // Streaming scan: calibrate-and-detect with the raw pre-filter over SCAN_LINES
    // consecutive rows with stars (levels measured outside the timing, their own stage).
    {
        let mut scan = ScanDetector::<64>::new(cal, DetectConfig::default(), SCAN_BG_STRIDE);
        let (mut t_scan, mut t_bg_rows) = (0u64, 0u64);
        let mut r = Ok(());
        for y in 0..SCAN_LINES {
            raw_line_noisy(y, &SCAN_STARS, &mut rng, &mut raw);
            let levels = LineLevels::measure(&G, &raw).map_err(|_| "levels")?;
            let t = measure(overhead, || {
                r = scan.push_raw_line(y as u16, black_box(&raw), &levels);
            });
            t_scan += t;
            if scan.detector().background_due(y as u16) || y == 0 {
                t_bg_rows += t;
            }
            r.map_err(|_| "push_raw_line failed")?;
        }
        t_scan += measure(overhead, || scan.finish());
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
        row(
            out,
            "scan_detect",
            "pixel",
            t_scan,
            (SCAN_LINES * ACTIVE) as u64,
        );
    }

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

    // Tracking frame: the per-frame cost of the firmware's tracking (firmware/src/stars.rs)
    // for TRACK_STARS 7x7 raw windows, each calibrated and centroided by applying its
    // window's `RawCogPlan` (the fused raw-window CoG power 1 in the 7x7 box,
    // `centroid::raw_cog`: the calibration folded into the sums; each star's background
    // given, carried from its last measurement; pixel-phase curve applied). The plans are
    // built beforehand, untimed: the firmware rebuilds a window's plan only when its star
    // moves to another anchor pixel (stage `raw_cog_plan_7x7` gives that cost per move;
    // `centroid_cog1c_raw_7x7` the one-shot plan + apply). Not included: the window capture
    // of the raw lines and the full-path fallback on flags. The general path
    // (calibrate_window + cog with a perimeter median + curve) is measured by
    // `window_calibrate` and `centroid_cog1c_7x7` below.
    {
        let mut wraw = [[0u16; 49]; TRACK_STARS];
        let mut wlevels = [[LineLevels::measure(&G, &raw).map_err(|_| "levels")?; 7]; TRACK_STARS];
        let mut rects = [Rect {
            x0: 0,
            y0: 0,
            width: 7,
            height: 7,
        }; TRACK_STARS];
        let mut line = [0u16; RAW_COLS];
        for (i, ((w, lv), rect)) in wraw
            .iter_mut()
            .zip(wlevels.iter_mut())
            .zip(rects.iter_mut())
            .enumerate()
        {
            let (sx, sy) = (40 + 31 * i, 50 + 29 * i);
            *rect = Rect {
                x0: (sx - 3) as u16,
                y0: (sy - 3) as u16,
                width: 7,
                height: 7,
            };
            let first = G.raw_col_of_x(sx - 3);
            for (r, l) in lv.iter_mut().enumerate() {
                raw_line_noisy(sy - 3 + r, &[(sx, sy)], &mut rng, &mut line);
                *l = LineLevels::measure(&G, &line).map_err(|_| "levels")?;
                w[7 * r..7 * r + 7].copy_from_slice(&line[first..first + 7]);
            }
        }
        let mut ok = true;
        let mut sum = 0.0f32;
        let mut plans = [None; TRACK_STARS];
        for (p, rect) in plans.iter_mut().zip(rects.iter()) {
            *p = RawCogPlan::new(&cal, *rect, (rect.x0 + 3, rect.y0 + 3), 7).ok();
        }
        let t_track = measure(overhead, || {
            for (((w, lv), rect), plan) in wraw
                .iter()
                .zip(wlevels.iter())
                .zip(rects.iter())
                .zip(plans.iter())
            {
                let win = RawWindow {
                    rect: *rect,
                    raw: black_box(w),
                    levels: lv,
                };
                match plan.as_ref().map(|p| p.apply(&cal, &win, &raw_params)) {
                    Some(Ok(r)) => {
                        if r.centroid.flags.contains(CentroidFlags::DEGENERATE) {
                            ok = false;
                        }
                        sum += r.centroid.x_px + r.centroid.y_px;
                    }
                    _ => ok = false,
                }
            }
        });
        black_box(sum);
        if !ok {
            return Err("tracking_frame failed");
        }
        row(out, "tracking_frame", "frame_30_stars", t_track, 1);
    }

    let mut t_cog1c = 0u64;
    let mut t_cog1c_raw = 0u64;
    let mut t_cog1c_raw5 = 0u64;
    let mut t_raw_plan = 0u64;
    let mut t_raw_planned = 0u64;

    // Star windows: 7x7 around a star, calibrated from its 7 raw lines, then centroided.
    let mut t_window = 0u64;
    let mut t_centroid = [[0u64; METHODS]; 2];
    for rep in 0..WINDOW_REPS {
        let (sx, sy) = (64 + 29 * rep, 80 + 23 * rep);
        let mut lines = [[0u16; RAW_COLS]; 7];
        let mut levels = [LineLevels::measure(&G, &raw).map_err(|_| "levels")?; 7];
        for (r, (l, lv)) in lines.iter_mut().zip(levels.iter_mut()).enumerate() {
            raw_line(sy - 3 + r, (sx, sy), &mut rng, l);
            *lv = LineLevels::measure(&G, l).map_err(|_| "levels")?;
        }
        let rect = Rect {
            x0: (sx - 3) as u16,
            y0: (sy - 3) as u16,
            width: 7,
            height: 7,
        };
        let first = G.raw_col_of_x(sx - 3);
        let mut wraw = [0u16; 49];
        for (r, l) in lines.iter().enumerate() {
            wraw[7 * r..7 * r + 7].copy_from_slice(&l[first..first + 7]);
        }
        let mut we = [Electrons::ZERO; 49];
        let mut wf = [PixelFlags::empty(); 49];
        let mut r = Ok(PixelFlags::empty());
        t_window += measure(overhead, || {
            r = cal.calibrate_window(rect, black_box(&wraw), &levels, &mut we, &mut wf);
        });
        r.map_err(|_| "calibrate_window failed")?;
        // The fused path: raw window and levels to the corrected centroid, calibration
        // included (the "window_calibrate + corrected CoG 7x7" as one stage).
        let rw = RawWindow {
            rect,
            raw: &wraw,
            levels: &levels,
        };
        let rw = black_box(&rw);
        let mut fused = None;
        t_cog1c_raw += measure(overhead, || {
            fused = Some(raw_cog(&cal, rw, (sx as u16, sy as u16), &raw_params));
        });
        let mut fused5 = None;
        t_cog1c_raw5 += measure(overhead, || {
            fused5 = Some(raw_cog(&cal, rw, (sx as u16, sy as u16), &raw_params5));
        });
        let fused5 = fused5.ok_or("raw_cog 5x5")?;
        if fused5.centroid.flags.bits() != 0 || fused5.general_path {
            return Err("raw_cog 5x5 flagged a clean star");
        }
        let fused = fused.ok_or("raw_cog")?;
        if fused.centroid.flags.bits() != 0 || fused.general_path {
            return Err("raw_cog flagged a clean star");
        }
        // The same box as a plan (built once per box move) and its application per frame.
        let anchor = (sx as u16, sy as u16);
        // Rebuilt in place, as the firmware keeps a plan per tracking window.
        let mut plan = RawCogPlan::EMPTY;
        let mut built = Err(());
        t_raw_plan += measure(overhead, || {
            built = plan
                .rebuild(&cal, black_box(rect), anchor, 7)
                .map_err(|_| ());
        });
        built.map_err(|_| "raw_cog plan")?;
        let plan = black_box(&plan);
        let mut planned = None;
        t_raw_planned += measure(overhead, || {
            planned = Some(plan.apply(&cal, rw, &raw_params));
        });
        let planned = planned
            .ok_or("raw_cog planned")?
            .map_err(|_| "raw_cog planned")?;
        if planned != fused {
            return Err("raw_cog plan + apply differs from the one-shot");
        }

        // Centroids on the 7x7 window and on its central 5x5.
        let mut we5 = [Electrons::ZERO; 25];
        let mut wf5 = [PixelFlags::empty(); 25];
        for r in 0..5 {
            we5[5 * r..5 * r + 5].copy_from_slice(&we[7 * (r + 1) + 1..7 * (r + 1) + 6]);
            wf5[5 * r..5 * r + 5].copy_from_slice(&wf[7 * (r + 1) + 1..7 * (r + 1) + 6]);
        }
        let rect5 = Rect {
            x0: rect.x0 + 1,
            y0: rect.y0 + 1,
            width: 5,
            height: 5,
        };
        let w7 = Window::new(rect, &we).ok_or("window 7")?;
        let w5 = Window::new(rect5, &we5).ok_or("window 5")?;
        let inputs = [
            CentroidInput::new(w5).with_pixel_flags(&wf5),
            CentroidInput::new(w7).with_pixel_flags(&wf),
        ];
        // The firmware's corrected CoG: power 1, 7x7 box, perimeter median, then the curve.
        let input7 = black_box(&inputs[1]);
        t_cog1c += measure(overhead, || {
            let c = curve.apply(cog(input7, &CogParams::new(CogPower::One, 7)));
            black_box(c.x_px + c.y_px);
        });
        for (input, acc) in inputs.iter().zip(t_centroid.iter_mut()) {
            let side = input.window.rect.width as u8;
            for (m, slot) in acc.iter_mut().enumerate() {
                let input = black_box(input);
                *slot += measure(overhead, || {
                    black_box(run_method(m, side, input));
                });
            }
        }
    }
    row(
        out,
        "window_calibrate",
        "window_7x7",
        t_window,
        WINDOW_REPS as u64,
    );
    row(
        out,
        "centroid_cog1c_7x7",
        "star",
        t_cog1c,
        WINDOW_REPS as u64,
    );
    row(
        out,
        "centroid_cog1c_raw_7x7",
        "star",
        t_cog1c_raw,
        WINDOW_REPS as u64,
    );
    row(
        out,
        "centroid_cog1c_raw_5x5",
        "star",
        t_cog1c_raw5,
        WINDOW_REPS as u64,
    );
    // The fused path split as the firmware's tracking runs it: the plan of a box (built when
    // the star moves to another anchor pixel) and its application to a frame's raw window.
    row(
        out,
        "raw_cog_plan_7x7",
        "box",
        t_raw_plan,
        WINDOW_REPS as u64,
    );
    row(
        out,
        "centroid_cog1c_raw_planned_7x7",
        "star",
        t_raw_planned,
        WINDOW_REPS as u64,
    );
    for (side, acc) in [5u8, 7].iter().zip(t_centroid.iter()) {
        for (m, t) in acc.iter().enumerate() {
            let mut name = Out::new();
            let _ = write!(name, "centroid_{}_{side}x{side}", METHOD_NAMES[m]);
            let name = core::str::from_utf8(&name.buf[..name.len]).map_err(|_| "utf8")?;
            row(out, name, "star", *t, WINDOW_REPS as u64);
        }
    }
    black_box(est.estimate());
    Ok(())
}

const METHODS: usize = 5;
const METHOD_NAMES: [&str; METHODS] = [
    "cog1",
    "cog2",
    "cog1_given_bg",
    "gauss_fit",
    "gauss_fit_given_bg",
];
/// The PSF's sigma of the synthetic stars, px.
const PSF_SIGMA_PX: f32 = 1.0;

/// A pixel-phase curve's bytes (power 1, `box_side`, `background`, a = 1.2 px): 33 knots of
/// an S-shaped correction; the values do not change the cost.
fn s_curve_bytes(box_side: u8, background: PixCorrBackground) -> [u8; 8 + 2 * 33] {
    let mut bytes = [0u8; 8 + 2 * 33];
    let header = CurveHeader {
        power: CogPower::One,
        box_side,
        background,
        knots: 33,
        a_px: U8F8::from_num(1.2),
        phase_max_px: U0F16::from_num(0.45),
    };
    bytes[..8].copy_from_slice(&header.to_bytes());
    for k in 1..33usize {
        let v = (k as i32 * (32 - k as i32) * 3) as i16;
        bytes[8 + 2 * k..10 + 2 * k].copy_from_slice(&v.to_le_bytes());
    }
    bytes
}

/// Runs centroid method `m` (an index into [`METHOD_NAMES`]) over the whole window
/// (box = window side).
#[inline(never)]
fn run_method(m: usize, side: u8, input: &CentroidInput<'_>) -> f32 {
    // The detector's background estimate, as `startrack accuracy` and the trade-off chart
    // give it to the `_given_bg` stages.
    let given = Background::Given {
        level_e: 10.0,
        variance_e2: 40.0,
    };
    let c = match m {
        0 => cog(input, &CogParams::new(CogPower::One, side)),
        1 => cog(input, &CogParams::new(CogPower::Two, side)),
        2 => cog(
            input,
            &CogParams {
                background: given,
                ..CogParams::new(CogPower::One, side)
            },
        ),
        3 => gauss_fit(input, &GaussFitParams::new(PSF_SIGMA_PX)),
        // The near-CRLB method as `startrack accuracy` runs it: background given and held
        // (not fitted), start box the window's side capped at 5.
        _ => gauss_fit(
            input,
            &GaussFitParams {
                fit_background: false,
                background: given,
                start_box: side.min(5),
                ..GaussFitParams::new(PSF_SIGMA_PX)
            },
        ),
    };
    c.x_px + c.y_px
}
