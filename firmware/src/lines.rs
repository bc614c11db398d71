//! The raw line buffers and their hand-off from readout to processing.
//!
//! Two line buffers (ping-pong) circulate between the readout task and the processing task
//! by ownership: a buffer is a `&'static mut LineBuf` that travels through two channels,
//!
//! ```text
//!   FREE ──> readout (unpacks the line's ADC words into it) ──> FILLED
//!        ──> process (reads it) ──> FREE
//! ```
//!
//! so while processing works on one line the readout fills the other, and the borrow
//! checker guarantees that no two tasks hold a buffer at once. The ADC words themselves
//! arrive by SPI DMA in a separate sample buffer and are put in their raw columns by the
//! readout (`LineJob::unpack`: a line read through windows fills only the columns read).
//!
//! Placement: the buffers are part of [`crate::memory::DmaRegion`], in `.bss` (AXI SRAM at
//! 0x2400_0000, which every DMA master reaches; the DTCM would not be) and made
//! non-cacheable by the MPU, so with the D-cache on the CPU still sees what the DMA wrote
//! without cache maintenance.

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use startrack_core::geometry::ReadoutGeometry;

/// The readout mode of this firmware: the CCD47-20 read through both outputs.
pub const GEOMETRY: ReadoutGeometry = ReadoutGeometry::CCD47_20_DUAL;

/// Samples per raw line (1072 for the CCD47-20).
pub const LINE_LEN: usize = GEOMETRY.line_len();

/// Number of line buffers: two, one being filled while the other is processed.
pub const BUFFERS: usize = 2;

/// One raw line: 16-bit ADC samples in physical column order.
pub type LineBuf = [u16; LINE_LEN];

/// A filled line on its way to processing.
pub struct RawLine {
    /// The tracker's frame number of the request the line was read for (wraps).
    pub frame: u32,
    /// Raw line index within the frame, 0-based (`0..GEOMETRY.lines`).
    pub line: u16,
    /// The frame's last digitised line (a windowed frame ends before `GEOMETRY.lines`).
    pub last: bool,
    /// The samples; the buffer goes back to [`FREE`] once processed.
    pub samples: &'static mut LineBuf,
}

/// Buffers ready to be filled by the readout DMA.
pub static FREE: Channel<CriticalSectionRawMutex, &'static mut LineBuf, BUFFERS> = Channel::new();

/// Filled lines waiting for processing, oldest first.
pub static FILLED: Channel<CriticalSectionRawMutex, RawLine, BUFFERS> = Channel::new();

/// Why the buffer pool could not be set up.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum PoolError {
    /// The free channel refused a buffer (cannot happen: it holds [`BUFFERS`]).
    FreeChannelFull,
}

/// Puts every line buffer (from the DMA region) in [`FREE`]. Call once, before the readout
/// task starts.
pub fn init(bufs: &'static mut [LineBuf; BUFFERS]) -> Result<(), PoolError> {
    for buf in bufs.iter_mut() {
        FREE.try_send(buf).map_err(|_| PoolError::FreeChannelFull)?;
    }
    Ok(())
}
