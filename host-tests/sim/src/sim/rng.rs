//! Counter-based randomness: an independent ChaCha8 stream for every (seed, frame, pixel,
//! purpose), so any sample can be drawn without drawing the ones before it.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// What a stream is used for; each purpose of each pixel gets its own stream.
#[derive(Clone, Copy, Debug)]
#[repr(u64)]
pub enum Purpose {
    /// Photon (star) shot noise.
    Photon = 0,
    /// Dark-charge shot noise.
    Dark = 1,
    /// Read noise.
    Read = 2,
    /// Fixed pattern: relative dark (DSNU).
    Dsnu = 3,
    /// Fixed pattern: flat field (PRNU).
    Prnu = 4,
    /// Fixed pattern: column bias.
    ColumnBias = 5,
    /// Fixed defects (hot and telegraph pixels), several draws in order.
    Defect = 6,
    /// Per-frame events (cosmic-ray hit, telegraph state), several draws in order.
    Event = 7,
}

/// Streams are numbered `pixel * PURPOSES + purpose`.
const PURPOSES: u64 = 8;

/// The stream of `purpose` at raw (`col`, `line`) of `frame` (frame `u32::MAX` is reserved
/// for the fixed patterns, which do not change from frame to frame).
pub fn stream(seed: u64, frame: u32, col: usize, line: usize, purpose: Purpose) -> ChaCha8Rng {
    let key = seed ^ (u64::from(frame).wrapping_add(1)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let mut r = ChaCha8Rng::seed_from_u64(key);
    let pixel = (line as u64) << 16 | col as u64;
    r.set_stream(pixel * PURPOSES + purpose as u64);
    r
}

/// The frame number used for fixed patterns.
pub const FIXED: u32 = u32::MAX;
