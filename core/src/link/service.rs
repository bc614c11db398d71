//! The link service: bytes in, commands applied, telemetry queued. The home feeds it what the
//! UART received ([`LinkService::receive`]), lets it run between frames
//! ([`LinkService::poll`]), passes it as the tracker's telemetry port, and sends what
//! [`LinkService::transmit`] gives when the UART can take it.
//!
//! - Every telecommand gets `TM[1,1]` (executed) or `TM[1,2]` with its [`Rejection`]; a
//!   rejection is also an anomaly event. A packet with a bad CRC or an unreadable header is
//!   rejected with the request id of its first four bytes when it has them.
//! - Telemetry waits in two bounded queues of COBS frames: `urgent` (verification reports,
//!   events) is sent before `bulk` (star lists, housekeeping, windows, table reports). A
//!   packet that does not fit its queue is dropped and counted (`tm_dropped`): a slow link
//!   loses telemetry, never frame time, and command answers are the last to go.
//! - Nothing blocks and nothing panics; every buffer is fixed: the receive frame
//!   ([`p::MAX_TC_LEN`] + COBS overhead), the queues ([`URGENT_QUEUE_BYTES`],
//!   [`BULK_QUEUE_BYTES`]), one telemetry packet's scratch.
//!
//! Cost: per received byte a push (and per packet a CRC-16 and the command); per frame one
//! star list (~0.9 KB for 32 stars) and, every `hk_period` frames, one report.

use super::command::{Command, Rejection, WindowKind, WindowRequest};
use super::framing::{Deframer, Pushed, encode, encoded_len_max};
use super::protocol::{self as p, MessageType};
use super::telemetry::{
    EVENT_DATA_LEN, FrameTotals, Housekeeping, LinkCounters, Writer, encode_stars, event,
    tracker_event,
};
use super::upload::{TableInfo, TableUpload, UploadRefusal};
use crate::calib::refresh::{Defect, DefectKind};
use crate::table::{AmendPlan, MAX_AMEND_PIXELS};
use crate::tracker::{
    CommandError, ConfigError, Event, FrameSummary, Mode, StarRecord, TelemetrySink, Tracker,
    TrackerConfig,
};
use crate::units::Kelvin;
use arbitrary_int::{u11, u14};
use heapless::Deque;
use spacepackets::ecss::tc::PusTcReader;
use spacepackets::ecss::tm::{PusTmCreator, PusTmSecondaryHeader};
use spacepackets::ecss::{CreatorConfig, MessageTypeId, PusError, PusPacket};
use spacepackets::{CcsdsPacket, PacketType, SpHeader};

/// Bytes of the urgent queue (verification reports and events: ~20 bytes each framed).
pub const URGENT_QUEUE_BYTES: usize = 2048;
/// Bytes of the bulk queue (a 32-star list is ~925 bytes framed).
pub const BULK_QUEUE_BYTES: usize = 8192;

const RX_FRAME: usize = encoded_len_max(p::MAX_TC_LEN);
const TX_FRAME: usize = encoded_len_max(p::MAX_TM_LEN);

/// Reads a diagnostic window for [`Command::Window`] (the board: not yet; the SIL: the
/// simulated frame).
pub trait WindowReader {
    /// Whether `request` can be read (inside the area, a source there).
    fn check(&mut self, request: &WindowRequest) -> bool;
    /// Row `row` (0-based within the window) into `out` (`side_px` values: raw ADU, or
    /// calibrated e- x 64); `false` if it cannot be read.
    fn read_row(&mut self, request: &WindowRequest, row: u16, out: &mut [i32]) -> bool;
}

/// A window reader that has no source (every window request is rejected).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoWindows;

impl WindowReader for NoWindows {
    fn check(&mut self, _request: &WindowRequest) -> bool {
        false
    }

    fn read_row(&mut self, _request: &WindowRequest, _row: u16, _out: &mut [i32]) -> bool {
        false
    }
}

/// What the link's mode and configuration commands act on: the tracker application
/// ([`Tracker`] implements it). A trait so that the same service also runs with no tracker
/// at all (the safe standby, [`LinkService::receive_standby`]).
pub trait TrackerControl {
    /// Asks for `mode` from the next frame ([`Tracker::command_mode`]).
    fn command_mode(&mut self, mode: Mode) -> Result<(), CommandError>;
    /// The configuration in force.
    fn config(&self) -> TrackerConfig;
    /// Replaces the configuration if it passes its checks ([`Tracker::set_config`]).
    fn set_config(&mut self, config: TrackerConfig) -> Result<(), ConfigError>;
    /// The pixels confirmed in flight that the table in force does not list
    /// ([`Tracker::new_defects`]; none by default).
    fn new_defects(&self) -> &[Defect] {
        &[]
    }
}

impl<const N: usize> TrackerControl for Tracker<'_, '_, N> {
    fn command_mode(&mut self, mode: Mode) -> Result<(), CommandError> {
        Tracker::command_mode(self, mode)
    }

    fn config(&self) -> TrackerConfig {
        *Tracker::config(self)
    }

    fn set_config(&mut self, config: TrackerConfig) -> Result<(), ConfigError> {
        Tracker::set_config(self, config)
    }

    fn new_defects(&self) -> &[Defect] {
        Tracker::new_defects(self)
    }
}

/// What a command acts on inside the service: the tracker if one runs.
struct Ctx<'a> {
    tracker: Option<&'a mut dyn TrackerControl>,
    tables: &'a mut dyn TableUpload,
    windows: &'a mut dyn WindowReader,
}

/// What commands act on, for one call.
pub struct Targets<'a, 't, 'b, const N: usize> {
    /// The tracker application.
    pub tracker: &'a mut Tracker<'t, 'b, N>,
    /// The table store.
    pub tables: &'a mut dyn TableUpload,
    /// The diagnostic window source.
    pub windows: &'a mut dyn WindowReader,
}

/// The link's state: receive framing, command execution, the telemetry queues.
pub struct LinkService {
    rx: Deframer<RX_FRAME>,
    urgent: Deque<u8, URGENT_QUEUE_BYTES>,
    bulk: Deque<u8, BULK_QUEUE_BYTES>,
    data: [u8; p::MAX_TM_LEN],
    packet: [u8; p::MAX_TM_LEN],
    framed: [u8; TX_FRAME],
    seq: [u16; 5],
    counters: LinkCounters,
    totals: FrameTotals,
    last: Option<FrameSummary>,
    stars: heapless::Vec<StarRecord, { p::MAX_LINK_STARS }>,
    /// Star lists still to send (`None`: every frame). Zero-valued defaults throughout, so
    /// a static service costs no flash.
    star_frames: Option<u16>,
    /// Housekeeping period, frames (`None`: [`Self::DEFAULT_HK_PERIOD`]).
    hk_period: Option<u16>,
    frames_since_hk: u16,
    staged: Option<TrackerConfig>,
    window: Option<(WindowRequest, u16)>,
    reset: bool,
    now_us: u64,
    answer: Answer,
    setup_faults: u16,
    /// The in-flight defect commit under way: its plan, the bytes written so far, and the
    /// link rounds in a row the table in force could not be read.
    amend: Option<(AmendPlan, u32, u16)>,
}

/// Bytes of an in-flight defect commit written to the store per link round (a flash unit
/// of 32 bytes programs in tens of microseconds on the STM32H7: ~8 KB is a few ms).
pub const AMEND_BYTES_PER_ROUND: u32 = 8192;

/// Link rounds in a row in which the table in force cannot be read before an in-flight
/// defect commit is given up (the board's store is out of reach while its erase task holds
/// it: ~2 s a sector, one round a frame).
pub const AMEND_READ_ROUNDS: u16 = 600;

impl Default for LinkService {
    fn default() -> Self {
        Self::new()
    }
}

/// What a command answers after its acceptance.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Answer {
    None,
    Pong,
    Housekeeping,
    Table(u8),
    Committed(TableInfo),
}

/// Which queue a packet goes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Queue {
    Urgent,
    Bulk,
}

impl LinkService {
    /// Housekeeping period at start, frames.
    pub const DEFAULT_HK_PERIOD: u16 = 10;

    /// A fresh link: star lists every frame, housekeeping every
    /// [`Self::DEFAULT_HK_PERIOD`] frames.
    pub const fn new() -> Self {
        Self {
            rx: Deframer::new(),
            urgent: Deque::new(),
            bulk: Deque::new(),
            data: [0; p::MAX_TM_LEN],
            packet: [0; p::MAX_TM_LEN],
            framed: [0; TX_FRAME],
            seq: [0; 5],
            counters: LinkCounters {
                rx_bytes: 0,
                packets: 0,
                framing_errors: 0,
                crc_errors: 0,
                accepted: 0,
                rejected: 0,
                tm_queued: 0,
                tm_dropped: 0,
                stars_not_sent: 0,
            },
            totals: FrameTotals {
                frames: 0,
                lines_refused: 0,
                candidates_dropped: 0,
                windows_dropped: 0,
                ring_lost: 0,
                calib_failed: 0,
                track_refused: 0,
                track_lost: 0,
                stars_dropped: 0,
            },
            last: None,
            stars: heapless::Vec::new(),
            star_frames: None,
            hk_period: None,
            frames_since_hk: 0,
            staged: None,
            window: None,
            reset: false,
            now_us: 0,
            answer: Answer::None,
            setup_faults: 0,
            amend: None,
        }
    }

    /// An in-flight defect commit is under way (`TC[133,7]` accepted, its table not yet
    /// committed or refused).
    pub fn defect_commit_pending(&self) -> bool {
        self.amend.is_some()
    }

    /// The link's counters.
    pub fn counters(&self) -> &LinkCounters {
        &self.counters
    }

    /// The tracker's loss counters since start.
    pub fn totals(&self) -> &FrameTotals {
        &self.totals
    }

    /// A reset was commanded (and acknowledged): the home resets once the queues are sent.
    pub fn reset_requested(&self) -> bool {
        self.reset
    }

    /// Telemetry bytes waiting.
    pub fn pending_tx(&self) -> usize {
        self.urgent.len() + self.bulk.len()
    }

    /// Sets the time telemetry is stamped with (the home's clock, us).
    pub fn set_time(&mut self, now_us: u64) {
        self.now_us = now_us;
    }

    /// Takes received bytes, executing every telecommand they complete.
    pub fn receive<const N: usize>(&mut self, bytes: &[u8], targets: &mut Targets<'_, '_, '_, N>) {
        let mut ctx = Ctx {
            tracker: Some(&mut *targets.tracker),
            tables: &mut *targets.tables,
            windows: &mut *targets.windows,
        };
        self.receive_ctx(bytes, &mut ctx);
    }

    /// Takes received bytes when no tracker runs (the safe standby after a set-up fault):
    /// ping, housekeeping (with the faults set by [`Self::set_setup_faults`]), tables and
    /// reset are served as always; mode and configuration commands are rejected with
    /// [`Rejection::Standby`], window requests with [`Rejection::WindowUnavailable`].
    pub fn receive_standby(&mut self, bytes: &[u8], tables: &mut dyn TableUpload) {
        let mut windows = NoWindows;
        let mut ctx = Ctx {
            tracker: None,
            tables,
            windows: &mut windows,
        };
        self.receive_ctx(bytes, &mut ctx);
    }

    /// Records the set-up steps that failed at this boot (`safe::SetupFaults` bits; those
    /// above bit 15 are not reported), for housekeeping.
    pub fn set_setup_faults(&mut self, bits: u32) {
        self.setup_faults = u16::try_from(bits & 0xFFFF).unwrap_or(u16::MAX);
    }

    fn receive_ctx(&mut self, bytes: &[u8], targets: &mut Ctx<'_>) {
        for &b in bytes {
            self.counters.rx_bytes = self.counters.rx_bytes.wrapping_add(1);
            match self.rx.push(b) {
                Pushed::Pending => {}
                Pushed::Error => {
                    self.counters.framing_errors = self.counters.framing_errors.wrapping_add(1);
                }
                Pushed::Packet(n) => {
                    self.counters.packets = self.counters.packets.wrapping_add(1);
                    // A frame decodes to at most its own length, so any decoded packet fits
                    // (one longer than a telecommand may be is rejected as malformed).
                    let mut pkt = [0u8; RX_FRAME];
                    let src = self.rx.packet(n);
                    let dst = pkt.get_mut(..src.len()).unwrap_or_default();
                    dst.copy_from_slice(src);
                    self.handle(dst, targets);
                }
            }
        }
        self.poll_windows(&mut *targets.windows);
        self.advance_amend(&mut *targets.tables);
    }

    /// Work between frames: sends the rows of a window being read as the bulk queue has
    /// room.
    pub fn poll<const N: usize>(&mut self, targets: &mut Targets<'_, '_, '_, N>) {
        self.poll_windows(&mut *targets.windows);
        self.advance_amend(&mut *targets.tables);
    }

    /// Work between frames with no tracker (the safe standby): an in-flight defect commit
    /// accepted before goes on.
    pub fn poll_standby(&mut self, tables: &mut dyn TableUpload) {
        self.advance_amend(tables);
    }

    /// Starts the in-flight defect commit: the table in force with the tracker's confirmed
    /// pixels added, into the store's inactive slot through the upload path.
    fn start_amend(&mut self, t: &mut Ctx<'_>) -> Result<(), Rejection> {
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
    fn advance_amend(&mut self, tables: &mut dyn TableUpload) {
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

    fn poll_windows(&mut self, windows: &mut dyn WindowReader) {
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

    /// A housekeeping report of the state now.
    pub fn housekeeping(&self, tables: &dyn TableUpload) -> Housekeeping {
        let s = self.last;
        Housekeeping {
            mode: s.map_or(Mode::Standby, |s| s.mode),
            next_mode: s.map_or(Mode::Standby, |s| s.next_mode),
            calibrated: s.is_some_and(|s| s.calibrated),
            temperature_source: s.map_or(crate::tracker::TemperatureSource::None, |s| {
                s.temperature_source
            }),
            temperature_k_bits: s.map_or(0, |s| s.temperature_k.to_bits()),
            frame: s.map_or(0, |s| s.frame),
            stars: s.map_or(0, |s| s.stars),
            centroids: s.map_or(0, |s| s.centroids),
            totals: self.totals,
            link: self.counters,
            table: tables.active(p::TABLE_KIND_CALIBRATION),
            uptime_us: self.now_us,
            setup_faults: self.setup_faults,
            dark_ratio_u8f8: s.map_or(0, |s| s.dark_drift.ratio_u8f8),
            status: if s.is_some_and(|s| s.dark_drift.out_of_band) {
                super::telemetry::status::DARK_DRIFT
            } else {
                0
            },
            defects_pending: s.map_or(0, |s| s.defects_pending),
        }
    }

    /// Queues a housekeeping report (the home may also call this on its own schedule).
    pub fn send_housekeeping(&mut self, tables: &dyn TableUpload) {
        let hk = self.housekeeping(tables);
        let len = hk.encode(&mut self.data).unwrap_or(0);
        self.send(p::APID_HOUSEKEEPING, p::TM_HOUSEKEEPING, len, Queue::Bulk);
    }

    /// Sends a frame's attitude report (the attitude stage's result, after the frame), on the
    /// bulk queue: counted dropped when the queue is full, like a star list.
    pub fn send_attitude(&mut self, report: &super::telemetry::AttitudeReport) {
        let len = report.encode(self.now_us, &mut self.data).unwrap_or(0);
        self.send(p::APID_ATTITUDE, p::TM_ATTITUDE, len, Queue::Bulk);
    }

    /// Called by the home after each frame (after the tracker reported it to this sink):
    /// periodic housekeeping.
    pub fn end_of_frame(&mut self, tables: &dyn TableUpload) {
        let period = self.hk_period.unwrap_or(Self::DEFAULT_HK_PERIOD);
        if period == 0 {
            return;
        }
        self.frames_since_hk = self.frames_since_hk.saturating_add(1);
        if self.frames_since_hk >= period {
            self.frames_since_hk = 0;
            self.send_housekeeping(tables);
        }
    }

    /// One decoded packet.
    fn handle(&mut self, pkt: &[u8], targets: &mut Ctx<'_>) {
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
            Answer::Housekeeping => self.send_housekeeping(&*targets.tables),
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
        }
        Ok(())
    }

    fn send_event(&mut self, id: u16, d: &[u8; EVENT_DATA_LEN], anomaly: bool) {
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
    fn send(&mut self, apid: u16, kind: MessageType, len: usize, queue: Queue) {
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
