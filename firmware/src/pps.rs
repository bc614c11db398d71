//! The sync pulse as the application takes it: the board's capture of the spacecraft's PPS
//! line pushes each edge, as the tracker clock's microsecond at the edge, into [`PULSES`]
//! (on the STM32H743 TIM5's input capture, `board::stm32h743::pps`; the emulated board has
//! no PPS line, so its reports say their time is not synchronised). The tracker task takes
//! them between frames ([`BoardPulses`], the core's [`SyncPulse`] port) before it serves the
//! link, so a time-set command applies to a pulse after it.
//!
//! Cost: a queue push a second; 4 pulses of queue (40 B).

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel as Queue;
use startrack_core::time::SyncPulse;

/// The pulses captured and not yet taken: the tracker clock's us at each edge.
pub static PULSES: Queue<CriticalSectionRawMutex, u64, 4> = Queue::new();

/// The captured pulses as the core's sync pulse port.
pub struct BoardPulses;

impl SyncPulse for BoardPulses {
    fn take_pulse(&mut self) -> Option<u64> {
        PULSES.try_receive().ok()
    }
}
