//! Replays the committed fuzz corpus through the same target bodies libFuzzer runs: every
//! file of `corpus/<target>/` once (a crash libFuzzer found stays here as a regression).
//! Cost: the whole corpus in well under a second each in the dev profile (each test prints
//! its count and time with `--nocapture`).

use std::path::{Path, PathBuf};
use std::time::Instant;

/// The files of `corpus/<target>/`, sorted (README files excepted).
fn corpus(target: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("corpus entry").path())
        .filter(|p| p.is_file() && p.extension().is_none_or(|x| x != "md"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let b = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            (p, b)
        })
        .collect()
}

/// Runs `body` on every file of `target`'s corpus, naming the file on a failure; returns the
/// corpus.
fn replay(target: &str, body: fn(&[u8])) -> Vec<(PathBuf, Vec<u8>)> {
    let files = corpus(target);
    let t0 = Instant::now();
    for (path, bytes) in &files {
        let r = std::panic::catch_unwind(|| body(bytes));
        assert!(r.is_ok(), "{target}: {} fails", path.display());
    }
    let bytes: usize = files.iter().map(|f| f.1.len()).sum();
    println!(
        "{target}: {} inputs, {bytes} bytes, replayed in {:.3} s",
        files.len(),
        t0.elapsed().as_secs_f64()
    );
    files
}

/// The names of the corpus files that start with `prefix`.
fn named<'a>(files: &'a [(PathBuf, Vec<u8>)], prefix: &str) -> Vec<&'a [u8]> {
    files
        .iter()
        .filter(|(p, _)| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with(prefix))
        })
        .map(|f| f.1.as_slice())
        .collect()
}

#[test]
fn table_corpus() {
    let files = replay("table", startrack_fuzz::table);
    // The seeds the host's writer made still parse: the corpus reaches past the checks.
    let valid = named(&files, "valid-");
    assert!(valid.len() >= 4, "{} valid tables", valid.len());
    for b in valid {
        let t = startrack_core::table::CalibTable::parse(b);
        assert!(t.is_ok(), "a valid seed is rejected: {t:?}");
    }
    // The small sensors' tables reach the tracker: two frames, and the bright spot found.
    let small = named(&files, "valid-small-");
    assert!(small.len() >= 4);
    for b in small {
        let r = startrack_fuzz::table_run(b);
        assert_eq!(r.frames, 2, "{r:?}");
    }
}

/// Resealing a written table or catalog changes nothing; resealing one with a flipped bit
/// leaves no CRC error (whatever else the flip broke).
#[test]
fn reseal_restores_the_crcs() {
    use startrack_core::catalog::{Catalog, CatalogError};
    use startrack_core::table::{CalibTable, TableError};
    for (target, reseal) in [
        ("table", startrack_fuzz::reseal_table as fn(&mut [u8])),
        ("catalog", startrack_fuzz::reseal_catalog),
    ] {
        let files = corpus(target);
        for b in named(&files, "valid-") {
            let mut c = b.to_vec();
            reseal(&mut c);
            assert_eq!(c, b, "{target}: resealing a valid seed changed it");
            for at in [c.len() / 2, c.len() - 1] {
                let mut m = b.to_vec();
                m[at] ^= 0x01;
                let crc_error = if target == "table" {
                    |m: &[u8]| {
                        matches!(
                            CalibTable::parse(m),
                            Err(TableError::HeaderCrc | TableError::SectionCrc(_))
                        )
                    }
                } else {
                    |m: &[u8]| {
                        matches!(
                            Catalog::parse(m),
                            Err(CatalogError::HeaderCrc
                                | CatalogError::StarCrc
                                | CatalogError::PairCrc
                                | CatalogError::KVectorCrc)
                        )
                    }
                };
                assert!(
                    crc_error(&m),
                    "{target}: a flipped bit at {at} passes the CRCs"
                );
                reseal(&mut m);
                assert!(
                    !crc_error(&m),
                    "{target}: resealed, a flip at {at} still fails a CRC"
                );
            }
        }
    }
}

#[test]
fn catalog_corpus() {
    let files = replay("catalog", startrack_fuzz::catalog);
    let valid = named(&files, "valid-");
    assert!(!valid.is_empty());
    for b in valid {
        let c = startrack_core::catalog::Catalog::parse(b);
        assert!(c.is_ok(), "a valid seed is rejected: {c:?}");
    }
}

#[test]
fn link_receive_corpus() {
    let files = replay("link_receive", startrack_fuzz::link_receive);
    assert!(named(&files, "valid-").len() >= 4);
    check_link_seeds(&files, startrack_fuzz::link_receive_run);
}

#[test]
fn link_standby_corpus() {
    let files = replay("link_standby", startrack_fuzz::link_standby);
    assert!(named(&files, "valid-").len() >= 4);
    check_link_seeds(&files, startrack_fuzz::link_standby_run);
}

/// The valid seeds reach command execution: their packets are all read (no CRC or framing
/// error), and an upload seed (abort, begin, chunks, commit, report; the chain one also asks
/// for a defect commit, refused with no defects) leaves its table in force.
fn check_link_seeds(files: &[(PathBuf, Vec<u8>)], run: fn(&[u8]) -> startrack_fuzz::LinkRun) {
    for b in named(files, "valid-") {
        let (c, _) = run(b);
        assert!(c.packets >= 3, "{c:?}");
        assert_eq!((c.crc_errors, c.framing_errors), (0, 0), "{c:?}");
    }
    let uploads = named(files, "valid-upload-");
    assert!(uploads.len() >= 2);
    for b in uploads {
        let (c, active) = run(b);
        assert!(c.accepted >= 6 && c.rejected <= 1, "{c:?}");
        assert!(active.is_some_and(|t| t.len_bytes > 0), "{c:?}");
    }
}

/// A telecommand is framed with its length field and CRC-16 set, and only when its length
/// is one a telecommand may have.
#[test]
fn telecommand_frames_are_bounded() {
    assert!(startrack_fuzz::telecommand_frame(&[0; 12]).is_none());
    assert!(startrack_fuzz::telecommand_frame(&[0; 1101]).is_none());
    let f = startrack_fuzz::telecommand_frame(&[0x18; 13]).expect("13 bytes frame");
    assert_eq!(f.last(), Some(&0));
    assert!(!f[..f.len() - 1].contains(&0));
}
