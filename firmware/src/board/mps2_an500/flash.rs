//! The table store's flash on `mps2-an500`: a RAM model of the STM32H743's bank 2 (1 MB,
//! eight 128 KB sectors, 32-byte program units) in the board's `STORE` region (QEMU's RAM at
//! 0x6000_0000), which the PIL loads with a bank image before boot. It keeps the H7's rules
//! that the core's store relies on: an erase is of whole sectors and sets 0xFF; a program is
//! of whole aligned units, only into an erased unit (a second program of a unit between two
//! erases is refused, as the H7's ECC would make it unreadable). Reads are plain loads (no
//! ECC to fault).
//!
//! Power cuts: every erase and program is also written through to the host's `pil-bank.bin`
//! (semihosting, which stops the emulated CPU until the host has written it), so the file is
//! the bank as it stands after each whole operation, and a QEMU killed at any instant leaves
//! it as a power cut between two flash operations would (a unit torn inside one is not
//! modelled here; the host's flash model and its tests cut inside units, docs/storage.md).
//! The next power-on loads that file (`startrack pil --keep-bank`).
//!
//! A unit counts as erased when it reads all 0xFF; one programmed since boot is marked in a
//! 4 KB bitmap, so that programming 0xFF words into it and then again is refused too.
//!
//! Cost: a program or erase is a RAM copy or fill (no 1-2 s sector erase: the emulated
//! erase is instant, so the upload's busy window is not exercised).

use crate::board::StoreFlash;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use startrack_core::store::{H743_BANK_B, H743_PROGRAM_UNIT_B, H743_SECTOR_B};

/// The region's address (memory map `STORE`).
pub const STORE_ADDRESS: usize = 0x6000_0000;

const UNITS: usize = (H743_BANK_B / H743_PROGRAM_UNIT_B) as usize;

/// The modelled bank.
pub struct RamBank {
    /// Units programmed since boot, a bit each.
    programmed: &'static mut [u32; UNITS / 32],
    /// The host's bank image, written through (none: the bank lives in RAM only).
    image: Option<semihosting::fs::File>,
}

/// Why an operation was refused.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum RamBankError {
    /// Outside the bank.
    OutOfBounds,
    /// Not aligned to the unit (program) or the sector (erase).
    NotAligned,
    /// A program into a unit not erased.
    NotErased {
        /// Offset of the unit, bytes from the bank's start.
        offset_b: u32,
    },
}

impl NorFlashError for RamBankError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            Self::NotAligned => NorFlashErrorKind::NotAligned,
            Self::NotErased { .. } => NorFlashErrorKind::Other,
        }
    }
}

impl RamBank {
    /// The bank, with its programmed-unit bitmap.
    pub fn new(programmed: &'static mut [u32; UNITS / 32]) -> Self {
        let image = semihosting::fs::File::options()
            .read(true)
            .write(true)
            .open(c"pil-bank.bin")
            .map_err(|_| defmt::warn!("pil: pil-bank.bin not writable: the bank is not kept"))
            .ok();
        Self { programmed, image }
    }

    /// Writes `start..end` of the bank to the host's image (the operation just done).
    fn write_through(&mut self, start: usize, end: usize) {
        use semihosting::io::{Seek, SeekFrom, Write};
        let Some(mut image) = self.image.take() else {
            return;
        };
        let written = match self.bytes().get(start..end) {
            Some(bytes) => image
                .seek(SeekFrom::Start(start as u64))
                .and_then(|_| image.write_all(bytes)),
            None => Ok(()),
        };
        match written {
            Ok(()) => self.image = Some(image),
            Err(_) => defmt::error!("pil: pil-bank.bin write failed: the bank is no longer kept"),
        }
    }

    fn bytes(&self) -> &[u8] {
        // SAFETY: the STORE region is 1 MB of RAM QEMU maps at STORE_ADDRESS (board memory
        // map), outside every linker section, and only this driver, which the store owns
        // exclusively, touches it.
        unsafe {
            core::slice::from_raw_parts(
                core::ptr::with_exposed_provenance::<u8>(STORE_ADDRESS),
                H743_BANK_B as usize,
            )
        }
    }

    fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: as in `bytes`; `&mut self` makes this the only reference.
        unsafe {
            core::slice::from_raw_parts_mut(
                core::ptr::with_exposed_provenance_mut::<u8>(STORE_ADDRESS),
                H743_BANK_B as usize,
            )
        }
    }

    fn range(offset: u32, len: usize, align: u32) -> Result<(usize, usize), RamBankError> {
        let end = (offset as usize)
            .checked_add(len)
            .filter(|&e| e <= H743_BANK_B as usize)
            .ok_or(RamBankError::OutOfBounds)?;
        if !offset.is_multiple_of(align) || !len.is_multiple_of(align as usize) {
            return Err(RamBankError::NotAligned);
        }
        Ok((offset as usize, end))
    }
}

impl ErrorType for RamBank {
    type Error = RamBankError;
}

impl ReadNorFlash for RamBank {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), RamBankError> {
        let (start, end) = Self::range(offset, bytes.len(), 1)?;
        bytes.copy_from_slice(
            self.bytes()
                .get(start..end)
                .ok_or(RamBankError::OutOfBounds)?,
        );
        Ok(())
    }

    fn capacity(&self) -> usize {
        H743_BANK_B as usize
    }
}

impl NorFlash for RamBank {
    const WRITE_SIZE: usize = H743_PROGRAM_UNIT_B as usize;
    const ERASE_SIZE: usize = H743_SECTOR_B as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), RamBankError> {
        let len = to.checked_sub(from).ok_or(RamBankError::OutOfBounds)?;
        let (start, end) = Self::range(from, len as usize, H743_SECTOR_B)?;
        self.bytes_mut()
            .get_mut(start..end)
            .ok_or(RamBankError::OutOfBounds)?
            .fill(0xFF);
        let unit = H743_PROGRAM_UNIT_B as usize;
        for u in start / unit..end / unit {
            if let Some(w) = self.programmed.get_mut(u / 32) {
                *w &= !(1 << (u % 32));
            }
        }
        self.write_through(start, end);
        Ok(())
    }

    fn write(&mut self, offset: u32, data: &[u8]) -> Result<(), RamBankError> {
        let (start, end) = Self::range(offset, data.len(), H743_PROGRAM_UNIT_B)?;
        let unit = H743_PROGRAM_UNIT_B as usize;
        // Every unit must be erased before any is programmed (the whole write or none).
        for u in start / unit..end / unit {
            let marked = self
                .programmed
                .get(u / 32)
                .is_some_and(|w| w & (1 << (u % 32)) != 0);
            let blank = self
                .bytes()
                .get(u * unit..(u + 1) * unit)
                .is_some_and(|b| b.iter().all(|&x| x == 0xFF));
            if marked || !blank {
                return Err(RamBankError::NotErased {
                    offset_b: (u * unit) as u32,
                });
            }
        }
        self.bytes_mut()
            .get_mut(start..end)
            .ok_or(RamBankError::OutOfBounds)?
            .copy_from_slice(data);
        for u in start / unit..end / unit {
            if let Some(w) = self.programmed.get_mut(u / 32) {
                *w |= 1 << (u % 32);
            }
        }
        self.write_through(start, end);
        Ok(())
    }
}

impl StoreFlash for RamBank {
    async fn erase_async(&mut self, from: u32, to: u32) -> Result<(), RamBankError> {
        self.erase(from, to)
    }

    fn mapped(&self, offset_b: u32, len_b: u32) -> Option<&[u8]> {
        let end = offset_b.checked_add(len_b)?;
        self.bytes().get(offset_b as usize..end as usize)
    }
}
