//! The sensor temperature with a fallback: the CCD board's sensor first, the MCU's internal
//! sensor when the first gives no plausible reading, and nothing when neither does (the
//! tracker then uses the table's hot-pixel reference temperature and its frame summary says
//! so).
//!
//! The MCU sensor measures the die, not the CCD: it is a coarse stand-in (the board's
//! thermal design sets how far apart they are), used so that the hot-pixel law follows the
//! temperature trend rather than staying at the table's reference. Housekeeping reports
//! which source was used ([`FallbackThermometer::source`]). Cost: one or two sensor reads
//! per frame and a range check.

use crate::tracker::Thermometer;
use crate::units::Kelvin;

/// Readings outside this range are faults (a disconnected sensor reads 0 or full scale):
/// 150 K ..= 400 K, wider than any CCD47-20 operating point.
pub(crate) const PLAUSIBLE_K: (Kelvin, Kelvin) =
    (Kelvin::const_from_int(150), Kelvin::const_from_int(400));

/// The CCD board's sensor as this design specifies it: a TI TMP117 (I2C, +-0.1 degC from
/// -20 to 50 degC, 16-bit result) bonded to the CCD's package, read over I2C once a frame.
/// Its register formats, so the conversion is tested on the host; the bus transfer is the
/// board's (`firmware/src/board/stm32h743/board_temp.rs`).
pub mod tmp117 {
    use crate::units::Kelvin;

    /// The result register (signed 16-bit, 7.8125 mdegC a count).
    pub const REG_TEMP_RESULT: u8 = 0x00;
    /// The device-id register; `DEVICE_ID` in its low 12 bits.
    pub const REG_DEVICE_ID: u8 = 0x0F;
    /// The TMP117's device id.
    pub(crate) const DEVICE_ID: u16 = 0x0117;
    /// What the result register holds after reset until the first conversion ends
    /// (-256 degC): no reading.
    pub const RESET_VALUE: u16 = 0x8000;

    /// 273.15 K as U16F16 bits (273.15 x 65536, rounded).
    const ZERO_CELSIUS_BITS: i64 = 17_901_158;

    /// The temperature of a result-register word (big-endian on the bus), or `None` for the
    /// reset value. Every word converts without overflow: counts of 1/128 degC are 512
    /// U16F16 bits, so -32,767 .. 32,767 counts give 1.1 M .. 34.7 M bits (8 .. 529 K), inside
    /// the format's 0 .. 65,536 K. Range checks against the CCD's are the caller's
    /// (`PLAUSIBLE_K`).
    pub fn kelvin(raw: u16) -> Option<Kelvin> {
        if raw == RESET_VALUE {
            return None;
        }
        let counts = i64::from(i16::from_ne_bytes(raw.to_ne_bytes()));
        let bits = u32::try_from(ZERO_CELSIUS_BITS + counts * 512).ok()?;
        Some(Kelvin::from_bits(bits))
    }

    /// Whether a device-id word names a TMP117 (the top 4 bits are its revision).
    pub fn is_tmp117(id: u16) -> bool {
        id & 0x0FFF == DEVICE_ID
    }
}

/// Where the last reading came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ThermoSource {
    /// The CCD board's sensor.
    External,
    /// The MCU's internal sensor (the external one failed).
    Mcu,
    /// Neither gave a plausible reading.
    None,
}

/// Two thermometers in order of preference, itself a [`Thermometer`].
#[derive(Clone, Copy, Debug)]
pub struct FallbackThermometer<E, M> {
    /// The CCD board's sensor.
    pub external: E,
    /// The MCU's sensor.
    pub mcu: M,
    source: ThermoSource,
    external_failures: u32,
    mcu_failures: u32,
}

impl<E: Thermometer, M: Thermometer> FallbackThermometer<E, M> {
    /// The chain, nothing read yet.
    pub const fn new(external: E, mcu: M) -> Self {
        Self {
            external,
            mcu,
            source: ThermoSource::None,
            external_failures: 0,
            mcu_failures: 0,
        }
    }

    /// Where the last reading came from.
    pub fn source(&self) -> ThermoSource {
        self.source
    }

    /// Readings the external sensor failed to give (absent or implausible).
    pub fn external_failures(&self) -> u32 {
        self.external_failures
    }

    /// Readings the MCU sensor failed to give, when it was asked.
    pub fn mcu_failures(&self) -> u32 {
        self.mcu_failures
    }
}

/// A reading inside [`PLAUSIBLE_K`].
fn plausible(t: Option<Kelvin>) -> Option<Kelvin> {
    t.filter(|k| (PLAUSIBLE_K.0..=PLAUSIBLE_K.1).contains(k))
}

impl<E: Thermometer, M: Thermometer> Thermometer for FallbackThermometer<E, M> {
    fn sensor_temperature_k(&mut self) -> Option<Kelvin> {
        let (reading, source) = match plausible(self.external.sensor_temperature_k()) {
            Some(k) => (Some(k), ThermoSource::External),
            None => {
                self.external_failures = self.external_failures.saturating_add(1);
                match plausible(self.mcu.sensor_temperature_k()) {
                    Some(k) => (Some(k), ThermoSource::Mcu),
                    None => {
                        self.mcu_failures = self.mcu_failures.saturating_add(1);
                        (None, ThermoSource::None)
                    }
                }
            }
        };
        self.source = source;
        reading
    }
}
