//! The SIL's flash table store through the real programs: `startrack sil --port P --flash
//! FILE --power-cut-at-write N` while `startrack gse upload-table` sends a new table; the SIL
//! exits with its power-cut code at flash step N, and a restart with the same FILE (a reboot)
//! has the old table or the new one in force (`gse status`), never none and never another;
//! a later upload then succeeds. N covers the first and last erase, the first data unit, one
//! in the middle, the last data unit and the header write.

use crate::served::{BIN, gse, id, in_force, upload};
use startrack_core::link::TableUpload;
use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_homes::flash_home::{FlashHome, flash_table};
use startrack_homes::sil::SilConfig;
use startrack_host::cli::sil::POWER_CUT_EXIT_CODE;
use startrack_sim::flash_model::CRC32;
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running `startrack sil --port 0 --flash FILE [...]` and its port.
struct Sil {
    child: Child,
    port: u16,
}

impl Sil {
    fn start(flash: &Path, cut: Option<u64>) -> Self {
        let mut cmd = Command::new(BIN);
        cmd.args(["sil", "--port", "0", "--stars", "4", "--flash"])
            .arg(flash)
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        if let Some(n) = cut {
            cmd.args(["--power-cut-at-write", &n.to_string()]);
        }
        let mut child = cmd.spawn().expect("spawn sil");
        let mut lines = BufReader::new(child.stderr.take().expect("stderr")).lines();
        let port = loop {
            let line = lines.next().expect("sil ended early").expect("stderr");
            if let Some(p) = line.strip_prefix("startrack sil: link on 127.0.0.1:") {
                break p.trim().parse().expect("port");
            }
        };
        // Keep draining its standard error so it never blocks on it.
        std::thread::spawn(move || for _ in lines {});
        Self { child, port }
    }

    /// Waits for the exit (at most `limit`); `None` if it is still running.
    fn wait_exit(&mut self, limit: Duration) -> Option<i32> {
        let end = Instant::now() + limit;
        while Instant::now() < end {
            if let Some(s) = self.child.try_wait().expect("wait") {
                return Some(s.code().unwrap_or(-1));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

impl Drop for Sil {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn power_cut_during_an_upload_leaves_the_old_or_the_new_table() {
    let dir = tempfile::tempdir().expect("tmp");
    let sc = SilConfig {
        stars: 4,
        ..SilConfig::default()
    };
    let params = SensorParams {
        seed: sc.seed,
        ..SensorParams::default()
    };
    let old = flash_table(&sc, &params).expect("old table");
    let new = Simulator::new(params.clone(), Vec::new())
        .truth_table_tiled(TruthSections::ALL, 4)
        .expect("new table");
    assert_ne!(id(&old), id(&new));
    let new_path = dir.path().join("new.tbl");
    std::fs::write(&new_path, &new).expect("write table");
    let new_arg = new_path.to_str().expect("utf-8 path");

    // The upload's flash steps, counted on the same store in this process.
    let steps = {
        let mut home =
            FlashHome::open(&dir.path().join("count.flash"), params.geometry, Some(&old))
                .expect("open");
        let before = home.steps();
        home.begin(
            TABLE_KIND_CALIBRATION,
            new.len() as u32,
            CRC32.checksum(&new),
        )
        .expect("begin");
        home.service().expect("erase");
        home.chunk(0, &new).expect("chunk");
        home.commit().expect("commit");
        home.steps() - before
    };
    let sectors = 2; // a 256 KB calibration slot
    assert_eq!(steps, sectors + new.len().div_ceil(32) as u64 + 1);

    let mut outcomes = Vec::new();
    for n in [1, sectors, sectors + 1, steps / 2, steps - 1, steps] {
        let flash = dir.path().join(format!("cut{n}.flash"));
        {
            let mut sil = Sil::start(&flash, Some(n));
            assert_eq!(in_force(sil.port), Some(id(&old)), "bring-up table");
            let (code, _, _) = gse(sil.port, &["upload-table", new_arg]);
            assert_ne!(code, 0, "cut at {n}: the upload cannot have completed");
            assert_eq!(
                sil.wait_exit(Duration::from_secs(20)),
                Some(i32::from(POWER_CUT_EXIT_CODE)),
                "cut at {n}: the SIL did not stop with its power-cut code"
            );
        }
        // Reboot: same file.
        let sil = Sil::start(&flash, None);
        let after = in_force(sil.port).expect("a table in force after the cut");
        assert!(
            after == id(&old) || after == id(&new),
            "cut at {n}: neither table in force: {after:?}"
        );
        upload(sil.port, &new_path, &new);
        outcomes.push((n, after == id(&new)));
    }
    // Only the header write puts the new table in force; a cut before it keeps the old one.
    for &(n, took_new) in &outcomes {
        if n < steps {
            assert!(
                !took_new,
                "cut at {n} before the header put the new table in force"
            );
        }
    }
}
