//! embassy-time's driver on `mps2-an500`: SysTick on the processor clock (QEMU's 25 MHz
//! `SYSCLK`, 40 ns a count), reloaded every millisecond; its interrupt counts the periods and
//! wakes the timers that are due. Time is `periods x 25,000 + counts into the period`,
//! in embassy's 1 MHz ticks (`/ 25`).
//!
//! Under QEMU's `-icount shift=N` every instruction advances the virtual clock by 2^N ns, so
//! SysTick counts instructions exactly: the time this driver gives is the emulated time.
//!
//! Start-up: cortex-m-rt's reset handler calls `__pre_init` (defined here) before it
//! initialises RAM; it starts SysTick counting down from 2^24 - 1 with no interrupt, so
//! [`init`] can tell how long the start-up (RAM zeroed, `.data` copied, the stack painted)
//! took, in counts.
//!
//! Cost: one interrupt a millisecond of emulated time (a few dozen instructions, more when a
//! timer is due); a timer wakes at the first period boundary at or after its instant, so
//! every wait is rounded up to the next millisecond.

use core::cell::{Cell, RefCell};
use core::task::Waker;
use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

/// SysTick counts a millisecond: 25,000 counts of the 25 MHz processor clock.
const COUNTS_PER_PERIOD: u32 = 25_000;
/// Counts per embassy tick (1 MHz).
const COUNTS_PER_TICK: u64 = 25;

/// SysTick's registers (only the counter and the pending flag are read after `init`).
const SYST_CVR: *const u32 = 0xE000_E018 as *const u32;
/// The interrupt control and state register: bit 26, PENDSTSET, a SysTick exception pending.
const SCB_ICSR: *const u32 = 0xE000_ED04 as *const u32;
const PENDSTSET: u32 = 1 << 26;

/// The driver: the periods counted, the timer queue and the next alarm, under a critical
/// section.
struct SysTickDriver {
    periods: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
    alarm: Mutex<Cell<u64>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    periods: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
    alarm: Mutex::new(Cell::new(u64::MAX)),
});

impl SysTickDriver {
    fn now_in(&self, cs: CriticalSection<'_>) -> u64 {
        self.counts_in(cs) / COUNTS_PER_TICK
    }

    fn counts_in(&self, cs: CriticalSection<'_>) -> u64 {
        let periods = self.periods.borrow(cs).get();
        // SAFETY: SYST_CVR and SCB_ICSR are the core's always-mapped, word-aligned registers;
        // reading them has no side effect (CVR's COUNTFLAG is in CSR, not read here).
        let (first, pending, second) = unsafe {
            (
                core::ptr::read_volatile(SYST_CVR),
                core::ptr::read_volatile(SCB_ICSR) & PENDSTSET != 0,
                core::ptr::read_volatile(SYST_CVR),
            )
        };
        // A wrap the interrupt has not counted yet (we are in a critical section): the second
        // read is after it.
        let (periods, cvr) = if pending {
            (periods + 1, second)
        } else {
            (periods, first)
        };
        let into = u64::from(COUNTS_PER_PERIOD - 1 - cvr.min(COUNTS_PER_PERIOD - 1));
        periods * u64::from(COUNTS_PER_PERIOD) + into
    }

    /// Wakes what is due and sets the next alarm.
    fn service(&self, cs: CriticalSection<'_>) {
        let now = self.now_in(cs);
        let next = self.queue.borrow(cs).borrow_mut().next_expiration(now);
        self.alarm.borrow(cs).set(next);
    }
}

impl Driver for SysTickDriver {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.now_in(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            if self.queue.borrow(cs).borrow_mut().schedule_wake(at, waker) {
                self.service(cs);
            }
        });
    }
}

// SysTick from the reset handler on, before RAM is initialised (so no Rust: no stack frame
// may assume anything, no static may be touched): reload 2^24 - 1, counter cleared, processor
// clock, enabled, no interrupt.
core::arch::global_asm!(
    ".section .text.__pre_init,\"ax\"",
    ".global __pre_init",
    ".type __pre_init,%function",
    ".thumb_func",
    "__pre_init:",
    "ldr r0, =0xE000E010",
    "ldr r1, =0x00FFFFFF",
    "str r1, [r0, #4]",
    "movs r1, #0",
    "str r1, [r0, #8]",
    "movs r1, #5",
    "str r1, [r0]",
    "bx lr",
);

/// Counts of the start-up SysTick can hold before it wraps (2^24 - 1, 0.67 s).
const STARTUP_RELOAD: u32 = 0x00FF_FFFF;

/// Starts the time base: processor clock, a period a millisecond, its interrupt on. Returns
/// the SysTick counts since the reset handler began (the start-up before `main`).
pub fn init(mut syst: SYST) -> u32 {
    // SAFETY: as in `now_in`.
    let startup = STARTUP_RELOAD - unsafe { core::ptr::read_volatile(SYST_CVR) };
    syst.disable_counter();
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(COUNTS_PER_PERIOD - 1);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    startup
}

/// SysTick counts (40 ns each) since [`init`]: the emulated time, finer than embassy's
/// ticks.
pub fn now_counts() -> u64 {
    critical_section::with(|cs| DRIVER.counts_in(cs))
}

/// The SysTick exception: one more period, and the timers that are due woken.
#[cortex_m_rt::exception]
fn SysTick() {
    critical_section::with(|cs| {
        let periods = DRIVER.periods.borrow(cs);
        periods.set(periods.get() + 1);
        if DRIVER.now_in(cs) >= DRIVER.alarm.borrow(cs).get() {
            DRIVER.service(cs);
        }
    });
}

/// SysTick counts the executor spent polling tasks (from `poll_start` to `executor_idle`,
/// embassy-executor's trace hooks): the counts in which instructions ran. The rest of the
/// emulated time the core slept (WFE) and QEMU moved the clock to the next interrupt, which
/// costs no instruction; the interrupts themselves (SysTick's, a few dozen instructions a
/// millisecond) are counted only when they fall in a busy interval.
static BUSY: Mutex<Cell<(u64, u64)>> = Mutex::new(Cell::new((0, 0)));

/// Busy SysTick counts since [`init`] (see [`BUSY`]).
pub fn busy_counts() -> u64 {
    critical_section::with(|cs| {
        let (busy, since) = BUSY.borrow(cs).get();
        // Called from a task: the current busy interval runs from `since` to now.
        busy + DRIVER.counts_in(cs).saturating_sub(since)
    })
}

#[unsafe(no_mangle)]
fn _embassy_trace_poll_start(_executor_id: u32) {
    critical_section::with(|cs| {
        let (busy, _) = BUSY.borrow(cs).get();
        BUSY.borrow(cs).set((busy, DRIVER.counts_in(cs)));
    });
}

#[unsafe(no_mangle)]
fn _embassy_trace_executor_idle(_executor_id: u32) {
    critical_section::with(|cs| {
        let (busy, since) = BUSY.borrow(cs).get();
        let now = DRIVER.counts_in(cs);
        BUSY.borrow(cs).set((busy + now.saturating_sub(since), now));
    });
}

#[unsafe(no_mangle)]
fn _embassy_trace_task_new(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_end(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_exec_begin(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_exec_end(_executor_id: u32, _task_id: u32) {}

#[unsafe(no_mangle)]
fn _embassy_trace_task_ready_begin(_executor_id: u32, _task_id: u32) {}
