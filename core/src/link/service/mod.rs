//! The link service: bytes in, commands applied, telemetry queued. The home feeds it what the
//! UART received ([`LinkService::receive`]), lets it run between frames
//! ([`LinkService::poll`]), passes it as the tracker's telemetry port, and sends what
//! [`LinkService::transmit`] gives when the UART can take it.
//!
//! - Every telecommand gets `TM[1,1]` (executed) or `TM[1,2]` with its
//!   [`Rejection`](super::Rejection); a rejection is also an anomaly event. A packet with a bad CRC or an unreadable header is
//!   rejected with the request id of its first four bytes when it has them.
//! - Telemetry waits in two bounded queues of COBS frames: `urgent` (verification reports,
//!   events) is sent before `bulk` (star lists, housekeeping, windows, table reports). A
//!   packet that does not fit its queue is dropped and counted (`tm_dropped`): a slow link
//!   loses telemetry, never frame time, and command answers are the last to go.
//! - Nothing blocks and nothing panics; every buffer is fixed: the receive frame
//!   ([`p::MAX_TC_LEN`] + COBS overhead), the queues ([`URGENT_QUEUE_BYTES`],
//!   [`BULK_QUEUE_BYTES`]), one telemetry packet's scratch.
//!
//! One file a job: this one the service's state and its entry points; `targets.rs` what
//! commands act on; `execute.rs` reading and executing a telecommand; `amend.rs` the
//! in-flight defect commit; `queues.rs` the telemetry queues and the tracker's telemetry
//! port.
//!
//! Cost: per received byte a push (and per packet a CRC-16 and the command); per frame one
//! star list (about 1 KB for 32 stars) and, every `hk_period` frames, one report.

mod amend;
mod execute;
mod queues;
mod targets;

pub use targets::{NoWindows, Targets, TrackerControl, WindowReader};

use super::command::WindowRequest;
use super::framing::{Deframer, Pushed, encoded_len_max};
use super::protocol as p;
use super::telemetry::{FrameTotals, LinkCounters};
use super::upload::{TableInfo, TableUpload};
use crate::table::AmendPlan;
use crate::tracker::{FrameSummary, StarRecord, TrackerConfig};
use heapless::Deque;
use targets::Ctx;

/// Bytes of the urgent queue (verification reports and events: ~20 bytes each framed).
pub const URGENT_QUEUE_BYTES: usize = 2048;
/// Bytes of the bulk queue (a 32-star list is about 1 KB framed).
pub const BULK_QUEUE_BYTES: usize = 8192;

const RX_FRAME: usize = encoded_len_max(p::MAX_TC_LEN);
const TX_FRAME: usize = encoded_len_max(p::MAX_TM_LEN);

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
    /// A time-set command's time, for the frame cycle's clock to take.
    time_set: Option<crate::time::Cuc>,
    /// A velocity command's velocity, for the frame cycle to take.
    velocity: Option<super::command::Velocity>,
}

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
                hits: 0,
                masked: 0,
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
            time_set: None,
            velocity: None,
        }
    }

    /// The time of the newest time-set command not yet taken (the spacecraft time of the next
    /// sync pulse): the frame cycle gives it to its clock.
    pub fn take_time_set(&mut self) -> Option<crate::time::Cuc> {
        self.time_set.take()
    }

    /// The velocity of the last velocity command not yet taken: the frame cycle keeps it for
    /// the attitude stage's aberration.
    pub fn take_velocity(&mut self) -> Option<super::command::Velocity> {
        self.velocity.take()
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
    ///
    /// [`Rejection::Standby`]: super::Rejection::Standby
    /// [`Rejection::WindowUnavailable`]: super::Rejection::WindowUnavailable
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
}
