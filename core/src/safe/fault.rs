//! The fault record: counters that survive a reset, in a RAM section the start-up code does
//! not clear, sealed with a CRC so that the random contents of RAM after power-on read as a
//! fresh record rather than as counts.
//!
//! RAM image: [`FAULT_RECORD_WORDS`] little-endian `u32` words
//!
//! ```text
//! word 0  magic 0x53544652 ("STFR")
//! word 1  boots since the record was fresh
//! word 2  resets by the watchdog
//! word 3  boots that had a set-up fault
//! word 4  the set-up faults of the last boot that had any (SetupFaults bits)
//! word 5  bits 0-7 the last reset's cause code, bits 8-15 the record version (1)
//! word 6  reserved, 0
//! word 7  CRC-32/ISO-HDLC of words 0-6 (28 bytes, little-endian)
//! ```
//!
//! Cost: one CRC over 28 bytes per load and per store. The firmware owns the memory (the
//! core forbids `unsafe`); it hands the words in and takes them back.

/// Words in the record's RAM image.
pub const FAULT_RECORD_WORDS: usize = 8;
/// The record's first word.
pub(crate) const FAULT_MAGIC: u32 = 0x5354_4652;
/// The record layout version (word 5, bits 8-15).
pub(crate) const FAULT_VERSION: u32 = 1;

const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

bitflags::bitflags! {
    /// Set-up steps that failed at a boot. Any of them puts the tracker in standby (or
    /// without a table: no star processing) with the link answering. Bit numbers are stable:
    /// housekeeping and the fault record carry them as a `u32`.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct SetupFaults: u32 {
        /// The line buffers could not be set up.
        const LINE_BUFFERS = 1 << 0;
        /// The tracker's buffers were already taken.
        const TRACKER_BUFFERS = 1 << 1;
        /// The tracker refused its configuration.
        const TRACKER_CONFIG = 1 << 2;
        /// The table store could not mount (its layout does not fit the flash).
        const FLASH_STORE = 1 << 3;
        /// No valid calibration table in flash.
        const NO_TABLE = 1 << 4;
        /// The calibration table in force is for another readout geometry.
        const TABLE_GEOMETRY = 1 << 5;
        /// The CCD board's temperature sensor does not answer (the MCU's is used).
        const EXTERNAL_THERMOMETER = 1 << 6;
        /// A task could not be spawned.
        const TASK_SPAWN = 1 << 7;
        /// The sensor readout (SPI, DMA) could not be set up.
        const READOUT = 1 << 8;
        /// No valid star catalog in its flash region (the tracker runs without attitude).
        const NO_CATALOG = 1 << 9;
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for SetupFaults {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "SetupFaults({=u32:#x})", self.bits());
    }
}

/// Why the MCU last reset (from its reset status register).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// Power-on or brown-out.
    PowerOn,
    /// The independent watchdog expired.
    Watchdog,
    /// A software reset (a commanded reset).
    Software,
    /// The reset pin.
    Pin,
    /// Anything else, or not known.
    Other,
}

impl ResetCause {
    /// The code in the record (word 5).
    pub(crate) const fn code(self) -> u8 {
        match self {
            Self::PowerOn => 1,
            Self::Watchdog => 2,
            Self::Software => 3,
            Self::Pin => 4,
            Self::Other => 5,
        }
    }

    /// The cause of a code, `None` for an unknown one.
    pub(crate) const fn from_code(code: u8) -> Option<Self> {
        match code {
            1 => Some(Self::PowerOn),
            2 => Some(Self::Watchdog),
            3 => Some(Self::Software),
            4 => Some(Self::Pin),
            5 => Some(Self::Other),
            _ => None,
        }
    }
}

/// The counters kept across resets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultRecord {
    /// Boots since the record was fresh (the first boot after power-on is 1).
    pub boots: u32,
    /// Resets by the watchdog.
    pub watchdog_resets: u32,
    /// Boots that had at least one set-up fault.
    pub setup_failure_boots: u32,
    /// The set-up faults of the last boot that had any.
    pub last_setup_faults: SetupFaults,
    /// The cause of the last reset (`None` before the first boot is recorded).
    pub last_reset: Option<ResetCause>,
}

impl FaultRecord {
    /// A record with nothing counted.
    pub const FRESH: Self = Self {
        boots: 0,
        watchdog_resets: 0,
        setup_failure_boots: 0,
        last_setup_faults: SetupFaults::empty(),
        last_reset: None,
    };

    /// Reads the RAM image: the record it holds, or [`Self::FRESH`] (and `false`) when the
    /// magic, version, cause code or CRC do not check (RAM after power-on, or a record
    /// overwritten by a runaway write).
    pub fn from_words(words: &[u32; FAULT_RECORD_WORDS]) -> (Self, bool) {
        let [magic, boots, wd, sf, last, meta, _reserved, crc] = *words;
        let cause = ResetCause::from_code((meta & 0xFF) as u8);
        let ok = magic == FAULT_MAGIC
            && (meta >> 8) & 0xFF == FAULT_VERSION
            && meta >> 16 == 0
            && crc == words_crc(words)
            && (cause.is_some() || meta & 0xFF == 0);
        if !ok {
            return (Self::FRESH, false);
        }
        (
            Self {
                boots,
                watchdog_resets: wd,
                setup_failure_boots: sf,
                last_setup_faults: SetupFaults::from_bits_retain(last),
                last_reset: cause,
            },
            true,
        )
    }

    /// The RAM image of the record, CRC sealed.
    pub fn to_words(&self) -> [u32; FAULT_RECORD_WORDS] {
        let cause = self.last_reset.map_or(0, |c| u32::from(c.code()));
        let mut w = [
            FAULT_MAGIC,
            self.boots,
            self.watchdog_resets,
            self.setup_failure_boots,
            self.last_setup_faults.bits(),
            cause | (FAULT_VERSION << 8),
            0,
            0,
        ];
        w[FAULT_RECORD_WORDS - 1] = words_crc(&w);
        w
    }

    /// Counts a boot and its reset cause.
    pub fn on_boot(&mut self, cause: ResetCause) {
        self.boots = self.boots.saturating_add(1);
        if cause == ResetCause::Watchdog {
            self.watchdog_resets = self.watchdog_resets.saturating_add(1);
        }
        self.last_reset = Some(cause);
    }

    /// Records the set-up faults of this boot (call once, when set-up is over; nothing is
    /// counted when there are none).
    pub fn on_setup_done(&mut self, faults: SetupFaults) {
        if !faults.is_empty() {
            self.setup_failure_boots = self.setup_failure_boots.saturating_add(1);
            self.last_setup_faults = faults;
        }
    }
}

/// CRC of words 0-6.
fn words_crc(words: &[u32; FAULT_RECORD_WORDS]) -> u32 {
    let mut digest = CRC.digest();
    for w in words.iter().take(FAULT_RECORD_WORDS - 1) {
        digest.update(&w.to_le_bytes());
    }
    digest.finalize()
}
