//! A mock of the STM32H743's internal NOR flash (one bank) that enforces its rules and cuts
//! the power on request, for the table store's tests and the software-in-the-loop.
//!
//! Rules enforced, as on the chip: erase per 128 KB sector sets 0xFF; programming per
//! 32-byte aligned unit, only into an erased unit (programming a unit twice between erases
//! is refused and recorded as a violation); a unit whose program or erase was cut reads as
//! an ECC error ([`FlashModelError::Ecc`], the chip's bus fault) or, as the worst case a
//! real ECC can miss, silently as garbage. Every unit program and every sector erase is a
//! *step*; [`MockFlash::cut_power`] makes step `n` the last (cut during it: the unit or
//! sector is left torn; cut after it: it completes), and every operation after that fails
//! with [`FlashModelError::PowerCut`] until [`MockFlash::power_on`] (a reboot).
//!
//! [`FileFlash`] keeps the same model in a file, so that a restart with the same file is a
//! reboot with the flash as the cut left it. Cost: one byte of state per 32-byte unit beside
//! the bytes; a 1 MB bank is a 1 MB + 32 KB file.

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use startrack_core::store::{EraseProgress, FlashStore, H743_BANK2, StoreError, TableKind};
use std::path::{Path, PathBuf};

/// Program unit, bytes (a 256-bit flash word).
pub const UNIT_B: usize = 32;
/// Erase unit, bytes (a sector).
pub const SECTOR_B: usize = 128 * 1024;
/// One STM32H743 bank, bytes.
pub const BANK_B: usize = 8 * SECTOR_B;

/// What a 32-byte unit holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnitState {
    /// Erased (reads 0xFF), programmable.
    Erased,
    /// Programmed once, completely.
    Written,
    /// Cut mid-program or mid-erase; its ECC fails, so a read is an error.
    Torn,
    /// Cut mid-program or mid-erase, but its ECC happens to pass: reads its garbage.
    TornSilent,
}

impl UnitState {
    const fn code(self) -> u8 {
        match self {
            Self::Erased => 0,
            Self::Written => 1,
            Self::Torn => 2,
            Self::TornSilent => 3,
        }
    }

    const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Self::Erased),
            1 => Some(Self::Written),
            2 => Some(Self::Torn),
            3 => Some(Self::TornSilent),
            _ => None,
        }
    }
}

/// When a power cut hits its step.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CutMode {
    /// During the step: the unit is left torn, the sector partly erased.
    During,
    /// Right after the step completed.
    After,
}

/// A refused or failed flash operation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashModelError {
    /// Offset or length not aligned to the unit the operation needs.
    NotAligned,
    /// Outside the device.
    OutOfBounds,
    /// A read touched a torn unit (the chip's ECC double-error bus fault).
    Ecc {
        /// Device offset of the unit.
        offset_b: u32,
    },
    /// Programming a unit that is not erased (refused; a rule violation).
    NotErased {
        /// Device offset of the unit.
        offset_b: u32,
    },
    /// The power is off (cut by [`MockFlash::cut_power`]).
    PowerCut,
}

impl NorFlashError for FlashModelError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::NotAligned => NorFlashErrorKind::NotAligned,
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The mock flash bank.
#[derive(Clone, Debug)]
pub struct MockFlash {
    bytes: Vec<u8>,
    units: Vec<UnitState>,
    steps: u64,
    cut: Option<(u64, CutMode)>,
    off: bool,
    violations: u64,
    rng: ChaCha8Rng,
}

impl MockFlash {
    /// An erased device of `capacity_b` bytes (a whole number of sectors); `seed` draws the
    /// garbage of torn units.
    pub fn new(capacity_b: usize, seed: u64) -> Self {
        let capacity_b = capacity_b.div_ceil(SECTOR_B) * SECTOR_B;
        Self {
            bytes: vec![0xFF; capacity_b],
            units: vec![UnitState::Erased; capacity_b / UNIT_B],
            steps: 0,
            cut: None,
            off: false,
            violations: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Steps (unit programs and sector erases) done since creation.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Rule violations attempted (programming a unit that is not erased).
    pub fn violations(&self) -> u64 {
        self.violations
    }

    /// Cuts the power at step number `step` (counted as [`Self::steps`] counts).
    pub fn cut_power(&mut self, step: u64, mode: CutMode) {
        self.cut = Some((step, mode));
    }

    /// Whether the power is off.
    pub fn is_off(&self) -> bool {
        self.off
    }

    /// Power back on (a reboot): the flash keeps what the cut left, no cut is pending.
    pub fn power_on(&mut self) {
        self.off = false;
        self.cut = None;
    }

    /// The whole device as memory-mapped bytes (what the chip's bus shows; torn units show
    /// their garbage here, so only read verified ranges through it).
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The state of the unit holding byte `offset_b`.
    pub fn unit_state(&self, offset_b: usize) -> Option<UnitState> {
        self.units.get(offset_b / UNIT_B).copied()
    }

    /// Overwrites bytes directly (a radiation upset or a test's corruption), bypassing the
    /// rules; the units touched are marked written (their ECC matches the new bytes).
    pub fn corrupt(&mut self, offset_b: usize, data: &[u8]) {
        for (i, &b) in data.iter().enumerate() {
            if let Some(x) = self.bytes.get_mut(offset_b + i) {
                *x = b;
            }
            if let Some(u) = self.units.get_mut((offset_b + i) / UNIT_B) {
                *u = UnitState::Written;
            }
        }
    }

    /// Marks the unit holding `offset_b` torn (a read of it fails).
    pub fn tear(&mut self, offset_b: usize) {
        if let Some(u) = self.units.get_mut(offset_b / UNIT_B) {
            *u = UnitState::Torn;
        }
    }

    /// One step: `Ok(true)` run it whole, `Ok(false)` cut during it, `Err` power is off.
    fn step(&mut self) -> Result<bool, FlashModelError> {
        if self.off {
            return Err(FlashModelError::PowerCut);
        }
        let n = self.steps;
        self.steps += 1;
        match self.cut {
            Some((at, mode)) if at == n => {
                self.off = true;
                Ok(mode == CutMode::After)
            }
            _ => Ok(true),
        }
    }

    fn torn_state(&mut self) -> UnitState {
        if self.rng.random_bool(0.5) {
            UnitState::Torn
        } else {
            UnitState::TornSilent
        }
    }

    fn check_range(&self, offset: u32, len: usize, align: usize) -> Result<usize, FlashModelError> {
        let start = offset as usize;
        if !start.is_multiple_of(align) || !len.is_multiple_of(align) {
            return Err(FlashModelError::NotAligned);
        }
        if start
            .checked_add(len)
            .is_none_or(|end| end > self.bytes.len())
        {
            return Err(FlashModelError::OutOfBounds);
        }
        Ok(start)
    }

    /// Serialises the whole state: magic, capacity, one state byte per unit, the bytes.
    fn to_file_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(12 + self.units.len() + self.bytes.len());
        out.extend_from_slice(FILE_MAGIC);
        out.extend_from_slice(&(self.bytes.len() as u32).to_le_bytes());
        out.extend(self.units.iter().map(|u| u.code()));
        out.extend_from_slice(&self.bytes);
        out
    }

    fn from_file_bytes(b: &[u8], seed: u64) -> Option<Self> {
        let magic = b.get(..8)?;
        if magic != FILE_MAGIC {
            return None;
        }
        let cap = u32::from_le_bytes(b.get(8..12)?.try_into().ok()?) as usize;
        if !cap.is_multiple_of(SECTOR_B) {
            return None;
        }
        let n_units = cap / UNIT_B;
        let units = b
            .get(12..12 + n_units)?
            .iter()
            .map(|&c| UnitState::from_code(c))
            .collect::<Option<Vec<_>>>()?;
        let bytes = b.get(12 + n_units..12 + n_units + cap)?.to_vec();
        if b.len() != 12 + n_units + cap {
            return None;
        }
        let mut flash = Self::new(cap, seed);
        flash.units = units;
        flash.bytes = bytes;
        Some(flash)
    }
}

const FILE_MAGIC: &[u8; 8] = b"STFLASH1";

impl ErrorType for MockFlash {
    type Error = FlashModelError;
}

impl ReadNorFlash for MockFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), FlashModelError> {
        if self.off {
            return Err(FlashModelError::PowerCut);
        }
        let start = self.check_range(offset, bytes.len(), 1)?;
        if !bytes.is_empty() {
            for unit in start / UNIT_B..=(start + bytes.len() - 1) / UNIT_B {
                if self.units.get(unit) == Some(&UnitState::Torn) {
                    return Err(FlashModelError::Ecc {
                        offset_b: (unit * UNIT_B) as u32,
                    });
                }
            }
        }
        bytes.copy_from_slice(&self.bytes[start..start + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.bytes.len()
    }
}

impl NorFlash for MockFlash {
    const WRITE_SIZE: usize = UNIT_B;
    const ERASE_SIZE: usize = SECTOR_B;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), FlashModelError> {
        if to < from {
            return Err(FlashModelError::OutOfBounds);
        }
        let start = self.check_range(from, (to - from) as usize, SECTOR_B)?;
        for sector in (start..to as usize).step_by(SECTOR_B) {
            let whole = self.step()?;
            for unit in sector / UNIT_B..(sector + SECTOR_B) / UNIT_B {
                // A cut erase leaves each unit erased, untouched or torn.
                let state = if whole {
                    UnitState::Erased
                } else {
                    match self.rng.random_range(0..3u8) {
                        0 => UnitState::Erased,
                        1 => self.units[unit],
                        _ => self.torn_state(),
                    }
                };
                let bytes = &mut self.bytes[unit * UNIT_B..(unit + 1) * UNIT_B];
                match state {
                    UnitState::Erased => bytes.fill(0xFF),
                    UnitState::Torn | UnitState::TornSilent => {
                        for b in bytes.iter_mut() {
                            *b |= self.rng.random::<u8>();
                        }
                    }
                    UnitState::Written => {}
                }
                self.units[unit] = state;
            }
            if !whole {
                return Err(FlashModelError::PowerCut);
            }
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), FlashModelError> {
        let start = self.check_range(offset, bytes.len(), UNIT_B)?;
        for (i, unit_bytes) in bytes.chunks(UNIT_B).enumerate() {
            let unit = start / UNIT_B + i;
            if self.units[unit] != UnitState::Erased {
                if self.off {
                    return Err(FlashModelError::PowerCut);
                }
                self.violations += 1;
                return Err(FlashModelError::NotErased {
                    offset_b: (unit * UNIT_B) as u32,
                });
            }
            let whole = self.step()?;
            let dst = &mut self.bytes[unit * UNIT_B..(unit + 1) * UNIT_B];
            if whole {
                dst.copy_from_slice(unit_bytes);
                self.units[unit] = UnitState::Written;
            } else {
                // Programming clears bits: a cut leaves some of the new zeros in place.
                let keep = self.rng.random_range(0..UNIT_B);
                for (k, (d, &s)) in dst.iter_mut().zip(unit_bytes).enumerate() {
                    if k < keep {
                        *d &= s;
                    }
                }
                self.units[unit] = self.torn_state();
                return Err(FlashModelError::PowerCut);
            }
        }
        Ok(())
    }
}

/// A [`MockFlash`] kept in a file: [`FileFlash::open`] loads it (or makes an erased bank),
/// [`FileFlash::save`] writes it back.
#[derive(Debug)]
pub struct FileFlash {
    path: PathBuf,
    /// The flash model (use it as the store's device).
    pub flash: MockFlash,
}

impl FileFlash {
    /// Opens `path`: the flash it holds, or an erased STM32H743 bank when the file does not
    /// exist. A file that is not a flash image is an error, never silently replaced.
    pub fn open(path: &Path) -> std::io::Result<Self> {
        let flash = match std::fs::read(path) {
            Ok(b) => MockFlash::from_file_bytes(&b, 1).ok_or_else(|| {
                std::io::Error::new(
                    std::io::ErrorKind::InvalidData,
                    format!("{} is not a flash image", path.display()),
                )
            })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => MockFlash::new(BANK_B, 1),
            Err(e) => return Err(e),
        };
        Ok(Self {
            path: path.to_path_buf(),
            flash,
        })
    }

    /// Writes the flash's state to the file (atomically: a temporary file, then a rename).
    pub fn save(&self) -> std::io::Result<()> {
        let tmp = self.path.with_extension("tmp");
        std::fs::write(&tmp, self.flash.to_file_bytes())?;
        std::fs::rename(&tmp, &self.path)
    }
}

/// The bytes of a freshly erased bank 2 holding `table` as the only table of `kind`, in slot
/// 0 with sequence number 1, from the slot's start to the end of the table's last unit: the
/// image a board's bank 2 gets at bring-up (`probe-rs download --base-address` the slot's
/// bus address, e.g. 0x0810_0000 for the calibration table). Made by the store itself, over
/// the flash model, so it is exactly what an upload writes.
pub fn slot_image(kind: TableKind, table: &[u8]) -> Result<Vec<u8>, StoreError> {
    let crc = store_crc32(table);
    let mut store =
        FlashStore::mount(MockFlash::new(BANK_B, 0), H743_BANK2).map_err(|e| e.error)?;
    store.begin(kind, u32::try_from(table.len()).unwrap_or(u32::MAX), crc)?;
    while store.erase_step()? != EraseProgress::Done {}
    store.chunk(0, table)?;
    let info = store.commit()?;
    let slot = H743_BANK2.slots_of(kind)[usize::from(info.slot)];
    let end = info.data_offset_b as usize + table.len().div_ceil(UNIT_B) * UNIT_B;
    Ok(store.flash().bytes()[slot.offset_b as usize..end].to_vec())
}

/// The CRC-32 of table images (CRC-32/ISO-HDLC, zlib's): the store's, and the one a table
/// upload over the link carries.
pub const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// CRC-32/ISO-HDLC, the store's CRC.
fn store_crc32(b: &[u8]) -> u32 {
    CRC32.checksum(b)
}
