//! The command and telemetry link, as the application serves it on any board. The protocol
//! is the core's [`LinkService`] (docs/protocol.md); the board moves the bytes
//! ([`crate::board`]'s `start_io`: on the STM32H743 USART3 by DMA, on `mps2-an500` a CMSDK
//! UART) between the wire and the [`RX`] and [`TX`] pipes.
//!
//! The tracker task owns the [`LinkService`] and serves it between frames ([`serve`]): it
//! takes the received bytes (commands act on the tracker there, never mid-frame) and moves
//! queued telemetry into [`TX`] as far as it has room, without waiting. A slow link therefore
//! leaves telemetry in the service's queues (dropped and counted when they are full), and a
//! flood of bytes fills [`RX`] (the excess is dropped and counted in [`RX_DROPPED`] by
//! [`received`], which the board's receive task calls): neither can stall the frame loop.
//! Both pipes are written with [`crate::pipe::write_fitting`], so a write that wraps around
//! a pipe's ring loses nothing.
//!
//! Memory: the pipes ([`RX_PIPE_BYTES`] + [`TX_PIPE_BYTES`]) in `.bss`, the service (~16 KB)
//! in [`SERVICE`]; the board's buffers are the board's.

use core::sync::atomic::{AtomicU32, Ordering};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use startrack_core::cycle::FrameCycle;
use startrack_core::link::{LinkService, NoWindows, TableUpload};

/// Bytes received and not yet served: what arrives in one frame at 921,600 bit/s with room
/// (a ground station that keeps 8 chunks of 1 KB in flight needs ~9 KB).
pub const RX_PIPE_BYTES: usize = 16 * 1024;
/// Telemetry handed to the transmit task and not yet sent.
pub const TX_PIPE_BYTES: usize = 4 * 1024;

/// The service, owned by the tracker task. A `StaticCell` set up at run time, so it lives in
/// `.bss`: a constant one would go to `.data` (the queues' uninitialised bytes are not
/// zeros), costing its ~16 KB twice, in flash and RAM.
pub static SERVICE: static_cell::StaticCell<LinkService> = static_cell::StaticCell::new();

/// Received bytes, from the receive task to the tracker task.
pub static RX: Pipe<CriticalSectionRawMutex, RX_PIPE_BYTES> = Pipe::new();
/// Telemetry bytes, from the tracker task to the transmit task.
pub static TX: Pipe<CriticalSectionRawMutex, TX_PIPE_BYTES> = Pipe::new();
/// Received bytes dropped because [`RX`] was full.
pub static RX_DROPPED: AtomicU32 = AtomicU32::new(0);
/// The UART's receive errors (overrun, framing, noise).
pub static RX_ERRORS: AtomicU32 = AtomicU32::new(0);

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
        crate::board::system_reset(startrack_core::safe::ResetCause::Software);
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
        // The room was checked and this task is the only writer: every byte goes in, across
        // the ring's end too ([`crate::pipe`]).
        crate::pipe::write_fitting(&TX, buf.get(..n).unwrap_or_default());
    }
}

/// Hands bytes the board received to the tracker task ([`RX`]); what does not fit is
/// dropped and counted in [`RX_DROPPED`]. Each board's receive task calls it.
pub fn received(bytes: &[u8]) {
    let taken = crate::pipe::write_fitting(&RX, bytes);
    if taken < bytes.len() {
        RX_DROPPED.fetch_add((bytes.len() - taken) as u32, Ordering::Relaxed);
    }
}
