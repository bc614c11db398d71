//! Star tracker firmware for the e2v CCD47-20: the application, the same on every board
//! ([`board`] says what a board provides; the STM32H743ZI of the NUCLEO-H743ZI is the flight
//! board, QEMU's `mps2-an500` the processor-in-the-loop one).
//!
//! What runs: the watchdog ([`watchdog`]), the fault record kept over a reset
//! ([`safe_state`]), the table store and the calibration table copied from it
//! ([`flash_store`]), the star catalog ([`catalog`]), the board's line path fed each frame's
//! request ([`lines`]), and the core's tracker application bound to those and to the log
//! ([`app`], [`telemetry`]): every processing step, from the bias of a line to a star's
//! centroid, the mode changes and the attitude, is the core's. This crate holds hardware
//! bindings and tasks only.
//!
//! Telemetry goes to the defmt log and to the command and telemetry link ([`link`]), whose
//! bytes the board moves.
#![no_std]
#![no_main]

mod app;
mod board;
mod catalog;
mod d2_ram;
mod flash_store;
mod lines;
mod link;
mod pipe;
mod pps;
mod safe_state;
mod spawn;
mod telemetry;
mod watchdog;

use embassy_executor::Spawner;
use spawn::spawn_or_log;
use startrack_core::safe::SetupFaults;
use startrack_core::store::TableKind;
use startrack_core::tracker::TrackerBuffers;
use static_cell::ConstStaticCell;

/// The tracker's large buffers (line ring, tracking windows, fused CoG plans, ~68 KB): all
/// zero, so in `.bss`; the tracker sets them up in place.
static TRACKER_BUFFERS: ConstStaticCell<TrackerBuffers> =
    ConstStaticCell::new(TrackerBuffers::new());

/// Set-up, in order: the board, the reset cause and the fault record, the watchdog (so a
/// hang in what follows resets), the table store and the calibration table, the catalog, the
/// board's I/O (the link, the line buffers), then the tracker and the board's line path. A
/// failed step is recorded in the fault record and housekeeping; one the tracker cannot run
/// without leads to the safe standby ([`safe_state::standby_forever`]), never to a return
/// with nothing running.
#[cfg_attr(feature = "board-stm32h743", embassy_executor::main)]
#[cfg_attr(
    feature = "board-mps2-an500",
    embassy_executor::main(entry = "cortex_m_rt::entry", executor = "crate::board::Executor")
)]
async fn main(spawner: Spawner) {
    let board::Parts {
        watchdog: wdg,
        flash,
        thermometer,
        thermometer_faults,
        d2_ready,
        io,
    } = board::init();
    let cause = board::reset_cause();
    let (mut record, kept) = safe_state::load_record();
    record.on_boot(cause);
    safe_state::store_record(&record);
    defmt::info!(
        "startrack firmware {=str}: board up; reset {}, fault record {} ({})",
        env!("CARGO_PKG_VERSION"),
        cause,
        record,
        if kept { "kept" } else { "fresh" }
    );
    let mut faults = thermometer_faults;

    spawn_or_log(spawner, "watchdog", watchdog::watchdog_task(wdg));
    let standby = spawn_or_log(spawner, "standby", safe_state::standby_task());

    let table = match flash_store::mount(flash) {
        Ok(mut store) => {
            let table = flash_store::load_calibration(&mut store, d2_ready);
            if let Err(e) = &table {
                faults |= match e {
                    flash_store::LoadError::GeometryMismatch { .. } => SetupFaults::TABLE_GEOMETRY,
                    _ => SetupFaults::NO_TABLE,
                };
            }
            let calibration = store.active(TableKind::Calibration).map(Into::into);
            let catalog = store.active(TableKind::Catalog).map(Into::into);
            safe_state::update_health(|h| {
                h.calibration = calibration;
                h.catalog = catalog;
            });
            // Shared by the tracker task (the link's uploads) and the erase task.
            flash_store::share(store);
            spawn_or_log(spawner, "store erase", flash_store::erase_task());
            table.ok()
        }
        Err(e) => {
            defmt::error!("store: cannot mount: {}", e);
            faults |= SetupFaults::FLASH_STORE | SetupFaults::NO_TABLE;
            None
        }
    };

    // The star catalog in the board's catalog region (no attitude without it).
    let catalog = match catalog::load() {
        Ok(c) => Some(c),
        Err(e) => {
            defmt::warn!(
                "catalog: none in flash at {=usize:#x} ({}): no attitude",
                board::CATALOG_ADDRESS,
                e
            );
            faults |= SetupFaults::NO_CATALOG;
            None
        }
    };

    let board::Started {
        line_buffers,
        lines,
        faults: io_faults,
    } = board::start_io(spawner, io);
    let mut fatal = io_faults;
    if let Some(bufs) = line_buffers
        && let Err(e) = lines::init(bufs)
    {
        defmt::error!("line buffers: {}", e);
        fatal |= SetupFaults::LINE_BUFFERS;
    }
    let buffers = TRACKER_BUFFERS.try_take();
    if buffers.is_none() {
        defmt::error!("tracker buffers already taken");
        fatal |= SetupFaults::TRACKER_BUFFERS;
    }

    let started = match (fatal.is_empty(), buffers, lines) {
        (true, Some(buffers), Some(lines)) => {
            let tracker = spawn_or_log(
                spawner,
                "tracker",
                app::tracker_task(table, catalog, buffers, thermometer),
            );
            let lines = board::start_lines(spawner, lines);
            if !(tracker && lines) {
                fatal |= SetupFaults::TASK_SPAWN;
            }
            tracker && lines
        }
        _ => false,
    };

    faults |= fatal;
    record.on_setup_done(faults);
    safe_state::store_record(&record);
    safe_state::update_health(|h| {
        h.record = record;
        h.setup_faults = faults;
    });
    if !started {
        // The tracker does not run: the safe standby keeps the watchdog fed and the
        // housekeeping (faults included) reported.
        if standby {
            safe_state::enter_standby(faults);
        } else {
            safe_state::standby_forever(faults).await;
        }
    }
}
