//! The flight firmware on QEMU's `mps2-an500` (`startrack pil --port P`) over its link: a
//! table upload and a reset, and an upload whose power is cut by killing QEMU. The firmware
//! writes every erase and program of its flash model through to the bank image in `--dir`,
//! and `startrack pil --keep-bank` powers on with what the cut left. After a cut while
//! `startrack gse upload-table` runs, the tracker boots with the old table or the new one in
//! force (`gse status`), never none and never another; after an upload that ends, a reboot
//! has the new one. Needs `qemu-system-arm` and `cargo pil-fw`; about a minute of wall
//! clock, so ignored in the default run (CI runs the upload and reset).
//!
//! ```sh
//! cargo pil-fw && cargo test -p startrack-host --test link pil_ -- --ignored
//! ```

use crate::served::{BIN, gse, id, in_force, upload};
use startrack_homes::flash_home::flash_table;
use startrack_homes::sil::SilConfig;
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// A running `startrack pil --port P --dir D` (a random scene), its link on a free port.
struct Pil {
    child: Child,
    dir: PathBuf,
    port: u16,
    /// Its standard output, line by line.
    lines: Receiver<String>,
}

impl Pil {
    /// Powers on (with the bank a previous run left in `dir` when `keep_bank`) and waits for
    /// the first frame.
    fn start(dir: &Path, keep_bank: bool) -> Self {
        let port = {
            let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
            l.local_addr().expect("addr").port()
        };
        let mut cmd = Command::new(BIN);
        cmd.args(["pil", "--frames", "1000", "--no-build"])
            .args(["--timeout-s", "300", "--port", &port.to_string(), "--dir"])
            .arg(dir)
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        if keep_bank {
            cmd.arg("--keep-bank");
        }
        let mut child = cmd.spawn().expect("spawn pil");
        let out = BufReader::new(child.stdout.take().expect("stdout"));
        let (tx, lines) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in out.lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let mut pil = Self {
            child,
            dir: dir.to_path_buf(),
            port,
            lines,
        };
        pil.wait_for("frame 0:");
        pil
    }

    /// Waits (at most 2 minutes) for an output line starting with `prefix`; returns it.
    fn wait_for(&mut self, prefix: &str) -> String {
        let end = Instant::now() + Duration::from_secs(120);
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) if line.starts_with(prefix) => return line,
                Ok(_) => {}
                Err(RecvTimeoutError::Timeout) => panic!("pil: no line `{prefix}` in time"),
                Err(RecvTimeoutError::Disconnected) => panic!("pil ended before `{prefix}`"),
            }
        }
    }

    /// Cuts the emulated board's power: kills QEMU (its pid from `qemu.pid`), then the host.
    fn cut(mut self) {
        let pid = std::fs::read_to_string(self.dir.join("qemu.pid")).expect("qemu.pid");
        let status = Command::new("kill")
            .args(["-KILL", pid.trim()])
            .status()
            .expect("kill");
        assert!(status.success(), "kill QEMU {pid}");
        // Killed: `drop` must not signal that pid again.
        let _ = std::fs::remove_file(self.dir.join("qemu.pid"));
        let _ = self.child.wait();
    }
}

impl Drop for Pil {
    fn drop(&mut self) {
        if let Ok(pid) = std::fs::read_to_string(self.dir.join("qemu.pid")) {
            let _ = Command::new("kill").args(["-KILL", pid.trim()]).status();
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The tables and QEMU's working folder: `old` (the SIL's, seed 1, that `startrack pil`
/// puts in a fresh bank) and two others (true calibrations of the same sensor, 16x16 tiles,
/// seeds 1 and 2) written as `a.tbl` and `b.tbl`.
struct Bench {
    dir: tempfile::TempDir,
    old: Vec<u8>,
    a: Vec<u8>,
    b: Vec<u8>,
}

impl Bench {
    fn new() -> Self {
        let dir = tempfile::tempdir().expect("tmp");
        let sc = SilConfig::default();
        let params = SensorParams {
            seed: sc.seed,
            ..SensorParams::default()
        };
        let old = flash_table(&sc, &params).expect("old table");
        let mut others = (1..=2).map(|seed| {
            let p = SensorParams {
                seed,
                ..params.clone()
            };
            Simulator::new(p, Vec::new())
                .truth_table_tiled(TruthSections::ALL, 4)
                .expect("table")
        });
        let (a, b) = (others.next().expect("a"), others.next().expect("b"));
        assert!(id(&old) != id(&a) && id(&a) != id(&b) && id(&old) != id(&b));
        for (name, t) in [("a.tbl", &a), ("b.tbl", &b)] {
            std::fs::write(dir.path().join(name), t).expect("write table");
        }
        Self { dir, old, a, b }
    }

    /// A file in the folder.
    fn file(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// Powers the PIL on in the folder's `run`: a fresh bank (the old table in force, checked)
    /// or, with `keep_bank`, the bank the last run left.
    fn power_on(&self, keep_bank: bool) -> Pil {
        let pil = Pil::start(&self.file("run"), keep_bank);
        if !keep_bank {
            assert_eq!(in_force(pil.port), Some(id(&self.old)), "a fresh bank");
        }
        pil
    }

    /// Starts the upload of `name` and cuts the power as soon as the bank image changed (the
    /// slot's first erase went through); the upload must not have ended.
    fn cut_during_upload(&self, pil: Pil, name: &str) {
        let bank = self.file("run").join("pil-bank.bin");
        let before = std::fs::read(&bank).expect("bank");
        let upload = {
            let (port, a) = (pil.port, self.file(name));
            std::thread::spawn(move || gse(port, &["upload-table", a.to_str().expect("utf-8")]))
        };
        let start = Instant::now();
        while std::fs::read(&bank).expect("bank") == before {
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "the upload never wrote the bank"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
        pil.cut();
        let (code, _, _) = upload.join().expect("gse thread");
        assert_ne!(code, 0, "the upload ended before the cut");
    }
}

/// CI's PIL run over the link: a few frames, one table upload to its end, one reset. The
/// firmware reboots with the software cause and the new table in force, and tracks again.
#[test]
#[ignore = "QEMU: cargo pil-fw, then cargo test -p startrack-host --test link pil_upload_then_reset -- --ignored"]
fn pil_upload_then_reset() {
    let bench = Bench::new();
    let mut pil = bench.power_on(false);
    upload(pil.port, &bench.file("a.tbl"), &bench.a);
    let (code, out, err) = gse(pil.port, &["reset"]);
    assert_eq!(code, 0, "gse reset: {out}{err}");
    pil.wait_for("boot: reset cause 3,");
    pil.wait_for("frame 0: acquisition");
    pil.wait_for("frame 1: tracking");
    assert_eq!(in_force(pil.port), Some(id(&bench.a)), "after the reset");
}

#[test]
#[ignore = "QEMU: cargo pil-fw, then cargo test -p startrack-host --test link pil_power_cut -- --ignored"]
fn pil_power_cut_during_an_upload_leaves_the_old_or_the_new_table() {
    let bench = Bench::new();
    // A fresh bank (the old table), an upload that ends, a power cycle: `a` is kept.
    let pil = bench.power_on(false);
    upload(pil.port, &bench.file("a.tbl"), &bench.a);
    pil.cut();
    let pil = bench.power_on(true);
    assert_eq!(
        in_force(pil.port),
        Some(id(&bench.a)),
        "the uploaded table over a power cycle"
    );

    // The upload of `b`, cut: `a` or `b` in force after the power-on, never none or another.
    bench.cut_during_upload(pil, "b.tbl");
    let pil = bench.power_on(true);
    let after = in_force(pil.port);
    assert!(
        after == Some(id(&bench.a)) || after == Some(id(&bench.b)),
        "after the cut: {after:?}"
    );
    // And the upload again, to its end.
    upload(pil.port, &bench.file("b.tbl"), &bench.b);
}

/// The same cut with the fresh bank's large 8x8-tiled table in force, then the upload again
/// to its end.
#[test]
#[ignore = "QEMU: cargo pil-fw, then cargo test -p startrack-host --test link pil_power_cut -- --ignored"]
fn pil_power_cut_with_the_fresh_table_then_an_upload() {
    let bench = Bench::new();
    let pil = bench.power_on(false);
    bench.cut_during_upload(pil, "a.tbl");
    let pil = bench.power_on(true);
    let after = in_force(pil.port);
    assert!(
        after == Some(id(&bench.old)) || after == Some(id(&bench.a)),
        "after the cut: {after:?}"
    );
    upload(pil.port, &bench.file("a.tbl"), &bench.a);
}
