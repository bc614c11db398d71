//! The ground tool against a tracker served on TCP (`startrack sil --port`, `startrack pil
//! --port`), as the tests that run the real programs use it: `gse` itself, the table in
//! force, a table's identity, an upload to its end.

use startrack_sim::flash_model::CRC32;
use std::path::Path;
use std::process::Command;

/// The `startrack` binary of this package.
pub const BIN: &str = env!("CARGO_BIN_EXE_startrack");

/// Runs `startrack gse --port PORT --timeout-s 30 ARGS`: its exit code, standard output and
/// standard error.
pub fn gse(port: u16, args: &[&str]) -> (i32, String, String) {
    let out = Command::new(BIN)
        .args(["gse", "--port", &port.to_string(), "--timeout-s", "30"])
        .args(args)
        .output()
        .expect("spawn gse");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// (length, CRC-32) of the calibration table in force, from `gse status`; `None` without one.
pub fn in_force(port: u16) -> Option<(u64, String)> {
    let (code, out, err) = gse(port, &["status"]);
    assert_eq!(code, 0, "gse status failed: {out}{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("status JSON");
    let t = v.get("table").filter(|t| !t.is_null())?;
    Some((
        t["len_bytes"].as_u64().expect("len"),
        t["crc32"].as_str().expect("crc").to_string(),
    ))
}

/// A table's (length, CRC-32), as [`in_force`] gives it.
pub fn id(table: &[u8]) -> (u64, String) {
    (table.len() as u64, format!("{:08x}", CRC32.checksum(table)))
}

/// Uploads `file` (whose bytes are `table`) with `gse upload-table` to its end; `table` is
/// then in force.
pub fn upload(port: u16, file: &Path, table: &[u8]) {
    let path = file.to_str().expect("utf-8 path");
    let (code, out, err) = gse(port, &["upload-table", path]);
    assert_eq!(code, 0, "upload of {path}: {out}{err}");
    assert_eq!(
        in_force(port),
        Some(id(table)),
        "after the upload of {path}"
    );
}
