//! The spacecraft's PPS line on PA0 (TIM5_CH1, alternate function 2), captured by TIM5
//! channel 1 (a 32-bit timer at 1 MHz, rising edge). The capture holds the timer's count at
//! the edge, whatever the interrupt's latency; the task then reads TIM5's count and
//! embassy-time's `Instant` together and takes the edge's age from the first, so each pulse
//! goes to [`crate::pps::PULSES`] as the tracker clock's microsecond at its edge. Both
//! counters run from the same oscillator: the conversion adds the two reads' gap (under
//! 1 us) to the capture's 1 us resolution ([`startrack_core::time::PULSE_JITTER_US`]).
//!
//! HIL step (not run yet: no board has run the firmware): feed PA0 a 1 Hz, 3.3 V pulse from
//! a GPS receiver's PPS or a signal generator locked to a reference, send `startrack gse
//! time-set S` within the second after a pulse, and check that the attitude reports' time
//! advances by 1 s per pulse with `time_bound_us` at most 20 us, and that the counter's
//! rate the clock measures matches the board's crystal against the reference.
//!
//! Cost: one interrupt a second.

use crate::pps::PULSES;
use embassy_stm32::peripherals::TIM5;
use embassy_stm32::timer::Channel;
use embassy_stm32::timer::input_capture::InputCapture;

/// Captures the PPS edges on TIM5 channel 1 for ever.
#[embassy_executor::task]
pub async fn pps_task(mut capture: InputCapture<'static, TIM5>) {
    loop {
        let at: u32 = capture.wait_for_rising_edge(Channel::Ch1).await;
        let count: u32 = embassy_stm32::pac::TIM5.cnt().read();
        let now_us = embassy_time::Instant::now().as_micros();
        let age_us = u64::from(count.wrapping_sub(at));
        if PULSES.try_send(now_us.saturating_sub(age_us)).is_err() {
            defmt::warn!("pps: pulse queue full, a pulse is dropped");
        }
    }
}
