//! libFuzzer driver of [`startrack_fuzz::link_standby`] (the body `cargo test` replays on the corpus).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| startrack_fuzz::link_standby(data));
