//! Safe states: what the tracker remembers about its faults across resets, what it reports
//! about its health, and where its sensor temperature comes from when a sensor fails.
//!
//! What it is for: a tracker in flight must never brick itself. A set-up failure puts it in
//! standby with the fault recorded and reported instead of stopping; resets (the watchdog's
//! among them) are counted in a record kept in RAM that survives a reset but reads as fresh
//! after power-on; housekeeping gathers mode, faults, counters, the table in force and the
//! uptime in one struct for the link. What it costs: a 32-byte RAM record (one CRC-32 per
//! boot and per update), a few counters per frame.
//!
//! - `fault.rs`: the reset-surviving [`FaultRecord`] and the set-up fault flags.
//! - `health.rs`: the [`Health`] housekeeping the link reports.
//! - `temperature.rs`: the [`FallbackThermometer`] (CCD-board sensor, else the MCU's) and
//!   the board sensor's registers ([`tmp117`]).
//!
//! The rules (which fault leads where) are in `docs/storage.md#safe-states`.

mod fault;
mod health;
mod temperature;

pub use fault::{FAULT_RECORD_WORDS, FaultRecord, ResetCause, SetupFaults};
pub use health::{Health, TableId};
pub use temperature::{FallbackThermometer, ThermoSource, tmp117};
