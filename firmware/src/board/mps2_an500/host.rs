//! The PIL host's channel: two named pipes the host (`startrack pil`) creates in QEMU's
//! working directory and the firmware opens by semihosting, `pil-req` (firmware to host:
//! each frame's readout request, each frame's outcome, the boot) and `pil-lines` (host to
//! firmware: the lines each request reads, rendered by the host's simulated CCD47-20 as the
//! SIL renders them).
//!
//! Why semihosting and not a second UART: a semihosting call stops the emulated CPU until the
//! host has answered, and under `-icount` the virtual clock advances only with instructions,
//! so the time the host takes to render a frame is not emulated time. The lines arrive at the
//! instant the frame's exposure ends, whatever the host's speed, and every run of a scene
//! takes the same instructions; a UART socket would let the host's speed into the emulated
//! time (and move 2 MB a full frame through a one-byte FIFO).
//!
//! Records, little-endian (the host's reader is `host-tests/src/pil.rs`):
//!
//! | record | bytes |
//! |---|---|
//! | boot | `b'B'`, reset cause u8, start-up SysTick counts u32 |
//! | request | `b'Q'`, frame u32, exposure us u32, kind u8 (0 full frame, 1 windows), windows u16, per window x0, y0, width, height u16 |
//! | outcome | `b'R'`, frame u32, mode u8, stars u16, SysTick counts since boot u64, of them busy u64, stack used bytes u32, attitude u8 (0 none, 1 fix, 2 refused), solve mode u8, matched u8, used u8, q f64 x 4, 1-sigma cross-boresight and roll rad f64, false-match probability f64, the frame's integration start and end us u64 x 2 (on the firmware's clock; all ones: none), then per star x px, y px, flux e- f32, flags u32 |
//! | line (host) | line u16 (0xFFFF: the frame reads no more; 0xFFFD, 0xFFFC: hang or panic, the fault tests), last u8, 0 u8, ready us u32 (when the sequencer's program for this frame has taken the line's last sample, from the program's start at the end of the exposure; for 0xFFFF the program's end), then the line's samples u16 x 1072 |

use crate::lines::{FrameRequest, LINE_LEN, LineBuf};
use semihosting::fs::File;
use semihosting::io::{Read, Write};
use startrack_core::cycle::FrameOutcome;
use startrack_core::solver::SolveMode;
use startrack_core::tracker::{Integration, Mode, StarRecord};

/// The line header's "no more lines" value.
pub const END_OF_FRAME: u16 = 0xFFFF;
/// The line header that makes the firmware hang (its thread-mode loop spins: the watchdog's
/// test), sent by `startrack pil --hang-at-frame`.
pub const INJECT_HANG: u16 = 0xFFFD;
/// The line header that makes the firmware panic, sent by `startrack pil --panic-at-frame`.
pub const INJECT_PANIC: u16 = 0xFFFC;

/// The two pipes, open.
pub struct HostChannel {
    req: File,
    lines: File,
}

/// Why the channel failed (the host went away or never came).
#[derive(Clone, Copy, Debug, defmt::Format)]
pub struct ChannelError;

impl From<semihosting::io::Error> for ChannelError {
    fn from(_: semihosting::io::Error) -> Self {
        ChannelError
    }
}

/// A line header from the host.
pub struct LineHeader {
    /// Raw line index, or [`END_OF_FRAME`].
    pub line: u16,
    /// The frame's last line.
    pub last: bool,
    /// When the line is read out, us from the start of the frame's program (the frame
    /// transfer at the end of the exposure): its last sample's tick in the host's compile of
    /// the frame's readout plan.
    pub ready_us: u32,
}

impl HostChannel {
    /// Opens `pil-req` then `pil-lines` (the host opens them in the same order, so neither
    /// side waits for the other forever).
    pub fn open() -> Result<Self, ChannelError> {
        let req = File::options()
            .write(true)
            .truncate(true)
            .create(true)
            .open(c"pil-req")?;
        let lines = File::open(c"pil-lines")?;
        Ok(Self { req, lines })
    }

    /// The boot record.
    pub fn boot(&mut self, cause: u8, startup_counts: u32) -> Result<(), ChannelError> {
        let mut b = [0u8; 6];
        b[0] = b'B';
        b[1] = cause;
        b[2..6].copy_from_slice(&startup_counts.to_le_bytes());
        self.req.write_all(&b)?;
        Ok(())
    }

    /// A frame's request.
    pub fn request(&mut self, req: &FrameRequest) -> Result<(), ChannelError> {
        let mut b = [0u8; 12];
        b[0] = b'Q';
        b[1..5].copy_from_slice(&req.frame.to_le_bytes());
        b[5..9].copy_from_slice(&req.exposure_us.to_le_bytes());
        // A truncated request is read as a full frame (as the sequencer compiles it).
        let windows = req.windows.as_ref().filter(|_| !req.truncated);
        b[9] = u8::from(windows.is_some());
        let n = windows.map_or(0, |w| w.len()) as u16;
        b[10..12].copy_from_slice(&n.to_le_bytes());
        self.req.write_all(&b)?;
        for r in windows.into_iter().flatten() {
            let mut w = [0u8; 8];
            for (i, v) in [r.x0, r.y0, r.width, r.height].into_iter().enumerate() {
                w[2 * i..2 * i + 2].copy_from_slice(&v.to_le_bytes());
            }
            self.req.write_all(&w)?;
        }
        Ok(())
    }

    /// The next line's header.
    pub fn line_header(&mut self) -> Result<LineHeader, ChannelError> {
        let mut h = [0u8; 8];
        self.lines.read_exact(&mut h)?;
        Ok(LineHeader {
            line: u16::from_le_bytes([h[0], h[1]]),
            last: h[2] != 0,
            ready_us: u32::from_le_bytes([h[4], h[5], h[6], h[7]]),
        })
    }

    /// The line's samples, into `buf`.
    pub fn line_samples(&mut self, buf: &mut LineBuf) -> Result<(), ChannelError> {
        // SAFETY: a `[u16; LINE_LEN]` is `2 * LINE_LEN` initialised bytes, any of whose bit
        // patterns is a valid `u16`, and `u8` needs no alignment; the view is dropped before
        // `buf` is used again. The M7 is little-endian, as the host writes.
        let bytes =
            unsafe { core::slice::from_raw_parts_mut(buf.as_mut_ptr().cast::<u8>(), 2 * LINE_LEN) };
        self.lines.read_exact(bytes)?;
        Ok(())
    }

    /// A frame's outcome with its stars.
    pub fn outcome(
        &mut self,
        outcome: &FrameOutcome,
        stars: &[StarRecord],
        counts: u64,
        busy_counts: u64,
        stack_used_b: u32,
        integration: Option<Integration>,
    ) -> Result<(), ChannelError> {
        let s = &outcome.summary;
        let mut b = [0u8; 104];
        b[0] = b'R';
        b[1..5].copy_from_slice(&s.frame.to_le_bytes());
        b[5] = match s.mode {
            Mode::Standby => 0,
            Mode::Acquisition => 1,
            Mode::Tracking => 2,
        };
        b[6..8].copy_from_slice(&(stars.len() as u16).to_le_bytes());
        b[8..16].copy_from_slice(&counts.to_le_bytes());
        b[16..24].copy_from_slice(&busy_counts.to_le_bytes());
        b[24..28].copy_from_slice(&stack_used_b.to_le_bytes());
        match &outcome.attitude {
            None => b[28] = 0,
            Some(Err(_)) => b[28] = 2,
            Some(Ok(fix)) => {
                b[28] = 1;
                b[29] = match fix.mode {
                    SolveMode::Tracking => 0,
                    SolveMode::LostInSpace => 1,
                };
                b[30] = fix.matched;
                b[31] = fix.used;
                let a = &fix.attitude;
                let extra = [
                    a.boresight_sigma_rad(),
                    a.roll_sigma_rad(),
                    fix.false_probability,
                ];
                for (i, v) in a.q.0.iter().chain(extra.iter()).enumerate() {
                    b[32 + 8 * i..40 + 8 * i].copy_from_slice(&v.to_le_bytes());
                }
            }
        }
        // The frame's integration on the firmware's clock (all ones: none), so that the host's
        // SIL can take its frames at the same instants.
        let (start_us, end_us) =
            integration.map_or((u64::MAX, u64::MAX), |i| (i.start_us, i.end_us));
        b[88..96].copy_from_slice(&start_us.to_le_bytes());
        b[96..104].copy_from_slice(&end_us.to_le_bytes());
        self.req.write_all(&b)?;
        for st in stars {
            let mut w = [0u8; 16];
            w[0..4].copy_from_slice(&st.x_px.to_le_bytes());
            w[4..8].copy_from_slice(&st.y_px.to_le_bytes());
            w[8..12].copy_from_slice(&st.flux_e.to_le_bytes());
            w[12..16].copy_from_slice(&st.flags.bits().to_le_bytes());
            self.req.write_all(&w)?;
        }
        Ok(())
    }
}
