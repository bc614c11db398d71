//! Star tracker firmware for the e2v CCD47-20 on an STM32H743ZI (NUCLEO-H743ZI).
//!
//! What runs: clocks at 480 MHz, the watchdog ([`watchdog`]), the fault record kept over a
//! reset ([`safe_state`]), the table store in flash bank 2 and the calibration table copied
//! from it ([`flash_store`]), the sensor temperature ([`mcu_temp`]), the CCD clocks played
//! from the core's compiled program by timer-paced DMA into GPIOE ([`sequencer`], with the
//! caches and the DMA region in [`memory`]), the line readout by SPI DMA in step with them
//! ([`readout`], [`lines`]), and the core's
//! tracker application bound to those and to the log ([`app`], [`telemetry`]): every
//! processing step, from the bias of a line to a star's centroid and the mode changes, is
//! the core's. This crate holds hardware and tasks only.
//!
//! Telemetry goes to the defmt log and to the command and telemetry link on USART3
//! ([`link`]); table uploads are refused until the flash slots are bound to it.
#![no_std]
#![no_main]

mod app;
mod board_temp;
mod catalog;
mod flash_store;
mod lines;
mod link;
mod mcu_temp;
mod mdma_list;
mod memory;
mod pps;
mod readout;
mod safe_state;
mod sequencer;
mod telemetry;
mod watchdog;

use defmt_rtt as _;
use embassy_executor::{SpawnError, SpawnToken, Spawner};
use embassy_stm32::flash::Flash;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::spi::Spi;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Config, bind_interrupts, dma, flash, interrupt, peripherals, usart};
use panic_probe as _;
use startrack_core::safe::SetupFaults;
use startrack_core::store::TableKind;
use startrack_core::tracker::TrackerBuffers;
use static_cell::ConstStaticCell;

/// The tracker's large buffers (line ring, tracking windows, fused CoG plans, ~68 KB): all
/// zero, so in `.bss`; the tracker sets them up in place.
static TRACKER_BUFFERS: ConstStaticCell<TrackerBuffers> =
    ConstStaticCell::new(TrackerBuffers::new());

/// The executor of the sequencer's feeder: interrupt-driven (UART4's vector, unused
/// otherwise) at a priority above thread mode, so the tracker's long frames cannot delay the
/// refill of the clock nodes.
static EXECUTOR_CLOCKS: embassy_executor::InterruptExecutor =
    embassy_executor::InterruptExecutor::new();

#[interrupt]
unsafe fn UART4() {
    // SAFETY: UART4's vector serves only this executor, started once in `main`.
    unsafe { EXECUTOR_CLOCKS.on_interrupt() }
}

/// The sequencer's compiled frames, one played while the next is compiled (2 x 56 KB,
/// CPU-only, cacheable `.bss`).
static SEQ_TABLES: ConstStaticCell<[sequencer::Tables; 2]> =
    ConstStaticCell::new([sequencer::Tables::new(), sequencer::Tables::new()]);

bind_interrupts!(
    /// Interrupts the drivers need: DMA1 stream 0 carries SPI1 RX (the ADC samples), DMA1
    /// stream 1 paces the clock (TIM6 update; the MDMA plays the words), streams 2 and 3 the link's
    /// USART3 transmit and receive; the flash interrupt ends an async erase of bank 2.
    struct Irqs {
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
        DMA1_STREAM1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
        DMA1_STREAM2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
        DMA1_STREAM3 => dma::InterruptHandler<peripherals::DMA1_CH3>;
        USART3 => usart::InterruptHandler<peripherals::USART3>;
        FLASH => flash::InterruptHandler;
        TIM5 => embassy_stm32::timer::CaptureCompareInterruptHandler<peripherals::TIM5>;
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
            // Shared by the tracker task (the link's uploads) and the erase task.
            flash_store::share(store);
            spawn_or_log(spawner, "store erase", flash_store::erase_task());
            table.ok()
        }
        Err(e) => {
            defmt::error!("store: cannot mount bank 2: {}", e);
            faults |= SetupFaults::FLASH_STORE | SetupFaults::NO_TABLE;
            None
        }
    };

    // The star catalog the programmer wrote to bank 1 (no attitude without it).
    let catalog = match catalog::load() {
        Ok(c) => Some(c),
        Err(e) => {
            defmt::warn!("catalog: none in flash at 0x0806_0000 ({}): no attitude", e);
            faults |= SetupFaults::NO_CATALOG;
            None
        }
    };

    // The CCD board's TMP117, else the MCU's sensor (a set-up fault housekeeping reports).
    let board_sensor = board_temp::Tmp117::new(p.I2C1, p.PB8, p.PB9);
    if board_sensor.is_none() {
        faults |= SetupFaults::EXTERNAL_THERMOMETER;
    }
    let thermometer = app::BoardThermometer::new(
        board_temp::BoardSensor(board_sensor),
        mcu_temp::McuThermometer::new(p.ADC3),
    );

    let mut fatal = SetupFaults::empty();
    // The DMA block (clock nodes and tables, line buffers, SPI samples) in its non-cacheable MPU region,
    // and the caches on.
    let dma_region = match memory::init() {
        Ok(r) => Some(r),
        Err(e) => {
            defmt::error!("DMA region and caches: {}", e);
            fatal |= SetupFaults::READOUT;
            None
        }
    };
    let (clock, samples, uart_bufs) = match dma_region {
        Some(memory::DmaRegion {
            clock,
            lines: line_bufs,
            samples,
            uart_rx,
            uart_tx,
        }) => {
            if let Err(e) = lines::init(line_bufs) {
                defmt::error!("line buffers: {}", e);
                fatal |= SetupFaults::LINE_BUFFERS;
            }
            (Some(clock), Some(samples), Some((uart_rx, uart_tx)))
        }
        None => (None, None, None),
    };
    let buffers = TRACKER_BUFFERS.try_take();
    if buffers.is_none() {
        defmt::error!("tracker buffers already taken");
        fatal |= SetupFaults::TRACKER_BUFFERS;
    }

    // The link: USART3 (ST-LINK virtual COM port), DMA1 stream 3 receive ring, stream 2
    // transmit, both buffers in the non-cacheable DMA region. Without it the tracker still
    // runs (its telemetry then only in the log).
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = link::BAUD;
    match (
        usart::Uart::new(
            p.USART3,
            p.PD9,
            p.PD8,
            p.DMA1_CH2,
            p.DMA1_CH3,
            Irqs,
            uart_config,
        ),
        uart_bufs,
    ) {
        (Ok(uart), Some((rx_ring, tx_buf))) => {
            let (tx, rx) = uart.split();
            spawn_or_log(
                spawner,
                "link rx",
                link::link_rx_task(rx.into_ring_buffered(rx_ring)),
            );
            spawn_or_log(spawner, "link tx", link::link_tx_task(tx, tx_buf));
        }
        (Err(e), _) => defmt::error!("link: USART3 configuration refused: {}", e),
        (_, None) => defmt::error!("link: no DMA buffers"),
    }

    // The sync pulse: the PPS line on PA0, TIM5 channel 1 input capture at 1 MHz. Without it
    // the reports say their time is not synchronised.
    {
        use embassy_stm32::gpio::Pull;
        use embassy_stm32::timer::input_capture::{CapturePin, InputCapture};
        use embassy_stm32::timer::low_level::CountingMode;
        let capture = InputCapture::new(
            p.TIM5,
            Some(CapturePin::new(p.PA0, Pull::Down)),
            None,
            None,
            None,
            Irqs,
            embassy_stm32::time::Hertz(1_000_000),
            CountingMode::EdgeAlignedUp,
        );
        spawn_or_log(spawner, "pps", pps::pps_task(capture));
    }

    let started = match (fatal.is_empty(), buffers, clock, samples) {
        (true, Some(buffers), Some(clock), Some(samples)) => {
            let clock_pins = [
                p.PE0.into(),
                p.PE1.into(),
                p.PE2.into(),
                p.PE3.into(),
                p.PE4.into(),
                p.PE5.into(),
                p.PE6.into(),
                p.PE7.into(),
                p.PE8.into(),
                p.PE9.into(),
                p.PE10.into(),
                p.PE11.into(),
                p.PE12.into(),
                p.PE13.into(),
                p.PE14.into(),
                p.PE15.into(),
            ];
            let seq = sequencer::Sequencer::new(p.TIM6, p.DMA1_CH1, p.MDMA_CH0, clock_pins, clock);
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
                app::tracker_task(table, catalog, buffers, thermometer),
            );
            let readout = spawn_or_log(spawner, "readout", readout::readout_task(adc, samples));
            let plans = spawn_or_log(spawner, "plan", sequencer::plan_task());
            let clocks = match SEQ_TABLES.try_take() {
                Some([a, b]) => {
                    use interrupt::{InterruptExt, Priority};
                    interrupt::UART4.set_priority(Priority::P6);
                    let clocks = EXECUTOR_CLOCKS.start(interrupt::UART4);
                    match sequencer::sequencer_task(seq, [a, b]) {
                        Ok(token) => {
                            clocks.spawn(token);
                            true
                        }
                        Err(e) => {
                            defmt::error!("cannot spawn sequencer: {}", e);
                            false
                        }
                    }
                }
                None => {
                    defmt::error!("sequencer tables already taken");
                    false
                }
            };
            if !(tracker && readout && clocks && plans) {
                fatal |= SetupFaults::TASK_SPAWN;
            }
            tracker && readout && clocks && plans
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
