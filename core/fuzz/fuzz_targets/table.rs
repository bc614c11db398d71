//! libFuzzer driver of [`startrack_fuzz::table`] (the body `cargo test` replays on the corpus).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| startrack_fuzz::table(data));
