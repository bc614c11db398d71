//! The STM32H743ZI board (NUCLEO-H743ZI): clocks at 480 MHz, the independent watchdog
//! (IWDG1), the table store in flash bank 2 ([`bank2`]), the CCD board's TMP117
//! ([`board_temp`]) with the MCU's sensor as its fallback ([`mcu_temp`]), the CCD clocks
//! played from the core's compiled program by timer-paced DMA into GPIOE ([`sequencer`],
//! [`mdma_list`], with the caches and the DMA region in [`memory`]), the line readout by SPI
//! DMA in step with them ([`readout`]), the link on USART3 by DMA ([`uart`]) and the PPS
//! line's capture on TIM5 ([`pps`]). What each
//! item is for is in [`crate::board`]; the pins and wiring are in docs/hardware.md.

pub mod bank2;
pub mod board_temp;
pub mod mcu_temp;
pub mod mdma_list;
pub mod memory;
pub mod pps;
pub mod readout;
pub mod sequencer;
pub mod uart;

use super::{Started, WatchdogPort};
use crate::d2_ram::D2Ready;
use crate::lines::LINE_LEN;
use crate::spawn::spawn_or_log;
use embassy_executor::Spawner;
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::peripherals::{self as p, IWDG1};
use embassy_stm32::spi::Spi;
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Config, Peri, bind_interrupts, dma, flash, interrupt, peripherals, usart};
use startrack_core::cycle::FrameOutcome;
use startrack_core::safe::{FallbackThermometer, ResetCause, SetupFaults};
use startrack_core::store::{H743_BANK2, Layout};
use startrack_core::tracker::{Integration, StarRecord};
use static_cell::ConstStaticCell;

use defmt_rtt as _;
use panic_probe as _;

/// The table store's flash: bank 2.
pub type Flash = bank2::Bank2;

/// The store's layout in bank 2 (docs/storage.md).
pub const STORE_LAYOUT: Layout = H743_BANK2;

/// The sensor temperature: the CCD board's TMP117, else the MCU's.
pub type Thermometer = FallbackThermometer<board_temp::BoardSensor, mcu_temp::McuThermometer>;

/// The star catalog's region (memory.x `CATALOG`: bank 1's last five sectors), written by
/// the programmer, never by the firmware.
pub const CATALOG_ADDRESS: usize = 0x0806_0000;
/// Its length, bytes.
pub const CATALOG_REGION_B: usize = 640 * 1024;

/// The independent watchdog.
pub struct Watchdog(IndependentWatchdog<'static, IWDG1>);

impl WatchdogPort for Watchdog {
    fn unleash(&mut self) {
        self.0.unleash();
    }
    fn pet(&mut self) {
        self.0.pet();
    }
}

/// The executor of the sequencer's feeder: interrupt-driven (UART4's vector, unused
/// otherwise) at a priority above thread mode, so the tracker's long frames cannot delay the
/// refill of the clock nodes.
static EXECUTOR_CLOCKS: embassy_executor::InterruptExecutor =
    embassy_executor::InterruptExecutor::new();

#[interrupt]
unsafe fn UART4() {
    // SAFETY: UART4's vector serves only this executor, started once in `start_lines`.
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
    pub struct Irqs {
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

/// The peripherals [`start_io`] takes: the link's USART3 with its DMA streams, and what the
/// line path needs.
pub struct Io {
    usart: Peri<'static, p::USART3>,
    usart_rx: Peri<'static, p::PD9>,
    usart_tx: Peri<'static, p::PD8>,
    usart_tx_dma: Peri<'static, p::DMA1_CH2>,
    usart_rx_dma: Peri<'static, p::DMA1_CH3>,
    pps_tim: Peri<'static, p::TIM5>,
    pps_pin: Peri<'static, p::PA0>,
    lines: LinePeripherals,
}

/// The sequencer's and the readout's peripherals.
struct LinePeripherals {
    tim: Peri<'static, p::TIM6>,
    pace: Peri<'static, p::DMA1_CH1>,
    mdma: Peri<'static, p::MDMA_CH0>,
    clock_pins: [Peri<'static, embassy_stm32::gpio::AnyPin>; 16],
    spi: Peri<'static, p::SPI1>,
    sck: Peri<'static, p::PA5>,
    miso: Peri<'static, p::PA6>,
    spi_dma: Peri<'static, p::DMA1_CH0>,
    cs: Peri<'static, p::PD14>,
}

/// What [`start_lines`] takes: the line path's peripherals and its DMA buffers.
pub struct LinePath {
    peripherals: LinePeripherals,
    clock: &'static mut sequencer::ClockBuffers,
    samples: &'static mut [u16; LINE_LEN],
}

/// What the application gets from the board at start-up.
pub struct Parts {
    /// IWDG1.
    pub watchdog: Watchdog,
    /// Flash bank 2.
    pub flash: Flash,
    /// The TMP117, else the MCU's sensor.
    pub thermometer: Thermometer,
    /// `EXTERNAL_THERMOMETER` when no TMP117 answered.
    pub thermometer_faults: SetupFaults,
    /// SRAM1-3 (the D2 domain's, `.d2sram`) clocked.
    pub d2_ready: D2Ready,
    /// The rest, for [`start_io`].
    pub io: Io,
}

/// Clocks up, SRAM1-3 clocked, the watchdog configured (not started), the flash driver, the
/// thermometers.
pub fn init() -> Parts {
    let p = embassy_stm32::init(clock_config());
    let d2_ready = enable_d2_sram();
    let watchdog = Watchdog(IndependentWatchdog::new(
        p.IWDG1,
        crate::watchdog::TIMEOUT_US,
    ));
    let flash = bank2::Bank2::new(embassy_stm32::flash::Flash::new(p.FLASH, Irqs));
    // The CCD board's TMP117, else the MCU's sensor (a set-up fault housekeeping reports).
    let board_sensor = board_temp::Tmp117::new(p.I2C1, p.PB8, p.PB9);
    let thermometer_faults = if board_sensor.is_none() {
        SetupFaults::EXTERNAL_THERMOMETER
    } else {
        SetupFaults::empty()
    };
    let thermometer = FallbackThermometer::new(
        board_temp::BoardSensor(board_sensor),
        mcu_temp::McuThermometer::new(p.ADC3),
    );
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
    Parts {
        watchdog,
        flash,
        thermometer,
        thermometer_faults,
        d2_ready,
        io: Io {
            usart: p.USART3,
            usart_rx: p.PD9,
            usart_tx: p.PD8,
            usart_tx_dma: p.DMA1_CH2,
            usart_rx_dma: p.DMA1_CH3,
            pps_tim: p.TIM5,
            pps_pin: p.PA0,
            lines: LinePeripherals {
                tim: p.TIM6,
                pace: p.DMA1_CH1,
                mdma: p.MDMA_CH0,
                clock_pins,
                spi: p.SPI1,
                sck: p.PA5,
                miso: p.PA6,
                spi_dma: p.DMA1_CH0,
                cs: p.PD14,
            },
        },
    }
}

/// Clocks the D2 domain's SRAM1, SRAM2 and SRAM3 (RCC_AHB2ENR; off after reset, when an
/// access to them is a bus fault), where the map puts `.d2sram`. The enable bits also
/// allocate the SRAMs to the CPU, so the D2 domain stays in DRun while the CPU runs (it does
/// anyway while DMA1 and the D2 peripherals are enabled). The read-back and DSB make the
/// enable take effect before the first access (RM0433: a delay of a few bus cycles after
/// setting a clock enable).
fn enable_d2_sram() -> D2Ready {
    let rcc = embassy_stm32::pac::RCC;
    rcc.ahb2enr().modify(|w| {
        w.set_sram1en(true);
        w.set_sram2en(true);
        w.set_sram3en(true);
    });
    let _ = rcc.ahb2enr().read();
    cortex_m::asm::dsb();
    // SAFETY: SRAM1-3 are clocked from here on (the bits are set above and nothing clears
    // them), and the map puts `.d2sram` in them.
    unsafe { D2Ready::new() }
}

/// Why the MCU reset (RCC_RSR), and clears the flags so the next reset reads its own.
pub fn reset_cause() -> ResetCause {
    let rcc = embassy_stm32::pac::RCC;
    let rsr = rcc.rsr().read();
    let cause = if rsr.iwdg1rstf() {
        ResetCause::Watchdog
    } else if rsr.sftrstf() {
        ResetCause::Software
    } else if rsr.porrstf() || rsr.borrstf() {
        ResetCause::PowerOn
    } else if rsr.pinrstf() {
        ResetCause::Pin
    } else {
        ResetCause::Other
    };
    rcc.rsr().modify(|w| w.set_rmvf(true));
    cause
}

/// The DMA block (clock nodes and tables, line buffers, SPI samples, the link's buffers) in
/// its non-cacheable MPU region and the caches on; then the link: USART3 (ST-LINK virtual
/// COM port), DMA1 stream 3 receive ring, stream 2 transmit. Without the link the tracker
/// still runs (its telemetry then only in the log).
pub fn start_io(spawner: Spawner, io: Io) -> Started<LinePath> {
    let Io {
        usart,
        usart_rx,
        usart_tx,
        usart_tx_dma,
        usart_rx_dma,
        pps_tim,
        pps_pin,
        lines,
    } = io;
    let region = match memory::init() {
        Ok(r) => r,
        Err(e) => {
            defmt::error!("DMA region and caches: {}", e);
            return Started {
                line_buffers: None,
                lines: None,
                faults: SetupFaults::READOUT,
            };
        }
    };
    let memory::DmaRegion {
        clock,
        lines: line_buffers,
        samples,
        uart_rx,
        uart_tx,
    } = region;
    let mut uart_config = usart::Config::default();
    uart_config.baudrate = uart::BAUD;
    match usart::Uart::new(
        usart,
        usart_rx,
        usart_tx,
        usart_tx_dma,
        usart_rx_dma,
        Irqs,
        uart_config,
    ) {
        Ok(uart) => {
            let (tx, rx) = uart.split();
            spawn_or_log(
                spawner,
                "link rx",
                uart::link_rx_task(rx.into_ring_buffered(uart_rx)),
            );
            spawn_or_log(spawner, "link tx", uart::link_tx_task(tx, uart_tx));
        }
        Err(e) => defmt::error!("link: USART3 configuration refused: {}", e),
    }
    // The sync pulse: the PPS line on PA0, TIM5 channel 1 input capture at 1 MHz. Without it
    // the reports say their time is not synchronised.
    {
        use embassy_stm32::gpio::Pull;
        use embassy_stm32::timer::input_capture::{CapturePin, InputCapture};
        use embassy_stm32::timer::low_level::CountingMode;
        let capture = InputCapture::new(
            pps_tim,
            Some(CapturePin::new(pps_pin, Pull::Down)),
            None,
            None,
            None,
            Irqs,
            embassy_stm32::time::Hertz(1_000_000),
            CountingMode::EdgeAlignedUp,
        );
        spawn_or_log(spawner, "pps", pps::pps_task(capture));
    }
    Started {
        line_buffers: Some(line_buffers),
        lines: Some(LinePath {
            peripherals: lines,
            clock,
            samples,
        }),
        faults: SetupFaults::empty(),
    }
}

/// The line path: the sequencer (its compiler in thread mode, its feeder in the
/// interrupt-level executor) and the SPI readout; `false` when a task could not start.
pub fn start_lines(spawner: Spawner, lines: LinePath) -> bool {
    let LinePath {
        peripherals: lp,
        clock,
        samples,
    } = lines;
    let seq = sequencer::Sequencer::new(lp.tim, lp.pace, lp.mdma, lp.clock_pins, clock);
    let spi = Spi::new_rxonly(
        lp.spi,
        lp.sck,
        lp.miso,
        lp.spi_dma,
        Irqs,
        readout::spi_config(),
    );
    let cs = Output::new(lp.cs, Level::High, Speed::VeryHigh);
    let adc = readout::AdcLink::new(spi, cs);
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
    readout && plans && clocks
}

/// Nothing more: the frame's outcome is in the log and on the link.
pub fn after_frame(
    _outcome: &FrameOutcome,
    _stars: &[StarRecord],
    _integration: Option<Integration>,
) {
}

/// Resets the MCU (RCC_RSR tells the next boot why: no mark needed).
pub fn system_reset(_cause: ResetCause) -> ! {
    cortex_m::peripheral::SCB::sys_reset()
}
