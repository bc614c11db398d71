//! The board layer: everything the application (every other module of this crate: the
//! tasks, their bindings to the core's frame cycle, the link service loop, the table store's
//! rounds, the safe states) needs from the hardware, and the boards that provide it. One board
//! is built at a time, chosen by a cargo feature:
//!
//! | feature | board | module | built with |
//! |---|---|---|---|
//! | `board-stm32h743` (default) | the STM32H743ZI on a NUCLEO-H743ZI | `stm32h743` | `cargo fw` |
//! | `board-mps2-an500` | QEMU's `mps2-an500` (Cortex-M7), for processor-in-the-loop runs | `mps2_an500` | `cargo pil-fw` |
//!
//! A board module provides exactly these items, and the application uses nothing else of it
//! (the traits below are checked against them at compile time):
//!
//! | item | what the application does with it |
//! |---|---|
//! | `init() -> Parts` | first thing at start-up: clocks and peripherals |
//! | `Parts::watchdog: Watchdog` ([`WatchdogPort`]) | started and fed by [`crate::watchdog`] |
//! | `Parts::flash: Flash` ([`StoreFlash`]) | the table store's NOR flash ([`crate::flash_store`]), laid out as `STORE_LAYOUT` |
//! | `Parts::thermometer: Thermometer` (the core's `SourcedThermometer`), `Parts::thermometer_faults` | the frame's sensor temperature, and the set-up fault when the board's sensor is missing |
//! | `Parts::d2_ready: D2Ready` | the word that the second RAM (`.d2sram`, [`crate::d2_ram`]) is usable: on the STM32H743 its D2 SRAM clocked |
//! | `Parts::io: Io` | what `start_io` and `start_lines` need (board-private) |
//! | `reset_cause()` | why the MCU reset, for the fault record ([`crate::safe_state`]) |
//! | `CATALOG_ADDRESS`, `CATALOG_REGION_B` | where the star catalog lies, memory-mapped ([`crate::catalog`]) |
//! | `start_io(spawner, io) -> Io2` | the link's byte tasks (into [`crate::link::RX`], out of [`crate::link::TX`]), the PPS capture where the board has one (into [`crate::pps::PULSES`]) and the line buffers ([`crate::lines::init`]); set-up faults |
//! | `start_lines(spawner, lines) -> bool` | the tasks that turn each [`crate::lines::REQUESTS`] into lines on [`crate::lines::FILLED`] |
//! | `after_frame(&FrameOutcome, &[StarRecord], Option<Integration>)` | the board's own use of each frame's outcome, stars and integration (as its line source gave it), after the application's |
//! | `system_reset(ResetCause) -> !` | a commanded reset (the cause for a board that must note it itself) |
//!
//! Costs are each board's (its module says them).

use crate::lines::{BUFFERS, LineBuf};
use embedded_storage::nor_flash::NorFlash;
use startrack_core::safe::SetupFaults;

#[cfg(all(feature = "board-stm32h743", feature = "board-mps2-an500"))]
compile_error!("choose one board: `board-stm32h743` or `board-mps2-an500`");

#[cfg(feature = "board-stm32h743")]
pub mod stm32h743;
#[cfg(feature = "board-stm32h743")]
pub use stm32h743::*;

#[cfg(feature = "board-mps2-an500")]
pub mod mps2_an500;
#[cfg(feature = "board-mps2-an500")]
pub use mps2_an500::*;

/// What [`start_io`] set up: the line buffers, what the line tasks need, and the set-up
/// faults (a `None` comes with its fault).
pub struct Started<L> {
    /// The raw line buffers, for [`crate::lines::init`].
    pub line_buffers: Option<&'static mut [LineBuf; BUFFERS]>,
    /// What [`start_lines`] takes.
    pub lines: Option<L>,
    /// What failed.
    pub faults: SetupFaults,
}

/// A watchdog that resets the MCU unless it is fed.
pub trait WatchdogPort {
    /// Starts it (it cannot be stopped again).
    fn unleash(&mut self);
    /// Feeds it.
    fn pet(&mut self);
}

/// The table store's flash as the application uses it: a NOR flash (offsets from the store's
/// start) with an erase that lets the executor run meanwhile, and its bytes memory-mapped.
pub trait StoreFlash: NorFlash {
    /// Erases `from..to` (whole sectors), waiting without blocking the other tasks.
    fn erase_async(
        &mut self,
        from: u32,
        to: u32,
    ) -> impl core::future::Future<Output = Result<(), Self::Error>>;

    /// The bytes at `offset_b..offset_b + len_b`, read in place, or `None` outside the
    /// store. Only for a range the store has just programmed and read back whole (no torn
    /// unit in it), while the caller holds the flash exclusively.
    fn mapped(&self, offset_b: u32, len_b: u32) -> Option<&[u8]>;
}

/// The selected board's items have the traits the application needs.
const _: () = {
    fn watchdog<T: WatchdogPort>() {}
    fn flash<T: StoreFlash>() {}
    fn thermometer<T: startrack_core::cycle::SourcedThermometer>() {}
    #[allow(dead_code)]
    fn check() {
        watchdog::<Watchdog>();
        flash::<Flash>();
        thermometer::<Thermometer>();
    }
};
