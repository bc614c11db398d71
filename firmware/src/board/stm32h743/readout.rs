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
//! # In step with the clocks
//! Each line comes from the sequencer ([`super::sequencer::LINE_JOBS`]), only the lines the
//! frame's plan digitises (the tracker's windows, or every line), each tagged with its raw
//! line index, the tracker's frame number and whether it ends the frame: the job says how
//! many words the line digitised (read pixels x outputs, in the order the pixels left the
//! register) and when its last sample is taken. After that instant the line's words are read
//! in one SPI burst into the sample buffer (DMA), then put in their raw columns
//! (`LineJob::unpack`) in a free line buffer, which goes on to processing. The ADC board
//! therefore buffers the samples (a FIFO of at least a line and the sequencer's ring, see
//! docs/hardware.md); with no ADC on the pins every word reads 0 (MISO pulled down).

use super::sequencer::LINE_JOBS;
use crate::lines::{FILLED, FREE, GEOMETRY, LINE_LEN, LineBuf, RawLine};
use embassy_stm32::gpio::Output;
use embassy_stm32::mode::Async;
use embassy_stm32::spi::{self, Spi, mode::Master};
use embassy_stm32::time::Hertz;
use embassy_time::Timer;

/// SPI clock for the ADC read-out: 30 MHz, so a line (1072 x 16 bits) takes 572 us.
pub const SPI_HZ: Hertz = Hertz(30_000_000);

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

    /// Reads `words.len()` samples by DMA, chip select held low for the whole burst.
    async fn read_words(&mut self, words: &mut [u16]) -> Result<(), spi::Error> {
        self.cs.set_low();
        let result = self.spi.read(words).await;
        self.cs.set_high();
        result
    }
}

/// The readout task: for each line the sequencer clocked, wait for its last sample, read its
/// words into `samples` (DMA), unpack them into a free line buffer and hand it to
/// processing. When processing has not yet returned a buffer the overrun is counted and
/// logged and the readout waits for one.
#[embassy_executor::task]
pub async fn readout_task(mut adc: AdcLink, samples: &'static mut [u16; LINE_LEN]) -> ! {
    defmt::info!(
        "readout: up to {} samples/line, {} lines/frame, SPI {} Hz, lines from the sequencer",
        LINE_LEN,
        GEOMETRY.lines,
        SPI_HZ.0
    );
    // A buffer kept back after a failed transfer, reused before asking FREE.
    let mut spare: Option<&'static mut LineBuf> = None;
    let mut overruns: u32 = 0;

    loop {
        let ready = LINE_JOBS.receive().await;
        Timer::at(ready.due).await;
        let (frame, line, last) = (ready.frame, ready.job.line, ready.last);
        let buf = match spare.take() {
            Some(buf) => buf,
            None => match FREE.try_receive() {
                Ok(buf) => buf,
                Err(_) => {
                    overruns = overruns.wrapping_add(1);
                    defmt::warn!(
                        "readout: no free line buffer at frame {} line {} (overruns: {})",
                        frame,
                        line,
                        overruns
                    );
                    FREE.receive().await
                }
            },
        };
        let n = (ready.job.words as usize).min(LINE_LEN);
        let words = &mut samples[..n];
        if let Err(e) = adc.read_words(words).await {
            // The line is lost; line indices stay tied to the sensor's rows.
            defmt::error!("readout: SPI error {} at frame {} line {}", e, frame, line);
            spare = Some(buf);
            continue;
        }
        match ready.job.unpack(GEOMETRY.outputs, 1, words, &mut buf[..]) {
            Ok(_) => {
                FILLED
                    .send(RawLine {
                        frame,
                        line,
                        last,
                        samples: buf,
                        integration: ready.integration,
                    })
                    .await;
            }
            Err(e) => {
                defmt::error!("readout: frame {} line {}: {}", frame, line, e);
                spare = Some(buf);
            }
        }
    }
}
