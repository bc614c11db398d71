//! The firmware's writes into its link pipes (`firmware/src/pipe.rs`, included here as the
//! firmware builds it): a write that wraps around the end of an embassy-sync `Pipe`'s ring
//! goes in whole, and only a full pipe refuses bytes. `Pipe::try_write` alone stops at the
//! ring's end; its short count read as "full" drops the received bytes' tail and the
//! telemetry's, and table uploads to the emulated tracker stall near their end
//! (docs/hardware.md, "Processor in the loop").

#[path = "../../../firmware/src/pipe.rs"]
mod pipe;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embassy_sync::pipe::Pipe;
use pipe::write_fitting;
use proptest::prelude::*;
use std::collections::VecDeque;

const CAP: usize = 64;

/// Everything the pipe holds, in order.
fn drain(p: &Pipe<NoopRawMutex, CAP>) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; CAP];
    while let Ok(n) = p.try_read(&mut buf) {
        out.extend_from_slice(&buf[..n]);
    }
    out
}

#[test]
fn a_write_across_the_rings_end_goes_in_whole() {
    let p = Pipe::<NoopRawMutex, CAP>::new();
    // Move the ring's start and end to 40 of 64: 24 bytes run to the ring's end.
    assert_eq!(write_fitting(&p, &[0xAA; 40]), 40);
    assert_eq!(drain(&p), vec![0xAA; 40]);
    let bytes: Vec<u8> = (0..50).collect();
    // The pipe's own write stops at the ring's end although it has room for all 50: the
    // short count the firmware took for a full pipe.
    let q = Pipe::<NoopRawMutex, CAP>::new();
    assert_eq!(write_fitting(&q, &[0; 40]), 40);
    drain(&q);
    assert_eq!(q.try_write(&bytes), Ok(24));
    // `write_fitting` writes on from the ring's start.
    assert_eq!(write_fitting(&p, &bytes), 50);
    assert_eq!(drain(&p), bytes);
}

#[test]
fn only_a_full_pipe_refuses_bytes() {
    let p = Pipe::<NoopRawMutex, CAP>::new();
    assert_eq!(write_fitting(&p, &[1; 60]), 60);
    assert_eq!(write_fitting(&p, &[2; 10]), 4);
    assert_eq!(write_fitting(&p, &[3; 1]), 0);
    assert_eq!(write_fitting(&p, &[]), 0);
}

proptest! {
    /// Any sequence of writes and reads: every write takes exactly what the pipe has room
    /// for, and the bytes read are the bytes taken, in order.
    #[test]
    fn writes_and_reads_keep_every_byte_that_fits(
        ops in prop::collection::vec((any::<bool>(), 0usize..100), 1..60)
    ) {
        let p = Pipe::<NoopRawMutex, CAP>::new();
        let mut model = VecDeque::new();
        let mut next = 0u8;
        for (write, n) in ops {
            if write {
                let bytes: Vec<u8> = (0..n).map(|i| next.wrapping_add(i as u8)).collect();
                let taken = write_fitting(&p, &bytes);
                prop_assert_eq!(taken, n.min(CAP - model.len()));
                model.extend(&bytes[..taken]);
                next = next.wrapping_add(taken as u8);
            } else {
                let mut buf = vec![0u8; n];
                let mut got = Vec::new();
                while got.len() < n {
                    match p.try_read(&mut buf[got.len()..]) {
                        Ok(k) => got.extend_from_slice(&buf[got.len()..got.len() + k]),
                        Err(_) => break,
                    }
                }
                let want: Vec<u8> = model.drain(..n.min(model.len())).collect();
                prop_assert_eq!(got, want);
            }
        }
        prop_assert_eq!(drain(&p), model.into_iter().collect::<Vec<_>>());
    }
}
