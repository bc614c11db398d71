//! The MCU's internal temperature sensor (ADC3, channel 18) as a [`Thermometer`]: the
//! fallback of the CCD board's sensor (`startrack_core::safe::FallbackThermometer`).
//!
//! It measures the die, not the CCD (see the core's fallback for what that means). A reading
//! is one blocking 16-bit conversion with the sensor's long sample time (~17 us at the ADC's
//! clock) at each frame start; the two factory calibration points (TS_CAL1 at 30 degC,
//! TS_CAL2 at 110 degC, 16-bit counts at 3.3 V, in system memory) give the line
//! `t = 30 + (raw - cal1) * 80 / (cal2 - cal1)` degC. A calibration pair that makes no line
//! (cal2 <= cal1) gives no reading.

use embassy_stm32::Peri;
use embassy_stm32::adc::{Adc, SampleTime, Temperature};
use embassy_stm32::peripherals::ADC3;
use startrack_core::tracker::Thermometer;
use startrack_core::units::Kelvin;

/// TS_CAL1: the sensor's count at 30 degC (RM0433 / DS12110, STM32H743 revision V).
const TS_CAL1_ADDR: usize = 0x1FF1_E820;
/// TS_CAL2: the sensor's count at 110 degC.
const TS_CAL2_ADDR: usize = 0x1FF1_E840;

/// The MCU sensor.
pub struct McuThermometer {
    adc: Adc<'static, ADC3>,
    channel: Temperature,
    cal1: u16,
    cal2: u16,
}

impl McuThermometer {
    /// Powers ADC3 and the sensor, reads the calibration points.
    pub fn new(adc3: Peri<'static, ADC3>) -> Self {
        let adc = Adc::new(adc3);
        let channel = adc.enable_temperature();
        // SAFETY: the two addresses are the factory calibration words in the read-only
        // system memory of every STM32H743 (always mapped, 2-byte aligned).
        let (cal1, cal2) = unsafe {
            (
                core::ptr::read_volatile(core::ptr::with_exposed_provenance::<u16>(TS_CAL1_ADDR)),
                core::ptr::read_volatile(core::ptr::with_exposed_provenance::<u16>(TS_CAL2_ADDR)),
            )
        };
        Self {
            adc,
            channel,
            cal1,
            cal2,
        }
    }
}

impl Thermometer for McuThermometer {
    fn sensor_temperature_k(&mut self) -> Option<Kelvin> {
        let raw = self
            .adc
            .blocking_read(&mut self.channel, SampleTime::CYCLES810_5);
        let span = i32::from(self.cal2) - i32::from(self.cal1);
        if span <= 0 {
            return None;
        }
        // Millikelvin: 273150 + 30000 + (raw - cal1) * 80000 / span, in i64 (no overflow).
        let mk = 303_150i64 + (i64::from(raw) - i64::from(self.cal1)) * 80_000 / i64::from(span);
        // U16F16 bits: mK x 2^16 / 1000 (a reading past 65535 K or below 0 is no reading).
        let bits = u32::try_from(mk.checked_mul(1 << 16)? / 1000).ok()?;
        Some(Kelvin::from_bits(bits))
    }
}
