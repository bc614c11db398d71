//! Safe states on any board: the fault record kept over a reset (the reset cause is the
//! board's `reset_cause`), the housekeeping the link will report, and the standby a set-up
//! failure falls back to.
//!
//! - The fault record ([`startrack_core::safe::FaultRecord`], 32 bytes) lives in
//!   cortex-m-rt's `.uninit` section (AXI SRAM, after `.bss`), which the start-up code
//!   neither zeroes nor initialises: it survives a watchdog or software reset. After
//!   power-on it holds whatever the SRAM powers up with, which the record's magic and CRC
//!   turn into a fresh record. It is written whole, 32-byte aligned (whole 64-bit ECC words
//!   of the AXI SRAM, so no read-modify-write of a never-written ECC word).
//! - [`HEALTH`] is the core's [`Health`]: set-up's fields, then the frame cycle's after every
//!   frame (the tracker task publishes it).
//! - [`standby_forever`] is where a set-up failure ends up (through [`enter_standby`] and
//!   [`standby_task`]): no frame processing, the watchdog fed, housekeeping logged, and the
//!   link served with no tracker ([`crate::link::serve_standby`]): ping, housekeeping with the
//!   set-up faults, tables and reset answered; mode and configuration commands refused with
//!   their own reason.

use crate::watchdog;
use core::cell::Cell;
use core::mem::MaybeUninit;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Timer};
use startrack_core::safe::{FAULT_RECORD_WORDS, FaultRecord, Health, SetupFaults};

/// The record's RAM image, aligned to a 32-byte line.
#[repr(C, align(32))]
struct RecordWords([u32; FAULT_RECORD_WORDS]);

/// The fault record's RAM, kept over a reset (not zeroed at start-up).
#[unsafe(link_section = ".uninit.FAULT_RECORD")]
static mut FAULT_RAM: MaybeUninit<RecordWords> = MaybeUninit::uninit();

/// Loads the record (fresh if the RAM does not hold one); `true` when one was kept.
pub fn load_record() -> (FaultRecord, bool) {
    // SAFETY: FAULT_RAM is only touched here and in `store_record`, both called from the
    // single start-up path in `main` (no task or interrupt uses it), so there is no
    // concurrent access. Reading it as plain `u32`s is defined whatever the bits are: every
    // bit pattern is a valid `u32`, and the RAM exists (it is a static of that size);
    // `read_volatile` keeps the compiler from assuming anything about uninitialised memory.
    let words = unsafe {
        core::ptr::read_volatile(core::ptr::addr_of!(FAULT_RAM).cast::<[u32; FAULT_RECORD_WORDS]>())
    };
    FaultRecord::from_words(&words)
}

/// Writes the record back (whole, sealed with its CRC).
pub fn store_record(record: &FaultRecord) {
    let words = RecordWords(record.to_words());
    // SAFETY: as in `load_record`: single start-up path, no concurrent access; the write
    // covers the whole static with a valid value.
    unsafe {
        core::ptr::write_volatile(
            core::ptr::addr_of_mut!(FAULT_RAM).cast::<RecordWords>(),
            words,
        );
    }
}

/// Housekeeping, shared by the tasks (copied in and out under a critical section).
pub static HEALTH: Mutex<CriticalSectionRawMutex, Cell<Health>> = Mutex::new(Cell::new(
    Health::new(FaultRecord::FRESH, SetupFaults::empty()),
));

/// Changes the housekeeping record.
pub fn update_health(f: impl FnOnce(&mut Health)) {
    HEALTH.lock(|cell| {
        let mut h = cell.get();
        f(&mut h);
        h.uptime_ms = Instant::now().as_millis();
        cell.set(h);
    });
}

/// Housekeeping now.
pub fn health() -> Health {
    HEALTH.lock(Cell::get)
}

/// Publishes the frame cycle's housekeeping (the tracker task, after every frame).
pub fn set_health(health: &Health) {
    HEALTH.lock(|cell| cell.set(*health));
}

/// How often standby logs housekeeping.
const STANDBY_LOG_EVERY: Duration = Duration::from_secs(10);

/// How often standby serves the link.
const STANDBY_SERVE_EVERY: Duration = Duration::from_millis(50);

/// The safe standby after a set-up failure: no frame processing; every 50 ms the link is
/// served (if the tracker task does not hold it) and the watchdog's progress marked (the loop
/// is alive); every 10 s housekeeping is logged.
pub async fn standby_forever(faults: SetupFaults) -> ! {
    update_health(|h| h.setup_faults |= faults);
    defmt::error!("safe standby: set-up faults {}", faults);
    let mut link = crate::link::standby_service(faults);
    let mut held = crate::flash_store::HeldTables::new();
    let per_log = STANDBY_LOG_EVERY.as_ticks() / STANDBY_SERVE_EVERY.as_ticks().max(1);
    let mut ticks = 0u64;
    loop {
        Timer::after(STANDBY_SERVE_EVERY).await;
        if let Some(link) = link.as_deref_mut() {
            crate::link::serve_standby(link, &mut held).await;
        }
        watchdog::progress();
        ticks = ticks.wrapping_add(1);
        if ticks.is_multiple_of(per_log.max(1)) {
            update_health(|_| {});
            let h = HEALTH.lock(Cell::get);
            defmt::warn!(
                "standby housekeeping: set-up faults {}, record {}, {} frames, uptime {=u64} ms, {=f32} K",
                h.setup_faults,
                h.record,
                h.frames,
                h.uptime_ms,
                h.temperature_k.map_or(f32::NAN, |t| t.to_num::<f32>())
            );
        }
    }
}

/// The request to enter the safe standby, with the faults that caused it.
static STANDBY: Signal<CriticalSectionRawMutex, SetupFaults> = Signal::new();

/// Asks for the safe standby (from set-up, or from a task that cannot go on).
pub fn enter_standby(faults: SetupFaults) {
    STANDBY.signal(faults);
}

/// The safe standby's task, spawned at start-up: waits (costing nothing) until
/// [`enter_standby`] is called, then runs [`standby_forever`].
#[embassy_executor::task]
pub async fn standby_task() {
    let faults = STANDBY.wait().await;
    standby_forever(faults).await
}
