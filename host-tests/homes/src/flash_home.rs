//! The software-in-the-loop's flash table store: the core's [`FlashStore`] over the flash
//! model kept in a file ([`FileFlash`]), served to the link through the core's
//! [`FlashTables`] and to the tracker as its table in force ([`FlashHome`]).
//!
//! What it is for: `startrack sil --port P --flash FILE [--power-cut-at-write N]` runs the
//! upload path the board runs (two slots, erase, units, header last) with power cuts, and a
//! restart with the same FILE is a reboot. What it costs: the 1 MB bank in memory, and a
//! write of the 1 MB + 32 KB file after every link round that programmed or erased flash.
//!
//! "In force" in the SIL: at boot the table of the newest valid slot is read from the store
//! (CRC checked again), parsed and checked against the sensor's geometry; a commit puts the
//! new table in force from the next frame (the board's firmware uses it from its next start).
//! The erase between `begin` and the chunks is run by [`FlashHome::service`] in the link
//! phase between frames (the model erases at once; on the board it is its own task).

use crate::sil::{self, SilConfig};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::{FlashTables, TableInfo, TableUpload, UploadRefusal, active_info};
use startrack_core::store::{FlashStore, H743_BANK2, StoreError, TableKind};
use startrack_core::table::CalibTable;
use startrack_core::tracker::TableStore;
use startrack_sim::flash_model::{CutMode, FileFlash, MockFlash, SECTOR_B};
use startrack_sim::sim::SensorParams;
use std::path::Path;

/// Tile size of the SIL's tables in flash (`2^3` = 8 x 8 px maps; a per-pixel table of the
/// CCD47-20 is ~3 MB, a slot holds 256 KB).
pub const FLASH_TILE_LOG2: u8 = 3;

/// The SIL's calibration table in its flash form (maps in [`FLASH_TILE_LOG2`] tiles).
pub fn flash_table(config: &SilConfig, params: &SensorParams) -> Result<Vec<u8>, String> {
    sil::truth_table_tiled(config, params, FLASH_TILE_LOG2)
}

/// The calibration table's own checks at commit, for the flash model: the core parses the
/// table where it lies and its geometry is the sensor's.
pub fn calibration_ok(geometry: ReadoutGeometry) -> impl FnMut(&mut MockFlash, u32, u32) -> bool {
    move |f, at, len| {
        let end = at as usize + len as usize;
        f.bytes()
            .get(at as usize..end)
            .and_then(|b| CalibTable::parse(b).ok())
            .is_some_and(|t| *t.geometry() == geometry)
    }
}

/// The flash store of the SIL, persisted in a file, with the table in force loaded for the
/// tracker.
pub struct FlashHome {
    file: FileFlash,
    store: FlashStore<MockFlash>,
    geometry: ReadoutGeometry,
    /// The table the tracker uses and its store info (CRC and length identify it).
    table: Option<(CalibTable<'static>, TableInfo)>,
    /// Flash steps when the file was last written.
    saved_steps: u64,
}

impl FlashHome {
    /// Boots from `path`: mounts the store on the flash the file holds (a new file: an erased
    /// bank, into which `initial` is uploaded as the bring-up table, then saved), and loads
    /// the table in force.
    pub fn open(
        path: &Path,
        geometry: ReadoutGeometry,
        initial: Option<&[u8]>,
    ) -> Result<Self, String> {
        let fresh = !path.exists();
        let mut file = FileFlash::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let flash = std::mem::replace(&mut file.flash, MockFlash::new(SECTOR_B, 0));
        let store = FlashStore::mount(flash, H743_BANK2)
            .map_err(|e| format!("{}: flash store: {}", path.display(), e.error))?;
        let mut home = Self {
            file,
            store,
            geometry,
            table: None,
            saved_steps: 0,
        };
        if fresh && let Some(t) = initial {
            home.bring_up(t)
                .map_err(|e| format!("bring-up table: {e}"))?;
        }
        home.saved_steps = u64::MAX;
        home.persist()
            .map_err(|e| format!("{}: {e}", path.display()))?;
        home.load();
        Ok(home)
    }

    /// A reboot: the flash keeps what it holds (power back on after a cut), the store is
    /// mounted again and the table in force loaded again.
    pub fn reboot(&mut self) -> Result<(), String> {
        let mut flash = std::mem::replace(
            &mut self.store,
            FlashStore::mount(MockFlash::new(H743_BANK2_CAPACITY, 0), H743_BANK2)
                .map_err(|e| e.error.to_string())?,
        )
        .into_flash();
        flash.power_on();
        self.store = FlashStore::mount(flash, H743_BANK2).map_err(|e| e.error.to_string())?;
        self.load();
        Ok(())
    }

    /// Cuts the power during the `n`-th flash step (unit program or sector erase) from now,
    /// `n` from 1.
    pub fn cut_power_at(&mut self, n: u64) {
        let at = self.store.flash().steps() + n.saturating_sub(1);
        self.store.flash_mut().cut_power(at, CutMode::During);
    }

    /// Cuts the power right after the `n`-th flash step from now completed, `n` from 1.
    pub fn cut_power_after(&mut self, n: u64) {
        let at = self.store.flash().steps() + n.saturating_sub(1);
        self.store.flash_mut().cut_power(at, CutMode::After);
    }

    /// Whether the power was cut.
    pub fn power_cut(&self) -> bool {
        self.store.flash().is_off()
    }

    /// Flash steps done since start.
    pub fn steps(&self) -> u64 {
        self.store.flash().steps()
    }

    /// The store.
    pub fn store(&self) -> &FlashStore<MockFlash> {
        &self.store
    }

    /// The owner's erase step: erases what the upload under way still needs (the model
    /// erases at once). An erase failure drops the upload; the link's chunks then get
    /// "no upload begun" and the ground starts again.
    pub fn service(&mut self) -> Result<(), StoreError> {
        FlashTables::new(&mut self.store, calibration_ok(self.geometry)).service_all()
    }

    /// Writes the flash to the file if a step was done since the last write.
    pub fn persist(&mut self) -> std::io::Result<()> {
        let steps = self.steps();
        if steps == self.saved_steps {
            return Ok(());
        }
        self.file.flash = self.store.flash().clone();
        self.file.save()?;
        self.file.flash = MockFlash::new(SECTOR_B, 0);
        self.saved_steps = steps;
        Ok(())
    }

    /// Loads the calibration table in force for the tracker (kept if it is the one loaded).
    fn load(&mut self) {
        let Some(info) = active_info(&self.store, TABLE_KIND_CALIBRATION) else {
            self.table = None;
            return;
        };
        if self
            .table
            .is_some_and(|(_, i)| (i.crc32, i.len_bytes) == (info.crc32, info.len_bytes))
        {
            self.table = self.table.map(|(t, _)| (t, info));
            return;
        }
        let mut buf = vec![0u8; info.len_bytes as usize];
        self.table = match self.store.read_active(TableKind::Calibration, &mut buf) {
            Ok(_) => {
                // Leaked: the tracker's table borrows it for the rest of the process, as the
                // board's RAM copy lives for the rest of the run (one per table committed).
                let bytes: &'static [u8] = buf.leak();
                CalibTable::parse(bytes)
                    .ok()
                    .filter(|t| *t.geometry() == self.geometry)
                    .map(|t| (t, info))
            }
            Err(_) => None,
        };
    }

    fn bring_up(&mut self, table: &[u8]) -> Result<TableInfo, UploadRefusal> {
        let len = u32::try_from(table.len()).map_err(|_| UploadRefusal::TooLong)?;
        let crc = startrack_sim::flash_model::CRC32.checksum(table);
        let mut up = FlashTables::new(&mut self.store, calibration_ok(self.geometry));
        up.begin(TABLE_KIND_CALIBRATION, len, crc)?;
        up.service_all().map_err(startrack_core::link::refusal_of)?;
        up.chunk(0, table)?;
        up.commit()
    }
}

/// Capacity of the bank the SIL's flash models, bytes.
const H743_BANK2_CAPACITY: usize = startrack_sim::flash_model::BANK_B;

impl TableUpload for FlashHome {
    fn begin(&mut self, kind: u8, total_len: u32, crc32: u32) -> Result<(), UploadRefusal> {
        FlashTables::new(&mut self.store, calibration_ok(self.geometry))
            .begin(kind, total_len, crc32)
    }

    fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), UploadRefusal> {
        FlashTables::new(&mut self.store, calibration_ok(self.geometry)).chunk(offset, data)
    }

    fn commit(&mut self) -> Result<TableInfo, UploadRefusal> {
        let info = FlashTables::new(&mut self.store, calibration_ok(self.geometry)).commit()?;
        // In force from the next frame.
        self.load();
        Ok(info)
    }

    fn abort(&mut self) {
        FlashTables::new(&mut self.store, calibration_ok(self.geometry)).abort();
    }

    fn active(&self, kind: u8) -> Option<TableInfo> {
        active_info(&self.store, kind)
    }

    fn read_active(&mut self, kind: u8, offset: u32, out: &mut [u8]) -> bool {
        startrack_core::link::read_active_at(&mut self.store, kind, offset, out)
    }
}

impl TableStore<'static> for FlashHome {
    fn active_table(&mut self) -> Option<CalibTable<'static>> {
        self.table.map(|(t, _)| t)
    }
}
