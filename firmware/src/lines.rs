//! The raw line buffers and their hand-off from the board's line path to processing, and
//! each frame's request to it ([`REQUESTS`]).
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
//! checker guarantees that no two tasks hold a buffer at once. The readout is the board's
//! (on the STM32H743 the ADC words arrive by SPI DMA in a separate sample buffer and are put
//! in their raw columns, `LineJob::unpack`: a line read through windows fills only the
//! columns read), and so is the buffers' placement (on the STM32H743 in its DMA region,
//! non-cacheable, `board::stm32h743::memory`).

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::signal::Signal;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::MAX_WINDOWS;
use startrack_core::tracker::Integration;
use startrack_core::window::Rect;

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
    /// When the frame's image was integrated, us of the board's clock (embassy-time): the
    /// line path's frame transfers (`None`: not known).
    pub integration: Option<Integration>,
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

/// One frame's request as the board's line path gets it (on the STM32H743 the sequencer):
/// the tracker's frame number, its exposure and its windows copied (no borrow crosses
/// tasks). Cost: ~530 bytes.
#[derive(Clone, Debug)]
pub struct FrameRequest {
    /// The tracker's frame number (tags the frame's lines).
    pub frame: u32,
    /// The exposure the tracker's configuration sets, us.
    pub exposure_us: u32,
    /// `None`: full frame; else the windows.
    pub windows: Option<heapless::Vec<Rect, MAX_WINDOWS>>,
    /// The request had more windows than a message holds (compiled as a full frame).
    pub truncated: bool,
}

impl FrameRequest {
    /// Copies `request` for frame `frame` with `exposure_us`.
    pub fn new(frame: u32, request: &ReadoutRequest<'_>, exposure_us: u32) -> Self {
        let (windows, truncated) = match request {
            ReadoutRequest::FullFrame => (None, false),
            ReadoutRequest::Windows(rects) => match heapless::Vec::from_slice(rects) {
                Ok(v) => (Some(v), false),
                Err(_) => (None, true),
            },
        };
        Self {
            frame,
            exposure_us,
            windows,
            truncated,
        }
    }
}

/// The latest request (a newer one replaces one not yet compiled).
pub static REQUESTS: Signal<CriticalSectionRawMutex, FrameRequest> = Signal::new();
