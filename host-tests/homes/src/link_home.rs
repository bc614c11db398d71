//! The link's host home: the table store in memory ([`MemoryTables`], the host binding of
//! the core's table-upload port), the simulated sensor as the diagnostic window source
//! ([`SimWindows`]), and the software-in-the-loop served over TCP ([`serve`]): the core's
//! [`LinkService`] on 127.0.0.1:P standing in for the UART, optionally with seeded bit
//! errors on the received bytes (`--link-noise`). With a sky scene ([`SilConfig::sky`]) each
//! frame's star list also goes through the attitude stage as on the board, and its attitude
//! report (`TM[134,2]`) goes out on the link: the core's frame cycle
//! ([`startrack_core::cycle`]) runs each frame and serves the link between frames, as on the
//! board.
//!
//! The server runs frames back to back; between two frames it serves the link for up to
//! [`LINK_PHASE_MS`] (longer while bytes keep arriving, at most [`LINK_PHASE_MAX_MS`]), so
//! a table upload goes at the TCP's speed and a frame never waits for the ground.
//!
//! The spacecraft's PPS line runs beside the frames ([`crate::pps::PpsModel`], on the
//! frame clock's counter, from [`SilConfig::spacecraft_epoch_us`] or [`sil::SIL_EPOCH_US`]);
//! the reports are on spacecraft time once the ground has sent a time-set command
//! (`startrack gse --port P time-set S`) and the next pulse has come.
//!
//! Cost: the frames' (see [`crate::sil`]); the link adds a few us a packet; a sky scene adds
//! the attitude stage's per frame and one 128-byte report (a 151-byte packet).

use crate::home::{ReadoutClock, SimLines, block_on, host_health};
use crate::sil::{self, SilConfig};
use rand::{RngExt, SeedableRng};
use startrack_core::calib::{FrameCalibration, LineLevels};
use startrack_core::catalog::Catalog;
use startrack_core::cycle::{CyclePorts, FrameCycle};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::{
    LinkService, TableInfo, TableUpload, UploadRefusal, WindowKind, WindowReader, WindowRequest,
};
use startrack_core::table::CalibTable;
use startrack_core::tracker::{
    Event, FixedTemperature, FrameSummary, StarRecord, TableStore, TelemetrySink, Tracker,
    TrackerBuffers,
};
use startrack_core::window::Rect;
use startrack_sim::flash_model::CRC32;
use startrack_sim::sim::{SensorParams, Simulator, Star};
use startrack_sim::sky::scene::committed_catalog;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

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

/// Diagnostic windows from the simulated sensor, of the frame after the request: raw, or
/// calibrated as the tracker calibrates a window (each line's bias from its own over-scan,
/// then the per-pixel formula with the tracker's calibration: its table, dark scale, exposure
/// and temperature, [`Tracker::calibration`]), in e- x 64.
pub struct SimWindows {
    /// The sensor.
    pub params: SensorParams,
    /// The stars of the frame to render.
    pub stars: Vec<Star>,
    /// Its stars that move during the exposure ([`Simulator::trails`]).
    pub trails: Vec<startrack_sim::trail::TrailedImage>,
    /// Its frame number (the noise draw).
    pub frame: u32,
    /// The tracker's calibration (calibrated windows need one).
    pub calibration: Option<FrameCalibration<'static>>,
    rendered: Option<(WindowRequest, Vec<i32>)>,
}

impl SimWindows {
    /// A source for `params`' sensor.
    pub fn new(params: SensorParams) -> Self {
        Self {
            params,
            stars: Vec::new(),
            trails: Vec::new(),
            frame: 0,
            calibration: None,
            rendered: None,
        }
    }
}

impl WindowReader for SimWindows {
    fn check(&mut self, r: &WindowRequest) -> bool {
        let g = self.params.geometry;
        let inside = u32::from(r.x0) + u32::from(r.side_px) <= u32::from(g.active_cols)
            && u32::from(r.y0) + u32::from(r.side_px) <= u32::from(g.active_rows);
        if !inside {
            return false;
        }
        let sim = Simulator {
            frame: self.frame,
            trails: self.trails.clone(),
            ..Simulator::new(self.params.clone(), self.stars.clone())
        };
        let rect = Rect {
            x0: r.x0,
            y0: r.y0,
            width: r.side_px,
            height: r.side_px,
        };
        let px = match r.kind {
            WindowKind::Raw => sim.render_window(rect).into_iter().map(i32::from).collect(),
            WindowKind::Calibrated => {
                let Some(cal) = self.calibration else {
                    return false;
                };
                match calibrated_window(&sim, &cal, rect) {
                    Some(px) => px,
                    None => return false,
                }
            }
        };
        self.rendered = Some((*r, px));
        true
    }

    fn read_row(&mut self, r: &WindowRequest, row: u16, out: &mut [i32]) -> bool {
        let Some((req, px)) = &self.rendered else {
            return false;
        };
        if req != r {
            return false;
        }
        let side = usize::from(r.side_px);
        let start = usize::from(row) * side;
        match px.get(start..start + side) {
            Some(src) if out.len() == side => {
                out.copy_from_slice(src);
                true
            }
            _ => false,
        }
    }
}

/// Window `rect` of `sim`'s frame calibrated with `cal`, e- x 64 (I26F6 bits).
fn calibrated_window(sim: &Simulator, cal: &FrameCalibration<'_>, rect: Rect) -> Option<Vec<i32>> {
    let raw = crate::demo::render_frame(sim);
    let g = sim.params.geometry;
    let lines = raw
        .chunks_exact(g.line_len())
        .map(|l| LineLevels::measure(&g, l))
        .collect::<Result<Vec<_>, _>>()
        .ok()?;
    let levels = crate::home::FrameLevels {
        geometry: g,
        lines,
        dark_scale_e: None,
    };
    let (e, _, _) = levels.calibrate_window(cal, &raw, rect).ok()?;
    Some(e.into_iter().map(|v| v.to_bits()).collect())
}

/// Between two frames the link is served at least this long, ms.
pub const LINK_PHASE_MS: u64 = 20;
/// ...and at most this long while bytes keep arriving, ms.
pub const LINK_PHASE_MAX_MS: u64 = 500;

/// What [`serve`] runs.
#[derive(Clone, Debug)]
pub struct ServeConfig {
    /// The scene, the sensor and the tracker (a sky scene, `sil.sky`, also runs the attitude
    /// stage after each frame and sends its report).
    pub sil: SilConfig,
    /// TCP port on 127.0.0.1 (0: any free port, reported through `on_listen`).
    pub port: u16,
    /// Probability that a received byte has one bit flipped (seeded by the scene's seed).
    pub link_noise: f64,
    /// Stop after this many frames (`None`: run until killed).
    pub max_frames: Option<u32>,
    /// Stop when this is set (checked between frames and in the link phase).
    pub stop: Option<std::sync::Arc<std::sync::atomic::AtomicBool>>,
    /// Keep the tables in the flash store over the flash model in this file (`None`: in
    /// memory).
    pub flash: Option<FlashConfig>,
}

/// The SIL's flash table store ([`crate::flash_home`]).
#[derive(Clone, Debug)]
pub struct FlashConfig {
    /// The file holding the flash (created erased, with the SIL's table, if absent).
    pub path: std::path::PathBuf,
    /// Cut the power during the N-th flash step (unit program or sector erase) after
    /// start-up, N from 1: the server then stops, the file holding the flash as cut.
    pub power_cut_at_write: Option<u64>,
}

/// The tables the SIL serves: in memory, or in the flash store.
trait SilTables: TableUpload + TableStore<'static> {
    /// The owner's erase step, between frames.
    fn service(&mut self) -> Result<(), String> {
        Ok(())
    }
    /// Keeps what the store holds (the flash file).
    fn persist(&mut self) -> Result<(), String> {
        Ok(())
    }
    /// A reset of the tracker: the store is mounted again.
    fn reboot(&mut self) -> Result<(), String> {
        Ok(())
    }
    /// Whether the power was cut.
    fn power_cut(&self) -> bool {
        false
    }
}

impl SilTables for MemoryTables {}

impl SilTables for crate::flash_home::FlashHome {
    fn service(&mut self) -> Result<(), String> {
        // An erase that fails drops the upload (the ground then sees "no upload begun").
        let _ = crate::flash_home::FlashHome::service(self);
        Ok(())
    }
    fn persist(&mut self) -> Result<(), String> {
        crate::flash_home::FlashHome::persist(self).map_err(|e| format!("flash file: {e}"))
    }
    fn reboot(&mut self) -> Result<(), String> {
        crate::flash_home::FlashHome::reboot(self)
    }
    fn power_cut(&self) -> bool {
        crate::flash_home::FlashHome::power_cut(self)
    }
}

/// Counts of a [`serve`] run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ServeReport {
    /// Frames run.
    pub frames: u32,
    /// Resets performed.
    pub resets: u32,
    /// Bytes received and sent.
    pub rx_bytes: u64,
    /// Bytes sent.
    pub tx_bytes: u64,
    /// The run ended with a power cut of the flash (`--power-cut-at-write`).
    pub power_cut: bool,
}

/// One connected ground station.
struct Client {
    stream: TcpStream,
    out: Vec<u8>,
}

impl Client {
    /// Sends what it can of `out` without waiting; `false` when the ground hung up.
    fn flush(&mut self, sent: &mut u64) -> bool {
        while !self.out.is_empty() {
            match self.stream.write(&self.out) {
                Ok(0) => return false,
                Ok(n) => {
                    self.out.drain(..n);
                    *sent += n as u64;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return true,
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(_) => return false,
            }
        }
        true
    }
}

/// Runs the SIL with its link on TCP: frames back to back, the link served between them.
/// `on_listen` is called once with the bound port.
pub fn serve(config: &ServeConfig, on_listen: &mut dyn FnMut(u16)) -> Result<ServeReport, String> {
    let listener = TcpListener::bind(("127.0.0.1", config.port)).map_err(|e| e.to_string())?;
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    on_listen(listener.local_addr().map_err(|e| e.to_string())?.port());

    let sc = &config.sil;
    let params = SensorParams {
        seed: sc.seed,
        ..SensorParams::default()
    };
    let base = sil::scene(sc, &params);
    // A sky scene: the on-board catalog's stars, and after each frame the attitude stage as
    // the board runs it (firmware/src/app.rs), its report sent on the link.
    let catalog_bytes = match sc.sky {
        Some(_) => committed_catalog()?,
        None => Vec::new(),
    };
    let sky = match sc.sky {
        Some(scene) => Some((
            scene,
            Catalog::parse(&catalog_bytes).map_err(|e| format!("catalog: {e}"))?,
        )),
        None => None,
    };
    let catalog = sky.as_ref().map(|(_, c)| c);
    let mut tables: Box<dyn SilTables> = match &config.flash {
        None => Box::new(MemoryTables::new(
            params.geometry,
            Some(sil::truth_table(sc, &params)?),
        )),
        Some(f) => {
            let table = crate::flash_home::flash_table(sc, &params)?;
            let mut home =
                crate::flash_home::FlashHome::open(&f.path, params.geometry, Some(&table))?;
            if let Some(n) = f.power_cut_at_write {
                home.cut_power_at(n);
            }
            Box::new(home)
        }
    };
    let mut windows = SimWindows::new(params.clone());
    let mut noise = rand_chacha::ChaCha8Rng::seed_from_u64(sc.seed ^ 0x4e4f_4953);
    let mut report = ServeReport::default();
    let mut client: Option<Client> = None;
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut frame = 0u32;
    let start = Instant::now();
    // The PPS line: spacecraft time at this boot's counter 0 (the counter restarts at a
    // reset, the spacecraft's time does not).
    let mut epoch_us = sc.spacecraft_epoch_us.unwrap_or(sil::SIL_EPOCH_US);

    'boot: loop {
        let mut pps = crate::pps::PpsModel::new(epoch_us, sc.counter_rate_ppm, sc.seed);
        let tracker =
            Tracker::<{ sil::SIL_CAPACITY }>::new(sc.tracker, params.geometry, &mut buffers)
                .map_err(|e| e.to_string())?;
        let mut link = Box::new(LinkService::new());
        // A reset starts the attitude stage afresh (no prior), as the board's does.
        let solver = sky
            .as_ref()
            .map(|(scene, cat)| sil::sky_solver(scene, *cat));
        let mut cycle = Box::new(FrameCycle::new(tracker, &mut link, solver, host_health()));
        let mut source = SimLines::new(|k| sil::frame_simulator(sc, &params, &base, catalog, k));
        let mut thermometer = FixedTemperature(None);
        loop {
            let stopped = config
                .stop
                .as_ref()
                .is_some_and(|s| s.load(std::sync::atomic::Ordering::Relaxed));
            if stopped || config.max_frames.is_some_and(|m| report.frames >= m) {
                return Ok(report);
            }
            // The link phase.
            let phase_end = Instant::now() + Duration::from_millis(LINK_PHASE_MS);
            let hard_end = Instant::now() + Duration::from_millis(LINK_PHASE_MAX_MS);
            windows.frame = frame;
            let sensor = sil::frame_simulator(sc, &params, &base, catalog, frame);
            (windows.stars, windows.trails) = (sensor.stars, sensor.trails);
            windows.calibration = cycle.tracker().calibration();
            // The pulses up to now first: a time-set received in this phase is for a later
            // pulse.
            pps.advance_to(u64::from(frame) * sc.period_us);
            cycle.sync(&mut pps);
            loop {
                if client.is_none()
                    && let Ok((s, _)) = listener.accept()
                {
                    let _ = s.set_nodelay(true);
                    if s.set_nonblocking(true).is_ok() {
                        client = Some(Client {
                            stream: s,
                            out: Vec::new(),
                        });
                    }
                }
                let mut got = false;
                if let Some(c) = client.as_mut() {
                    let mut buf = [0u8; 512];
                    match c.stream.read(&mut buf) {
                        Ok(0) => client = None,
                        Ok(n) => {
                            got = true;
                            report.rx_bytes += n as u64;
                            let bytes = buf.get_mut(..n).unwrap_or_default();
                            if config.link_noise > 0.0 {
                                for b in bytes.iter_mut() {
                                    if noise.random_bool(config.link_noise.min(1.0)) {
                                        *b ^= 1 << noise.random_range(0..8);
                                    }
                                }
                            }
                            cycle.set_link_time(start.elapsed().as_micros() as u64);
                            cycle.receive(bytes, &mut *tables, &mut windows);
                            // The erase an accepted `begin` asks for, before the next bytes.
                            tables.service()?;
                        }
                        Err(e)
                            if matches!(
                                e.kind(),
                                ErrorKind::WouldBlock | ErrorKind::Interrupted
                            ) => {}
                        Err(_) => client = None,
                    }
                }
                cycle.poll(&mut *tables, &mut windows);
                tables.service()?;
                tables.persist()?;
                if tables.power_cut() {
                    // The board is off: nothing more is sent, the flash stays as cut.
                    report.power_cut = true;
                    return Ok(report);
                }
                drain(&mut cycle, &mut client, &mut report);
                if cycle.reset_requested() {
                    tables.reboot()?;
                    report.resets += 1;
                    epoch_us += u64::from(frame) * sc.period_us;
                    frame = 0;
                    continue 'boot;
                }
                let now = Instant::now();
                if now >= hard_end || (now >= phase_end && !got) {
                    break;
                }
                if !got {
                    std::thread::sleep(Duration::from_millis(1));
                }
            }
            // The frame.
            source.readout_done_us.set(0);
            let mut clock = ReadoutClock {
                frame,
                period_us: sc.period_us,
                readout_done_us: source.readout_done_us.clone(),
            };
            cycle.set_link_time(start.elapsed().as_micros() as u64);
            let table_in_force = tables.active(TABLE_KIND_CALIBRATION);
            let mut ports = CyclePorts {
                clock: &mut clock,
                thermometer: &mut thermometer,
                tables: &mut *tables,
                table_in_force,
                telemetry: &mut NoTelemetry,
            };
            let Ok(_) = block_on(cycle.run_frame(&mut source, &mut ports));
            drain(&mut cycle, &mut client, &mut report);
            report.frames += 1;
            frame += 1;
        }
    }
}

/// The served SIL keeps no records of its own: the link carries them.
struct NoTelemetry;

impl TelemetrySink for NoTelemetry {
    fn star(&mut self, _frame: u32, _star: &StarRecord) {}
    fn frame(&mut self, _summary: &FrameSummary) {}
    fn event(&mut self, _event: &Event) {}
}

/// Moves the link's queued telemetry to the client (all of it: TCP is the fast UART here);
/// without a client it is discarded, as a UART with nobody listening would.
fn drain<const N: usize>(
    cycle: &mut FrameCycle<'_, '_, '_, '_, N>,
    client: &mut Option<Client>,
    report: &mut ServeReport,
) {
    let mut buf = [0u8; 4096];
    loop {
        let n = cycle.transmit(&mut buf);
        if n == 0 {
            break;
        }
        if let Some(c) = client.as_mut() {
            c.out.extend_from_slice(buf.get(..n).unwrap_or_default());
        }
    }
    if let Some(c) = client.as_mut()
        && !c.flush(&mut report.tx_bytes)
    {
        *client = None;
    }
}
