//! The telemetry out: two bounded queues of COBS-framed TM packets (`urgent` before
//! `bulk`), the packets the service builds into them (housekeeping, attitude, events, star
//! lists), and the tracker's telemetry port ([`TelemetrySink`] for [`LinkService`]). Cost:
//! per packet one PUS-C header, a CRC-16 and the COBS encoding; a full queue drops and
//! counts rather than waits.

use super::super::framing::encode;
use super::super::protocol::{self as p, MessageType};
use super::super::telemetry::{
    AttitudeReport, EVENT_DATA_LEN, Housekeeping, Writer, encode_stars, status, tracker_event,
};
use super::super::upload::TableInfo;
use super::{LinkService, Queue};
use crate::tracker::{Event, FrameSummary, Mode, StarRecord, TelemetrySink, TemperatureSource};
use arbitrary_int::{u11, u14};
use heapless::Deque;
use spacepackets::SpHeader;
use spacepackets::ecss::tm::{PusTmCreator, PusTmSecondaryHeader};
use spacepackets::ecss::{CreatorConfig, MessageTypeId};

impl LinkService {
    /// Copies queued telemetry into `out` (urgent first), as much as fits; returns the bytes
    /// written. The home calls it with what its UART can take now.
    pub fn transmit(&mut self, out: &mut [u8]) -> usize {
        let mut n = 0;
        for slot in out.iter_mut() {
            match self.urgent.pop_front().or_else(|| self.bulk.pop_front()) {
                Some(b) => {
                    *slot = b;
                    n += 1;
                }
                None => break,
            }
        }
        n
    }

    /// A housekeeping report of the state now, with `table_in_force` the calibration table
    /// the store holds in force (`TableUpload::active` of the calibration kind).
    pub fn housekeeping(&self, table_in_force: Option<TableInfo>) -> Housekeeping {
        let s = self.last;
        Housekeeping {
            mode: s.map_or(Mode::Standby, |s| s.mode),
            next_mode: s.map_or(Mode::Standby, |s| s.next_mode),
            calibrated: s.is_some_and(|s| s.calibrated),
            temperature_source: s.map_or(TemperatureSource::None, |s| s.temperature_source),
            temperature_k_bits: s.map_or(0, |s| s.temperature_k.to_bits()),
            frame: s.map_or(0, |s| s.frame),
            stars: s.map_or(0, |s| s.stars),
            centroids: s.map_or(0, |s| s.centroids),
            totals: self.totals,
            link: self.counters,
            table: table_in_force,
            uptime_us: self.now_us,
            setup_faults: self.setup_faults,
            dark_ratio_u8f8: s.map_or(0, |s| s.dark_drift.ratio_u8f8),
            status: if s.is_some_and(|s| s.dark_drift.out_of_band) {
                status::DARK_DRIFT
            } else {
                0
            },
            defects_pending: s.map_or(0, |s| s.defects_pending),
            hits: s.map_or(0, |s| s.hits),
            masked: s.map_or(0, |s| s.masked),
            obstructions: s.map_or(0, |s| s.obstructions.bits()),
        }
    }

    /// Queues a housekeeping report (the home may also call this on its own schedule).
    pub fn send_housekeeping(&mut self, table_in_force: Option<TableInfo>) {
        let hk = self.housekeeping(table_in_force);
        let len = hk.encode(&mut self.data).unwrap_or(0);
        self.send(p::APID_HOUSEKEEPING, p::TM_HOUSEKEEPING, len, Queue::Bulk);
    }

    /// Sends a frame's attitude report (the attitude stage's result, after the frame), on the
    /// bulk queue: counted dropped when the queue is full, like a star list.
    pub fn send_attitude(&mut self, report: &AttitudeReport) {
        let len = report.encode(&mut self.data).unwrap_or(0);
        self.send(p::APID_ATTITUDE, p::TM_ATTITUDE, len, Queue::Bulk);
    }

    /// Called by the home after each frame (after the tracker reported it to this sink):
    /// periodic housekeeping, reporting `table_in_force` as [`Self::housekeeping`] does.
    pub fn end_of_frame(&mut self, table_in_force: Option<TableInfo>) {
        let period = self.hk_period.unwrap_or(Self::DEFAULT_HK_PERIOD);
        if period == 0 {
            return;
        }
        self.frames_since_hk = self.frames_since_hk.saturating_add(1);
        if self.frames_since_hk >= period {
            self.frames_since_hk = 0;
            self.send_housekeeping(table_in_force);
        }
    }

    pub(super) fn send_event(&mut self, id: u16, d: &[u8; EVENT_DATA_LEN], anomaly: bool) {
        let len = Writer::new(&mut self.data)
            .u16(id)
            .bytes(d)
            .finish()
            .unwrap_or(0);
        let kind = if anomaly {
            p::TM_EVENT_ANOMALY
        } else {
            p::TM_EVENT_INFO
        };
        self.send(p::APID_CONTROL, kind, len, Queue::Urgent);
    }

    /// Builds a TM packet with the first `len` bytes of `self.data`, frames it and queues
    /// it, or counts it dropped.
    pub(super) fn send(&mut self, apid: u16, kind: MessageType, len: usize, queue: Queue) {
        // One sequence count per APID (0x100..=0x104).
        let slot = usize::from(apid.wrapping_sub(p::APID_CONTROL)).min(4);
        let seq = self.seq.get(slot).copied().unwrap_or(0);
        if let Some(s) = self.seq.get_mut(slot) {
            *s = s.wrapping_add(1) & 0x3FFF;
        }
        let stamp = self.now_us.to_be_bytes();
        let src = self.data.get(..len).unwrap_or(&[]);
        let sp = SpHeader::new_for_unseg_tm(u11::new(apid & 0x7FF), u14::new(seq & 0x3FFF), 0);
        let sec = PusTmSecondaryHeader::new_simple(
            MessageTypeId::new(kind.service, kind.subtype),
            &stamp,
        );
        let tm = PusTmCreator::new(sp, sec, src, CreatorConfig::default());
        let framed = tm
            .write_to_slice(&mut self.packet)
            .ok()
            .and_then(|n| self.packet.get(..n))
            .and_then(|pkt| encode(pkt, &mut self.framed));
        let Some(n) = framed else {
            self.counters.tm_dropped = self.counters.tm_dropped.wrapping_add(1);
            return;
        };
        let bytes = self.framed.get(..n).unwrap_or(&[]);
        let ok = match queue {
            Queue::Urgent => push_all(&mut self.urgent, bytes),
            Queue::Bulk => push_all(&mut self.bulk, bytes),
        };
        if ok {
            self.counters.tm_queued = self.counters.tm_queued.wrapping_add(1);
        } else {
            self.counters.tm_dropped = self.counters.tm_dropped.wrapping_add(1);
        }
    }
}

/// Pushes `bytes` whole or not at all.
fn push_all<const C: usize>(q: &mut Deque<u8, C>, bytes: &[u8]) -> bool {
    if C - q.len() < bytes.len() {
        return false;
    }
    bytes.iter().all(|&b| q.push_back(b).is_ok())
}

impl TelemetrySink for LinkService {
    fn star(&mut self, _frame: u32, star: &StarRecord) {
        if self.stars.push(*star).is_err() {
            self.counters.stars_not_sent = self.counters.stars_not_sent.wrapping_add(1);
        }
    }

    fn frame(&mut self, s: &FrameSummary) {
        let t = &mut self.totals;
        let add = |a: &mut u32, v: u32| *a = a.wrapping_add(v);
        add(&mut t.frames, 1);
        add(&mut t.lines_refused, u32::from(s.lines_refused));
        add(&mut t.candidates_dropped, s.candidates_dropped);
        add(&mut t.windows_dropped, u32::from(s.windows_dropped));
        add(&mut t.ring_lost, u32::from(s.ring_lost));
        add(&mut t.calib_failed, u32::from(s.calib_failed));
        add(&mut t.track_refused, u32::from(s.track_refused));
        add(&mut t.track_lost, u32::from(s.track_lost));
        add(&mut t.stars_dropped, u32::from(s.stars_dropped));
        add(&mut t.hits, u32::from(s.hits));
        add(&mut t.masked, u32::from(s.masked));
        self.last = Some(*s);
        if self.star_frames != Some(0) {
            let len = encode_stars(s.frame, s.mode, &self.stars, &mut self.data).unwrap_or(0);
            self.send(p::APID_STARS, p::TM_STARS, len, Queue::Bulk);
            if let Some(n) = self.star_frames.as_mut() {
                *n = n.saturating_sub(1);
            }
        }
        self.stars.clear();
    }

    fn event(&mut self, e: &Event) {
        if let Event::ConfigApplied { .. } = e {
            self.staged = None;
        }
        let (id, d) = tracker_event(e);
        self.send_event(id, &d, false);
    }
}
