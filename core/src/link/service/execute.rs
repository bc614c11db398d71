//! Reading and executing a telecommand: the packet's checks (length, CRC, PUS-C version,
//! APID), the typed command, what it does to the tracker, the table store or the window
//! readout, and the verification report (`TM[1,1]` or `TM[1,2]` with the rejection and an
//! anomaly event) with the command's answer. Cost: one CRC-16 and a parse per packet; a
//! diagnostic window is sent a row at a time as the bulk queue has room.

use super::super::command::{Command, Rejection, WindowKind};
use super::super::framing::encoded_len_max;
use super::super::protocol::{self as p, MessageType};
use super::super::telemetry::{EVENT_DATA_LEN, Writer, event};
use super::super::upload::{TableInfo, UploadRefusal};
use super::targets::{Ctx, WindowReader};
use super::{Answer, BULK_QUEUE_BYTES, LinkService, Queue};
use crate::tracker::{CommandError, TrackerConfig};
use spacepackets::ecss::tc::PusTcReader;
use spacepackets::ecss::{PusError, PusPacket};
use spacepackets::{CcsdsPacket, PacketType};

impl LinkService {
    /// One decoded packet.
    pub(super) fn handle(&mut self, pkt: &[u8], targets: &mut Ctx<'_>) {
        let request_id = match pkt.get(..4) {
            Some(&[a, b, c, d]) => Some(u32::from_be_bytes([a, b, c, d])),
            _ => None,
        };
        let outcome = self.execute(pkt, targets);
        match (outcome, request_id) {
            (Ok(()), Some(id)) => {
                self.counters.accepted = self.counters.accepted.wrapping_add(1);
                let len = Writer::new(&mut self.data).u32(id).finish().unwrap_or(0);
                self.send(p::APID_CONTROL, p::TM_ACCEPTED, len, Queue::Urgent);
                self.after_accept(targets);
            }
            (Err(r), id) => {
                self.counters.rejected = self.counters.rejected.wrapping_add(1);
                let id = id.unwrap_or(0);
                let len = Writer::new(&mut self.data)
                    .u32(id)
                    .u16(r.code())
                    .u32(r.parameter())
                    .finish()
                    .unwrap_or(0);
                self.send(p::APID_CONTROL, p::TM_REJECTED, len, Queue::Urgent);
                let mut d = [0u8; EVENT_DATA_LEN];
                Writer::new(&mut d).u32(id).u16(r.code()).u32(r.parameter());
                self.send_event(event::COMMAND_REJECTED, &d, true);
            }
            (Ok(()), None) => {}
        }
    }

    /// Reports sent after a command's acceptance (its answer follows the acceptance).
    fn after_accept(&mut self, targets: &mut Ctx<'_>) {
        match core::mem::replace(&mut self.answer, Answer::None) {
            Answer::None => {}
            Answer::Pong => self.send(p::APID_CONTROL, p::TM_PONG, 0, Queue::Urgent),
            Answer::Housekeeping => {
                self.send_housekeeping(targets.tables.active(p::TABLE_KIND_CALIBRATION))
            }
            Answer::Table(kind) => {
                let info = targets.tables.active(kind);
                let i = info.unwrap_or(TableInfo {
                    kind,
                    len_bytes: 0,
                    crc32: 0,
                    sequence: 0,
                });
                let len = Writer::new(&mut self.data)
                    .u8(kind)
                    .u8(u8::from(info.is_some()))
                    .u32(i.len_bytes)
                    .u32(i.crc32)
                    .u32(i.sequence)
                    .finish()
                    .unwrap_or(0);
                self.send(p::APID_DIAGNOSTICS, p::TM_TABLE_REPORT, len, Queue::Bulk);
            }
            Answer::Committed(i) => {
                let mut d = [0u8; EVENT_DATA_LEN];
                Writer::new(&mut d)
                    .u8(i.kind)
                    .u32(i.len_bytes)
                    .u32(i.crc32)
                    .u32(i.sequence);
                self.send_event(event::TABLE_ACCEPTED, &d, false);
            }
        }
        self.poll_windows(&mut *targets.windows);
    }

    /// Reads and executes one packet.
    fn execute(&mut self, pkt: &[u8], targets: &mut Ctx<'_>) -> Result<(), Rejection> {
        if pkt.len() > p::MAX_TC_LEN {
            return Err(Rejection::Malformed);
        }
        let tc = match PusTcReader::new(pkt) {
            Ok(tc) => tc,
            Err(PusError::ChecksumFailure(_)) => {
                self.counters.crc_errors = self.counters.crc_errors.wrapping_add(1);
                return Err(Rejection::Checksum);
            }
            Err(_) => return Err(Rejection::Malformed),
        };
        // PUS version 2 (PUS-C) in the secondary header's first byte; the whole frame is the
        // packet.
        let version = pkt.get(6).map(|b| b >> 4);
        if tc.packet_type() != PacketType::Tc
            || version != Some(2)
            || tc.len_packed() != pkt.len()
            || tc.ccsds_version().value() != 0
        {
            return Err(Rejection::Malformed);
        }
        let apid = tc.apid().value();
        if apid != p::APID_CONTROL {
            return Err(Rejection::UnknownApid(apid));
        }
        let kind = MessageType {
            service: tc.service_type_id(),
            subtype: tc.message_subtype_id(),
        };
        let cmd = Command::parse(kind, tc.app_data())?;
        self.apply(cmd, targets)
    }

    fn apply(&mut self, cmd: Command<'_>, t: &mut Ctx<'_>) -> Result<(), Rejection> {
        // The store holds the defect commit's upload: the ground's upload waits for it.
        if self.amend.is_some()
            && matches!(
                cmd,
                Command::TableBegin { .. }
                    | Command::TableChunk { .. }
                    | Command::TableCommit
                    | Command::TableAbort
                    | Command::TableCommitDefects
            )
        {
            return Err(Rejection::Upload(UploadRefusal::Busy));
        }
        match cmd {
            Command::Ping => self.answer = Answer::Pong,
            Command::Housekeeping => self.answer = Answer::Housekeeping,
            Command::HousekeepingPeriod(f) => {
                self.hk_period = Some(f);
                self.frames_since_hk = 0;
            }
            Command::SetMode(m) => {
                let tracker = t.tracker.as_deref_mut().ok_or(Rejection::Standby)?;
                tracker.command_mode(m).map_err(|e| match e {
                    CommandError::NothingToTrack => Rejection::NothingToTrack,
                })?;
            }
            Command::SetParams { params, count } => {
                let tracker = t.tracker.as_deref_mut().ok_or(Rejection::Standby)?;
                let mut c = self.staged.unwrap_or(tracker.config());
                for &(id, v) in params.iter().take(count) {
                    set_param(&mut c, id, v)?;
                }
                tracker.set_config(c).map_err(Rejection::Config)?;
                self.staged = Some(c);
            }
            Command::Reset => self.reset = true,
            Command::Stars(n) => self.star_frames = (n != u16::MAX).then_some(n),
            Command::Window(req) => {
                if self.window.is_some() || !t.windows.check(&req) {
                    return Err(Rejection::WindowUnavailable);
                }
                self.window = Some((req, 0));
            }
            Command::TableBegin {
                kind,
                total_len,
                crc32,
            } => t
                .tables
                .begin(kind, total_len, crc32)
                .map_err(Rejection::Upload)?,
            Command::TableChunk { offset, data } => {
                t.tables.chunk(offset, data).map_err(Rejection::Upload)?;
            }
            Command::TableCommit => match t.tables.commit() {
                Ok(info) => self.answer = Answer::Committed(info),
                Err(r) => {
                    let mut d = [0u8; EVENT_DATA_LEN];
                    Writer::new(&mut d)
                        .u8(p::TABLE_KIND_CALIBRATION)
                        .u16(r.code());
                    self.send_event(event::TABLE_REFUSED, &d, true);
                    return Err(Rejection::Upload(r));
                }
            },
            Command::TableAbort => t.tables.abort(),
            Command::TableReport(kind) => self.answer = Answer::Table(kind),
            Command::TableCommitDefects => self.start_amend(t)?,
            Command::TimeSet(c) => self.time_set = Some(c),
            Command::Velocity(v) => self.velocity = Some(v),
        }
        Ok(())
    }

    pub(super) fn poll_windows(&mut self, windows: &mut dyn WindowReader) {
        let Some((req, mut row)) = self.window else {
            return;
        };
        let side = usize::from(req.side_px);
        let need = encoded_len_max(6 + 7 + p::TIMESTAMP_LEN + 2 + 9 + side * 4);
        while row < req.side_px && BULK_QUEUE_BYTES - self.bulk.len() >= need {
            let mut values = [0i32; p::MAX_WINDOW_PX as usize];
            let Some(vals) = values.get_mut(..side) else {
                break;
            };
            if !windows.read_row(&req, row, vals) {
                // The source lost the window: the rest is not sent (the ground sees rows
                // missing), and the next window request is free to start.
                row = req.side_px;
                break;
            }
            let mut w = Writer::new(&mut self.data);
            w.u16(req.x0)
                .u16(req.y0)
                .u16(req.side_px)
                .u16(row)
                .u8(match req.kind {
                    WindowKind::Raw => 0,
                    WindowKind::Calibrated => 1,
                });
            for v in vals.iter() {
                w.u32(u32::from_ne_bytes(v.to_ne_bytes()));
            }
            let len = w.finish().unwrap_or(0);
            self.send(p::APID_DIAGNOSTICS, p::TM_WINDOW_ROW, len, Queue::Bulk);
            row += 1;
        }
        self.window = (row < req.side_px).then_some((req, row));
    }
}

/// Sets parameter `id` of `c` to `v` (see [`p::PARAMS`]).
fn set_param(c: &mut TrackerConfig, id: u8, v: u32) -> Result<(), Rejection> {
    let small = || u16::try_from(v).map_err(|_| Rejection::BadValue);
    match id {
        1 => c.exposure_ms = v,
        2 => c.detect.pixel_sigmas = f32::from_bits(v),
        3 => c.detect.peak_sigmas = f32::from_bits(v),
        4 => c.detect.min_snr = f32::from_bits(v),
        5 => c.min_track_stars = small()?,
        6 => c.reacquire_every = v,
        7 => c.max_stars = small()?,
        _ => return Err(Rejection::BadValue),
    }
    Ok(())
}
