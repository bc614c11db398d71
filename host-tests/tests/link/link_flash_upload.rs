//! The link's table-upload port over the flash store (`FlashTables`): every refusal the link
//! reports comes from the store's typed error, the erase is the owner's step (chunks are
//! refused `Busy` until it ran), commit runs the calibration table's own checks, and the
//! table in force the link reports is the store's.

use startrack_core::link::protocol::TABLE_KIND_CALIBRATION;
use startrack_core::link::{FlashTables, TableUpload, UploadRefusal, refusal_of};
use startrack_core::store::{FlashStore, H743_BANK2, StoreError, TableKind};
use startrack_core::table::CalibTable;
use startrack_homes::sil::SilConfig;
use startrack_sim::flash_model::CRC32;
use startrack_sim::flash_model::{BANK_B, MockFlash};
use startrack_sim::sim::SensorParams;

/// The calibration check the SIL uses: the core parses the table where it lies.
fn parses(f: &mut MockFlash, at: u32, len: u32) -> bool {
    f.bytes()
        .get(at as usize..(at + len) as usize)
        .is_some_and(|b| CalibTable::parse(b).is_ok())
}

/// The SIL's table in its flash form (maps in tiles, to fit a slot).
fn table() -> Vec<u8> {
    let sc = SilConfig::default();
    let params = SensorParams {
        seed: sc.seed,
        ..SensorParams::default()
    };
    startrack_homes::flash_home::flash_table(&sc, &params).expect("truth table")
}

fn store() -> FlashStore<MockFlash> {
    FlashStore::mount(MockFlash::new(BANK_B, 3), H743_BANK2)
        .map_err(|e| e.error)
        .expect("mount")
}

#[test]
fn upload_through_the_port_erases_between_begin_and_chunks() {
    let t = table();
    let len = t.len() as u32;
    let crc = CRC32.checksum(&t);
    let mut s = store();
    let mut up = FlashTables::new(&mut s, parses);
    assert_eq!(up.begin(9, len, crc), Err(UploadRefusal::UnknownKind));
    assert_eq!(up.chunk(0, &t[..64]), Err(UploadRefusal::NotStarted));
    assert_eq!(up.commit(), Err(UploadRefusal::NotStarted));
    assert_eq!(
        up.begin(TABLE_KIND_CALIBRATION, 0, crc),
        Err(UploadRefusal::Invalid)
    );
    assert_eq!(
        up.begin(TABLE_KIND_CALIBRATION, u32::MAX, crc),
        Err(UploadRefusal::TooLong)
    );
    up.begin(TABLE_KIND_CALIBRATION, len, crc).expect("begin");
    assert_eq!(
        up.begin(TABLE_KIND_CALIBRATION, len, crc),
        Err(UploadRefusal::Busy)
    );
    // Not erased yet: the link's chunks and commit wait for the owner's erase step.
    assert_eq!(up.chunk(0, &t[..64]), Err(UploadRefusal::Busy));
    assert_eq!(up.commit(), Err(UploadRefusal::Busy));
    assert!(up.service().is_some_and(|r| r.is_ok()));
    up.service_all().expect("erase");
    assert!(up.service().is_none(), "nothing left to erase");
    assert_eq!(
        up.chunk(64, &t[..64]),
        Err(UploadRefusal::OutOfOrder { expected: 0 })
    );
    for (i, c) in t.chunks(1000).enumerate() {
        up.chunk((i * 1000) as u32, c).expect("chunk");
    }
    assert_eq!(up.chunk(len, &[0]), Err(UploadRefusal::TooLong));
    let info = up.commit().expect("commit");
    assert_eq!((info.kind, info.len_bytes, info.crc32), (1, len, crc));
    assert_eq!(up.active(TABLE_KIND_CALIBRATION), Some(info));
    assert_eq!(up.active(2), None);
    assert_eq!(up.active(77), None);
    up.abort(); // nothing under way: ignored
    assert_eq!(up.active(TABLE_KIND_CALIBRATION), Some(info));
}

#[test]
fn commit_refuses_what_the_table_checks_or_crc_refuse() {
    let t = table();
    let len = t.len() as u32;
    let mut s = store();
    let mut up = FlashTables::new(&mut s, parses);
    // Incomplete keeps the upload; a wrong CRC drops it.
    up.begin(TABLE_KIND_CALIBRATION, len, CRC32.checksum(&t) ^ 1)
        .expect("begin");
    up.service_all().expect("erase");
    up.chunk(0, &t[..100]).expect("chunk");
    assert_eq!(up.commit(), Err(UploadRefusal::Incomplete));
    up.chunk(100, &t[100..]).expect("chunk");
    assert_eq!(up.commit(), Err(UploadRefusal::CrcMismatch));
    assert_eq!(up.commit(), Err(UploadRefusal::NotStarted));
    // A table with the right CRC that the core does not parse.
    let mut bad = t.clone();
    bad[0] ^= 0xFF;
    up.begin(TABLE_KIND_CALIBRATION, len, CRC32.checksum(&bad))
        .expect("begin");
    up.service_all().expect("erase");
    up.chunk(0, &bad).expect("chunk");
    assert_eq!(up.commit(), Err(UploadRefusal::Invalid));
    assert_eq!(up.active(TABLE_KIND_CALIBRATION), None);
    // Abort drops the upload; the next begin is free.
    up.begin(TABLE_KIND_CALIBRATION, len, 0).expect("begin");
    up.abort();
    up.begin(TABLE_KIND_CALIBRATION, len, 0)
        .expect("begin after abort");
    assert_eq!(s.active(TableKind::Calibration), None);
}

#[test]
fn every_store_error_has_its_refusal() {
    use startrack_core::store::FlashFault;
    let cases = [
        (StoreError::Flash(FlashFault::Other), UploadRefusal::Storage),
        (
            StoreError::VerifyFailed { offset_b: 0 },
            UploadRefusal::Storage,
        ),
        (
            StoreError::UploadInProgress {
                kind: TableKind::Calibration,
            },
            UploadRefusal::Busy,
        ),
        (StoreError::NotErased, UploadRefusal::Busy),
        (StoreError::NoUpload, UploadRefusal::NotStarted),
        (
            StoreError::OutOfOrder {
                expected_b: 96,
                got_b: 0,
            },
            UploadRefusal::OutOfOrder { expected: 96 },
        ),
        (
            StoreError::Incomplete {
                received_b: 1,
                total_b: 2,
            },
            UploadRefusal::Incomplete,
        ),
        (
            StoreError::CrcMismatch {
                expected: 1,
                computed: 2,
            },
            UploadRefusal::CrcMismatch,
        ),
        (StoreError::Invalid, UploadRefusal::Invalid),
        (StoreError::EmptyTable, UploadRefusal::Invalid),
    ];
    for (e, r) in cases {
        assert_eq!(refusal_of(e), r, "{e:?}");
    }
}
