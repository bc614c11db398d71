//! The CCD board's temperature sensor: a TI TMP117 on I2C1 (PB8 SCL, PB9 SDA: the NUCLEO's
//! Arduino D15/D14), address 0x48 (ADD0 to ground), as a [`Thermometer`]: the first choice of
//! the core's `FallbackThermometer`, the MCU's sensor ([`super::mcu_temp`]) the second.
//!
//! A reading is one blocking register read (write the register pointer, read two bytes) at
//! each frame start: ~0.1 ms at 400 kHz, bounded by a 2 ms bus timeout so a missing or stuck
//! sensor costs at most that and gives no reading (the fallback then reads the MCU). The
//! sensor converts continuously (its default, 15.5 ms a conversion with 8 averages); the
//! word's conversion to kelvin is the core's (`startrack_core::safe::tmp117`),
//! tested on the host for every 16-bit word.

use embassy_stm32::Peri;
use embassy_stm32::i2c::{self, I2c};
use embassy_stm32::mode::Blocking;
use embassy_stm32::peripherals::{I2C1, PB8, PB9};
use embassy_stm32::time::Hertz;
use startrack_core::safe::tmp117;
use startrack_core::tracker::Thermometer;
use startrack_core::units::Kelvin;

/// The sensor's 7-bit I2C address (ADD0 tied to ground).
pub const ADDRESS: u8 = 0x48;

/// The TMP117 on the CCD board.
pub struct Tmp117 {
    bus: I2c<'static, Blocking, i2c::Master>,
}

impl Tmp117 {
    /// Sets up I2C1 at 400 kHz with a 2 ms timeout and checks the device id; `None` (a
    /// set-up fault: no board sensor) if no TMP117 answers.
    pub fn new(
        peri: Peri<'static, I2C1>,
        scl: Peri<'static, PB8>,
        sda: Peri<'static, PB9>,
    ) -> Option<Self> {
        let mut config = i2c::Config::default();
        config.frequency = Hertz::khz(400);
        config.timeout = embassy_time::Duration::from_millis(2);
        let mut sensor = Self {
            bus: I2c::new_blocking(peri, scl, sda, config),
        };
        match sensor.read_register(tmp117::REG_DEVICE_ID) {
            Some(id) if tmp117::is_tmp117(id) => Some(sensor),
            Some(id) => {
                defmt::warn!("board thermometer: device id {=u16:#x} is not a TMP117", id);
                None
            }
            None => {
                defmt::warn!("board thermometer: no answer at {=u8:#x}", ADDRESS);
                None
            }
        }
    }

    /// One 16-bit register (big-endian on the bus), or `None` on any bus error or timeout.
    fn read_register(&mut self, register: u8) -> Option<u16> {
        let mut word = [0u8; 2];
        self.bus
            .blocking_write_read(ADDRESS, &[register], &mut word)
            .ok()?;
        Some(u16::from_be_bytes(word))
    }
}

impl Thermometer for Tmp117 {
    fn sensor_temperature_k(&mut self) -> Option<Kelvin> {
        tmp117::kelvin(self.read_register(tmp117::REG_TEMP_RESULT)?)
    }
}

/// The board's sensor if set-up found it, else no reading (the fallback reads the MCU).
pub struct BoardSensor(pub Option<Tmp117>);

impl Thermometer for BoardSensor {
    fn sensor_temperature_k(&mut self) -> Option<Kelvin> {
        self.0.as_mut()?.sensor_temperature_k()
    }
}
