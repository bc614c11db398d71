//! The store: mounts the slots, says which table is in force, and runs an upload (begin,
//! erase steps, chunks, commit or abort) into the slot that is not.

use super::error::{FlashFault, StoreError};
use super::header::{CRC, HEADER_LEN, HeaderError, SlotHeader};
use super::kind::TableKind;
use super::layout::{Layout, Slot};
use embedded_storage::nor_flash::{NorFlash, NorFlashError};

/// Bytes read at a time when a slot's CRC is checked (a stack buffer).
const READ_BLOCK_B: usize = 256;

/// What mount (or the last operation) found in a slot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SlotState {
    /// The header unit is erased: nothing committed (the rest may hold anything).
    Blank,
    /// A read failed (on the chip: an ECC error on a torn or half-erased unit).
    Unreadable,
    /// The header unit is not a valid header of this kind.
    BadHeader(HeaderError),
    /// A valid header, but the table bytes do not have its CRC.
    BadData(SlotHeader),
    /// An upload is writing this slot.
    Uploading,
    /// A valid header and table.
    Valid(SlotHeader),
}

/// The table in force for a kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ActiveTable {
    /// Slot 0 or 1.
    pub slot: u8,
    /// Its header: sequence number, length, CRC.
    pub header: SlotHeader,
    /// Device offset of the table's first byte.
    pub data_offset_b: u32,
}

impl ActiveTable {
    /// The table's bytes within a memory-mapped view of the whole device (`None` if the
    /// view is too short).
    pub fn bytes<'m>(&self, device: &'m [u8]) -> Option<&'m [u8]> {
        let start = self.data_offset_b as usize;
        device.get(start..start.checked_add(self.header.len_b as usize)?)
    }
}

/// What a successful commit put in force.
pub type CommitInfo = ActiveTable;

/// Progress of the erase step of an upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EraseProgress {
    /// Sectors still to erase.
    Remaining(u32),
    /// The target slot is erased and checked blank: chunks may come.
    Done,
}

/// An upload in progress, as housekeeping reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UploadStatus {
    /// The kind being uploaded.
    pub kind: TableKind,
    /// The slot being written.
    pub slot: u8,
    /// Sectors still to erase.
    pub sectors_to_erase: u32,
    /// Bytes received.
    pub received_b: u32,
    /// Bytes announced.
    pub total_b: u32,
}

/// The state of an upload.
#[derive(Clone, Copy, Debug)]
struct Upload {
    kind: TableKind,
    slot: u8,
    total_b: u32,
    crc32: u32,
    sequence: u32,
    /// Sectors of the slot already erased (in order from the slot's start).
    erased_sectors: u32,
    /// Bytes received; the ones past the last whole unit wait in `staged`.
    received_b: u32,
    staged: [u8; HEADER_LEN],
}

/// A mounted store over a NOR flash device `F`.
///
/// Costs: mount reads every slot header and the bytes of every table once (its CRC); an
/// upload programs each 32-byte unit once, erases the target slot's sectors (one call each,
/// 1-2 s on the STM32H7), and reads the table back once before its header is written.
pub struct FlashStore<F> {
    flash: F,
    layout: Layout,
    states: [[SlotState; 2]; TableKind::COUNT],
    /// Highest sequence number seen in a header that passed its CRC, per kind.
    max_sequence: [u32; TableKind::COUNT],
    upload: Option<Upload>,
}

/// A refused mount: the layout does not fit the device; the device is given back.
pub struct MountError<F> {
    /// The device, untouched.
    pub flash: F,
    /// Why.
    pub error: StoreError,
}

impl<F: NorFlash> FlashStore<F> {
    /// Mounts the store: checks the layout against the device, then every slot's header and
    /// table CRC. Any flash content is accepted: a slot that does not check out is not used.
    /// The newest valid slot of each kind is in force.
    pub fn mount(mut flash: F, layout: Layout) -> Result<Self, MountError<F>> {
        if let Err(error) = layout.check(flash.capacity(), F::ERASE_SIZE, F::WRITE_SIZE) {
            return Err(MountError { flash, error });
        }
        let mut states = [[SlotState::Blank; 2]; TableKind::COUNT];
        let mut max_sequence = [0u32; TableKind::COUNT];
        for kind in TableKind::ALL {
            for (s, slot) in layout.slots_of(kind).iter().enumerate() {
                let state = scan_slot(&mut flash, kind, slot);
                if let SlotState::Valid(h) | SlotState::BadData(h) = state
                    && let Some(m) = max_sequence.get_mut(kind.index())
                {
                    *m = (*m).max(h.sequence);
                }
                if let Some(st) = states.get_mut(kind.index()).and_then(|p| p.get_mut(s)) {
                    *st = state;
                }
            }
        }
        Ok(Self {
            flash,
            layout,
            states,
            max_sequence,
            upload: None,
        })
    }

    /// The layout in use.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The device (for a memory-mapped view of an active table, or a test).
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// The device, for a home that erases [`Self::pending_erase`]'s range with its own
    /// (async) driver before [`Self::confirm_erased`]. Anything else written through it is
    /// outside the store's promises (mount still refuses what does not check out).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the device back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// What is known of `kind`'s two slots.
    pub fn slot_states(&self, kind: TableKind) -> [SlotState; 2] {
        self.states
            .get(kind.index())
            .copied()
            .unwrap_or([SlotState::Blank; 2])
    }

    /// The table in force for `kind`: the valid slot with the higher sequence number.
    pub fn active(&self, kind: TableKind) -> Option<ActiveTable> {
        let slots = self.layout.slots_of(kind);
        let mut best: Option<ActiveTable> = None;
        for (s, (state, slot)) in self.slot_states(kind).iter().zip(slots).enumerate() {
            if let SlotState::Valid(header) = *state
                && best.is_none_or(|b| header.sequence > b.header.sequence)
            {
                best = Some(ActiveTable {
                    slot: s as u8,
                    header,
                    data_offset_b: slot.data_offset_b(),
                });
            }
        }
        best
    }

    /// Copies the table in force into `out` and checks its CRC again; returns its bytes.
    pub fn read_active<'o>(
        &mut self,
        kind: TableKind,
        out: &'o mut [u8],
    ) -> Result<&'o [u8], StoreError> {
        let active = self.active(kind).ok_or(StoreError::NoTable)?;
        let len = active.header.len_b as usize;
        let need_b = active.header.len_b;
        let dst = out
            .get_mut(..len)
            .ok_or(StoreError::BufferTooSmall { need_b })?;
        self.flash
            .read(active.data_offset_b, dst)
            .map_err(|e| StoreError::Flash(e.kind().into()))?;
        let computed = CRC.checksum(dst);
        if computed != active.header.crc32 {
            return Err(StoreError::CrcMismatch {
                expected: active.header.crc32,
                computed,
            });
        }
        Ok(dst)
    }

    /// The upload in progress, if any.
    pub fn upload_status(&self) -> Option<UploadStatus> {
        let u = self.upload.as_ref()?;
        Some(UploadStatus {
            kind: u.kind,
            slot: u.slot,
            sectors_to_erase: self.sectors_in(u).saturating_sub(u.erased_sectors),
            received_b: u.received_b,
            total_b: u.total_b,
        })
    }

    /// Starts an upload of a `kind` table of `total_len_b` bytes whose CRC-32/ISO-HDLC is
    /// `crc32`, into the slot that is not in force. Touches no flash: the slot is erased by
    /// [`Self::erase_step`] (or [`Self::pending_erase`] and [`Self::confirm_erased`]).
    pub fn begin(
        &mut self,
        kind: TableKind,
        total_len_b: u32,
        crc32: u32,
    ) -> Result<(), StoreError> {
        if let Some(u) = &self.upload {
            return Err(StoreError::UploadInProgress { kind: u.kind });
        }
        if total_len_b == 0 {
            return Err(StoreError::EmptyTable);
        }
        let slot = self.target_slot(kind);
        let capacity_b = self.slot(kind, slot).capacity_b();
        if total_len_b > capacity_b {
            return Err(StoreError::TooLong {
                len_b: total_len_b,
                capacity_b,
            });
        }
        let sequence = self
            .max_sequence
            .get(kind.index())
            .copied()
            .unwrap_or(u32::MAX)
            .checked_add(1)
            .ok_or(StoreError::SequenceExhausted)?;
        self.set_state(kind, slot, SlotState::Uploading);
        self.upload = Some(Upload {
            kind,
            slot,
            total_b: total_len_b,
            crc32,
            sequence,
            erased_sectors: 0,
            received_b: 0,
            staged: [0xFF; HEADER_LEN],
        });
        Ok(())
    }

    /// The next sector to erase (device offset and length, bytes), for a home that erases
    /// it itself (e.g. with an async flash driver) and then calls [`Self::confirm_erased`].
    pub fn pending_erase(&self) -> Option<(u32, u32)> {
        let u = self.upload.as_ref()?;
        if u.erased_sectors >= self.sectors_in(u) {
            return None;
        }
        let sector_b = F::ERASE_SIZE as u32;
        let from = self
            .slot(u.kind, u.slot)
            .offset_b
            .saturating_add(u.erased_sectors.saturating_mul(sector_b));
        Some((from, sector_b))
    }

    /// Checks that the sector [`Self::pending_erase`] named reads blank, and moves on to
    /// the next one. A sector that does not read blank drops the upload.
    pub fn confirm_erased(&mut self) -> Result<EraseProgress, StoreError> {
        let (from, len) = self.pending_erase().ok_or(StoreError::NoUpload)?;
        if let Err(e) = self.blank_check(from, len) {
            self.drop_upload();
            return Err(e);
        }
        let total = self.upload.as_ref().map_or(0, |u| self.sectors_in(u));
        let u = self.upload.as_mut().ok_or(StoreError::NoUpload)?;
        u.erased_sectors = u.erased_sectors.saturating_add(1);
        Ok(match total.saturating_sub(u.erased_sectors) {
            0 => EraseProgress::Done,
            n => EraseProgress::Remaining(n),
        })
    }

    /// Erases the next sector of the target slot (blocking: 1-2 s on the STM32H7; run it
    /// where a stall is harmless, never in the frame loop) and checks it blank.
    pub fn erase_step(&mut self) -> Result<EraseProgress, StoreError> {
        if self.upload.is_none() {
            return Err(StoreError::NoUpload);
        }
        let Some((from, len)) = self.pending_erase() else {
            return Ok(EraseProgress::Done);
        };
        if let Err(e) = self.flash.erase(from, from.saturating_add(len)) {
            self.drop_upload();
            return Err(StoreError::Flash(e.kind().into()));
        }
        self.confirm_erased()
    }

    /// Takes the table's bytes from `offset_b` on (chunks in order, any length), and
    /// programs every completed 32-byte unit.
    pub fn chunk(&mut self, offset_b: u32, data: &[u8]) -> Result<(), StoreError> {
        let u = self.upload.as_ref().ok_or(StoreError::NoUpload)?;
        if u.erased_sectors < self.sectors_in(u) {
            return Err(StoreError::NotErased);
        }
        if offset_b != u.received_b {
            return Err(StoreError::OutOfOrder {
                expected_b: u.received_b,
                got_b: offset_b,
            });
        }
        let end_b = u32::try_from(data.len())
            .ok()
            .and_then(|n| offset_b.checked_add(n))
            .unwrap_or(u32::MAX);
        if end_b > u.total_b {
            return Err(StoreError::PastEnd {
                end_b,
                total_b: u.total_b,
            });
        }
        for &byte in data {
            let (unit_full, unit_start) = {
                let u = self.upload.as_mut().ok_or(StoreError::NoUpload)?;
                let pos = u.received_b as usize % HEADER_LEN;
                if let Some(b) = u.staged.get_mut(pos) {
                    *b = byte;
                }
                u.received_b = u.received_b.saturating_add(1);
                (
                    pos + 1 == HEADER_LEN,
                    u.received_b.saturating_sub(HEADER_LEN as u32),
                )
            };
            if unit_full {
                self.program_staged(unit_start)?;
            }
        }
        Ok(())
    }

    /// Completes the upload: programs the last partial unit (padded with 0xFF), reads the
    /// whole table back and checks the announced CRC, then writes the header (the last
    /// write) and reads it back. On success the new table is in force. `NotErased` and
    /// `Incomplete` keep the upload (its missing steps may follow); any other error drops
    /// it, and the table in force stays.
    pub fn commit(&mut self) -> Result<CommitInfo, StoreError> {
        self.commit_checked(|_, _, _| true)
    }

    /// [`Self::commit`] with the table's own checks: once the bytes read back have the
    /// announced CRC and before the header is written, `check(device, data_offset_b, len_b)`
    /// looks at the table where it lies (e.g. parses a calibration table through a
    /// memory-mapped view, all its units programmed and read back); `false` commits nothing
    /// ([`StoreError::Invalid`]) and drops the upload.
    pub fn commit_checked(
        &mut self,
        check: impl FnOnce(&mut F, u32, u32) -> bool,
    ) -> Result<CommitInfo, StoreError> {
        let u = *self.upload.as_ref().ok_or(StoreError::NoUpload)?;
        // Refusals that touch no flash keep the upload: the missing steps may still come.
        if u.erased_sectors < self.sectors_in(&u) {
            return Err(StoreError::NotErased);
        }
        if u.received_b != u.total_b {
            return Err(StoreError::Incomplete {
                received_b: u.received_b,
                total_b: u.total_b,
            });
        }
        let result = self.finish(&u, check);
        self.upload = None;
        match result {
            Ok(info) => {
                self.set_state(u.kind, u.slot, SlotState::Valid(info.header));
                if let Some(m) = self.max_sequence.get_mut(u.kind.index()) {
                    *m = (*m).max(u.sequence);
                }
                Ok(info)
            }
            Err(e) => {
                self.rescan(u.kind, u.slot);
                Err(e)
            }
        }
    }

    /// Drops the upload in progress; the table in force stays. Touches no flash.
    pub fn abort(&mut self) -> Result<(), StoreError> {
        if self.upload.is_none() {
            return Err(StoreError::NoUpload);
        }
        self.drop_upload();
        Ok(())
    }

    // --- internals ---------------------------------------------------------------------

    fn finish(
        &mut self,
        u: &Upload,
        check: impl FnOnce(&mut F, u32, u32) -> bool,
    ) -> Result<CommitInfo, StoreError> {
        let tail = u.received_b as usize % HEADER_LEN;
        if tail != 0 {
            let start = u.received_b.saturating_sub(tail as u32);
            if let Some(upload) = self.upload.as_mut() {
                for b in upload.staged.iter_mut().skip(tail) {
                    *b = 0xFF;
                }
            }
            self.program_staged(start)?;
        }
        let slot = *self.slot(u.kind, u.slot);
        let computed = self.crc_of(slot.data_offset_b(), u.total_b)?;
        if computed != u.crc32 {
            return Err(StoreError::CrcMismatch {
                expected: u.crc32,
                computed,
            });
        }
        if !check(&mut self.flash, slot.data_offset_b(), u.total_b) {
            return Err(StoreError::Invalid);
        }
        let header = SlotHeader {
            kind: u.kind,
            sequence: u.sequence,
            len_b: u.total_b,
            crc32: u.crc32,
        };
        let bytes = header.encode();
        self.flash
            .write(slot.offset_b, &bytes)
            .map_err(|e| StoreError::Flash(e.kind().into()))?;
        let mut back = [0u8; HEADER_LEN];
        self.flash
            .read(slot.offset_b, &mut back)
            .map_err(|e| StoreError::Flash(e.kind().into()))?;
        if back != bytes {
            return Err(StoreError::VerifyFailed {
                offset_b: slot.offset_b,
            });
        }
        Ok(ActiveTable {
            slot: u.slot,
            header,
            data_offset_b: slot.data_offset_b(),
        })
    }

    /// Programs the staged unit as table bytes `table_offset_b..+32`.
    fn program_staged(&mut self, table_offset_b: u32) -> Result<(), StoreError> {
        let Some(u) = self.upload.as_ref() else {
            return Err(StoreError::NoUpload);
        };
        let at = self
            .slot(u.kind, u.slot)
            .data_offset_b()
            .saturating_add(table_offset_b);
        let unit = u.staged;
        if let Err(e) = self.flash.write(at, &unit) {
            self.drop_upload();
            return Err(StoreError::Flash(e.kind().into()));
        }
        if let Some(u) = self.upload.as_mut() {
            u.staged = [0xFF; HEADER_LEN];
        }
        Ok(())
    }

    /// CRC of `len_b` bytes from `from_b`, read a block at a time.
    fn crc_of(&mut self, from_b: u32, len_b: u32) -> Result<u32, StoreError> {
        crc_of(&mut self.flash, from_b, len_b).map_err(StoreError::Flash)
    }

    fn blank_check(&mut self, from_b: u32, len_b: u32) -> Result<(), StoreError> {
        let mut buf = [0u8; READ_BLOCK_B];
        let mut at = 0u32;
        while at < len_b {
            let n = (len_b - at).min(READ_BLOCK_B as u32);
            let dst = buf.get_mut(..n as usize).unwrap_or(&mut []);
            let offset_b = from_b.saturating_add(at);
            self.flash
                .read(offset_b, dst)
                .map_err(|_| StoreError::VerifyFailed { offset_b })?;
            if let Some(i) = dst.iter().position(|&b| b != 0xFF) {
                return Err(StoreError::VerifyFailed {
                    offset_b: offset_b.saturating_add(i as u32),
                });
            }
            at += n;
        }
        Ok(())
    }

    fn drop_upload(&mut self) {
        if let Some(u) = self.upload.take() {
            self.rescan(u.kind, u.slot);
        }
    }

    /// Reads a slot's state again (after an upload into it stopped).
    fn rescan(&mut self, kind: TableKind, slot: u8) {
        let s = *self.slot(kind, slot);
        let state = scan_slot(&mut self.flash, kind, &s);
        self.set_state(kind, slot, state);
    }

    fn sectors_in(&self, u: &Upload) -> u32 {
        self.slot(u.kind, u.slot).len_b / (F::ERASE_SIZE as u32).max(1)
    }

    fn slot(&self, kind: TableKind, slot: u8) -> &Slot {
        let pair = self.layout.slots_of(kind);
        if slot == 0 { &pair[0] } else { &pair[1] }
    }

    fn set_state(&mut self, kind: TableKind, slot: u8, state: SlotState) {
        if let Some(st) = self
            .states
            .get_mut(kind.index())
            .and_then(|p| p.get_mut(usize::from(slot)))
        {
            *st = state;
        }
    }

    /// The slot an upload of `kind` writes: never the one in force; with none in force, a
    /// slot without a readable header of its own first (slot 0 when both are alike).
    fn target_slot(&self, kind: TableKind) -> u8 {
        match self.active(kind) {
            Some(a) => 1 - a.slot,
            None => 0,
        }
    }
}

/// Reads and checks one slot. Reads only the header unit and, when the header is valid, the
/// table's units (which were all programmed and verified before that header was written).
fn scan_slot<F: NorFlash>(flash: &mut F, kind: TableKind, slot: &Slot) -> SlotState {
    let mut b = [0u8; HEADER_LEN];
    if flash.read(slot.offset_b, &mut b).is_err() {
        return SlotState::Unreadable;
    }
    let header = match SlotHeader::decode(&b, kind, slot.capacity_b()) {
        Ok(h) => h,
        Err(HeaderError::Erased) => return SlotState::Blank,
        Err(e) => return SlotState::BadHeader(e),
    };
    match crc_of(flash, slot.data_offset_b(), header.len_b) {
        Ok(crc) if crc == header.crc32 => SlotState::Valid(header),
        Ok(_) => SlotState::BadData(header),
        Err(_) => SlotState::Unreadable,
    }
}

/// CRC-32/ISO-HDLC of `len_b` bytes of `flash` from `from_b`.
fn crc_of<F: NorFlash>(flash: &mut F, from_b: u32, len_b: u32) -> Result<u32, FlashFault> {
    let mut digest = CRC.digest();
    let mut buf = [0u8; READ_BLOCK_B];
    let mut at = 0u32;
    while at < len_b {
        let n = (len_b - at).min(READ_BLOCK_B as u32);
        let dst = buf.get_mut(..n as usize).unwrap_or(&mut []);
        flash
            .read(from_b.saturating_add(at), dst)
            .map_err(|e| FlashFault::from(e.kind()))?;
        digest.update(dst);
        at += n;
    }
    Ok(digest.finalize())
}
