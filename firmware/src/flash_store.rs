//! The table store on any board: the core's two-slot [`FlashStore`] over the board's
//! [`StoreFlash`] (on the STM32H743 flash bank 2, `board::stm32h743::bank2`; on `mps2-an500`
//! a RAM model of it), and the calibration table in force copied to RAM for the tracker.
//!
//! - [`mount`] mounts the store at start-up; [`load_calibration`] copies the calibration
//!   table in force into [`TABLE_RAM_B`] bytes of RAM (checking its CRC again) and has the
//!   core parse it there. The copy is in `.d2sram` ([`crate::d2_ram`]: the H7's D2 SRAM),
//!   written and read by the CPU only (no DMA), cached.
//! - [`erase_pending`] is the erase step of an upload, run by [`erase_task`]: never the
//!   frame loop.
//! - The link's uploads: the mounted store is shared ([`share`], [`SHARED`], an embassy-sync
//!   mutex) between the tracker task, which serves the link between frames through the
//!   core's [`FlashTables`] ([`with_link_tables`]), and [`erase_task`], which erases the
//!   slot an accepted `begin` targets (woken by [`ERASE`]). The tracker task only ever
//!   *tries* the lock: while an erase holds it (1-2 s a sector), the link is served by
//!   [`HeldTables`] (uploads refused "busy", the table in force reported from the last
//!   round) and frames keep running.
//!
//! Why a RAM copy: while a sector of the H7's bank 2 is erased (1-2 s) or programmed, reads
//! of bank 2 wait for the operation's end (RM0433, flash read-while-write is only across
//! banks). The
//! tracker reads its table for every calibrated pixel, so a table read in place from bank 2
//! would stall the frame loop during an upload. Read from RAM, it never touches the flash.
//! A newly committed table is in force in flash at once (housekeeping and the table report
//! show it) and in the tracker from the next start: the ground commits, then commands a
//! reset. Swapping the RAM copy under a running tracker would need a second 192 KB buffer.

use crate::board::{Flash, STORE_LAYOUT, StoreFlash};
use crate::d2_ram::{D2Cell, D2Ready, D2Static};
use crate::lines::GEOMETRY;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::{FlashTables, TableInfo, TableUpload, UploadRefusal};
use startrack_core::store::{EraseProgress, FlashStore, StoreError, TableKind};
use startrack_core::table::{CalibTable, TableError};

/// Largest calibration table the tracker can use (its RAM copy), bytes: 192 KB, enough for
/// the CCD47-20's dark map in 4x4 tiles (64 KB) and flat map in 8x8 tiles (32 KB) with
/// every list. A larger table can be stored but is refused at start-up.
pub const TABLE_RAM_B: usize = 192 * 1024;

/// The RAM copy of the calibration table in force: in `.d2sram` (the H7's SRAM1-2), which
/// the start-up code leaves as it is, so handed out zeroed by [`TABLE_RAM`].
#[unsafe(link_section = ".d2sram.TABLE_RAM")]
static TABLE_CELL: D2Cell<[u8; TABLE_RAM_B]> = D2Cell::new();
/// [`TABLE_CELL`], handed out once.
static TABLE_RAM: D2Static<[u8; TABLE_RAM_B]> = D2Static::new(&TABLE_CELL);

/// The store on this board.
pub type Store = FlashStore<Flash>;

/// The mounted store, shared by the tracker task (the link's uploads, between frames) and
/// [`erase_task`]; `None` when the store could not be mounted.
pub static SHARED: Mutex<CriticalSectionRawMutex, Option<Store>> = Mutex::new(None);

/// Wakes [`erase_task`]: an upload's slot waits for its erase.
pub static ERASE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Mounts the store on the board's flash and logs what each slot holds.
pub fn mount(flash: Flash) -> Result<Store, StoreError> {
    let store = FlashStore::mount(flash, STORE_LAYOUT).map_err(|e| e.error)?;
    for kind in TableKind::ALL {
        let [s0, s1] = store.slot_states(kind);
        defmt::info!(
            "store: {} slot 0 {}, slot 1 {}, in force {}",
            kind,
            s0,
            s1,
            store.active(kind)
        );
    }
    Ok(store)
}

/// Why no calibration table is used.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum LoadError {
    /// The store has none, or could not copy it (too large for RAM, a read error).
    Store(StoreError),
    /// The RAM copy was taken already (a second call).
    NoBuffer,
    /// The core rejected the bytes (the store's CRC passed, so: another format version,
    /// or a table that was uploaded bad).
    Table(TableError),
    /// A valid table, made for another readout geometry than this firmware's.
    GeometryMismatch {
        /// The geometry in the table.
        table: ReadoutGeometry,
        /// The geometry this firmware reads.
        firmware: ReadoutGeometry,
    },
}

/// Copies the calibration table in force into RAM and returns it parsed (once per start).
/// Every error is logged; the firmware then runs uncalibrated, which every frame summary
/// flags and housekeeping counts.
pub fn load_calibration(store: &mut Store, d2: D2Ready) -> Result<CalibTable<'static>, LoadError> {
    let result = load(store, d2);
    match &result {
        Ok(table) => defmt::info!(
            "calib: table in force {} ({} bytes), saturation {} ADU, column bias {}, dark map {}, flat map {}, {} hot, {} telegraph",
            store.active(TableKind::Calibration),
            table.len_bytes(),
            table.saturation_adu(),
            table.has_column_bias(),
            table.dark_map().is_some(),
            table.flat_map().is_some(),
            table.hot_pixels().len(),
            table.telegraph_pixels().len()
        ),
        Err(e) => defmt::error!("calib: no usable table: {}; running UNCALIBRATED", e),
    }
    result
}

fn load(store: &mut Store, d2: D2Ready) -> Result<CalibTable<'static>, LoadError> {
    let ram: &'static mut [u8; TABLE_RAM_B] = TABLE_RAM.try_take(d2).ok_or(LoadError::NoBuffer)?;
    let bytes: &'static [u8] = store
        .read_active(TableKind::Calibration, ram)
        .map_err(LoadError::Store)?;
    let table = CalibTable::parse(bytes).map_err(LoadError::Table)?;
    if *table.geometry() == GEOMETRY {
        Ok(table)
    } else {
        Err(LoadError::GeometryMismatch {
            table: *table.geometry(),
            firmware: GEOMETRY,
        })
    }
}

/// The calibration table's own checks for [`FlashStore::commit_checked`]: the core parses
/// the uploaded table where it lies in the store and its geometry must be this firmware's.
pub fn calibration_ok(flash: &mut Flash, offset_b: u32, len_b: u32) -> bool {
    // The store calls this after programming every unit of the range and reading it all
    // back (its CRC), holding the flash exclusively: what `mapped` asks.
    flash
        .mapped(offset_b, len_b)
        .is_some_and(|bytes| CalibTable::parse(bytes).is_ok_and(|t| *t.geometry() == GEOMETRY))
}

/// The erase step of an upload, for the task that owns the store: erases the next sector of
/// the target slot with the async driver (1-2 s in which this task waits and the others,
/// the frame loop among them, run), then has the store check it blank.
pub async fn erase_pending(store: &mut Store) -> Result<EraseProgress, StoreError> {
    let Some((from, len)) = store.pending_erase() else {
        return match store.upload_status() {
            Some(_) => Ok(EraseProgress::Done),
            None => Err(StoreError::NoUpload),
        };
    };
    if let Err(e) = store.flash_mut().erase_async(from, from + len).await {
        defmt::error!("store: erase of {=u32:#x}: {}", from, e);
    }
    // A failed erase leaves the sector not blank: the check below refuses it and drops the
    // upload; the table in force is untouched either way.
    store.confirm_erased()
}

/// Hands the mounted store to [`SHARED`] (at start-up, before the tasks that use it run).
pub fn share(store: Store) {
    match SHARED.try_lock() {
        Ok(mut slot) => *slot = Some(store),
        Err(_) => defmt::error!("store: shared slot locked at start-up; uploads refused"),
    }
}

/// The link's table store for a round when [`SHARED`] is held by an erase (or there is no
/// store): every upload step is refused with `refusal`, the table in force is the one the
/// last round saw, and an abort is kept for the next round that holds the store.
pub struct HeldTables {
    /// The calibration table in force at the last round that held the store.
    pub active: Option<TableInfo>,
    /// What upload steps get: `Busy` while erasing, `Storage` without a store.
    pub refusal: UploadRefusal,
    /// An abort to apply when the store is next held.
    pub abort_pending: bool,
}

impl HeldTables {
    /// Before the first round.
    pub const fn new() -> Self {
        Self {
            active: None,
            refusal: UploadRefusal::Storage,
            abort_pending: false,
        }
    }
}

impl TableUpload for HeldTables {
    fn begin(&mut self, _kind: u8, _total_len: u32, _crc32: u32) -> Result<(), UploadRefusal> {
        Err(self.refusal)
    }

    fn chunk(&mut self, _offset: u32, _data: &[u8]) -> Result<(), UploadRefusal> {
        Err(self.refusal)
    }

    fn commit(&mut self) -> Result<TableInfo, UploadRefusal> {
        Err(self.refusal)
    }

    fn abort(&mut self) {
        self.abort_pending = true;
    }

    fn active(&self, kind: u8) -> Option<TableInfo> {
        self.active.filter(|i| i.kind == kind)
    }
}

/// Runs `f` with the link's table store for one round, never waiting: the flash store
/// through the core's [`FlashTables`] (commit runs [`calibration_ok`]) when [`SHARED`] is
/// free, else `held` (refusing "busy" while [`erase_task`] erases). Afterwards `held` knows
/// the table in force, and [`ERASE`] is signalled if an accepted `begin` left a slot to
/// erase.
pub fn with_link_tables<R>(held: &mut HeldTables, f: impl FnOnce(&mut dyn TableUpload) -> R) -> R {
    let Ok(mut guard) = SHARED.try_lock() else {
        held.refusal = UploadRefusal::Busy;
        return f(held);
    };
    let Some(store) = guard.as_mut() else {
        held.refusal = UploadRefusal::Storage;
        return f(held);
    };
    let mut tables = FlashTables::new(store, calibration_ok as fn(&mut Flash, u32, u32) -> bool);
    if core::mem::take(&mut held.abort_pending) {
        tables.abort();
    }
    let r = f(&mut tables);
    held.active = tables.active(TABLE_KIND_CALIBRATION);
    if tables.store().pending_erase().is_some() {
        ERASE.signal(());
    }
    r
}

/// The erase task: when [`ERASE`] fires, erases the upload's slot sector by sector
/// ([`erase_pending`], the async driver: the executor runs the frame loop meanwhile),
/// holding [`SHARED`] for one sector at a time. A failed erase drops the upload (logged);
/// the ground then sees "no upload begun" and starts again.
#[embassy_executor::task]
pub async fn erase_task() {
    loop {
        ERASE.wait().await;
        loop {
            let mut guard = SHARED.lock().await;
            let Some(store) = guard.as_mut() else { break };
            if store.pending_erase().is_none() {
                break;
            }
            match erase_pending(store).await {
                Ok(EraseProgress::Done) => {
                    defmt::info!("store: upload slot erased");
                    break;
                }
                Ok(EraseProgress::Remaining(_)) => {}
                Err(e) => {
                    defmt::error!("store: erase failed, upload dropped: {}", e);
                    break;
                }
            }
        }
    }
}
