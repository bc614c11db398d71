//! The flight application's safe states on QEMU's `mps2-an500` (`startrack pil`,
//! docs/hardware.md "Processor in the loop"): a panic and a hang at frame 1 each end in a
//! reset whose cause the next boot reports (5 other, 2 watchdog), and the tracker acquires
//! again from frame 0. They need `qemu-system-arm` and the image `cargo pil-fw` builds, and
//! take about 10 s of wall clock each, so they are ignored in the default run:
//!
//! ```sh
//! cargo pil-fw && cargo test -p startrack-host --test cli pil_faults -- --ignored
//! ```

use crate::common_cli::startrack;

/// Runs `startrack pil --frames 3 --sky` with `fault` at frame 1: the boot lines' causes and
/// the frame lines.
fn run_with(fault: &str) -> (Vec<String>, Vec<String>) {
    let dir = tempfile::tempdir().unwrap();
    let dir_arg = dir.path().to_str().unwrap();
    let (ok, out, err) = startrack(&[
        "pil",
        "--frames",
        "3",
        "--sky",
        "--no-build",
        fault,
        "1",
        "--timeout-s",
        "300",
        "--dir",
        dir_arg,
    ]);
    assert!(ok, "startrack pil {fault} 1 failed:\n{out}\n{err}");
    let boots = out
        .lines()
        .filter_map(|l| l.strip_prefix("boot: reset cause "))
        .map(|l| l.split(',').next().unwrap_or("").to_string())
        .collect();
    let frames = out
        .lines()
        .filter(|l| l.starts_with("frame "))
        .map(str::to_string)
        .collect();
    (boots, frames)
}

/// The frames after the reset: frame 0 acquires (lost in space), frame 1 tracks.
fn acquires_again(frames: &[String]) {
    assert_eq!(frames.len(), 3, "{frames:#?}");
    assert!(
        frames[0].starts_with("frame 0: acquisition"),
        "{}",
        frames[0]
    );
    assert!(
        frames[1].starts_with("frame 0: acquisition"),
        "{}",
        frames[1]
    );
    assert!(
        frames[1].contains("attitude lost in space"),
        "{}",
        frames[1]
    );
    assert!(frames[2].starts_with("frame 1: tracking"), "{}", frames[2]);
}

#[test]
#[ignore = "QEMU: cargo pil-fw, then cargo test -p startrack-host --test cli pil_faults -- --ignored"]
fn pil_faults_a_hang_ends_in_the_watchdogs_reset() {
    let (boots, frames) = run_with("--hang-at-frame");
    assert_eq!(boots, ["1", "2"], "power-on, then the watchdog");
    acquires_again(&frames);
}

#[test]
#[ignore = "QEMU: cargo pil-fw, then cargo test -p startrack-host --test cli pil_faults -- --ignored"]
fn pil_faults_a_panic_ends_in_a_reset() {
    let (boots, frames) = run_with("--panic-at-frame");
    assert_eq!(
        boots,
        ["1", "5"],
        "power-on, then the panic handler's reset"
    );
    acquires_again(&frames);
}
