//! The table store in memory: the host binding of the core's table-upload and table-store
//! ports for the SIL and the link tests. A committed table is kept (leaked) for the rest of the
//! process, as flash keeps it; the upload under way is a `Vec`. Cost: one copy of each
//! uploaded byte and one CRC-32 over the table at commit.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::{TableInfo, TableUpload, UploadRefusal};
use startrack_core::table::CalibTable;
use startrack_core::tracker::TableStore;
use startrack_sim::flash_model::CRC32;

/// Largest table the memory store takes, bytes (a per-pixel table of the CCD47-20 is ~3 MB;
/// the board's flash slot is 128 KB).
pub const MEMORY_MAX_TABLE: u32 = 8 << 20;

struct Upload {
    kind: u8,
    total_len: u32,
    crc32: u32,
    bytes: Vec<u8>,
}

/// The table store in memory: the table in force (a committed table is kept for the rest of
/// the process, as flash keeps it), and the upload under way.
pub struct MemoryTables {
    geometry: ReadoutGeometry,
    active: Option<(CalibTable<'static>, TableInfo)>,
    /// The bytes of the table in force.
    active_bytes: &'static [u8],
    upload: Option<Upload>,
    sequence: u32,
}

/// Leaks `bytes` and parses them as a table of `geometry`.
fn keep(
    bytes: Vec<u8>,
    geometry: &ReadoutGeometry,
) -> Option<(CalibTable<'static>, &'static [u8])> {
    let b: &'static [u8] = bytes.leak();
    let t = CalibTable::parse(b).ok()?;
    (t.geometry() == geometry).then_some((t, b))
}

impl MemoryTables {
    /// A store for tables of `geometry`, with `initial` in force if it is a usable table.
    pub fn new(geometry: ReadoutGeometry, initial: Option<Vec<u8>>) -> Self {
        let active = initial.and_then(|b| {
            let info = TableInfo {
                kind: TABLE_KIND_CALIBRATION,
                len_bytes: u32::try_from(b.len()).ok()?,
                crc32: CRC32.checksum(&b),
                sequence: 0,
            };
            keep(b, &geometry).map(|t| (t, info))
        });
        Self {
            geometry,
            active_bytes: active.map_or(&[], |((_, b), _)| b),
            active: active.map(|((t, _), i)| (t, i)),
            upload: None,
            sequence: 0,
        }
    }
}

impl TableUpload for MemoryTables {
    fn begin(&mut self, kind: u8, total_len: u32, crc32: u32) -> Result<(), UploadRefusal> {
        if self.upload.is_some() {
            return Err(UploadRefusal::Busy);
        }
        if kind != TABLE_KIND_CALIBRATION {
            return Err(UploadRefusal::UnknownKind);
        }
        if total_len == 0 || total_len > MEMORY_MAX_TABLE {
            return Err(UploadRefusal::TooLong);
        }
        self.upload = Some(Upload {
            kind,
            total_len,
            crc32,
            bytes: Vec::new(),
        });
        Ok(())
    }

    fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), UploadRefusal> {
        let u = self.upload.as_mut().ok_or(UploadRefusal::NotStarted)?;
        let at = u32::try_from(u.bytes.len()).map_err(|_| UploadRefusal::TooLong)?;
        if offset != at {
            return Err(UploadRefusal::OutOfOrder { expected: at });
        }
        let end = u64::from(at) + data.len() as u64;
        if end > u64::from(u.total_len) {
            return Err(UploadRefusal::TooLong);
        }
        u.bytes.extend_from_slice(data);
        Ok(())
    }

    fn commit(&mut self) -> Result<TableInfo, UploadRefusal> {
        let u = self.upload.take().ok_or(UploadRefusal::NotStarted)?;
        if u.bytes.len() as u64 != u64::from(u.total_len) {
            return Err(UploadRefusal::Incomplete);
        }
        if CRC32.checksum(&u.bytes) != u.crc32 {
            return Err(UploadRefusal::CrcMismatch);
        }
        let (table, bytes) = keep(u.bytes, &self.geometry).ok_or(UploadRefusal::Invalid)?;
        self.active_bytes = bytes;
        self.sequence += 1;
        let info = TableInfo {
            kind: u.kind,
            len_bytes: u.total_len,
            crc32: u.crc32,
            sequence: self.sequence,
        };
        self.active = Some((table, info));
        Ok(info)
    }

    fn abort(&mut self) {
        self.upload = None;
    }

    fn active(&self, kind: u8) -> Option<TableInfo> {
        self.active.map(|(_, i)| i).filter(|i| i.kind == kind)
    }

    fn read_active(&mut self, kind: u8, offset: u32, out: &mut [u8]) -> bool {
        let at = offset as usize;
        match self
            .active(kind)
            .and(self.active_bytes.get(at..at + out.len()))
        {
            Some(b) => {
                out.copy_from_slice(b);
                true
            }
            None => false,
        }
    }
}

impl TableStore<'static> for MemoryTables {
    fn active_table(&mut self) -> Option<CalibTable<'static>> {
        self.active.map(|(t, _)| t)
    }
}
