//! Star tracker firmware for the e2v CCD47-20 on an STM32H743ZI (NUCLEO-H743ZI).
//!
//! What runs: clocks at 480 MHz, the calibration table check ([`calib_store`]), the line
//! readout by SPI DMA into ping-pong buffers ([`readout`], [`lines`]), and the core's
//! tracker application bound to those and to the log ([`app`], [`telemetry`]): every
//! processing step, from the bias of a line to a star's centroid and the mode changes, is
//! the core's. This crate holds hardware and tasks only.
//!
//! Boundary, honestly: there is no CCD clock sequencer yet, so no CCD is driven; lines are
//! SPI bursts paced by a timer (see [`readout`]). Telemetry goes to the defmt log and to the
//! command and telemetry link on USART3 ([`link`]); table uploads are refused until the flash
//! slots are bound.
#![no_std]
#![no_main]

mod app;
mod calib_store;
mod lines;
mod link;
mod readout;
mod telemetry;

use defmt_rtt as _;
use embassy_executor::{SpawnError, SpawnToken, Spawner};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::spi::Spi;
use embassy_stm32::{Config, bind_interrupts, dma, peripherals, usart};
use panic_probe as _;
use startrack_core::tracker::TrackerBuffers;
use static_cell::ConstStaticCell;

/// The tracker's large buffers (line ring, tracking windows, fused CoG plans, ~68 KB): all
/// zero, so in `.bss`; the tracker sets them up in place.
static TRACKER_BUFFERS: ConstStaticCell<TrackerBuffers> =
    ConstStaticCell::new(TrackerBuffers::new());

bind_interrupts!(
    /// Interrupts the drivers need: DMA1 stream 0 carries SPI1 RX (the ADC samples).
    struct Irqs {
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
        USART3 => usart::InterruptHandler<peripherals::USART3>;
        DMA1_STREAM1 => dma::InterruptHandler<peripherals::DMA1_CH1>;
        DMA1_STREAM2 => dma::InterruptHandler<peripherals::DMA1_CH2>;
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

    if let Err(e) = lines::init() {
        defmt::error!("line buffers: {}", e);
        return;
    }

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
    // The link: USART3 (ST-LINK virtual COM port), DMA1 stream 1 receive ring, stream 2
    // transmit. Without it the tracker still runs (its telemetry then only in the log).
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = link::BAUD;
    match (
        usart::Uart::new(
            p.USART3,
            p.PD9,
            p.PD8,
            p.DMA1_CH2,
            p.DMA1_CH1,
            Irqs,
            uart_config,
        ),
        link::DMA_RING.try_take(),
    ) {
        (Ok(uart), Some(ring)) => {
            let (tx, rx) = uart.split();
            spawn_or_log(
                spawner,
                "link rx",
                link::link_rx_task(rx.into_ring_buffered(ring)),
            );
            spawn_or_log(spawner, "link tx", link::link_tx_task(tx));
        }
        (Err(e), _) => defmt::error!("link: USART3 configuration refused: {}", e),
        (_, None) => defmt::error!("link: DMA ring already taken"),
    }
    spawn_or_log(spawner, "tracker", app::tracker_task(table, buffers));
    spawn_or_log(spawner, "readout", readout::readout_task(adc));
}
