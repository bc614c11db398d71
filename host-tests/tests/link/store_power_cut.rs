//! The table store against power cuts: an upload and commit of a calibration table is cut
//! at every one of its flash steps (each sector erase and each 32-byte program, the header
//! write last), during the step (the unit or sector left torn) and right after it. After
//! every cut the tracker boots (mount) with the old table or the new one, checked bit for bit
//! and parsed by the core, never a corrupt one and never none while one was valid; and the
//! next upload after the reboot succeeds.

use startrack_test_support::table_fixtures;

use startrack_core::store::{EraseProgress, FlashStore, H743_BANK2, StoreError, TableKind};
use startrack_core::table::CalibTable;
use startrack_sim::flash_model::{BANK_B, CutMode, MockFlash};
use table_fixtures::*;

const KIND: TableKind = TableKind::Calibration;

fn crc32_of(b: &[u8]) -> u32 {
    crc32(b)
}

fn mount(flash: MockFlash) -> FlashStore<MockFlash> {
    match FlashStore::mount(flash, H743_BANK2) {
        Ok(s) => s,
        Err(e) => panic!("mount refused the layout: {}", e.error),
    }
}

/// begin, every erase step, chunks of `chunk_b` bytes, commit.
fn upload(
    store: &mut FlashStore<MockFlash>,
    table: &[u8],
    chunk_b: usize,
) -> Result<(), StoreError> {
    store.begin(KIND, table.len() as u32, crc32_of(table))?;
    while store.erase_step()? != EraseProgress::Done {}
    for (i, c) in table.chunks(chunk_b).enumerate() {
        store.chunk((i * chunk_b) as u32, c)?;
    }
    // Committed only if the core parses it where it lies (the calibration table's own checks).
    store
        .commit_checked(|f, at, len| {
            CalibTable::parse(&f.bytes()[at as usize..(at + len) as usize]).is_ok()
        })
        .map(|_| ())
}

/// The bytes of the table in force, checked: CRC (by the store), parsed by the core.
fn active_table(store: &FlashStore<MockFlash>) -> Option<Vec<u8>> {
    let active = store.active(KIND)?;
    let bytes = active.bytes(store.flash().bytes())?;
    assert_eq!(crc32_of(bytes), active.header.crc32);
    assert!(
        CalibTable::parse(bytes).is_ok(),
        "active table does not parse"
    );
    Some(bytes.to_vec())
}

/// A flash holding `tables` committed in order.
fn flash_with(tables: &[&[u8]]) -> MockFlash {
    let mut store = mount(MockFlash::new(BANK_B, 7));
    for t in tables {
        upload(&mut store, t, 96).expect("setting up");
    }
    store.into_flash()
}

/// Cuts `new`'s upload at every step of it, both ways, from a flash holding `before`;
/// returns the number of cut points.
fn cut_everywhere(before: &[&[u8]], new: &[u8], next: &[u8], chunk_b: usize) -> usize {
    let base = flash_with(before);
    let old: Option<Vec<u8>> = before.last().map(|t| t.to_vec());
    assert_eq!(active_table(&mount(base.clone())), old);
    // The slot in force (header and table units), which no step may touch.
    let kept = mount(base.clone()).active(KIND).map(|a| {
        let start = (a.data_offset_b - 32) as usize;
        start..a.data_offset_b as usize + (a.header.len_b as usize).div_ceil(32) * 32
    });

    // Dry run: the steps of this upload.
    let mut dry = mount(base.clone());
    let start = dry.flash().steps();
    upload(&mut dry, new, chunk_b).expect("uncut upload");
    let steps = dry.flash().steps() - start;
    let units = new.len().div_ceil(32) as u64;
    assert_eq!(
        steps,
        2 + units + 1,
        "2 sector erases, the table's units, the header"
    );
    assert_eq!(active_table(&mount(dry.into_flash())).as_deref(), Some(new));

    let mut points = 0;
    for k in 0..steps {
        for mode in [CutMode::During, CutMode::After] {
            let mut flash = base.clone();
            flash.cut_power(start + k, mode);
            let mut store = mount(flash);
            assert!(
                upload(&mut store, new, chunk_b).is_err(),
                "step {k} {mode:?} not cut"
            );
            let mut flash = store.into_flash();
            assert!(flash.is_off());
            if let Some(r) = kept.clone() {
                assert_eq!(
                    flash.bytes()[r.clone()],
                    base.bytes()[r.clone()],
                    "step {k} {mode:?}: the slot in force was written"
                );
                assert!(
                    r.step_by(32)
                        .all(|o| flash.unit_state(o) == base.unit_state(o))
                );
            }
            flash.power_on();
            let store = mount(flash);
            let got = active_table(&store);
            let header_done = k + 1 == steps && mode == CutMode::After;
            let header_torn = k + 1 == steps && mode == CutMode::During;
            if header_done {
                assert_eq!(
                    got.as_deref(),
                    Some(new),
                    "step {k} {mode:?}: header written"
                );
            } else if header_torn {
                // A torn header is refused, unless its ECC and CRC both pass on exactly the
                // header intended (the unit complete in all but name).
                assert!(
                    got.as_deref() == Some(new) || got == old,
                    "step {k} {mode:?}: neither the old nor the new table"
                );
            } else {
                assert_eq!(got, old, "step {k} {mode:?}: the old table must stay");
            }
            assert_eq!(store.flash().violations(), 0);
            // The next upload after the reboot works from whatever the cut left.
            let mut store = store;
            upload(&mut store, next, chunk_b)
                .unwrap_or_else(|e| panic!("step {k} {mode:?}: upload after the cut: {e}"));
            let store = mount(store.into_flash());
            assert_eq!(active_table(&store).as_deref(), Some(next));
            assert_eq!(store.flash().violations(), 0);
            points += 1;
        }
    }
    points
}

#[test]
fn a_power_cut_at_every_step_leaves_the_old_or_the_new_table() {
    let a = full_spec(SMALL, 0, 0).write();
    let b = full_spec(SMALL_DUAL, 3, 1).write();
    let c = full_spec(SMALL_DUAL, 10, 0).write();
    let d = gains_only(SMALL).write();
    let mut points = 0;
    // One table in force, a second uploaded: the target slot was never used.
    points += cut_everywhere(&[&a], &b, &c, 96);
    // Two tables: the upload erases the older one's slot, never the one in force.
    points += cut_everywhere(&[&a, &b], &c, &d, 100);
    // Nothing in force yet: a cut leaves nothing or the new table, never garbage.
    points += cut_everywhere(&[], &d, &a, 7);
    // Chunks of one byte, and of the whole table at once.
    points += cut_everywhere(&[&c], &a, &b, 1);
    points += cut_everywhere(&[&d, &c], &b, &a, b.len());
    // A CCD47-20 table (dark and flat maps in 16 x 16 tiles), in link-sized chunks.
    let ccd = full_spec(CCD, 4, 4).write();
    points += cut_everywhere(&[&a, &c], &ccd, &b, 200);
    println!(
        "power-cut points covered: {points} (CCD47-20 table: {} bytes)",
        ccd.len()
    );
    let per_upload = |t: &[u8]| 2 * (2 + t.len().div_ceil(32) + 1);
    assert_eq!(
        points,
        per_upload(&b)
            + per_upload(&c)
            + per_upload(&d)
            + per_upload(&a)
            + per_upload(&b)
            + per_upload(&ccd)
    );
}

#[test]
fn a_cut_upload_then_a_reboot_then_another_cut_keeps_the_table() {
    // Two cuts in a row in the same slot (torn units left from the first), then a clean
    // upload: the original table stays in force until the clean commit.
    let a = full_spec(SMALL, 0, 0).write();
    let b = full_spec(SMALL_DUAL, 3, 1).write();
    let mut flash = flash_with(&[&a]);
    let last_data_step = 2 + b.len().div_ceil(32) as u64 - 1;
    for k in [5u64, last_data_step] {
        let at = flash.steps() + k;
        flash.cut_power(at, CutMode::During);
        let mut store = mount(flash);
        assert!(upload(&mut store, &b, 64).is_err());
        flash = store.into_flash();
        flash.power_on();
        assert_eq!(active_table(&mount(flash.clone())).as_deref(), Some(&a[..]));
    }
    let mut store = mount(flash);
    upload(&mut store, &b, 64).expect("clean upload");
    assert_eq!(
        active_table(&mount(store.into_flash())).as_deref(),
        Some(&b[..])
    );
}
