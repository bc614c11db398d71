//! The link's table-upload port served by the flash table store: [`FlashTables`] borrows a
//! [`FlashStore`] and answers the link's `begin`, `chunk`, `commit`, `abort` and `active`
//! with it, every [`StoreError`] mapped to an [`UploadRefusal`] ([`refusal_of`]).
//!
//! What it is for: one binding of the store to the link for every home (the board over flash
//! bank 2, the software-in-the-loop over the flash model), so the two run the same upload.
//! What it costs: nothing beyond the store's calls; it holds a borrow and a check function.
//!
//! # The erase is the owner's step
//! `begin` touches no flash: the slot the table goes to is erased afterwards, one 128 KB
//! sector at a time (1-2 s each on the STM32H7), and chunks are refused with
//! [`UploadRefusal::Busy`] until it is. The link never erases: the home runs
//! [`FlashTables::service`] (a blocking [`FlashStore::erase_step`]) between frames or from
//! its own task, or erases [`FlashStore::pending_erase`]'s range with its own async driver
//! and calls [`FlashStore::confirm_erased`] (the board's `flash_store::erase_pending`). A
//! ground station that sends chunks before the erase is done gets `Busy` and resends.
//!
//! # Commit runs the table's own checks
//! A calibration table is committed with [`FlashStore::commit_checked`] and the home's
//! `check(device, data_offset_b, len_b)`: the home parses the table where it lies (the board
//! through the memory-mapped bank, the host through the model's bytes) and compares its
//! geometry with the sensor's. A table of another kind (the catalog) is committed on
//! its CRC alone.

use super::upload::{TableInfo, TableUpload, UploadRefusal};
use crate::store::{EraseProgress, FlashStore, StoreError, TableKind};
use embedded_storage::nor_flash::NorFlash;

/// The refusal the link reports for a store error.
///
/// `UploadInProgress` and `NotErased` are [`UploadRefusal::Busy`] (abort first, or wait for
/// the erase); `TooLong` and `PastEnd` are `TooLong`; `EmptyTable` and `Invalid` are
/// `Invalid`; `NoUpload` is `NotStarted`; flash failures, a failed verify and the errors an
/// upload cannot meet (layout, no table, buffer, sequence numbers used up) are `Storage`.
pub const fn refusal_of(e: StoreError) -> UploadRefusal {
    match e {
        StoreError::UploadInProgress { .. } | StoreError::NotErased => UploadRefusal::Busy,
        StoreError::TooLong { .. } | StoreError::PastEnd { .. } => UploadRefusal::TooLong,
        StoreError::EmptyTable | StoreError::Invalid => UploadRefusal::Invalid,
        StoreError::NoUpload => UploadRefusal::NotStarted,
        StoreError::OutOfOrder { expected_b, .. } => UploadRefusal::OutOfOrder {
            expected: expected_b,
        },
        StoreError::Incomplete { .. } => UploadRefusal::Incomplete,
        StoreError::CrcMismatch { .. } => UploadRefusal::CrcMismatch,
        StoreError::Flash(_)
        | StoreError::VerifyFailed { .. }
        | StoreError::UnsupportedFlash
        | StoreError::BadLayout { .. }
        | StoreError::SequenceExhausted
        | StoreError::NoTable
        | StoreError::BufferTooSmall { .. } => UploadRefusal::Storage,
    }
}

/// The table of link kind `kind` in force in `store`, as the link reports it.
pub fn active_info<F: NorFlash>(store: &FlashStore<F>, kind: u8) -> Option<TableInfo> {
    let kind = TableKind::from_code(kind)?;
    let a = store.active(kind)?;
    Some(TableInfo {
        kind: kind.code(),
        len_bytes: a.header.len_b,
        crc32: a.header.crc32,
        sequence: a.header.sequence,
    })
}

/// The link's table store over a [`FlashStore`]: borrow the store for a link round, serve
/// the link, run [`Self::service`] between frames.
///
/// `check(device, data_offset_b, len_b)` is the calibration table's own check at commit
/// (`true`: a usable table of this sensor).
pub struct FlashTables<'s, F, C> {
    store: &'s mut FlashStore<F>,
    check: C,
}

impl<'s, F, C> FlashTables<'s, F, C>
where
    F: NorFlash,
    C: FnMut(&mut F, u32, u32) -> bool,
{
    /// The link's view of `store`, committing calibration tables that pass `check`.
    pub fn new(store: &'s mut FlashStore<F>, check: C) -> Self {
        Self { store, check }
    }

    /// The store.
    pub fn store(&self) -> &FlashStore<F> {
        self.store
    }

    /// Runs one erase step of the upload under way, if its slot is not erased yet: `None`
    /// when there is nothing to erase, else the step's result (an error drops the upload; the
    /// table in force stays). Blocking, one sector (1-2 s on the STM32H7): the home calls it
    /// where a stall is harmless (between frames in the SIL, where the flash model erases at
    /// once; never in the board's frame loop, which erases from its own task instead).
    pub fn service(&mut self) -> Option<Result<EraseProgress, StoreError>> {
        self.store.pending_erase()?;
        Some(self.store.erase_step())
    }

    /// [`Self::service`] until the slot is erased or an erase fails.
    pub fn service_all(&mut self) -> Result<(), StoreError> {
        while let Some(step) = self.service() {
            step?;
        }
        Ok(())
    }
}

impl<F, C> TableUpload for FlashTables<'_, F, C>
where
    F: NorFlash,
    C: FnMut(&mut F, u32, u32) -> bool,
{
    fn begin(&mut self, kind: u8, total_len: u32, crc32: u32) -> Result<(), UploadRefusal> {
        let kind = TableKind::from_code(kind).ok_or(UploadRefusal::UnknownKind)?;
        self.store.begin(kind, total_len, crc32).map_err(refusal_of)
    }

    fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), UploadRefusal> {
        self.store.chunk(offset, data).map_err(refusal_of)
    }

    fn commit(&mut self) -> Result<TableInfo, UploadRefusal> {
        let kind = self
            .store
            .upload_status()
            .ok_or(UploadRefusal::NotStarted)?
            .kind;
        let committed = match kind {
            TableKind::Calibration => self.store.commit_checked(&mut self.check),
            TableKind::Catalog => self.store.commit(),
        };
        let info = committed.map_err(refusal_of)?;
        Ok(TableInfo {
            kind: kind.code(),
            len_bytes: info.header.len_b,
            crc32: info.header.crc32,
            sequence: info.header.sequence,
        })
    }

    fn abort(&mut self) {
        // No upload under way (NoUpload) is the only error: nothing to drop.
        let _ = self.store.abort();
    }

    fn active(&self, kind: u8) -> Option<TableInfo> {
        active_info(self.store, kind)
    }

    fn read_active(&mut self, kind: u8, offset: u32, out: &mut [u8]) -> bool {
        read_active_at(self.store, kind, offset, out)
    }
}

/// Reads `out.len()` bytes of the table of link kind `kind` in force from byte `offset`
/// (the slot in force is never written while it is in force); `false` past its end or on a
/// read error.
pub fn read_active_at<F: NorFlash>(
    store: &mut FlashStore<F>,
    kind: u8,
    offset: u32,
    out: &mut [u8],
) -> bool {
    let Some(a) = TableKind::from_code(kind).and_then(|k| store.active(k)) else {
        return false;
    };
    let Ok(n) = u32::try_from(out.len()) else {
        return false;
    };
    if offset.checked_add(n).is_none_or(|end| end > a.header.len_b) {
        return false;
    }
    store
        .flash_mut()
        .read(a.data_offset_b + offset, out)
        .is_ok()
}
