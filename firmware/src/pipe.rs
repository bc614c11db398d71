//! Writing into the link's byte pipes (embassy-sync [`Pipe`]s) without losing bytes at the
//! end of their ring.
//!
//! `Pipe::try_write` copies only into the free space that runs to the end of the pipe's
//! ring buffer: a write that would wrap past that end returns a short count although the
//! pipe has room for all of it. Read as "the pipe is full", that short count loses the
//! rest: a received chunk's tail (the command then fails its COBS or CRC check) or a
//! telemetry packet's tail (the ground loses that packet and the next one). [`write_fitting`]
//! writes again from the ring's start, so only a pipe that is really full drops bytes.
//!
//! This file depends on embassy-sync alone, so the host tests include it as it is built
//! (`host-tests/tests/link/link_pipe.rs`).
//!
//! Cost: one or two copies (the part up to the ring's end, then the part from its start),
//! each under the pipe's lock.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::pipe::Pipe;

/// Writes as much of `bytes` as `pipe` has room for, in order, across the end of its ring,
/// and returns how many: all of them unless the pipe filled. Never waits.
pub fn write_fitting<M: RawMutex, const N: usize>(pipe: &Pipe<M, N>, bytes: &[u8]) -> usize {
    let mut written = 0;
    while let Some(rest) = bytes.get(written..).filter(|rest| !rest.is_empty()) {
        match pipe.try_write(rest) {
            Ok(n) if n > 0 => written += n,
            _ => break,
        }
    }
    written
}
