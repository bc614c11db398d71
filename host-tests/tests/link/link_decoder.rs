//! The link's receive side against any bytes: it never panics, every decoded packet gets
//! exactly one verification report, a corrupted command is never executed, framing round
//! trips, and each command is accepted or rejected with its typed reason. Found cases of the
//! fuzz target (`core/fuzz`, docs/protocol.md) are replayed in `fuzz_regressions`.

use proptest::prelude::*;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::framing::{Deframer, Pushed, encode, encoded_len_max};
use startrack_core::link::protocol::{self as p, MessageType};
use startrack_core::link::telemetry::Reader;
use startrack_core::link::{LinkService, NoWindows, Targets};
use startrack_core::tracker::{Tracker, TrackerBuffers, TrackerConfig};
use startrack_ground::{Tm, decode_tm, frame_telecommand};
use startrack_homes::memory_tables::MemoryTables;

/// Runs `bytes` through a fresh link bound to a fresh tracker; returns the link and the
/// telemetry it sent.
fn feed(chunks: &[&[u8]]) -> (Box<LinkService>, Vec<Tm>) {
    let mut buffers = Box::new(TrackerBuffers::new());
    let mut tracker = Box::new(
        Tracker::<32>::new(
            TrackerConfig::FLIGHT,
            ReadoutGeometry::CCD47_20_DUAL,
            &mut buffers,
        )
        .expect("tracker"),
    );
    let mut tables = MemoryTables::new(ReadoutGeometry::CCD47_20_DUAL, None);
    let mut link = Box::new(LinkService::new());
    let mut tm = Vec::new();
    let mut out = vec![0u8; 1 << 16];
    let mut de = Box::new(Deframer::<{ encoded_len_max(p::MAX_TM_LEN) }>::new());
    for c in chunks {
        let mut t = Targets {
            tracker: &mut tracker,
            tables: &mut tables,
            windows: &mut NoWindows,
        };
        link.receive(c, &mut t);
        let n = link.transmit(&mut out);
        for &b in &out[..n] {
            if let Pushed::Packet(len) = de.push(b) {
                tm.push(decode_tm(de.packet(len)).expect("the link's telemetry decodes"));
            }
        }
    }
    (link, tm)
}

/// A framed telecommand and its request id.
fn tc(kind: MessageType, data: &[u8], seq: u16) -> (Vec<u8>, u32) {
    frame_telecommand(kind, data, seq)
}

/// (accepted, rejected with code) verification reports for request `id`.
fn verdicts(tm: &[Tm], id: u32) -> Vec<Result<(), u16>> {
    tm.iter()
        .filter_map(Tm::verdict)
        .filter(|&(i, _)| i == id)
        .map(|(_, v)| v.map_err(|(code, _)| code))
        .collect()
}

fn any_command() -> impl Strategy<Value = (MessageType, Vec<u8>)> {
    let kinds: Vec<MessageType> = p::MESSAGES
        .iter()
        .filter(|m| m.direction == p::Direction::Telecommand)
        .map(|m| m.kind)
        .collect();
    (
        prop::sample::select(kinds),
        prop::collection::vec(any::<u8>(), 0..24),
    )
}

proptest! {
    #![proptest_config(startrack_test_support::regressions_beside_source(ProptestConfig { cases: 256, ..ProptestConfig::default() }))]

    #[test]
    fn any_bytes_never_panic_and_each_packet_gets_one_report(
        chunks in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..300), 1..8)
    ) {
        let refs: Vec<&[u8]> = chunks.iter().map(Vec::as_slice).collect();
        let (link, tm) = feed(&refs);
        let c = link.counters();
        prop_assert_eq!(c.rx_bytes as usize, chunks.iter().map(Vec::len).sum::<usize>());
        prop_assert_eq!(c.accepted + c.rejected, c.packets);
        let reports = tm.iter().filter(|t| t.kind == p::TM_ACCEPTED || t.kind == p::TM_REJECTED).count();
        prop_assert_eq!(reports as u32, c.packets);
    }

    #[test]
    fn every_command_gets_one_verdict_among_noise(
        cmds in prop::collection::vec(any_command(), 1..10),
        junk in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..40), 10),
    ) {
        let mut stream = Vec::new();
        let mut ids = Vec::new();
        for (k, ((kind, data), j)) in cmds.iter().zip(&junk).enumerate() {
            // Junk, then a delimiter so the next frame starts clean.
            stream.extend_from_slice(j);
            stream.push(0);
            let (f, id) = tc(*kind, data, k as u16);
            stream.extend_from_slice(&f);
            ids.push(id);
        }
        let (_, tm) = feed(&[&stream]);
        for id in ids {
            prop_assert_eq!(verdicts(&tm, id).len(), 1, "request {:#x}", id);
        }
    }

    #[test]
    fn a_corrupted_command_is_never_executed(
        (kind, data) in any_command(),
        at in any::<prop::sample::Index>(),
        flip in 1u8..=255,
    ) {
        let (mut f, id) = tc(kind, &data, 7);
        let i = at.index(f.len() - 1); // not the delimiter
        f[i] ^= flip;
        let (link, tm) = feed(&[&f, &[0]]);
        prop_assert_eq!(link.counters().accepted, 0);
        prop_assert!(verdicts(&tm, id).iter().all(|v| v.is_err()));
    }

    #[test]
    fn framing_round_trips(pkt in prop::collection::vec(any::<u8>(), 1..1100)) {
        let mut f = vec![0u8; encoded_len_max(pkt.len())];
        let n = encode(&pkt, &mut f).expect("fits");
        prop_assert!(f[..n - 1].iter().all(|&b| b != 0));
        let mut d = Deframer::<{ encoded_len_max(p::MAX_TC_LEN) }>::new();
        let mut got = None;
        for &b in &f[..n] {
            if let Pushed::Packet(len) = d.push(b) {
                got = Some(d.packet(len).to_vec());
            }
        }
        prop_assert_eq!(got, Some(pkt));
    }
}

/// A command (type, data) and the verdict it must get.
type Case = ((MessageType, Vec<u8>), Result<(), u16>);

/// The typed verdict of each command on a fresh tracker (standby, no table, nothing to
/// track, no window source).
#[test]
fn each_command_is_accepted_or_rejected_with_its_reason() {
    let velocity = |v: [f32; 3]| {
        let mut d: Vec<u8> = v.iter().flat_map(|c| c.to_be_bytes()).collect();
        d.extend_from_slice(&[0x83, 0, 0, 0, 0x80, 0]);
        d
    };
    let mode = |m: u8| (p::TC_SET_MODE, vec![m]);
    let cases: Vec<Case> = vec![
        ((p::TC_PING, vec![]), Ok(())),
        ((p::TC_PING, vec![1]), Err(5)),
        ((p::TC_HOUSEKEEPING, vec![]), Ok(())),
        ((p::TC_HOUSEKEEPING_PERIOD, vec![0, 5]), Ok(())),
        (mode(0), Ok(())),
        (mode(1), Ok(())),
        (mode(2), Err(7)),
        (mode(3), Err(6)),
        ((p::TC_SET_PARAMS, [1u8, 0, 0, 0, 50].to_vec()), Ok(())),
        ((p::TC_SET_PARAMS, [9u8, 0, 0, 0, 50].to_vec()), Err(6)),
        ((p::TC_SET_PARAMS, [7u8, 0, 0, 0, 0].to_vec()), Err(8)),
        ((p::TC_SET_PARAMS, [2u8, 0x7f, 0xc0, 0, 0].to_vec()), Err(8)),
        ((p::TC_STARS, vec![0, 3]), Ok(())),
        ((p::TC_WINDOW, vec![0, 1, 0, 1, 0, 8, 0]), Err(10)),
        ((p::TC_WINDOW, vec![0, 1, 0, 1, 0, 65, 0]), Err(6)),
        ((p::TC_TABLE_CHUNK, vec![0, 0, 0, 0, 1]), Err(9)),
        ((p::TC_TABLE_COMMIT, vec![]), Err(9)),
        (
            (p::TC_TABLE_BEGIN, [2u8, 0, 0, 1, 0, 0, 0, 0, 0].to_vec()),
            Err(9),
        ),
        (
            (p::TC_TABLE_BEGIN, [1u8, 0, 0, 0, 4, 0, 0, 0, 0].to_vec()),
            Ok(()),
        ),
        ((p::TC_TABLE_CHUNK, vec![0, 0, 0, 2, 1]), Err(9)),
        ((p::TC_TABLE_CHUNK, vec![0, 0, 0, 0, 1, 2, 3, 4]), Ok(())),
        ((p::TC_TABLE_COMMIT, vec![]), Err(9)),
        ((p::TC_TABLE_ABORT, vec![]), Ok(())),
        ((p::TC_TABLE_REPORT, vec![1]), Ok(())),
        ((p::TC_TIME_SET, vec![0x1E, 0x83, 0, 0, 0, 0x80, 0]), Ok(())),
        (
            (p::TC_TIME_SET, vec![0x2E, 0x83, 0, 0, 0, 0x80, 0]),
            Err(13),
        ),
        ((p::TC_TIME_SET, vec![0x83, 0, 0, 0, 0x80, 0]), Err(5)),
        (
            (p::TC_VELOCITY, velocity([7_500.0, -29_800.0, 12.0])),
            Ok(()),
        ),
        ((p::TC_VELOCITY, velocity([400_000.0, 0.0, 0.0])), Err(6)),
        ((p::TC_VELOCITY, velocity([f32::NAN, 0.0, 0.0])), Err(6)),
        ((p::TC_VELOCITY, velocity([0.0; 3])[..17].to_vec()), Err(5)),
        ((p::TC_RESET, vec![]), Ok(())),
        (
            (
                MessageType {
                    service: 200,
                    subtype: 1,
                },
                vec![],
            ),
            Err(4),
        ),
    ];
    let mut stream = Vec::new();
    let mut ids = Vec::new();
    for (k, ((kind, data), _)) in cases.iter().enumerate() {
        let (f, id) = tc(*kind, data, k as u16);
        stream.extend_from_slice(&f);
        ids.push(id);
    }
    let (link, tm) = feed(&[&stream]);
    for ((cmd, want), id) in cases.iter().zip(ids) {
        assert_eq!(verdicts(&tm, id), vec![*want], "{cmd:?}");
    }
    assert!(link.reset_requested());
    // The upload refusals carry their typed code: out of order says where to resume.
    let (_, tm) = feed(&[
        &tc(p::TC_TABLE_BEGIN, &[1, 0, 0, 0, 8, 0, 0, 0, 0], 1).0,
        &tc(p::TC_TABLE_CHUNK, &[0, 0, 0, 3, 9], 2).0,
    ]);
    let rej = tm
        .iter()
        .find(|t| t.kind == p::TM_REJECTED)
        .expect("a rejection");
    let mut r = Reader::new(&rej.data);
    let _ = r.u32();
    assert_eq!(r.u16(), Some(9));
    assert_eq!(r.u32(), Some(5 << 16), "out of order, expected offset 0");
    // A wrong APID and a bad CRC are rejected with their reasons.
    let (mut f, id) = tc(p::TC_PING, &[], 3);
    let n = f.len();
    f[n - 2] ^= 0x01; // inside the COBS-coded CRC
    let (link, tm) = feed(&[&f]);
    assert_eq!(
        link.counters().crc_errors + link.counters().rejected,
        2,
        "{tm:?}"
    );
    assert!(verdicts(&tm, id).iter().all(|v| v.is_err()));
}

/// Inputs the fuzz target found, replayed (core/fuzz/regressions/).
#[test]
fn fuzz_regressions() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../core/fuzz/regressions");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return;
    };
    for e in entries {
        let bytes = std::fs::read(e.expect("entry").path()).expect("read");
        let (link, _) = feed(&[&bytes]);
        let c = link.counters();
        assert_eq!(c.accepted + c.rejected, c.packets);
    }
}

/// The service's memory as the docs state it (~17 KB: core/src/link/mod.rs, docs/protocol.md).
#[test]
fn link_service_size() {
    let n = std::mem::size_of::<LinkService>();
    let plan = std::mem::size_of::<startrack_core::table::AmendPlan>();
    println!("LinkService: {n} bytes, of which the defect commit's plan {plan}");
    assert!((16_500..=18_000).contains(&n), "{n} bytes");
    assert!(plan <= 1_300, "{plan} bytes");
}
