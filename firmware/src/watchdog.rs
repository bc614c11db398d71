//! The board's watchdog (IWDG1 on the STM32H743, the CMSDK watchdog on `mps2-an500`), fed by the frame loop's progress: a frame loop that
//! stops (a hung DMA, a deadlock, a runaway task) resets the MCU within [`TIMEOUT_US`], and
//! the reset is counted in the fault record ([`crate::safe_state`]).
//!
//! The tracker task calls [`progress`] after every frame (the safe-standby loop does once a
//! second); [`watchdog_task`] checks every [`CHECK_PERIOD`] and feeds the IWDG only if
//! progress was made since the last feed. A frame takes its exposure (frame transfers are
//! the exposure apart, never closer than a full readout: docs/sequencer.md), so at the
//! start-up exposure the 8 s timeout spans several frames; an upload's sector erase (async, 1-2 s) does
//! not stall the frame loop, so it never trips the watchdog. The IWDG runs from the LSI
//! (32 kHz) and cannot be stopped once started: a debugger that halts the core must freeze
//! it (DBGMCU), or the board resets under the probe.

use crate::board::{Watchdog, WatchdogPort};
use core::sync::atomic::{AtomicU32, Ordering};
use embassy_time::{Duration, Timer};

/// The watchdog's timeout, us.
pub const TIMEOUT_US: u32 = 8_000_000;
/// How often the watchdog task looks at the progress counter.
pub const CHECK_PERIOD: Duration = Duration::from_secs(1);

/// Frames (or standby ticks) completed since start-up.
static PROGRESS: AtomicU32 = AtomicU32::new(0);

/// Marks one unit of progress of the frame loop (or the safe-standby loop).
pub fn progress() {
    PROGRESS.fetch_add(1, Ordering::Relaxed);
}

/// Starts the watchdog and feeds it while the progress counter moves.
#[embassy_executor::task]
pub async fn watchdog_task(mut wdg: Watchdog) {
    wdg.unleash();
    let mut fed_at = PROGRESS.load(Ordering::Relaxed);
    loop {
        Timer::after(CHECK_PERIOD).await;
        let now = PROGRESS.load(Ordering::Relaxed);
        if now != fed_at {
            wdg.pet();
            fed_at = now;
        }
    }
}
