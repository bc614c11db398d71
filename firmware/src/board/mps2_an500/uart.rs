//! The link's bytes on `mps2-an500`: CMSDK APB UART0 (0x4000_4000), which QEMU connects to
//! its first `-serial` character device (the PIL makes it a TCP socket on 127.0.0.1, so the
//! ground tool's `--port` reaches it as it reaches the served SIL). [`link_rx_task`] moves
//! received bytes into [`crate::link::RX`], [`link_tx_task`] sends what [`TX`] holds; the
//! protocol is the application's ([`crate::link`]).
//!
//! The UART has a one-byte buffer each way and QEMU paces it by the character device, not by
//! the baud rate. Both tasks poll (no interrupt: the board has no device crate), every
//! [`POLL_US`] while idle; each poll drains what is there.
//!
//! Cost: a poll is a few register reads; a byte a few more.

use crate::link::{RX_ERRORS, TX};
use core::sync::atomic::Ordering;
use embassy_time::Timer;

/// UART0's registers.
const BASE: usize = 0x4000_4000;
const DATA: usize = BASE;
const STATE: usize = BASE + 0x04;
const CTRL: usize = BASE + 0x08;
const BAUDDIV: usize = BASE + 0x10;
/// STATE: transmit buffer full, receive buffer full, receive overrun.
const TX_FULL: u32 = 1 << 0;
const RX_FULL: u32 = 1 << 1;
const RX_OVERRUN: u32 = 1 << 3;
/// CTRL: transmit and receive enabled.
const TX_EN: u32 = 1 << 0;
const RX_EN: u32 = 1 << 1;

/// The baud divider: the 25 MHz APB clock over the flight link's 921,600 bit/s (QEMU needs
/// one of at least 16 to enable the UART; it does not pace by it).
const DIVIDER: u32 = 27;

/// How long an idle task sleeps between polls, us.
pub const POLL_US: u64 = 200;

fn read(addr: usize) -> u32 {
    // SAFETY: `addr` is one of UART0's word-aligned registers, always mapped on this board;
    // reading DATA takes the received byte, which only the receive task does.
    unsafe { core::ptr::read_volatile(core::ptr::with_exposed_provenance::<u32>(addr)) }
}

fn write(addr: usize, value: u32) {
    // SAFETY: as in `read`; only `init` writes CTRL and BAUDDIV, only the transmit task DATA
    // and the receive task STATE (its overrun flag, write-one-to-clear).
    unsafe { core::ptr::write_volatile(core::ptr::with_exposed_provenance_mut::<u32>(addr), value) }
}

/// Enables UART0, both ways, no interrupt.
pub fn init() {
    write(BAUDDIV, DIVIDER);
    write(CTRL, TX_EN | RX_EN);
}

/// Moves received bytes into [`crate::link::RX`] ([`crate::link::received`]: a full pipe
/// drops them, counted).
#[embassy_executor::task]
pub async fn link_rx_task() {
    let mut buf = [0u8; 64];
    loop {
        let mut n = 0;
        while n < buf.len() {
            let state = read(STATE);
            if state & RX_OVERRUN != 0 {
                write(STATE, RX_OVERRUN);
                RX_ERRORS.fetch_add(1, Ordering::Relaxed);
            }
            if state & RX_FULL == 0 {
                break;
            }
            if let Some(b) = buf.get_mut(n) {
                *b = read(DATA) as u8;
            }
            n += 1;
        }
        if n == 0 {
            Timer::after_micros(POLL_US).await;
            continue;
        }
        crate::link::received(buf.get(..n).unwrap_or_default());
    }
}

/// Sends what [`TX`] holds, a byte whenever the transmit buffer is free.
#[embassy_executor::task]
pub async fn link_tx_task() {
    let mut buf = [0u8; 256];
    loop {
        let n = TX.read(&mut buf).await;
        for &b in buf.get(..n).unwrap_or_default() {
            while read(STATE) & TX_FULL != 0 {
                Timer::after_micros(POLL_US).await;
            }
            write(DATA, u32::from(b));
        }
    }
}
