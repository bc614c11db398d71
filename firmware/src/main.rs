//! Star tracker firmware for the e2v CCD47-20 on an STM32H743ZI (NUCLEO-H743ZI).
//!
//! What runs: clocks at 480 MHz, the watchdog ([`watchdog`]), the fault record kept over a
//! reset ([`safe_state`]), the table store in flash bank 2 and the calibration table copied
//! from it ([`flash_store`]), the sensor temperature ([`mcu_temp`]), the line
//! readout by SPI DMA into ping-pong buffers ([`readout`], [`lines`]), and the core's
//! tracker application bound to those and to the log ([`app`], [`telemetry`]): every
//! processing step, from the bias of a line to a star's centroid and the mode changes, is
//! the core's. This crate holds hardware and tasks only.
//!
//! Boundary, honestly: there is no CCD clock sequencer yet, so no CCD is driven; lines are
//! SPI bursts paced by a timer (see [`readout`]). The defmt log is the only telemetry.
#![no_std]
#![no_main]

mod app;
mod flash_store;
mod lines;
mod mcu_temp;
mod readout;
mod safe_state;
mod telemetry;
mod watchdog;

use defmt_rtt as _;
use embassy_executor::{SpawnError, SpawnToken, Spawner};
use embassy_stm32::flash::Flash;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::spi::Spi;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Config, bind_interrupts, dma, flash, peripherals};
use panic_probe as _;
use startrack_core::safe::SetupFaults;
use startrack_core::store::TableKind;
use startrack_core::tracker::TrackerBuffers;
use static_cell::ConstStaticCell;

/// The tracker's large buffers (line ring, tracking windows, fused CoG plans, ~68 KB): all
/// zero, so in `.bss`; the tracker sets them up in place.
static TRACKER_BUFFERS: ConstStaticCell<TrackerBuffers> =
    ConstStaticCell::new(TrackerBuffers::new());

bind_interrupts!(
    /// Interrupts the drivers need: DMA1 stream 0 carries SPI1 RX (the ADC samples); the
    /// flash interrupt ends an async erase of bank 2.
    struct Irqs {
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
        FLASH => flash::InterruptHandler;
    }
);

/// The clock tree: 480 MHz core from the 8 MHz HSE.
///
/// On the NUCLEO-H743ZI the ST-LINK drives HSE with an 8 MHz clock (MCO), hence `Bypass`.
/// PLL1: 8 MHz / 2 = 4 MHz reference, x240 = 960 MHz VCO (wide range);
/// P / 2 = 480 MHz SYSCLK, Q / 8 = 120 MHz (SPI1/2/3 kernel clock, the default mux).
/// Buses: CPU 480 MHz, AXI/AHB 240 MHz, APB1..4 120 MHz, the limits at VOS0.
/// 480 MHz needs voltage scale 0, which only revision V silicon has (NUCLEO-H743ZI2; the
/// first NUCLEO-H743ZI boards carry revision Y, limited to 400 MHz: there use `mul = MUL200`
/// and `VoltageScale::Scale1`, which gives 400 MHz, AHB 200 MHz, APB 100 MHz, SPI 25 MHz).
fn clock_config() -> Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllDiv, PllMul, PllPreDiv, PllSource,
        Sysclk, VoltageScale,
    };
    use embassy_stm32::time::Hertz;

    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Bypass,
    });
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSE,
        prediv: PllPreDiv::DIV2,
        mul: PllMul::MUL240,
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: Some(PllDiv::DIV8),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.d1c_pre = AHBPrescaler::DIV1;
    config.rcc.ahb_pre = AHBPrescaler::DIV2;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale0;
    // ADC3 (the MCU temperature sensor) from per_ck = HSI 64 MHz, divided below 50 MHz by
    // the driver; the default PLL2_P is not running.
    config.rcc.mux.adcsel = embassy_stm32::rcc::mux::Adcsel::PER;
    config
}

/// Spawns a task, or logs why it could not be (a task spawned twice); `false` then.
fn spawn_or_log<S>(spawner: Spawner, name: &str, token: Result<SpawnToken<S>, SpawnError>) -> bool {
    match token {
        Ok(token) => {
            spawner.spawn(token);
            true
        }
        Err(e) => {
            defmt::error!("cannot spawn {=str}: {}", name, e);
            false
        }
    }
}

/// Set-up, in order: the reset cause and the fault record, the watchdog (so a hang in what
/// follows resets), the table store and the calibration table, the thermometers, the line
/// buffers and the readout, then the tracker. A failed step is recorded in the fault record
/// and housekeeping; one the tracker cannot run without leads to the safe standby
/// ([`safe_state::standby_forever`]), never to a return with nothing running.
#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clock_config());
    let cause = safe_state::reset_cause();
    let (mut record, kept) = safe_state::load_record();
    record.on_boot(cause);
    safe_state::store_record(&record);
    defmt::info!(
        "startrack firmware {=str}: clocks up; reset {}, fault record {} ({})",
        env!("CARGO_PKG_VERSION"),
        cause,
        record,
        if kept { "kept" } else { "fresh" }
    );
    let mut faults = SetupFaults::empty();

    let wdg = IndependentWatchdog::new(p.IWDG1, watchdog::TIMEOUT_US);
    spawn_or_log(spawner, "watchdog", watchdog::watchdog_task(wdg));
    let standby = spawn_or_log(spawner, "standby", safe_state::standby_task());

    let table = match flash_store::mount(Flash::new(p.FLASH, Irqs)) {
        Ok(mut store) => {
            let table = flash_store::load_calibration(&mut store);
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
            // The store is kept for its owner, the link's upload handling (which runs the
            // erase with `flash_store::erase_pending`); until it is bound, nothing writes
            // the flash.
            let _store: &'static mut flash_store::Store = flash_store::STORE.init(store);
            table.ok()
        }
        Err(e) => {
            defmt::error!("store: cannot mount bank 2: {}", e);
            faults |= SetupFaults::FLASH_STORE | SetupFaults::NO_TABLE;
            None
        }
    };

    let thermometer = app::BoardThermometer::new(
        mcu_temp::NoBoardSensor,
        mcu_temp::McuThermometer::new(p.ADC3),
    );
    // No CCD-board sensor is wired yet: the MCU sensor stands in (housekeeping says so).
    faults |= SetupFaults::EXTERNAL_THERMOMETER;

    let mut fatal = SetupFaults::empty();
    if let Err(e) = lines::init() {
        defmt::error!("line buffers: {}", e);
        fatal |= SetupFaults::LINE_BUFFERS;
    }
    let buffers = TRACKER_BUFFERS.try_take();
    if buffers.is_none() {
        defmt::error!("tracker buffers already taken");
        fatal |= SetupFaults::TRACKER_BUFFERS;
    }

    let started = match (fatal.is_empty(), buffers) {
        (true, Some(buffers)) => {
            let spi = Spi::new_rxonly(
                p.SPI1,
                p.PA5,
                p.PA6,
                p.DMA1_CH0,
                Irqs,
                readout::spi_config(),
            );
            let cs = Output::new(p.PD14, Level::High, Speed::VeryHigh);
            let adc = readout::AdcLink::new(spi, cs);
            let tracker = spawn_or_log(
                spawner,
                "tracker",
                app::tracker_task(table, buffers, thermometer),
            );
            let readout = spawn_or_log(spawner, "readout", readout::readout_task(adc));
            if !(tracker && readout) {
                fatal |= SetupFaults::TASK_SPAWN;
            }
            tracker && readout
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
