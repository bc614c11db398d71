//! The thread-mode executor on `mps2-an500`: embassy's raw executor polled in a loop that
//! sleeps with WFI until an interrupt or a wake from a task. Embassy's own Cortex-M executor
//! sleeps with WFE, which QEMU executes as a no-op: the loop would spin through the idle time
//! (the exposures), polling the run queue hundreds of millions of times, and the time the
//! executor is busy ([`super::time::busy_counts`]) would include it. QEMU models WFI as a
//! sleep, and under `-icount ... sleep=off` jumps its clock to the next interrupt, so an idle
//! millisecond costs no instruction and no host time.

use core::sync::atomic::{AtomicBool, Ordering};
use embassy_executor::{Spawner, raw};

/// Work was signalled since the last poll.
static WORK: AtomicBool = AtomicBool::new(true);

/// embassy's pender: a task or an interrupt woke a task of this executor.
#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    WORK.store(true, Ordering::Release);
}

/// The thread-mode executor.
pub struct Executor {
    inner: raw::Executor,
}

impl Executor {
    /// A new executor (one: it is the program's).
    pub fn new() -> Self {
        Self {
            inner: raw::Executor::new(core::ptr::null_mut()),
        }
    }

    /// Spawns with `init`, then polls whenever there is work and sleeps otherwise.
    pub fn run(&'static mut self, init: impl FnOnce(Spawner)) -> ! {
        init(self.inner.spawner());
        loop {
            // SAFETY: `poll` is called from thread mode only, on the executor's own thread,
            // never re-entrantly (this loop is the only caller).
            unsafe { self.inner.poll() };
            // With interrupts masked, a wake between the check and the WFI still ends the
            // WFI (the interrupt pends), and its handler runs once they are unmasked.
            cortex_m::interrupt::disable();
            if !WORK.swap(false, Ordering::AcqRel) {
                cortex_m::asm::wfi();
            }
            // SAFETY: re-enables what was disabled just above; no critical section spans
            // this point.
            unsafe { cortex_m::interrupt::enable() };
        }
    }
}
