//! The command and telemetry link on the board: USART3 (the NUCLEO's ST-LINK virtual COM
//! port, PD8 TX / PD9 RX; an RS-422 transceiver on the same pins in flight) at
//! [`BAUD`], receive by DMA into a ring buffer, transmit by DMA. The protocol is the core's
//! [`LinkService`] (docs/protocol.md); this file moves bytes only.
//!
//! Two tasks beside readout and processing: [`link_rx_task`] copies what the DMA ring
//! received into the [`RX`] pipe, [`link_tx_task`] sends what the [`TX`] pipe holds. The
//! tracker task owns the [`LinkService`] and serves it between frames ([`serve`]): it takes
//! the received bytes (commands act on the tracker there, never mid-frame) and moves queued
//! telemetry into [`TX`] as far as it has room, without waiting. A slow link therefore
//! leaves telemetry in the service's queues (dropped and counted when they are full), and
//! a flood of bytes fills [`RX`] (the excess is dropped and counted by the receive task):
//! neither can stall the frame loop.
//!
//! Memory: the pipes ([`RX_PIPE_BYTES`] + [`TX_PIPE_BYTES`]) in `.bss`, the DMA ring
//! ([`RX_RING_BYTES`]) and transmit buffer ([`TX_DMA_BYTES`]) in the non-cacheable DMA
//! region, the service (~16 KB) in the tracker task's static.

use core::sync::atomic::{AtomicU32, Ordering};
use embassy_stm32::mode::Async;
use embassy_stm32::usart::{RingBufferedUartRx, UartTx};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use startrack_core::cycle::FrameCycle;
use startrack_core::link::{LinkService, NoWindows, TableUpload};

/// The link's bit rate (the ST-LINK V3 bridge takes it; an RS-422 line up to 10 Mbit/s).
pub const BAUD: u32 = 921_600;
/// Bytes received and not yet served: what arrives in one frame at [`BAUD`] with room (a
/// ground station that keeps 8 chunks of 1 KB in flight needs ~9 KB).
pub const RX_PIPE_BYTES: usize = 16 * 1024;
/// Telemetry handed to the transmit task and not yet sent.
pub const TX_PIPE_BYTES: usize = 4 * 1024;
/// The receive DMA ring (half-transfer and transfer-complete interrupts at 512 bytes), in the
/// non-cacheable DMA region ([`crate::memory::DmaRegion`]).
pub const RX_RING_BYTES: usize = 1024;
/// The transmit DMA buffer, in the same region: the D-cache would otherwise hide the bytes
/// the CPU copies into it from the DMA.
pub const TX_DMA_BYTES: usize = 512;

/// The service, owned by the tracker task. A `StaticCell` set up at run time, so it lives in
/// `.bss`: a constant one would go to `.data` (the queues' uninitialised bytes are not
/// zeros), costing its ~16 KB twice, in flash and RAM.
pub static SERVICE: static_cell::StaticCell<LinkService> = static_cell::StaticCell::new();

/// Received bytes, from the receive task to the tracker task.
pub static RX: Pipe<CriticalSectionRawMutex, RX_PIPE_BYTES> = Pipe::new();
/// Telemetry bytes, from the tracker task to the transmit task.
pub static TX: Pipe<CriticalSectionRawMutex, TX_PIPE_BYTES> = Pipe::new();
/// Received bytes dropped because [`RX`] was full, and receive errors (overrun, framing,
/// noise) of the USART.
pub static RX_DROPPED: AtomicU32 = AtomicU32::new(0);
/// USART receive errors (the ring is restarted after each).
pub static RX_ERRORS: AtomicU32 = AtomicU32::new(0);

/// Copies the DMA ring's bytes into [`RX`]; a full pipe drops them (counted).
#[embassy_executor::task]
pub async fn link_rx_task(mut rx: RingBufferedUartRx<'static>) {
    let mut buf = [0u8; 256];
    loop {
        match rx.read(&mut buf).await {
            Ok(n) => {
                let bytes = buf.get(..n).unwrap_or_default();
                let taken = RX.try_write(bytes).unwrap_or(0);
                if taken < n {
                    RX_DROPPED.fetch_add((n - taken) as u32, Ordering::Relaxed);
                }
            }
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

/// One link service round between frames: received bytes executed on the cycle's tracker,
/// the link's work between frames (window rows, the in-flight defect commit) moved on,
/// telemetry moved into [`TX`] while it has room. Never waits.
pub fn serve<const N: usize>(
    cycle: &mut FrameCycle<'static, '_, '_, '_, N>,
    tables: &mut dyn TableUpload,
) {
    let mut buf = [0u8; 256];
    cycle.set_link_time(embassy_time::Instant::now().as_micros());
    while let Ok(n) = RX.try_read(&mut buf) {
        cycle.receive(buf.get(..n).unwrap_or_default(), tables, &mut NoWindows);
    }
    cycle.poll(tables, &mut NoWindows);
    send_queued(|out| cycle.transmit(out), &mut buf);
}

/// The service for the safe standby: [`SERVICE`] with the set-up `faults` in its
/// housekeeping, or `None` if the tracker task already holds it (the tracker then serves the
/// link itself).
pub fn standby_service(
    faults: startrack_core::safe::SetupFaults,
) -> Option<&'static mut LinkService> {
    let link = SERVICE
        .try_uninit()
        .map(|slot| slot.write(LinkService::new()))?;
    link.set_setup_faults(faults.bits());
    Some(link)
}

/// One link round in the safe standby (no tracker): received bytes executed with
/// [`LinkService::receive_standby`] against the flash store (through `held` while an erase
/// holds it, as between frames), telemetry moved into [`TX`]; a reset command resets.
pub async fn serve_standby(link: &mut LinkService, held: &mut crate::flash_store::HeldTables) {
    let mut buf = [0u8; 256];
    link.set_time(embassy_time::Instant::now().as_micros());
    while let Ok(n) = RX.try_read(&mut buf) {
        crate::flash_store::with_link_tables(held, |tables| {
            link.receive_standby(buf.get(..n).unwrap_or_default(), tables);
        });
    }
    send_queued(|out| link.transmit(out), &mut buf);
    if link.reset_requested() {
        // Let the transmit task send the acceptance, then reset.
        embassy_time::Timer::after_millis(50).await;
        cortex_m::peripheral::SCB::sys_reset();
    }
}

/// Moves queued telemetry into [`TX`] while it has room; never waits.
fn send_queued(mut transmit: impl FnMut(&mut [u8]) -> usize, buf: &mut [u8]) {
    loop {
        let room = (TX_PIPE_BYTES - TX.len()).min(buf.len());
        let n = transmit(buf.get_mut(..room).unwrap_or_default());
        if n == 0 {
            break;
        }
        // The room was checked; a short write cannot happen with one writer.
        let _ = TX.try_write(buf.get(..n).unwrap_or_default());
    }
}
