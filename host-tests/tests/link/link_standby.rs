//! The link with no tracker running (the safe standby after a set-up fault): it still
//! answers every command, serves housekeeping with the faults and the tables, and refuses
//! mode and configuration commands with their own typed reason.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::framing::{Deframer, Pushed, encoded_len_max};
use startrack_core::link::protocol::{self as p, MessageType};
use startrack_core::link::telemetry::Housekeeping;
use startrack_core::link::{LinkService, Rejection};
use startrack_core::safe::SetupFaults;
use startrack_core::tracker::Mode;
use startrack_ground::{Tm, decode_tm, frame_telecommand};
use startrack_homes::memory_tables::MemoryTables;

/// Sends one telecommand to a standby link; returns its verdict (Ok, or the rejection code)
/// and every telemetry packet it produced.
fn command(
    link: &mut LinkService,
    tables: &mut MemoryTables,
    kind: MessageType,
    data: &[u8],
    seq: u16,
) -> (Result<(), u16>, Vec<Tm>) {
    let (frame, id) = frame_telecommand(kind, data, seq);
    link.receive_standby(&frame, tables);
    let mut out = vec![0u8; 1 << 16];
    let n = link.transmit(&mut out);
    let mut de = Deframer::<{ encoded_len_max(p::MAX_TM_LEN) }>::new();
    let mut tm = Vec::new();
    for &b in &out[..n] {
        if let Pushed::Packet(len) = de.push(b) {
            tm.push(decode_tm(de.packet(len)).expect("the link's telemetry decodes"));
        }
    }
    let verdicts: Vec<Result<(), u16>> = tm
        .iter()
        .filter_map(|t| t.verdict())
        .filter(|&(i, _)| i == id)
        .map(|(_, v)| v.map_err(|(code, _)| code))
        .collect();
    assert_eq!(
        verdicts.len(),
        1,
        "{kind:?}: one verification report, got {verdicts:?}"
    );
    (verdicts[0], tm)
}

#[test]
fn standby_link_answers_and_refuses_what_needs_the_tracker() {
    let mut link = Box::new(LinkService::new());
    let faults = SetupFaults::LINE_BUFFERS | SetupFaults::NO_TABLE;
    link.set_setup_faults(faults.bits());
    let mut tables = MemoryTables::new(ReadoutGeometry::CCD47_20_DUAL, None);

    let (v, tm) = command(&mut link, &mut tables, p::TC_PING, &[], 1);
    assert_eq!(v, Ok(()));
    assert!(tm.iter().any(|t| t.kind == p::TM_PONG), "ping answered");

    let (v, tm) = command(&mut link, &mut tables, p::TC_HOUSEKEEPING, &[], 2);
    assert_eq!(v, Ok(()));
    let hk = tm
        .iter()
        .find(|t| t.kind == p::TM_HOUSEKEEPING)
        .and_then(|t| Housekeeping::decode(&t.data))
        .expect("a housekeeping report");
    assert_eq!(u32::from(hk.setup_faults), faults.bits());
    assert_eq!(hk.mode, Mode::Standby);
    assert_eq!(hk.table, None);

    // Mode (acquisition) and configuration commands need the tracker.
    let standby = Rejection::Standby.code();
    let (v, _) = command(&mut link, &mut tables, p::TC_SET_MODE, &[1], 3);
    assert_eq!(v, Err(standby));
    // exposure_ms (id 1) = 500: a well-formed configuration command.
    let (v, _) = command(
        &mut link,
        &mut tables,
        p::TC_SET_PARAMS,
        &[1, 0, 0, 1, 244],
        4,
    );
    assert_eq!(v, Err(standby), "set-params");

    // Tables and reset are served.
    let (v, _) = command(&mut link, &mut tables, p::TC_TABLE_ABORT, &[], 5);
    assert_eq!(v, Ok(()));
    let (v, tm) = command(
        &mut link,
        &mut tables,
        p::TC_TABLE_REPORT,
        &[p::TABLE_KIND_CALIBRATION],
        6,
    );
    assert_eq!(v, Ok(()));
    assert!(tm.iter().any(|t| t.kind == p::TM_TABLE_REPORT));
    let (v, _) = command(&mut link, &mut tables, p::TC_RESET, &[], 7);
    assert_eq!(v, Ok(()));
    assert!(link.reset_requested());
}
