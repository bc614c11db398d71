//! The link's bytes on this board: USART3 (the NUCLEO's ST-LINK virtual COM port, PD8 TX /
//! PD9 RX; an RS-422 transceiver on the same pins in flight) at [`BAUD`], receive by DMA
//! into a ring buffer ([`RX_RING_BYTES`]), transmit by DMA ([`TX_DMA_BYTES`]), both buffers in
//! the non-cacheable DMA region ([`super::memory::DmaRegion`]). [`link_rx_task`] copies what
//! the ring received into [`crate::link::RX`], [`link_tx_task`] sends what [`TX`] holds; the
//! protocol is the application's ([`crate::link`]).

use crate::link::{RX_ERRORS, TX};
use core::sync::atomic::Ordering;
use embassy_stm32::mode::Async;
use embassy_stm32::usart::{RingBufferedUartRx, UartTx};

/// The link's bit rate (the ST-LINK V3 bridge takes it; an RS-422 line up to 10 Mbit/s).
pub const BAUD: u32 = 921_600;
/// The receive DMA ring (half-transfer and transfer-complete interrupts at 512 bytes), in the
/// non-cacheable DMA region ([`super::memory::DmaRegion`]).
pub const RX_RING_BYTES: usize = 1024;
/// The transmit DMA buffer, in the same region: the D-cache would otherwise hide the bytes
/// the CPU copies into it from the DMA.
pub const TX_DMA_BYTES: usize = 512;

/// Copies the DMA ring's bytes into [`crate::link::RX`] ([`crate::link::received`]: a full
/// pipe drops them, counted).
#[embassy_executor::task]
pub async fn link_rx_task(mut rx: RingBufferedUartRx<'static>) {
    let mut buf = [0u8; 256];
    loop {
        match rx.read(&mut buf).await {
            Ok(n) => crate::link::received(buf.get(..n).unwrap_or_default()),
            Err(e) => {
                // The ring restarts on its next read; the partial frame fails its COBS or
                // CRC check and is counted by the service.
                RX_ERRORS.fetch_add(1, Ordering::Relaxed);
                defmt::warn!("link: receive error {}", e);
            }
        }
    }
}

/// Sends what [`TX`] holds.
#[embassy_executor::task]
pub async fn link_tx_task(mut tx: UartTx<'static, Async>, buf: &'static mut [u8; TX_DMA_BYTES]) {
    loop {
        let n = TX.read(buf).await;
        if let Err(e) = tx.write(buf.get(..n).unwrap_or_default()).await {
            defmt::warn!("link: transmit error {}", e);
        }
    }
}
