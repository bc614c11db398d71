//! Where the slots are: two per table kind, each a whole number of erase sectors, and the
//! STM32H743's bank-2 map.

use super::error::StoreError;
use super::header::HEADER_LEN;
use super::kind::TableKind;

/// One slot: a byte range of the flash device, a whole number of erase sectors. Its first
/// [`HEADER_LEN`] bytes are the header, the table's bytes follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Slot {
    /// Start, bytes from the start of the flash device (a sector boundary).
    pub offset_b: u32,
    /// Length in bytes (a whole number of sectors).
    pub len_b: u32,
}

impl Slot {
    /// Largest table the slot holds, bytes.
    pub const fn capacity_b(&self) -> u32 {
        self.len_b.saturating_sub(HEADER_LEN as u32)
    }

    /// Device offset of the table's first byte.
    pub const fn data_offset_b(&self) -> u32 {
        self.offset_b.saturating_add(HEADER_LEN as u32)
    }

    /// One past the slot's last byte (saturating).
    const fn end_b(&self) -> u32 {
        self.offset_b.saturating_add(self.len_b)
    }
}

/// The two slots of every table kind, indexed by [`TableKind::index`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Layout {
    /// `slots[kind.index()]` are the kind's slot 0 and slot 1.
    pub slots: [[Slot; 2]; TableKind::COUNT],
}

/// Size of an STM32H743 flash sector (its erase unit), bytes.
pub const H743_SECTOR_B: u32 = 128 * 1024;
/// Size of an STM32H743 flash program unit (a 256-bit flash word with its own ECC), bytes.
pub const H743_PROGRAM_UNIT_B: u32 = 32;
/// Size of one STM32H743 flash bank, bytes (8 sectors).
pub const H743_BANK_B: u32 = 8 * H743_SECTOR_B;
/// Bus address of the STM32H743's bank 2, where the slots live (the code runs from bank 1).
pub const H743_BANK2_ADDRESS: u32 = 0x0810_0000;

/// The STM32H743 bank-2 map, offsets from the start of bank 2: two sectors (256 KB) per slot;
/// calibration in sectors 0-1 and 2-3, catalog in 4-5 and 6-7.
pub const H743_BANK2: Layout = Layout {
    slots: [
        [
            Slot {
                offset_b: 0,
                len_b: 2 * H743_SECTOR_B,
            },
            Slot {
                offset_b: 2 * H743_SECTOR_B,
                len_b: 2 * H743_SECTOR_B,
            },
        ],
        [
            Slot {
                offset_b: 4 * H743_SECTOR_B,
                len_b: 2 * H743_SECTOR_B,
            },
            Slot {
                offset_b: 6 * H743_SECTOR_B,
                len_b: 2 * H743_SECTOR_B,
            },
        ],
    ],
};

impl Layout {
    /// The two slots of `kind`.
    pub const fn slots_of(&self, kind: TableKind) -> &[Slot; 2] {
        match kind {
            TableKind::Calibration => &self.slots[0],
            TableKind::Catalog => &self.slots[1],
        }
    }

    /// Checks the layout against a device of `capacity_b` bytes with the given erase and
    /// program units: every slot whole sectors, inside the device, larger than its header,
    /// no two overlapping; the program unit must divide the header.
    pub fn check(
        &self,
        capacity_b: usize,
        erase_b: usize,
        program_b: usize,
    ) -> Result<(), StoreError> {
        if program_b == 0 || !HEADER_LEN.is_multiple_of(program_b) || erase_b == 0 {
            return Err(StoreError::UnsupportedFlash);
        }
        let capacity_b = u32::try_from(capacity_b).unwrap_or(u32::MAX);
        let erase_b = u32::try_from(erase_b).unwrap_or(u32::MAX);
        let mut all = [Slot {
            offset_b: 0,
            len_b: 0,
        }; 2 * TableKind::COUNT];
        for (kind, pair) in TableKind::ALL.iter().zip(self.slots.iter()) {
            for (s, slot) in pair.iter().enumerate() {
                let bad = !slot.offset_b.is_multiple_of(erase_b)
                    || !slot.len_b.is_multiple_of(erase_b)
                    || slot.len_b <= HEADER_LEN as u32
                    || slot
                        .offset_b
                        .checked_add(slot.len_b)
                        .is_none_or(|end| end > capacity_b);
                if bad {
                    return Err(StoreError::BadLayout {
                        kind: *kind,
                        slot: s as u8,
                    });
                }
                if let Some(entry) = all.get_mut(kind.index() * 2 + s) {
                    *entry = *slot;
                }
            }
        }
        for (i, a) in all.iter().enumerate() {
            for b in all.iter().skip(i + 1) {
                if a.offset_b < b.end_b() && b.offset_b < a.end_b() {
                    let kind = TableKind::ALL
                        .get(i / 2)
                        .copied()
                        .unwrap_or(TableKind::Calibration);
                    return Err(StoreError::BadLayout {
                        kind,
                        slot: (i % 2) as u8,
                    });
                }
            }
        }
        Ok(())
    }
}
