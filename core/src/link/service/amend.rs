//! The in-flight defect commit (`TC[133,7]`): the table in force with the tracker's
//! confirmed defect pixels added ([`crate::table::AmendPlan`]), streamed into the store's
//! inactive slot through the upload path a bounded number of bytes a link round, then
//! committed. Cost: per round at most [`AMEND_BYTES_PER_ROUND`] bytes read from the table in
//! force and written as chunks.

use super::super::command::Rejection;
use super::super::protocol as p;
use super::super::telemetry::{EVENT_DATA_LEN, Writer, event};
use super::super::upload::{TableUpload, UploadRefusal};
use super::LinkService;
use super::targets::Ctx;
use crate::calib::refresh::DefectKind;
use crate::table::{AmendPlan, MAX_AMEND_PIXELS};
use crate::units::Kelvin;

/// Bytes of an in-flight defect commit written to the store per link round (a flash unit
/// of 32 bytes programs in tens of microseconds on the STM32H7: ~8 KB is a few ms).
pub const AMEND_BYTES_PER_ROUND: u32 = 8192;

/// Link rounds in a row in which the table in force cannot be read before an in-flight
/// defect commit is given up (the board's store is out of reach while its erase task holds
/// it: ~2 s a sector, one round a frame).
pub const AMEND_READ_ROUNDS: u16 = 600;

impl LinkService {
    /// Starts the in-flight defect commit: the table in force with the tracker's confirmed
    /// pixels added, into the store's inactive slot through the upload path.
    pub(super) fn start_amend(&mut self, t: &mut Ctx<'_>) -> Result<(), Rejection> {
        let tracker = t.tracker.as_deref_mut().ok_or(Rejection::Standby)?;
        let mut hot = [(0u16, 0u16); MAX_AMEND_PIXELS];
        let mut tel = [(0u16, 0u16); MAX_AMEND_PIXELS];
        let (mut nh, mut nt) = (0, 0);
        for d in tracker.new_defects() {
            let (list, n) = match d.kind {
                DefectKind::Hot => (&mut hot, &mut nh),
                DefectKind::Telegraph => (&mut tel, &mut nt),
            };
            if let Some(slot) = list.get_mut(*n) {
                *slot = (d.x_px, d.y_px);
                *n += 1;
            }
        }
        let kind = p::TABLE_KIND_CALIBRATION;
        let info = t
            .tables
            .active(kind)
            .ok_or(Rejection::Amend(crate::table::AmendError::Read))?;
        // A new hot section takes the last frame's temperature as its reference.
        let t_ref = Kelvin::from_bits(self.last.map_or(0, |s| s.temperature_k.to_bits()));
        let tables = &mut *t.tables;
        let mut read = |at: u32, out: &mut [u8]| tables.read_active(kind, at, out);
        let plan = AmendPlan::new(
            &mut read,
            info.len_bytes,
            hot.get(..nh).unwrap_or(&[]),
            tel.get(..nt).unwrap_or(&[]),
            t_ref,
        )
        .map_err(Rejection::Amend)?;
        t.tables
            .begin(kind, plan.len_bytes(), plan.crc32())
            .map_err(Rejection::Upload)?;
        self.amend = Some((plan, 0, 0));
        Ok(())
    }

    /// Moves the in-flight defect commit on: chunks as the store takes them (it refuses
    /// them busy until the owner has erased the slot), at most [`AMEND_BYTES_PER_ROUND`],
    /// then the commit. Ends with a `DEFECTS_COMMITTED` event, or a `TABLE_REFUSED`
    /// anomaly (the upload dropped, the table in force kept).
    pub(super) fn advance_amend(&mut self, tables: &mut dyn TableUpload) {
        let Some((plan, mut next, unread)) = self.amend.take() else {
            return;
        };
        let kind = p::TABLE_KIND_CALIBRATION;
        let mut buf = [0u8; p::MAX_CHUNK_BYTES];
        let mut budget = AMEND_BYTES_PER_ROUND;
        while next < plan.len_bytes() && budget > 0 {
            let emitted = {
                let mut read = |at: u32, out: &mut [u8]| tables.read_active(kind, at, out);
                plan.emit(&mut read, next, &mut buf)
            };
            let n = match emitted {
                Ok(n) if n > 0 => n,
                Err(crate::table::AmendError::Read) if unread < AMEND_READ_ROUNDS => {
                    // The store may be out of reach this round (its erase running).
                    self.amend = Some((plan, next, unread + 1));
                    return;
                }
                _ => return self.amend_failed(tables, UploadRefusal::Storage),
            };
            match tables.chunk(next, buf.get(..n).unwrap_or(&[])) {
                Ok(()) => {
                    let n = u32::try_from(n).unwrap_or(u32::MAX);
                    next = next.saturating_add(n);
                    budget = budget.saturating_sub(n);
                }
                Err(UploadRefusal::Busy) => {
                    // The slot is not erased yet: the owner's erase runs between rounds.
                    self.amend = Some((plan, next, 0));
                    return;
                }
                Err(r) => return self.amend_failed(tables, r),
            }
        }
        if next < plan.len_bytes() {
            self.amend = Some((plan, next, 0));
            return;
        }
        match tables.commit() {
            Ok(info) => {
                let mut d = [0u8; EVENT_DATA_LEN];
                let count = |a: &[(u16, u16)]| u16::try_from(a.len()).unwrap_or(u16::MAX);
                Writer::new(&mut d)
                    .u16(count(plan.added_hot()))
                    .u16(count(plan.added_telegraph()))
                    .u32(info.len_bytes)
                    .u32(info.crc32)
                    .u32(info.sequence);
                self.send_event(event::DEFECTS_COMMITTED, &d, false);
            }
            Err(UploadRefusal::Busy) => self.amend = Some((plan, next, 0)),
            Err(r) => self.amend_failed(tables, r),
        }
    }

    fn amend_failed(&mut self, tables: &mut dyn TableUpload, r: UploadRefusal) {
        tables.abort();
        let mut d = [0u8; EVENT_DATA_LEN];
        Writer::new(&mut d)
            .u8(p::TABLE_KIND_CALIBRATION)
            .u16(r.code());
        self.send_event(event::TABLE_REFUSED, &d, true);
    }
}
