//! Flash bank 2 (0x0810_0000, 1 MB; the firmware runs from bank 1) as the table store's
//! NOR flash: offsets from the bank's start, programs and erases through embassy-stm32's
//! flash driver, reads through [`ecc_guarded_read`] so that a unit torn by a power cut reads
//! as an error, not a bus fault. Its erase is also offered async ([`Bank2::erase_async`]): the
//! driver then waits for the flash interrupt and the executor keeps running the other tasks.
//! Reads of bank 2 wait while a sector of it is erased or programmed (RM0433: read-while-write
//! only across banks), which is why the tracker reads a RAM copy of its table
//! ([`crate::flash_store`]).

use crate::board::StoreFlash;
use embassy_stm32::flash::{Async, Error as DriverError, FLASH_BASE, Flash};
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use startrack_core::store::{H743_BANK_B, H743_BANK2_ADDRESS, H743_PROGRAM_UNIT_B, H743_SECTOR_B};

/// Bank 2's offset in embassy's flash offsets (from `FLASH_BASE`, 0x0800_0000).
const BANK2_OFFSET: u32 = H743_BANK2_ADDRESS - FLASH_BASE as u32;

/// Flash bank 2 as a NOR flash device (offsets from 0x0810_0000).
pub struct Bank2 {
    flash: Flash<'static, Async>,
}

/// Why a bank-2 operation failed.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum Bank2Error {
    /// The driver refused or the flash reported an error.
    Driver(DriverError),
    /// A read met an ECC double error (a torn or half-erased unit).
    Ecc {
        /// Offset of the read, bytes from the start of bank 2.
        offset_b: u32,
    },
    /// Outside bank 2.
    OutOfBounds,
}

impl NorFlashError for Bank2Error {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Self::Driver(e) => e.kind(),
            Self::Ecc { .. } => NorFlashErrorKind::Other,
            Self::OutOfBounds => NorFlashErrorKind::OutOfBounds,
        }
    }
}

impl Bank2 {
    /// Bank 2 of `flash`.
    pub fn new(flash: Flash<'static, Async>) -> Self {
        Self { flash }
    }
}

impl ErrorType for Bank2 {
    type Error = Bank2Error;
}

impl ReadNorFlash for Bank2 {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Bank2Error> {
        let end = offset as usize + bytes.len();
        if end > H743_BANK_B as usize {
            return Err(Bank2Error::OutOfBounds);
        }
        ecc_guarded_read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        H743_BANK_B as usize
    }
}

impl NorFlash for Bank2 {
    const WRITE_SIZE: usize = H743_PROGRAM_UNIT_B as usize;
    const ERASE_SIZE: usize = H743_SECTOR_B as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Bank2Error> {
        if to < from || to > H743_BANK_B {
            return Err(Bank2Error::OutOfBounds);
        }
        self.flash
            .blocking_erase(BANK2_OFFSET + from, BANK2_OFFSET + to)
            .map_err(Bank2Error::Driver)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Bank2Error> {
        if offset as usize + bytes.len() > H743_BANK_B as usize {
            return Err(Bank2Error::OutOfBounds);
        }
        self.flash
            .blocking_write(BANK2_OFFSET + offset, bytes)
            .map_err(Bank2Error::Driver)
    }
}

/// SCB CCR bit 8, BFHFNMIGN: handlers at priority -1 (and code running with FAULTMASK set)
/// ignore precise data bus faults of loads.
const CCR_BFHFNMIGN: u32 = 1 << 8;

/// Reads bank-2 bytes so that an ECC double error (a 32-byte unit torn by a power cut during
/// its program or erase) gives an error instead of a bus fault: the loads run with FAULTMASK
/// set and CCR.BFHFNMIGN, which make the core ignore their bus faults, and the bank's
/// DBECCERR flag (FLASH_SR2 bit 26) says whether one happened; it is then cleared.
/// The data cache is not enabled by this firmware, so no stale line hides a fresh erase.
fn ecc_guarded_read(offset: u32, out: &mut [u8]) -> Result<(), Bank2Error> {
    let bank = embassy_stm32::pac::FLASH.bank(1);
    let base = (H743_BANK2_ADDRESS + offset) as usize;
    // SAFETY: `base .. base + out.len()` lies inside bank 2 (checked by the caller), which is
    // memory-mapped and readable; the loads are volatile byte reads of that region and write
    // only into `out`. FAULTMASK is set just around them (no interrupt, no fault handler runs
    // meanwhile) and CCR is restored to its previous value; nothing else in this firmware
    // changes CCR concurrently (FAULTMASK masks every other context).
    unsafe {
        let scb = &*cortex_m::peripheral::SCB::PTR;
        let ccr = scb.ccr.read();
        scb.ccr.write(ccr | CCR_BFHFNMIGN);
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
        core::arch::asm!("cpsid f", options(nomem, nostack, preserves_flags));
        for (i, b) in out.iter_mut().enumerate() {
            *b = core::ptr::read_volatile(core::ptr::with_exposed_provenance::<u8>(base + i));
        }
        cortex_m::asm::dsb();
        core::arch::asm!("cpsie f", options(nomem, nostack, preserves_flags));
        scb.ccr.write(ccr);
        cortex_m::asm::isb();
    }
    if bank.sr().read().dbeccerr() {
        bank.ccr().write(|w| w.set_clr_dbeccerr(true));
        return Err(Bank2Error::Ecc { offset_b: offset });
    }
    Ok(())
}

impl StoreFlash for Bank2 {
    /// Erases `from..to` (offsets in bank 2, whole sectors), waiting for the flash interrupt
    /// rather than spinning: the executor runs the other tasks meanwhile.
    async fn erase_async(&mut self, from: u32, to: u32) -> Result<(), Bank2Error> {
        if to < from || to > H743_BANK_B {
            return Err(Bank2Error::OutOfBounds);
        }
        self.flash
            .erase(BANK2_OFFSET + from, BANK2_OFFSET + to)
            .await
            .map_err(Bank2Error::Driver)
    }

    fn mapped(&self, offset_b: u32, len_b: u32) -> Option<&[u8]> {
        if offset_b.checked_add(len_b)? > H743_BANK_B {
            return None;
        }
        let start =
            core::ptr::with_exposed_provenance::<u8>((H743_BANK2_ADDRESS + offset_b) as usize);
        // SAFETY: the range lies inside bank 2 (checked above), memory-mapped and readable.
        // The caller reads only a range the store has just programmed and read back whole
        // (its CRC), so no unit in it is torn (no ECC fault), and nothing writes or erases it
        // while the slice lives: it borrows `self`, the only writer.
        Some(unsafe { core::slice::from_raw_parts(start, len_b as usize) })
    }
}
