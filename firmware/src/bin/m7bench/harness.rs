//! The bench's measuring and reporting: SysTick as a tick counter, its conversion to
//! instructions by a calibration loop of known length, and output over ARM semihosting.
//!
//! Counting: QEMU does not model the DWT cycle counter, so the bench times with SysTick on the
//! core clock while QEMU runs with `-icount shift=N` (every instruction advances virtual time
//! by 2^N ns). [`Bench::calibrate`] times [`known_loop`] (3 instructions an iteration) in the
//! same run and converts ticks to instructions with it, so the numbers depend neither on N
//! nor on the board's clock; they are *instructions*, not cycles (QEMU models no pipeline,
//! cache or wait states). A measurement costs two SysTick reads (a few instructions, taken
//! off as the calibrated overhead of an empty measurement).
//!
//! Output: [`Out`] buffers a line and hands it to the host with `SYS_WRITE0`; [`exit`] ends
//! QEMU with `SYS_EXIT` (status 0 or 1). A panic prints one `#` line and exits with 1.

use core::arch::asm;
use core::fmt::Write;
use core::hint::black_box;
use core::sync::atomic::{AtomicU32, Ordering};

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
pub fn exit(ok: bool) -> ! {
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
pub struct Out {
    buf: [u8; 160],
    len: usize,
}

impl Out {
    pub const fn new() -> Self {
        Self {
            buf: [0; 160],
            len: 0,
        }
    }

    /// What was written since the last flush (a name built with `write!`).
    pub fn as_str(&self) -> Result<&str, &'static str> {
        core::str::from_utf8(&self.buf[..self.len]).map_err(|_| "utf8")
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
// SysTick as a tick counter extended by its wrap interrupt.

const SYST_CSR: *mut u32 = 0xE000_E010 as *mut u32;
const SYST_RVR: *mut u32 = 0xE000_E014 as *mut u32;
const SYST_CVR: *mut u32 = 0xE000_E018 as *mut u32;
const RELOAD: u32 = 0x00FF_FFFF;

static WRAPS: AtomicU32 = AtomicU32::new(0);

/// The SysTick exception: one more wrap of the 24-bit counter.
pub unsafe extern "C" fn systick_handler() {
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

/// The running tick counter and its calibration: measures closures and prints CSV rows.
pub struct Bench {
    /// Ticks of an empty measurement.
    overhead: u64,
    /// Ticks of `cal_instr` instructions.
    cal_ticks: u64,
    /// Instructions of the calibration loop.
    cal_instr: u64,
}

impl Bench {
    /// Starts SysTick, measures the empty measurement and the calibration loop, and prints
    /// the calibration (a `#` line) and the CSV header.
    pub fn calibrate(out: &mut Out) -> Result<Self, &'static str> {
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
        Ok(Self {
            overhead,
            cal_ticks,
            cal_instr,
        })
    }

    /// Ticks `f` takes, minus the cost of an empty measurement.
    #[inline(always)]
    pub fn measure(&self, f: impl FnMut()) -> u64 {
        measure(self.overhead, f)
    }

    /// Prints the CSV row `stage,unit,instructions per unit` for `ticks` over `units` units.
    pub fn row(&self, out: &mut Out, stage: &str, unit: &str, ticks: u64, units: u64) {
        let v = instr_x100(ticks, units, self.cal_ticks, self.cal_instr);
        let _ = writeln!(out, "{stage},{unit},{}.{:02}", v / 100, v % 100);
    }
}
