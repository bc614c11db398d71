//! Raw line readout: receives each CCD line (1072 16-bit samples) from the external SAR ADC
//! by SPI receive DMA into a free line buffer and hands the filled buffer to processing.
//!
//! # Hardware (NUCLEO-H743ZI)
//! The ADC is an external 16-bit SAR ADC with an SPI output (read-only: no MOSI), on SPI1:
//!
//! | signal | pin | NUCLEO connector |
//! |---|---|---|
//! | SPI1_SCK | PA5 | CN7 pin 10 (Arduino D13) |
//! | SPI1_MISO (ADC SDO) | PA6 | CN7 pin 12 (Arduino D12) |
//! | ADC chip select / line gate (GPIO, active low) | PD14 | CN7 pin 16 (Arduino D10) |
//!
//! SPI1 runs in master, receive-only mode, 16-bit words, mode 0, at [`SPI_HZ`] (the SPI123
//! kernel clock is PLL1_Q = 120 MHz, divided by 4). SPI1 RX is served by DMA1 stream 0
//! (`DMA1_CH0`, routed by DMAMUX1); PA7 (SPI1_MOSI) is not used because the NUCLEO wires it
//! to the Ethernet PHY.
//!
//! # What this does not do yet
//! There is no CCD clock sequencer yet, so nothing drives the CCD or paces the ADC: each
//! line is a plain SPI burst of 1072 words started by a timer tick ([`LINE_PERIOD`]) that
//! stands in for the sequencer's "line ready" event. With no ADC on the pins the samples are
//! whatever MISO reads (the pull-down makes that 0). The sequencer will replace the ticker
//! and drive the ADC's conversion start; the buffer hand-off stays as it is.

use crate::lines::{FILLED, FREE, GEOMETRY, LINE_LEN, LineBuf, RawLine};
use embassy_stm32::gpio::Output;
use embassy_stm32::mode::Async;
use embassy_stm32::spi::{self, Spi, mode::Master};
use embassy_stm32::time::Hertz;
use embassy_time::{Duration, Ticker};

/// SPI clock for the ADC read-out: 30 MHz, so a line (1072 x 16 bits) takes 572 us.
pub const SPI_HZ: Hertz = Hertz(30_000_000);

/// Line period while no sequencer paces the readout: 2 ms, about 2 s per 1033-line frame.
pub const LINE_PERIOD: Duration = Duration::from_millis(2);

/// The SPI configuration for the ADC: mode 0, MSB first, 16-bit words (set per transfer by
/// the word type), MISO pulled down so that an unconnected ADC reads 0.
pub fn spi_config() -> spi::Config {
    let mut config = spi::Config::default();
    config.frequency = SPI_HZ;
    config.mode = spi::MODE_0;
    config.bit_order = spi::BitOrder::MsbFirst;
    config.miso_pull = embassy_stm32::gpio::Pull::Down;
    config
}

/// The link to the external ADC: SPI1 with receive DMA, and its chip-select line.
pub struct AdcLink {
    spi: Spi<'static, Async, Master>,
    cs: Output<'static>,
}

impl AdcLink {
    /// Wraps an SPI set up with [`spi_config`] and the ADC's chip select (idle high).
    pub fn new(spi: Spi<'static, Async, Master>, cs: Output<'static>) -> Self {
        Self { spi, cs }
    }

    /// Reads one line into `buf` by DMA, chip select held low for the whole line.
    async fn read_line(&mut self, buf: &mut LineBuf) -> Result<(), spi::Error> {
        self.cs.set_low();
        let result = self.spi.read(&mut buf[..]).await;
        self.cs.set_high();
        result
    }
}

/// Position of the next line in the frame.
struct LineCounter {
    frame: u32,
    line: u16,
}

impl LineCounter {
    fn advance(&mut self) {
        self.line += 1;
        if self.line >= GEOMETRY.lines {
            self.line = 0;
            self.frame = self.frame.wrapping_add(1);
        }
    }
}

/// The readout task: one line per tick, into whichever buffer is free, then on to
/// processing. When processing has not yet returned a buffer (it fell behind by a whole
/// line) the overrun is counted and logged and the readout waits for a buffer.
#[embassy_executor::task]
pub async fn readout_task(mut adc: AdcLink) -> ! {
    defmt::info!(
        "readout: {} samples/line, {} lines/frame, SPI {} Hz, line period {} us (no sequencer: timer-paced)",
        LINE_LEN,
        GEOMETRY.lines,
        SPI_HZ.0,
        LINE_PERIOD.as_micros()
    );
    let mut ticker = Ticker::every(LINE_PERIOD);
    let mut pos = LineCounter { frame: 0, line: 0 };
    // A buffer kept back after a failed transfer, reused before asking FREE.
    let mut spare: Option<&'static mut LineBuf> = None;
    let mut overruns: u32 = 0;

    loop {
        ticker.next().await;
        let buf = match spare.take() {
            Some(buf) => buf,
            None => match FREE.try_receive() {
                Ok(buf) => buf,
                Err(_) => {
                    overruns = overruns.wrapping_add(1);
                    defmt::warn!(
                        "readout: no free line buffer at frame {} line {} (overruns: {})",
                        pos.frame,
                        pos.line,
                        overruns
                    );
                    FREE.receive().await
                }
            },
        };
        match adc.read_line(buf).await {
            Ok(()) => {
                FILLED
                    .send(RawLine {
                        frame: pos.frame,
                        line: pos.line,
                        samples: buf,
                    })
                    .await;
            }
            Err(e) => {
                // The line is lost; the frame position still advances so that line indices
                // stay tied to the sensor's rows.
                defmt::error!(
                    "readout: SPI error {} at frame {} line {}",
                    e,
                    pos.frame,
                    pos.line
                );
                spare = Some(buf);
            }
        }
        pos.advance();
    }
}
