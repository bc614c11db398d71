//! Star tracker firmware for the e2v CCD47-20 on an STM32H743ZI (NUCLEO-H743ZI).
//!
//! What runs: clocks at 480 MHz, the calibration table check ([`calib_store`]), the line
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
mod calib_store;
mod lines;
mod memory;
mod readout;
mod sequencer;
mod telemetry;

use defmt_rtt as _;
use embassy_executor::{SpawnError, SpawnToken, Spawner};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::spi::Spi;
use embassy_stm32::{Config, bind_interrupts, dma, interrupt, peripherals};
use panic_probe as _;
use startrack_core::tracker::TrackerBuffers;
use static_cell::ConstStaticCell;

/// The tracker's large buffers (line ring, tracking windows, fused CoG plans, ~68 KB): all
/// zero, so in `.bss`; the tracker sets them up in place.
static TRACKER_BUFFERS: ConstStaticCell<TrackerBuffers> =
    ConstStaticCell::new(TrackerBuffers::new());

/// The executor of the sequencer's feeder: interrupt-driven (UART4's vector, unused
/// otherwise) at a priority above thread mode, so the tracker's long frames cannot delay the
/// refill of the clock ring.
static EXECUTOR_CLOCKS: embassy_executor::InterruptExecutor =
    embassy_executor::InterruptExecutor::new();

#[interrupt]
unsafe fn UART4() {
    // SAFETY: UART4's vector serves only this executor, started once in `main`.
    unsafe { EXECUTOR_CLOCKS.on_interrupt() }
}

/// The sequencer's compiled frame (56 KB, CPU-only, cacheable `.bss`).
static SEQ_TABLES: ConstStaticCell<sequencer::Tables> =
    ConstStaticCell::new(sequencer::Tables::new());

bind_interrupts!(
    /// Interrupts the drivers need: DMA1 stream 0 carries SPI1 RX (the ADC samples), DMA1
    /// stream 1 the clock words (TIM6 update into GPIOE BSRR).
    struct Irqs {
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
        DMA1_STREAM1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
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
    config
}

/// Spawns a task, or logs why it could not be (a task spawned twice).
fn spawn_or_log<S>(spawner: Spawner, name: &str, token: Result<SpawnToken<S>, SpawnError>) {
    match token {
        Ok(token) => spawner.spawn(token),
        Err(e) => defmt::error!("cannot spawn {=str}: {}", name, e),
    }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_stm32::init(clock_config());
    defmt::info!(
        "startrack firmware {=str}: clocks up",
        env!("CARGO_PKG_VERSION")
    );

    let table = calib_store::load().ok();

    let dma_region = match memory::init() {
        Ok(r) => r,
        Err(e) => {
            defmt::error!("DMA region and caches: {}", e);
            return;
        }
    };
    let memory::DmaRegion {
        ring,
        lines: line_bufs,
        samples,
    } = dma_region;

    if let Err(e) = lines::init(line_bufs) {
        defmt::error!("line buffers: {}", e);
        return;
    }

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
    let seq = sequencer::Sequencer::new(p.TIM6, p.DMA1_CH1, Irqs, clock_pins, ring);

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

    let Some(buffers) = TRACKER_BUFFERS.try_take() else {
        defmt::error!("tracker buffers already taken");
        return;
    };
    spawn_or_log(spawner, "tracker", app::tracker_task(table, buffers));
    spawn_or_log(spawner, "readout", readout::readout_task(adc, samples));
    match SEQ_TABLES.try_take() {
        Some(tables) => {
            use interrupt::{InterruptExt, Priority};
            interrupt::UART4.set_priority(Priority::P6);
            let clocks = EXECUTOR_CLOCKS.start(interrupt::UART4);
            match sequencer::sequencer_task(seq, tables) {
                Ok(token) => clocks.spawn(token),
                Err(e) => defmt::error!("cannot spawn sequencer: {}", e),
            }
        }
        None => defmt::error!("sequencer tables already taken"),
    }
}
