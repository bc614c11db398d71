//! The ground side of the link: a client that speaks the tracker's protocol over TCP (the
//! SIL's stand-in for the UART), for `startrack gse` and the link tests. It builds
//! telecommands with `spacepackets`, frames them with COBS, and reads the telemetry back
//! with the core's own layouts ([`startrack_core::link::telemetry`]).
//!
//! Every command waits for its `TM[1,1]` or `TM[1,2]` (matched by request id); a rejection is a
//! [`GroundError::Rejected`] with the tracker's reason.

use arbitrary_int::{u11, u14};
use spacepackets::SpHeader;
use spacepackets::ecss::tc::{PusTcCreator, PusTcSecondaryHeader};
use spacepackets::ecss::tm::PusTmReader;
use spacepackets::ecss::{CreatorConfig, MessageTypeId};
use startrack_core::link::framing::{Deframer, Pushed, encode, encoded_len_max};
use startrack_core::link::mode_number;
use startrack_core::link::protocol::{self as p, MessageType};
use startrack_core::link::telemetry::{
    ATTITUDE_FORMAT, ATTITUDE_LEN, AttitudeReport, Housekeeping, Reader, decode_stars, event,
};
use startrack_core::link::{Rejection, TableInfo, UploadRefusal, WindowKind};
use startrack_core::time::Cuc;
use startrack_core::tracker::{Mode, StarRecord};
use std::fmt;
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// Why a ground operation failed.
#[derive(Clone, Debug, PartialEq)]
pub enum GroundError {
    /// No connection to the tracker, or it closed.
    Link(String),
    /// No answer in time.
    Timeout(String),
    /// The tracker rejected a command.
    Rejected {
        /// The command.
        command: &'static str,
        /// The reason code ([`Rejection::code`]).
        code: u16,
        /// The reason's parameter.
        parameter: u32,
    },
    /// An answer did not read as the protocol says.
    Protocol(String),
}

impl fmt::Display for GroundError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Link(m) => write!(f, "link: {m}"),
            Self::Timeout(m) => write!(f, "no answer: {m}"),
            Self::Rejected {
                command,
                code,
                parameter,
            } => {
                write!(f, "{command} rejected: {}", Rejection::name_of(*code))?;
                if *code == 9 {
                    let refusal = parameter >> 16;
                    write!(f, " (refusal {refusal}")?;
                    if refusal == u32::from(UploadRefusal::OutOfOrder { expected: 0 }.code()) {
                        write!(f, ", expected offset low bits {}", parameter & 0xFFFF)?;
                    }
                    write!(f, ")")?;
                } else if *parameter != 0 {
                    write!(f, " ({parameter:#x})")?;
                }
                Ok(())
            }
            Self::Protocol(m) => write!(f, "protocol: {m}"),
        }
    }
}

impl std::error::Error for GroundError {}

/// One telemetry packet, read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tm {
    /// APID.
    pub apid: u16,
    /// Service and subtype.
    pub kind: MessageType,
    /// Sequence count.
    pub seq: u16,
    /// The tracker's uptime when sent, us.
    pub time_us: u64,
    /// Source data.
    pub data: Vec<u8>,
}

/// A command's verification report: accepted, or rejected with its reason code and parameter.
pub type Verdict = Result<(), (u16, u32)>;

impl Tm {
    /// The request id and verdict if this is a verification report (`TM[1,1]`, `TM[1,2]`).
    pub fn verdict(&self) -> Option<(u32, Verdict)> {
        if self.apid != p::APID_CONTROL {
            return None;
        }
        let mut r = Reader::new(&self.data);
        let id = r.u32()?;
        match self.kind {
            k if k == p::TM_ACCEPTED => Some((id, Ok(()))),
            k if k == p::TM_REJECTED => {
                Some((id, Err((r.u16().unwrap_or(0), r.u32().unwrap_or(0)))))
            }
            _ => None,
        }
    }
}

/// Resumptions one table upload may take before the ground tool gives up on it.
const MAX_RESUMES_PER_UPLOAD: u32 = 64;

/// A connection to the tracker.
pub struct Ground {
    stream: TcpStream,
    rx: Box<Deframer<{ encoded_len_max(p::MAX_TM_LEN) }>>,
    pending: std::collections::VecDeque<Tm>,
    seq: u16,
    timeout: Duration,
    /// Packets that did not decode (bad CRC, not PUS-C TM).
    pub bad_packets: u32,
    /// Times a command is sent again after a corrupted or unanswered attempt (2).
    pub retries: u32,
    /// Times a table upload resumed after a lost or corrupted chunk.
    pub resumes: u32,
    /// Attempts the last [`Self::command`] took.
    pub last_attempts: u32,
}

/// Request id of a telecommand: its packet id and sequence control, as `TM[1,x]` echo them.
fn request_id(packet: &[u8]) -> u32 {
    packet
        .get(..4)
        .map_or(0, |b| u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
}

impl Ground {
    /// Connects to the tracker's link on 127.0.0.1:`port`; each answer is awaited at most
    /// `timeout`.
    pub fn connect(port: u16, timeout: Duration) -> Result<Self, GroundError> {
        let stream = TcpStream::connect(("127.0.0.1", port))
            .map_err(|e| GroundError::Link(format!("127.0.0.1:{port}: {e}")))?;
        stream
            .set_nodelay(true)
            .and_then(|()| stream.set_read_timeout(Some(Duration::from_millis(50))))
            .map_err(|e| GroundError::Link(e.to_string()))?;
        Ok(Self {
            stream,
            rx: Box::new(Deframer::new()),
            pending: Default::default(),
            seq: 0,
            timeout,
            bad_packets: 0,
            retries: 2,
            resumes: 0,
            last_attempts: 0,
        })
    }

    /// The framed bytes of telecommand `kind` with `data` and its request id (the next
    /// sequence count).
    pub fn telecommand(&mut self, kind: MessageType, data: &[u8]) -> (Vec<u8>, u32) {
        let seq = self.seq;
        self.seq = (self.seq + 1) & 0x3FFF;
        frame_telecommand(kind, data, seq)
    }

    /// Sends raw bytes (a framed command, or anything).
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<(), GroundError> {
        self.stream
            .write_all(bytes)
            .map_err(|e| GroundError::Link(e.to_string()))
    }

    /// Sends telecommand `kind` and returns its request id.
    pub fn send(&mut self, kind: MessageType, data: &[u8]) -> Result<u32, GroundError> {
        let (framed, id) = self.telecommand(kind, data);
        self.send_raw(&framed)?;
        Ok(id)
    }

    /// The next telemetry packet, waiting until `deadline`.
    pub fn next_tm(&mut self, deadline: Instant) -> Result<Tm, GroundError> {
        if let Some(t) = self.pending.pop_front() {
            return Ok(t);
        }
        let mut buf = [0u8; 4096];
        loop {
            if Instant::now() >= deadline {
                return Err(GroundError::Timeout("telemetry".into()));
            }
            let n = match self.stream.read(&mut buf) {
                Ok(0) => return Err(GroundError::Link("the tracker closed the link".into())),
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    continue;
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(GroundError::Link(e.to_string())),
            };
            for &b in &buf[..n] {
                if let Pushed::Packet(len) = self.rx.push(b) {
                    match decode_tm(self.rx.packet(len)) {
                        Some(t) => self.pending.push_back(t),
                        None => self.bad_packets += 1,
                    }
                }
            }
            if let Some(t) = self.pending.pop_front() {
                return Ok(t);
            }
        }
    }

    /// Waits for the verification of request `id`; other packets go to `seen`.
    fn verification(
        &mut self,
        id: u32,
        command: &'static str,
        deadline: Instant,
        seen: &mut Vec<Tm>,
    ) -> Result<(), GroundError> {
        loop {
            let t = self.next_tm(deadline).map_err(|e| match e {
                GroundError::Timeout(_) => {
                    GroundError::Timeout(format!("{command}: no verification"))
                }
                e => e,
            })?;
            match t.verdict() {
                Some((i, Ok(()))) if i == id => return Ok(()),
                Some((i, Err((code, parameter)))) if i == id => {
                    return Err(GroundError::Rejected {
                        command,
                        code,
                        parameter,
                    });
                }
                // Another command's report (one sent before this, answered late).
                Some(_) => {}
                None => seen.push(t),
            }
        }
    }

    /// Sends a command and waits for its acceptance; returns the packets seen meanwhile. A
    /// command that arrived corrupted (rejected for its checksum or as malformed) or went
    /// unanswered for a share of the timeout is sent again, up to [`Self::retries`] times.
    pub fn command(
        &mut self,
        command: &'static str,
        kind: MessageType,
        data: &[u8],
    ) -> Result<Vec<Tm>, GroundError> {
        let attempts = self.retries + 1;
        let share = self.timeout / attempts;
        let mut seen = Vec::new();
        let mut last = GroundError::Timeout(format!("{command}: no verification"));
        for attempt in 1..=attempts {
            self.last_attempts = attempt;
            let deadline = Instant::now() + share;
            let id = self.send(kind, data)?;
            match self.verification(id, command, deadline, &mut seen) {
                Ok(()) => return Ok(seen),
                Err(e @ GroundError::Rejected { code: 1 | 2, .. })
                | Err(e @ GroundError::Timeout(_)) => last = e,
                Err(e) => return Err(e),
            }
        }
        Err(last)
    }

    /// Sends a command and returns, after its acceptance, the first answer of `answer` on
    /// `apid`.
    fn ask(
        &mut self,
        command: &'static str,
        kind: MessageType,
        data: &[u8],
        apid: u16,
        answer: MessageType,
    ) -> Result<Tm, GroundError> {
        let deadline = Instant::now() + self.timeout;
        let mut seen = self.command(command, kind, data)?;
        loop {
            if let Some(i) = seen.iter().position(|t| t.apid == apid && t.kind == answer) {
                return Ok(seen.swap_remove(i));
            }
            seen.clear();
            seen.push(self.next_tm(deadline).map_err(|e| match e {
                GroundError::Timeout(_) => GroundError::Timeout(format!("{command}: no answer")),
                e => e,
            })?);
        }
    }

    /// Pings the tracker.
    pub fn ping(&mut self) -> Result<(), GroundError> {
        self.ask("ping", p::TC_PING, &[], p::APID_CONTROL, p::TM_PONG)
            .map(|_| ())
    }

    /// The housekeeping report now.
    pub fn status(&mut self) -> Result<Housekeeping, GroundError> {
        let t = self.ask(
            "housekeeping",
            p::TC_HOUSEKEEPING,
            &[],
            p::APID_HOUSEKEEPING,
            p::TM_HOUSEKEEPING,
        )?;
        Housekeeping::decode(&t.data)
            .ok_or_else(|| GroundError::Protocol("housekeeping report of another layout".into()))
    }

    /// Commands `mode` from the next frame on.
    pub fn set_mode(&mut self, mode: Mode) -> Result<(), GroundError> {
        self.command("set-mode", p::TC_SET_MODE, &[mode_number(mode)])
            .map(|_| ())
    }

    /// Resets the tracker.
    pub fn reset(&mut self) -> Result<(), GroundError> {
        self.command("reset", p::TC_RESET, &[]).map(|_| ())
    }

    /// Commits the pixels the tracker's in-flight watch confirmed into a new calibration
    /// table (`TC[133,7]`) and waits for the end of the commit: the hot and telegraph
    /// pixels added and the table now in force, or the store's refusal.
    pub fn commit_defects(&mut self) -> Result<(u16, u16, TableInfo), GroundError> {
        let deadline = Instant::now() + self.timeout;
        let mut seen = self.command("table-commit-defects", p::TC_TABLE_COMMIT_DEFECTS, &[])?;
        loop {
            for t in seen.drain(..) {
                if t.apid != p::APID_CONTROL
                    || (t.kind != p::TM_EVENT_INFO && t.kind != p::TM_EVENT_ANOMALY)
                {
                    continue;
                }
                let mut r = Reader::new(&t.data);
                match r.u16() {
                    Some(event::DEFECTS_COMMITTED) => {
                        let (hot, tel) = (r.u16().unwrap_or(0), r.u16().unwrap_or(0));
                        let info = TableInfo {
                            kind: p::TABLE_KIND_CALIBRATION,
                            len_bytes: r.u32().unwrap_or(0),
                            crc32: r.u32().unwrap_or(0),
                            sequence: r.u32().unwrap_or(0),
                        };
                        return Ok((hot, tel, info));
                    }
                    Some(event::TABLE_REFUSED) => {
                        let _kind = r.u8();
                        let code = r.u16().unwrap_or(0);
                        return Err(GroundError::Protocol(format!(
                            "table-commit-defects: the store refused the new table (refusal {code})"
                        )));
                    }
                    _ => {}
                }
            }
            seen.push(self.next_tm(deadline).map_err(|e| match e {
                GroundError::Timeout(_) => {
                    GroundError::Timeout("table-commit-defects: no end of the commit".into())
                }
                e => e,
            })?);
        }
    }

    /// Uploads `table` as a calibration table in chunks of `chunk` bytes (at most
    /// [`p::MAX_CHUNK_BYTES`]), `window` chunks in flight, then commits it.
    pub fn upload_table(
        &mut self,
        table: &[u8],
        chunk: usize,
        window: usize,
    ) -> Result<TableInfo, GroundError> {
        let chunk = chunk.clamp(1, p::MAX_CHUNK_BYTES);
        let total = u32::try_from(table.len())
            .map_err(|_| GroundError::Protocol("table longer than 4 GB".into()))?;
        let crc = startrack_sim::flash_model::CRC32.checksum(table);
        let mut begin = vec![p::TABLE_KIND_CALIBRATION];
        begin.extend_from_slice(&total.to_be_bytes());
        begin.extend_from_slice(&crc.to_be_bytes());
        // A clean start: an upload left by an interrupted ground tool is dropped (one ground
        // station commands the tracker).
        self.command("table-abort", p::TC_TABLE_ABORT, &[])?;
        // A command sent again because its answer was late may find its first copy executed:
        // a begin then meets its own upload (busy), a commit finds none (not started). The
        // table report at the end says whether the table in force is this one.
        let own = |g: &Self, e: &GroundError, refusal: u16| {
            g.last_attempts > 1
                && matches!(e, GroundError::Rejected { code: 9, parameter, .. }
                    if parameter >> 16 == u32::from(refusal))
        };
        if let Err(e) = self.command("table-begin", p::TC_TABLE_BEGIN, &begin)
            && !own(self, &e, UploadRefusal::Busy.code())
        {
            return Err(e);
        }
        let chunks: Vec<&[u8]> = table.chunks(chunk).collect();
        if let Err(e) = self.send_chunks(&chunks, chunk, window.max(1)) {
            let _ = self.send(p::TC_TABLE_ABORT, &[]);
            return Err(e);
        }
        if let Err(e) = self.command("table-commit", p::TC_TABLE_COMMIT, &[])
            && !own(self, &e, UploadRefusal::NotStarted.code())
        {
            return Err(e);
        }
        let t = self.ask(
            "table-report",
            p::TC_TABLE_REPORT,
            &[p::TABLE_KIND_CALIBRATION],
            p::APID_DIAGNOSTICS,
            p::TM_TABLE_REPORT,
        )?;
        let mut r = Reader::new(&t.data);
        let (kind, present) = (r.u8(), r.u8());
        let info = TableInfo {
            kind: kind.unwrap_or(0),
            len_bytes: r.u32().unwrap_or(0),
            crc32: r.u32().unwrap_or(0),
            sequence: r.u32().unwrap_or(0),
        };
        if present != Some(1) || info.len_bytes != total || info.crc32 != crc {
            return Err(GroundError::Protocol(format!(
                "committed, but the table in force is {info:?}"
            )));
        }
        Ok(info)
    }

    /// Sends `chunks` (each `chunk` bytes but the last) with `window` in flight. The store
    /// takes chunks in order only, so the first chunk without an acceptance is where the
    /// upload stands: a chunk rejected, or lost (a later one answered first, or nothing
    /// answered in a share of the timeout), makes the upload resume there; an out-of-order
    /// refusal says where the store is (the low 16 bits of its offset; at the table's end,
    /// every chunk is in and the upload goes on to its commit).
    fn send_chunks(
        &mut self,
        chunks: &[&[u8]],
        chunk: usize,
        window: usize,
    ) -> Result<(), GroundError> {
        // The limit is this upload's (`self.resumes` counts over the connection's life).
        let limit = self.resumes.saturating_add(MAX_RESUMES_PER_UPLOAD);
        let share = self.timeout / (self.retries + 1);
        let mut in_flight: std::collections::VecDeque<(usize, u32)> = Default::default();
        let (mut next, mut done) = (0usize, 0usize);
        let mut deadline = Instant::now() + share;
        while done < chunks.len() {
            while next < chunks.len() && in_flight.len() < window {
                let mut d = ((next * chunk) as u32).to_be_bytes().to_vec();
                d.extend_from_slice(chunks[next]);
                in_flight.push_back((next, self.send(p::TC_TABLE_CHUNK, &d)?));
                next += 1;
            }
            let verdict = match self.next_tm(deadline) {
                Ok(t) => t,
                Err(GroundError::Timeout(_)) => {
                    // Nothing answered: resume at the first chunk not accepted.
                    self.resume(&mut in_flight, &mut next, done, limit)?;
                    deadline = Instant::now() + share;
                    continue;
                }
                Err(e) => return Err(e),
            };
            if verdict.apid != p::APID_CONTROL
                || (verdict.kind != p::TM_ACCEPTED && verdict.kind != p::TM_REJECTED)
            {
                continue;
            }
            let mut r = Reader::new(&verdict.data);
            let Some(pos) = r
                .u32()
                .and_then(|id| in_flight.iter().position(|&(_, i)| i == id))
            else {
                continue;
            };
            deadline = Instant::now() + share;
            if pos == 0 && verdict.kind == p::TM_ACCEPTED {
                in_flight.pop_front();
                done += 1;
                continue;
            }
            // The first chunk in flight failed or was lost. An out-of-order refusal names
            // where the store stands: the start of a chunk, or the table's end when every
            // chunk is stored and only acceptances were lost.
            let (code, param) = (r.u16(), r.u32());
            let total = chunks.iter().map(|c| c.len()).sum::<usize>();
            let stands = match (code, param) {
                (Some(9), Some(v)) if v >> 16 == 5 => (done..=chunks.len())
                    .take(64)
                    .find(|&k| (k * chunk).min(total) as u32 & 0xFFFF == v & 0xFFFF),
                _ => None,
            };
            if let Some(k) = stands {
                done = k;
            }
            self.resume(&mut in_flight, &mut next, done, limit)?;
        }
        Ok(())
    }

    fn resume(
        &mut self,
        in_flight: &mut std::collections::VecDeque<(usize, u32)>,
        next: &mut usize,
        done: usize,
        limit: u32,
    ) -> Result<(), GroundError> {
        self.resumes += 1;
        if self.resumes > limit {
            return Err(GroundError::Timeout(format!(
                "table-chunk: the upload stalled at chunk {done} after {MAX_RESUMES_PER_UPLOAD} resumptions"
            )));
        }
        in_flight.clear();
        *next = done;
        Ok(())
    }

    /// The star lists of the next `frames` frames (frame, mode, stars); star lists are then
    /// sent every frame again.
    pub fn stars(&mut self, frames: u16) -> Result<Vec<(u32, Mode, Vec<StarRecord>)>, GroundError> {
        let frames = frames.min(u16::MAX - 1);
        self.command("stars", p::TC_STARS, &frames.to_be_bytes())?;
        let mut out = Vec::new();
        while out.len() < usize::from(frames) {
            let deadline = Instant::now() + self.timeout;
            let t = self.next_tm(deadline)?;
            if t.apid != p::APID_STARS || t.kind != p::TM_STARS {
                continue;
            }
            let mut stars = vec![
                StarRecord {
                    x_px: 0.0,
                    y_px: 0.0,
                    flux_e: 0.0,
                    snr: 0.0,
                    sigma_x_px: 0.0,
                    sigma_y_px: 0.0,
                    cov_xy_px2: 0.0,
                    flags: Default::default(),
                    provenance: Default::default(),
                    psf_a_px: 0.0,
                    chi2_dof: 0.0,
                };
                p::MAX_LINK_STARS
            ];
            let (frame, mode, n) = decode_stars(&t.data, &mut stars)
                .ok_or_else(|| GroundError::Protocol("star list of another layout".into()))?;
            stars.truncate(n);
            out.push((frame, mode, stars));
        }
        self.command("stars", p::TC_STARS, &u16::MAX.to_be_bytes())?;
        Ok(out)
    }

    /// The attitude reports of the next `frames` frames (`TM[134,2]`, sent after every frame
    /// by a tracker that runs its attitude stage; none come from one that does not, and
    /// this then times out).
    pub fn attitude(&mut self, frames: usize) -> Result<Vec<AttitudeReport>, GroundError> {
        let mut out = Vec::with_capacity(frames);
        // Each report is awaited at most the timeout, whatever other telemetry comes.
        let mut deadline = Instant::now() + self.timeout;
        while out.len() < frames {
            let t = self.next_tm(deadline).map_err(|e| match e {
                GroundError::Timeout(_) => GroundError::Timeout("attitude report".into()),
                e => e,
            })?;
            if t.apid != p::APID_ATTITUDE || t.kind != p::TM_ATTITUDE {
                continue;
            }
            out.push(decode_attitude(&t.data).map_err(|e| GroundError::Protocol(e.to_string()))?);
            deadline = Instant::now() + self.timeout;
        }
        Ok(out)
    }

    /// The time-set command: `at_next_pulse` is the spacecraft time of the tracker's next
    /// sync pulse (`TC[9,128]`, CUC with its P-field).
    pub fn set_time(&mut self, at_next_pulse: Cuc) -> Result<(), GroundError> {
        self.command("time-set", p::TC_TIME_SET, &at_next_pulse.with_p_field())
            .map(|_| ())
    }

    /// The velocity command: the spacecraft's velocity `v_m_s` (ICRF, barycentric, m/s) at
    /// spacecraft time `at` (`TC[134,1]`).
    pub fn set_velocity(&mut self, v_m_s: [f64; 3], at: Cuc) -> Result<(), GroundError> {
        let mut d = Vec::with_capacity(18);
        for c in v_m_s {
            d.extend_from_slice(&(c as f32).to_be_bytes());
        }
        d.extend_from_slice(&at.t_field());
        self.command("velocity", p::TC_VELOCITY, &d).map(|_| ())
    }

    /// A `side` x `side` window at (`x0`, `y0`) of the next frame, row-major (raw ADU, or
    /// e- x 64 calibrated).
    pub fn window(
        &mut self,
        x0: u16,
        y0: u16,
        side: u16,
        kind: WindowKind,
    ) -> Result<Vec<i32>, GroundError> {
        let mut d = Vec::new();
        d.extend_from_slice(&x0.to_be_bytes());
        d.extend_from_slice(&y0.to_be_bytes());
        d.extend_from_slice(&side.to_be_bytes());
        d.push(match kind {
            WindowKind::Raw => 0,
            WindowKind::Calibrated => 1,
        });
        let seen = self.command("window", p::TC_WINDOW, &d)?;
        let n = usize::from(side);
        let mut px = vec![0i32; n * n];
        let mut rows = vec![false; n];
        let mut queue: std::collections::VecDeque<Tm> = seen.into();
        let deadline = Instant::now() + self.timeout;
        while rows.iter().any(|r| !r) {
            let t = match queue.pop_front() {
                Some(t) => t,
                None => self.next_tm(deadline)?,
            };
            if t.apid != p::APID_DIAGNOSTICS || t.kind != p::TM_WINDOW_ROW {
                continue;
            }
            let mut r = Reader::new(&t.data);
            let head = (r.u16(), r.u16(), r.u16(), r.u16(), r.u8());
            let (Some(x), Some(y), Some(s), Some(row), Some(_)) = head else {
                return Err(GroundError::Protocol("window row too short".into()));
            };
            if (x, y, s) != (x0, y0, side) || usize::from(row) >= n || r.rest().len() != n * 4 {
                continue;
            }
            for (i, c) in r.rest().chunks_exact(4).enumerate() {
                px[usize::from(row) * n + i] = i32::from_be_bytes([c[0], c[1], c[2], c[3]]);
            }
            rows[usize::from(row)] = true;
        }
        Ok(px)
    }
}

/// Telecommand `kind` with `data` and sequence count `seq`, COBS-framed, and its request id.
pub fn frame_telecommand(kind: MessageType, data: &[u8], seq: u16) -> (Vec<u8>, u32) {
    let sp = SpHeader::new_for_unseg_tc(u11::new(p::APID_CONTROL), u14::new(seq & 0x3FFF), 0);
    let sec = PusTcSecondaryHeader::new_simple(MessageTypeId::new(kind.service, kind.subtype));
    let tc = PusTcCreator::new(sp, sec, data, CreatorConfig::default());
    let mut pkt = vec![0u8; tc.len_written()];
    let n = tc.write_to_slice(&mut pkt).unwrap_or(0);
    pkt.truncate(n);
    let mut framed = vec![0u8; encoded_len_max(pkt.len())];
    let m = encode(&pkt, &mut framed).unwrap_or(0);
    framed.truncate(m);
    (framed, request_id(&pkt))
}

/// Why an attitude report's source data did not read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum AttitudeDecodeError {
    /// Not the report's length ([`ATTITUDE_LEN`] bytes).
    Length {
        /// Bytes received.
        got: usize,
    },
    /// Another format than [`ATTITUDE_FORMAT`] (its eighth byte).
    Format(u8),
    /// The right length and format, but a status or a flag bit the protocol does not have
    /// (garbled).
    Status(u8),
}

impl fmt::Display for AttitudeDecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Length { got } => {
                write!(f, "attitude report of {got} bytes, not {ATTITUDE_LEN}")
            }
            Self::Format(v) => write!(
                f,
                "attitude report of format {v}, not {ATTITUDE_FORMAT} (format 1 reads 0)"
            ),
            Self::Status(s) => write!(f, "attitude report with unknown status {s} or flags"),
        }
    }
}

impl std::error::Error for AttitudeDecodeError {}

/// The attitude report (`TM[134,2]`) in a packet's source data.
pub fn decode_attitude(data: &[u8]) -> Result<AttitudeReport, AttitudeDecodeError> {
    if data.len() != ATTITUDE_LEN {
        return Err(AttitudeDecodeError::Length { got: data.len() });
    }
    match data.get(7) {
        Some(&v) if v != ATTITUDE_FORMAT => return Err(AttitudeDecodeError::Format(v)),
        _ => {}
    }
    AttitudeReport::decode(data).ok_or(AttitudeDecodeError::Status(
        data.get(4).copied().unwrap_or(0),
    ))
}

/// A telemetry packet's fields, or `None` if it is not a PUS-C TM with a good CRC.
pub fn decode_tm(pkt: &[u8]) -> Option<Tm> {
    let tm = PusTmReader::new(pkt, p::TIMESTAMP_LEN).ok()?;
    let stamp: [u8; 8] = tm.timestamp().try_into().ok()?;
    Some(Tm {
        apid: tm.apid().value(),
        kind: MessageType {
            service: tm.service_type_id(),
            subtype: tm.message_subtype_id(),
        },
        seq: pkt
            .get(2..4)
            .map_or(0, |b| u16::from_be_bytes([b[0], b[1]]) & 0x3FFF),
        time_us: u64::from_be_bytes(stamp),
        data: tm.source_data().to_vec(),
    })
}
