//! Caches on, with every DMA buffer in one non-cacheable MPU region.
//!
//! The M7's D-cache would hide DMA writes from the CPU (and CPU writes from the DMA) unless
//! each buffer is cleaned or invalidated around each transfer. Instead all DMA buffers live
//! in [`DmaRegion`], a 32 KB-aligned static of at most 32 KB in `.bss` (AXI SRAM, which DMA1
//! and the MDMA reach; DMA1 does not reach DTCM), and MPU region 0 makes exactly that block
//! normal memory, non-cacheable, non-executable. Everything else (stack, tracker state, the sequencer's
//! tables, code) is cached. Cost: none per transfer; 32 KB of AXI SRAM (23 KB used) served
//! uncached.

use super::sequencer::ClockBuffers;
use super::uart::{RX_RING_BYTES, TX_DMA_BYTES};
use crate::lines::{BUFFERS, LINE_LEN, LineBuf};
use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicBool, Ordering};

/// log2 of the region's size and alignment (32 KB).
const REGION_LOG2: u32 = 15;

/// Every buffer a DMA stream reads or writes.
#[repr(C)]
pub struct DmaRegion {
    /// The sequencer's MDMA node ring, chain tables and pacing word (the MDMA and DMA1
    /// stream 1 read them).
    pub clock: ClockBuffers,
    /// The raw line buffers (processing reads them).
    pub lines: [LineBuf; BUFFERS],
    /// One line's ADC words (SPI1 RX DMA writes), before they are unpacked into a line.
    pub samples: [u16; LINE_LEN],
    /// The link's USART3 receive ring (DMA1 stream 3 writes).
    pub uart_rx: [u8; RX_RING_BYTES],
    /// The link's USART3 transmit buffer (DMA1 stream 2 reads).
    pub uart_tx: [u8; TX_DMA_BYTES],
}

const _: () = assert!(core::mem::size_of::<DmaRegion>() <= 1 << REGION_LOG2);

/// The region, aligned to its size as the MPU requires. (A `ConstStaticCell` would put its
/// flag beside a 32 KB-aligned value and double the block; the flag lives apart instead.)
#[repr(C, align(32768))]
struct Aligned(UnsafeCell<DmaRegion>);

// SAFETY: the only access is the one `&mut` that `take` hands out, once (`TAKEN`).
unsafe impl Sync for Aligned {}

static DMA_REGION: Aligned = Aligned(UnsafeCell::new(DmaRegion {
    clock: ClockBuffers::new(),
    lines: [[0; LINE_LEN]; BUFFERS],
    samples: [0; LINE_LEN],
    uart_rx: [0; RX_RING_BYTES],
    uart_tx: [0; TX_DMA_BYTES],
}));

static TAKEN: AtomicBool = AtomicBool::new(false);

/// The region, the first time only.
fn take() -> Option<&'static mut DmaRegion> {
    if TAKEN.swap(true, Ordering::AcqRel) {
        return None;
    }
    // SAFETY: `TAKEN` was false, so no other reference to the region exists or will.
    Some(unsafe { &mut *DMA_REGION.0.get() })
}

/// Why the caches were left off.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum MemoryError {
    /// The DMA region was already taken.
    AlreadyTaken,
    /// The core peripherals were already taken.
    CorePeripherals,
    /// The linker did not align the region to its size.
    Misaligned(u32),
}

/// Takes the DMA region, makes it non-cacheable, then turns on the I-cache and the D-cache.
/// Call once, before any DMA starts.
pub fn init() -> Result<&'static mut DmaRegion, MemoryError> {
    let region = take().ok_or(MemoryError::AlreadyTaken)?;
    let base = core::ptr::from_mut(region) as u32;
    if base & ((1 << REGION_LOG2) - 1) != 0 {
        return Err(MemoryError::Misaligned(base));
    }
    let mut cp = cortex_m::Peripherals::take().ok_or(MemoryError::CorePeripherals)?;
    // RASR: XN, AP = full access, TEX = 1 C = 0 B = 0 (normal, non-cacheable), size 2^15,
    // enabled.
    let rasr = (1 << 28) | (0b011 << 24) | (0b001 << 19) | ((REGION_LOG2 - 1) << 1) | 1;
    cortex_m::asm::dmb();
    // SAFETY: the MPU is off while region 0 is written; the region covers only the DMA
    // buffers, and PRIVDEFENA keeps the default map for everything else.
    unsafe {
        cp.MPU.ctrl.write(0);
        cp.MPU.rnr.write(0);
        cp.MPU.rbar.write(base);
        cp.MPU.rasr.write(rasr);
        cp.MPU.ctrl.write((1 << 2) | 1);
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
    cp.SCB.enable_icache();
    cp.SCB.enable_dcache(&mut cp.CPUID);
    Ok(region)
}
