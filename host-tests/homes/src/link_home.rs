//! The link's host home: the software-in-the-loop served over TCP ([`serve`]), with its table
//! store in memory ([`MemoryTables`], [`crate::memory_tables`]) or on the flash model ([`crate::flash_home`]) and the
//! simulated sensor as the diagnostic window source ([`SimWindows`]): the core's
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
use crate::memory_tables::MemoryTables;
use crate::sil::{self, SilConfig};
use crate::sim_windows::SimWindows;
use rand::{RngExt, SeedableRng};
use startrack_core::catalog::Catalog;
use startrack_core::cycle::{CyclePorts, FrameCycle};
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::{LinkService, TableUpload};
use startrack_core::tracker::{
    Event, FixedTemperature, FrameSummary, StarRecord, TableStore, TelemetrySink, Tracker,
    TrackerBuffers,
};
use startrack_sim::sim::SensorParams;
use startrack_sim::sky::scene::committed_catalog;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

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
        let mut source = SimLines::new(|k| sil::frame_simulator(sc, &params, &base, catalog, k))
            .with_timing(sil::frame_timing(sc));
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
