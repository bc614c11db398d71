//! Property tests of the table store on the mock H7 flash: random sequences of uploads of
//! both kinds (some cut by a power loss at a random step, some aborted), corruptions and
//! torn units anywhere in the slots, each followed by a reboot; and random flash contents.
//! After every reboot the table in force of each kind is, bit for bit, one that was
//! committed (never a corrupt one), and the newest committed one as long as no corruption
//! touched its slot; no NOR rule is ever broken; no content makes mount or an upload panic.

use proptest::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use startrack_core::store::{
    EraseProgress, FlashStore, H743_BANK2, SlotHeader, SlotState, StoreError, TableKind,
};
use startrack_sim::flash_model::{BANK_B, CutMode, MockFlash};

fn crc32(b: &[u8]) -> u32 {
    crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC).checksum(b)
}

fn mount(flash: MockFlash) -> FlashStore<MockFlash> {
    match FlashStore::mount(flash, H743_BANK2) {
        Ok(s) => s,
        Err(e) => panic!("mount refused the layout: {}", e.error),
    }
}

fn upload(
    store: &mut FlashStore<MockFlash>,
    kind: TableKind,
    table: &[u8],
    chunk_b: usize,
) -> Result<(), StoreError> {
    store.begin(kind, table.len() as u32, crc32(table))?;
    while store.erase_step()? != EraseProgress::Done {}
    for (i, c) in table.chunks(chunk_b).enumerate() {
        store.chunk((i * chunk_b) as u32, c)?;
    }
    store.commit().map(|_| ())
}

fn active_bytes(store: &FlashStore<MockFlash>, kind: TableKind) -> Option<Vec<u8>> {
    let a = store.active(kind)?;
    let b = a
        .bytes(store.flash().bytes())
        .expect("active table inside the device");
    assert_eq!(crc32(b), a.header.crc32, "active table fails its CRC");
    Some(b.to_vec())
}

#[derive(Clone, Debug)]
enum Op {
    /// Upload a random table; `cut`: (fraction of its steps in 1/1000, during the step).
    Upload {
        kind: usize,
        len: usize,
        seed: u64,
        chunk_b: usize,
        cut: Option<(u32, bool)>,
    },
    /// Begin, erase, some chunks, abort.
    Abort {
        kind: usize,
        len: usize,
        chunks: usize,
    },
    /// Overwrite bytes of a slot (an upset).
    Corrupt {
        kind: usize,
        slot: usize,
        at: u32,
        bytes: Vec<u8>,
    },
    /// Tear a unit of a slot (reads fail).
    Tear { kind: usize, slot: usize, at: u32 },
}

fn op() -> impl Strategy<Value = Op> {
    prop_oneof![
        4 => (0..2usize, 1..3000usize, any::<u64>(), 1..400usize,
              prop::option::of((0..1000u32, any::<bool>())))
            .prop_map(|(kind, len, seed, chunk_b, cut)| Op::Upload { kind, len, seed, chunk_b, cut }),
        1 => (0..2usize, 1..3000usize, 0..5usize)
            .prop_map(|(kind, len, chunks)| Op::Abort { kind, len, chunks }),
        1 => (0..2usize, 0..2usize, 0..3200u32, prop::collection::vec(any::<u8>(), 1..8))
            .prop_map(|(kind, slot, at, bytes)| Op::Corrupt { kind, slot, at, bytes }),
        1 => (0..2usize, 0..2usize, 0..3200u32)
            .prop_map(|(kind, slot, at)| Op::Tear { kind, slot, at }),
    ]
}

fn random_table(len: usize, seed: u64) -> Vec<u8> {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    (0..len).map(|_| r.random::<u8>()).collect()
}

/// Whether device range `at..at+len` touches the bytes of the table in force of `kind`.
fn touches_active(store: &FlashStore<MockFlash>, kind: TableKind, at: u32, len: u32) -> bool {
    store.active(kind).is_some_and(|a| {
        let slot = store.layout().slots_of(kind)[usize::from(a.slot)];
        let end = a.data_offset_b + a.header.len_b;
        at < end && slot.offset_b < at + len
    })
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig { cases: 96, ..ProptestConfig::default() }))]

    #[test]
    fn uploads_cuts_and_corruptions_never_give_a_corrupt_table(
        ops in prop::collection::vec(op(), 1..12),
        flash_seed in any::<u64>(),
    ) {
        let mut store = mount(MockFlash::new(BANK_B, flash_seed));
        // Every table committed per kind, and the one expected in force (None: unknown,
        // after an upset hit the slot in force).
        let mut history: [Vec<Vec<u8>>; 2] = [vec![], vec![]];
        let mut known: [Option<Vec<u8>>; 2] = [None, None];
        let mut known_valid = [true, true];
        for op in ops {
            match op {
                Op::Upload { kind, len, seed, chunk_b, cut } => {
                    let k = TableKind::ALL[kind];
                    let table = random_table(len, seed);
                    let steps = 2 + len.div_ceil(32) as u64 + 1;
                    match cut {
                        None => {
                            upload(&mut store, k, &table, chunk_b).expect("uncut upload");
                            history[kind].push(table.clone());
                            known[kind] = Some(table);
                            known_valid[kind] = true;
                        }
                        Some((frac, during)) => {
                            let at = u64::from(frac) * steps / 1000;
                            let mode = if during { CutMode::During } else { CutMode::After };
                            let mut flash = store.into_flash();
                            let start = flash.steps();
                            flash.cut_power(start + at, mode);
                            store = mount(flash);
                            prop_assert!(upload(&mut store, k, &table, chunk_b).is_err());
                            let mut flash = store.into_flash();
                            flash.power_on();
                            store = mount(flash);
                            if at + 1 == steps {
                                history[kind].push(table.clone());
                                let got = active_bytes(&store, k);
                                if mode == CutMode::After {
                                    prop_assert_eq!(got.as_ref(), Some(&table));
                                } else {
                                    prop_assert!(got.as_ref() == Some(&table) || !known_valid[kind] || got == known[kind]);
                                }
                                if got.as_ref() == Some(&table) {
                                    known[kind] = got;
                                    known_valid[kind] = true;
                                }
                            }
                        }
                    }
                }
                Op::Abort { kind, len, chunks } => {
                    let k = TableKind::ALL[kind];
                    let table = random_table(len, 99);
                    store.begin(k, len as u32, crc32(&table)).expect("begin");
                    while store.erase_step().expect("erase") != EraseProgress::Done {}
                    for (i, c) in table.chunks(64).take(chunks).enumerate() {
                        store.chunk((i * 64) as u32, c).expect("chunk");
                    }
                    store.abort().expect("abort");
                }
                Op::Corrupt { kind, slot, at, bytes } => {
                    let k = TableKind::ALL[kind];
                    let s = store.layout().slots_of(k)[slot];
                    let at = s.offset_b + at;
                    if touches_active(&store, k, at, bytes.len() as u32) {
                        known_valid[kind] = false;
                    }
                    let mut flash = store.into_flash();
                    flash.corrupt(at as usize, &bytes);
                    store = mount(flash);
                }
                Op::Tear { kind, slot, at } => {
                    let k = TableKind::ALL[kind];
                    let s = store.layout().slots_of(k)[slot];
                    let at = s.offset_b + at;
                    if touches_active(&store, k, at - at % 32, 32) {
                        known_valid[kind] = false;
                    }
                    let mut flash = store.into_flash();
                    flash.tear(at as usize);
                    store = mount(flash);
                }
            }
            // A reboot after every operation.
            store = mount(store.into_flash());
            prop_assert_eq!(store.flash().violations(), 0);
            for (kind, k) in TableKind::ALL.into_iter().enumerate() {
                let got = active_bytes(&store, k);
                if let Some(t) = &got {
                    prop_assert!(history[kind].contains(t), "{:?}: a table never committed", k);
                }
                if known_valid[kind] {
                    prop_assert_eq!(&got, &known[kind], "{:?}: not the newest table", k);
                }
            }
        }
    }

    #[test]
    fn a_random_header_unit_is_refused_with_a_reason(
        bytes in prop::array::uniform32(any::<u8>()),
        cap in 0..300_000u32,
    ) {
        // Random bytes never pass magic, version and CRC together (2^-72); never a panic.
        prop_assert!(SlotHeader::decode(&bytes, TableKind::Calibration, cap).is_err());
    }

    #[test]
    fn random_flash_contents_mount_and_take_an_upload(
        seed in any::<u64>(),
        fill in prop::sample::select(vec![0usize, 1, 2]),
        len in 1..2000usize,
    ) {
        // 0: every byte random; 1: random header units only (the rest erased); 2: random
        // bytes with torn units scattered.
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        let mut flash = MockFlash::new(BANK_B, seed);
        match fill {
            0 => {
                let bytes: Vec<u8> = (0..BANK_B).map(|_| r.random::<u8>()).collect();
                flash.corrupt(0, &bytes);
            }
            1 => {
                for k in TableKind::ALL {
                    for s in H743_BANK2.slots_of(k) {
                        let bytes: Vec<u8> = (0..32).map(|_| r.random::<u8>()).collect();
                        flash.corrupt(s.offset_b as usize, &bytes);
                    }
                }
            }
            _ => {
                let bytes: Vec<u8> = (0..BANK_B).map(|_| r.random::<u8>()).collect();
                flash.corrupt(0, &bytes);
                for _ in 0..200 {
                    flash.tear(r.random_range(0..BANK_B));
                }
                for k in TableKind::ALL {
                    for s in H743_BANK2.slots_of(k) {
                        flash.tear(s.offset_b as usize);
                    }
                }
            }
        }
        let mut store = mount(flash);
        for k in TableKind::ALL {
            // Random bytes are never a table (a header needs magic, version, kind, CRC).
            prop_assert_eq!(store.active(k), None);
            for st in store.slot_states(k) {
                prop_assert!(!matches!(st, SlotState::Valid(_)));
            }
        }
        let table = random_table(len, seed ^ 1);
        upload(&mut store, TableKind::Catalog, &table, 123).expect("upload over garbage");
        let store = mount(store.into_flash());
        prop_assert_eq!(active_bytes(&store, TableKind::Catalog), Some(table));
        prop_assert_eq!(store.active(TableKind::Calibration), None);
        prop_assert_eq!(store.flash().violations(), 0);
    }
}
