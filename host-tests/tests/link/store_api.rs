//! The table store's operations one by one: every refusal is typed and changes nothing in
//! force, the layout is checked at mount, a table is read in place and copied, and the
//! flash model's rules and its file round trip hold.

use startrack_core::store::{
    EraseProgress, FlashStore, H743_BANK2, HeaderError, Layout, Slot, SlotHeader, SlotState,
    StoreError, TableKind,
};
use startrack_sim::flash_model::{BANK_B, FileFlash, FlashModelError, MockFlash, UNIT_B};

use embedded_storage::nor_flash::{NorFlash, ReadNorFlash};

const CAL: TableKind = TableKind::Calibration;

fn crc32(b: &[u8]) -> u32 {
    crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(b)
}

fn fresh() -> FlashStore<MockFlash> {
    match FlashStore::mount(MockFlash::new(BANK_B, 3), H743_BANK2) {
        Ok(s) => s,
        Err(e) => panic!("{}", e.error),
    }
}

fn erase_all(store: &mut FlashStore<MockFlash>) {
    let mut n = 0;
    while store.erase_step().expect("erase") != EraseProgress::Done {
        n += 1;
    }
    assert_eq!(n, 1, "two sectors per slot: Remaining(1), then Done");
}

fn table(len: usize) -> Vec<u8> {
    (0..len).map(|i| (i * 7 + 3) as u8).collect()
}

#[test]
fn an_upload_refuses_every_out_of_turn_step_and_keeps_the_table_in_force() {
    let mut store = fresh();
    let t = table(1000);
    assert_eq!(store.chunk(0, &t), Err(StoreError::NoUpload));
    assert_eq!(store.commit(), Err(StoreError::NoUpload));
    assert_eq!(store.abort(), Err(StoreError::NoUpload));
    assert_eq!(store.erase_step(), Err(StoreError::NoUpload));
    assert_eq!(store.begin(CAL, 0, 0), Err(StoreError::EmptyTable));
    let cap = H743_BANK2.slots_of(CAL)[0].capacity_b();
    assert_eq!(
        store.begin(CAL, cap + 1, 0),
        Err(StoreError::TooLong {
            len_b: cap + 1,
            capacity_b: cap
        })
    );

    store.begin(CAL, t.len() as u32, crc32(&t)).expect("begin");
    assert_eq!(
        store.begin(TableKind::Catalog, 10, 0),
        Err(StoreError::UploadInProgress { kind: CAL })
    );
    assert_eq!(store.chunk(0, &t[..10]), Err(StoreError::NotErased));
    assert_eq!(store.commit(), Err(StoreError::NotErased));
    assert_eq!(store.pending_erase(), Some((0, 128 * 1024)));
    erase_all(&mut store);
    assert_eq!(store.pending_erase(), None);
    store.chunk(0, &t[..100]).expect("first chunk");
    assert_eq!(
        store.chunk(50, &t[50..150]),
        Err(StoreError::OutOfOrder {
            expected_b: 100,
            got_b: 50
        })
    );
    assert_eq!(
        store.chunk(100, &[0; 901]),
        Err(StoreError::PastEnd {
            end_b: 1001,
            total_b: 1000
        })
    );
    // Incomplete keeps the upload: the rest may still come.
    assert_eq!(
        store.commit(),
        Err(StoreError::Incomplete {
            received_b: 100,
            total_b: 1000
        })
    );
    let status = store.upload_status().expect("still uploading");
    assert_eq!((status.received_b, status.total_b), (100, 1000));
    store.chunk(100, &t[100..]).expect("rest");
    let info = store.commit().expect("commit");
    assert_eq!(info.header.sequence, 1);
    assert_eq!(info.slot, 0);
    assert_eq!(store.active(CAL), Some(info));
    assert_eq!(store.upload_status(), None);

    // A table whose bytes do not have the announced CRC is refused; the first stays.
    let u = table(700);
    store.begin(CAL, 700, crc32(&u) ^ 1).expect("begin");
    erase_all(&mut store);
    store.chunk(0, &u).expect("chunk");
    assert_eq!(
        store.commit(),
        Err(StoreError::CrcMismatch {
            expected: crc32(&u) ^ 1,
            computed: crc32(&u)
        })
    );
    assert_eq!(store.active(CAL), Some(info));
    // Aborted mid-way: the first stays, and a reboot agrees.
    store.begin(CAL, 700, crc32(&u)).expect("begin");
    erase_all(&mut store);
    store.chunk(0, &u[..300]).expect("chunk");
    store.abort().expect("abort");
    assert_eq!(store.active(CAL), Some(info));
    let mut store = FlashStore::mount(store.into_flash(), H743_BANK2)
        .ok()
        .expect("mount");
    assert_eq!(store.active(CAL), Some(info));
    let mut buf = vec![0u8; 999];
    assert_eq!(
        store.read_active(CAL, &mut buf),
        Err(StoreError::BufferTooSmall { need_b: 1000 })
    );
    let mut buf = vec![0u8; 4096];
    assert_eq!(store.read_active(CAL, &mut buf).expect("copy"), &t[..]);
    assert_eq!(
        store.read_active(TableKind::Catalog, &mut buf),
        Err(StoreError::NoTable)
    );

    // The next upload goes to slot 1 with sequence 2, then slot 0 again with 3.
    for (slot, seq) in [(1, 2), (0, 3)] {
        store.begin(CAL, 700, crc32(&u)).expect("begin");
        erase_all(&mut store);
        store.chunk(0, &u).expect("chunk");
        let info = store.commit().expect("commit");
        assert_eq!((info.slot, info.header.sequence), (slot, seq));
    }
    let states = store.slot_states(CAL);
    assert!(matches!(states[0], SlotState::Valid(h) if h.sequence == 3));
    assert!(matches!(states[1], SlotState::Valid(h) if h.sequence == 2));
}

#[test]
fn mount_refuses_a_bad_layout_and_gives_the_device_back() {
    let slot = |offset_b, len_b| Slot { offset_b, len_b };
    let sector = 128 * 1024;
    let bad = [
        // Overlapping slots.
        [
            [slot(0, sector), slot(0, sector)],
            [slot(2 * sector, sector), slot(3 * sector, sector)],
        ],
        // Not a whole sector.
        [
            [slot(0, 4096), slot(sector, sector)],
            [slot(2 * sector, sector), slot(3 * sector, sector)],
        ],
        // Past the device.
        [
            [slot(0, sector), slot(sector, sector)],
            [slot(2 * sector, sector), slot(8 * sector, sector)],
        ],
    ];
    for slots in bad {
        let Err(e) = FlashStore::mount(MockFlash::new(BANK_B, 1), Layout { slots }) else {
            panic!("bad layout mounted: {slots:?}");
        };
        assert!(
            matches!(e.error, StoreError::BadLayout { .. }),
            "{}",
            e.error
        );
        assert_eq!(e.flash.capacity(), BANK_B);
    }
}

#[test]
fn the_header_rejects_every_single_bit_flip_and_a_wrong_kind() {
    let h = SlotHeader {
        kind: CAL,
        sequence: 42,
        len_b: 1234,
        crc32: 0xDEAD_BEEF,
    };
    let b = h.encode();
    assert_eq!(SlotHeader::decode(&b, CAL, 4096), Ok(h));
    assert_eq!(
        SlotHeader::decode(&b, TableKind::Catalog, 4096),
        Err(HeaderError::Kind)
    );
    assert_eq!(SlotHeader::decode(&b, CAL, 1000), Err(HeaderError::Length));
    assert_eq!(
        SlotHeader::decode(&[0xFF; 32], CAL, 4096),
        Err(HeaderError::Erased)
    );
    for i in 0..32 * 8 {
        let mut x = b;
        x[i / 8] ^= 1 << (i % 8);
        assert!(SlotHeader::decode(&x, CAL, 4096).is_err(), "bit {i}");
    }
}

#[test]
fn the_flash_model_enforces_the_nor_rules() {
    let mut f = MockFlash::new(BANK_B, 5);
    let unit = [0x5A; UNIT_B];
    assert_eq!(f.write(16, &unit), Err(FlashModelError::NotAligned));
    assert_eq!(f.write(0, &unit[..16]), Err(FlashModelError::NotAligned));
    assert_eq!(f.erase(0, 4096), Err(FlashModelError::NotAligned));
    assert_eq!(
        f.write(BANK_B as u32, &unit),
        Err(FlashModelError::OutOfBounds)
    );
    f.write(64, &unit).expect("program an erased unit");
    assert_eq!(
        f.write(64, &unit),
        Err(FlashModelError::NotErased { offset_b: 64 })
    );
    assert_eq!(f.violations(), 1);
    let mut b = [0u8; 40];
    f.read(60, &mut b).expect("read");
    assert_eq!(&b[..4], &[0xFF; 4]);
    assert_eq!(&b[4..36], &unit);
    f.tear(96);
    assert_eq!(
        f.read(90, &mut b),
        Err(FlashModelError::Ecc { offset_b: 96 })
    );
    f.erase(0, 128 * 1024).expect("erase");
    f.read(60, &mut b).expect("read after erase");
    assert_eq!(b, [0xFF; 40]);
    assert_eq!(f.steps(), 2, "one unit program and one sector erase");
}

#[test]
fn the_flash_file_round_trips_and_refuses_a_foreign_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("flash.bin");
    let mut ff = FileFlash::open(&path).expect("new file");
    assert_eq!(ff.flash.capacity(), BANK_B);
    ff.flash.write(0, &[1; 32]).expect("write");
    ff.flash.tear(64);
    ff.save().expect("save");
    let mut again = FileFlash::open(&path).expect("reopen");
    assert_eq!(again.flash.bytes(), ff.flash.bytes());
    let mut b = [0u8; 32];
    assert_eq!(
        again.flash.read(64, &mut b),
        Err(FlashModelError::Ecc { offset_b: 64 })
    );
    std::fs::write(&path, b"not a flash image").expect("write");
    let err = FileFlash::open(&path).expect_err("garbage accepted");
    assert_eq!(err.kind(), std::io::ErrorKind::InvalidData);
}

#[test]
fn the_storage_page_shows_the_bank2_layout() {
    use startrack_core::store::{H743_BANK2_ADDRESS, H743_SECTOR_B};
    let page = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/storage.md"))
        .expect("docs/storage.md");
    let rows: Vec<Vec<String>> = page
        .lines()
        .skip_while(|l| !l.starts_with("| kind | slot | bank-2 offset"))
        .skip(2)
        .take_while(|l| l.starts_with('|'))
        .map(|l| {
            l.trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_string())
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 4, "docs/storage.md: one row per slot");
    let mut i = 0;
    for kind in TableKind::ALL {
        for (s, slot) in H743_BANK2.slots_of(kind).iter().enumerate() {
            let first = slot.offset_b / H743_SECTOR_B;
            let last = (slot.offset_b + slot.len_b) / H743_SECTOR_B - 1;
            let want = [
                format!("{kind:?}").to_lowercase(),
                s.to_string(),
                format!("0x{:05X}", slot.offset_b),
                format!("0x{:08X}", H743_BANK2_ADDRESS + slot.offset_b),
                slot.len_b.to_string(),
                format!("{first}-{last}"),
            ];
            assert_eq!(rows[i], want, "docs/storage.md flash map, row {i}");
            i += 1;
        }
    }
}

#[test]
fn a_slot_image_flashed_into_an_erased_bank_is_the_table_in_force() {
    let t = table(5000);
    let image = startrack_sim::flash_model::slot_image(CAL, &t).expect("image");
    assert_eq!(
        image.len(),
        32 + 5024,
        "header unit, then the table to its last unit"
    );
    let mut flash = MockFlash::new(BANK_B, 9);
    flash.corrupt(0, &image);
    let store = FlashStore::mount(flash, H743_BANK2).ok().expect("mount");
    let active = store.active(CAL).expect("the image's table is in force");
    assert_eq!(active.header.sequence, 1);
    assert_eq!(active.bytes(store.flash().bytes()), Some(&t[..]));
}

#[test]
fn a_table_its_own_checks_refuse_is_not_committed() {
    use startrack_core::table::CalibTable;
    let mut store = fresh();
    let good = table(300);
    store.begin(CAL, 300, crc32(&good)).expect("begin");
    erase_all(&mut store);
    store.chunk(0, &good).expect("chunk");
    let info = store.commit().expect("commit");
    // Bytes with the right CRC that are not a calibration table: refused by its parser.
    let not_a_table = table(400);
    store.begin(CAL, 400, crc32(&not_a_table)).expect("begin");
    erase_all(&mut store);
    store.chunk(0, &not_a_table).expect("chunk");
    let parses = |f: &mut MockFlash, at: u32, len: u32| {
        CalibTable::parse(&f.bytes()[at as usize..(at + len) as usize]).is_ok()
    };
    assert_eq!(store.commit_checked(parses), Err(StoreError::Invalid));
    assert_eq!(store.upload_status(), None);
    assert_eq!(store.active(CAL), Some(info));
    let store = FlashStore::mount(store.into_flash(), H743_BANK2)
        .ok()
        .expect("mount");
    assert_eq!(store.active(CAL), Some(info));
}
