//! The ground tool's table upload over a downlink that loses a chunk's acceptance: the
//! tracker stored the chunk, and the chunks after it, but the ground never heard so. The
//! ground must find where the store stands from the out-of-order refusals of what it sends
//! again, up to the table's end when every chunk is in (an offset that is no chunk's
//! start), and commit; not resume at the lost chunk until it gives up ("the upload stalled
//! at chunk 8 after 64 resumptions").
//!
//! The tracker here is the core's link service in its standby (the table commands are the
//! same) over an in-memory store, on TCP, with one acceptance taken out of its telemetry.

use startrack_core::link::LinkService;
use startrack_core::link::framing::{Deframer, Pushed, encoded_len_max};
use startrack_core::link::protocol as p;
use startrack_ground::{Ground, decode_tm};
use startrack_homes::memory_tables::MemoryTables;
use startrack_sim::flash_model::CRC32;
use startrack_sim::sim::truth::TruthSections;
use startrack_sim::sim::{SensorParams, Simulator};
use std::io::{ErrorKind, Read, Write};
use std::net::TcpListener;
use std::time::Duration;

const CHUNK: usize = 1024;

/// Serves one ground connection on a standby link over `tables`, dropping the acceptance of
/// the chunk at `lost_offset` (its first copy); returns the port and the server thread.
fn serve_losing(
    tables: MemoryTables,
    lost_offset: u32,
) -> (u16, std::thread::JoinHandle<MemoryTables>) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let server = std::thread::spawn(move || {
        let mut tables = tables;
        let (mut sock, _) = listener.accept().expect("accept");
        sock.set_read_timeout(Some(Duration::from_millis(5)))
            .expect("timeout");
        let mut link = Box::new(LinkService::new());
        let mut uplink = Deframer::<{ encoded_len_max(p::MAX_TC_LEN) }>::new();
        let mut downlink = Deframer::<{ encoded_len_max(p::MAX_TM_LEN) }>::new();
        let mut lost_id = None;
        let mut dropped = false;
        let (mut buf, mut out) = (vec![0u8; 4096], vec![0u8; 1 << 16]);
        loop {
            let n = match sock.read(&mut buf) {
                Ok(0) => return tables,
                Ok(n) => n,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => 0,
                Err(e) => panic!("read: {e}"),
            };
            // The request id of the chunk whose acceptance is lost (its first copy).
            for &b in &buf[..n] {
                if let Pushed::Packet(len) = uplink.push(b) {
                    let pkt = uplink.packet(len);
                    let is_lost = pkt.get(7..9)
                        == Some(&[p::TC_TABLE_CHUNK.service, p::TC_TABLE_CHUNK.subtype])
                        && pkt.get(11..15) == Some(&lost_offset.to_be_bytes());
                    if is_lost && lost_id.is_none() {
                        lost_id = Some(u32::from_be_bytes([pkt[0], pkt[1], pkt[2], pkt[3]]));
                    }
                }
            }
            link.receive_standby(&buf[..n], &mut tables);
            let m = link.transmit(&mut out);
            let mut frame = Vec::new();
            for &b in &out[..m] {
                frame.push(b);
                if let Pushed::Packet(len) = downlink.push(b) {
                    let tm = decode_tm(downlink.packet(len)).expect("telemetry decodes");
                    let lose = !dropped
                        && tm
                            .verdict()
                            .is_some_and(|(id, v)| v.is_ok() && Some(id) == lost_id);
                    if lose {
                        dropped = true;
                    } else {
                        sock.write_all(&frame).expect("write");
                    }
                    frame.clear();
                }
            }
            assert!(frame.is_empty(), "the link transmits whole frames");
        }
    });
    (port, server)
}

#[test]
fn an_upload_ends_when_a_chunks_acceptance_is_lost() {
    let params = SensorParams::default();
    let table = Simulator::new(params.clone(), Vec::new())
        .truth_table_tiled(TruthSections::ALL, 4)
        .expect("table");
    let chunks = table.len().div_ceil(CHUNK);
    assert_eq!(chunks, 15, "the PIL's upload: 15 chunks of 1 KB");
    // A chunk in the middle (what the PIL lost), and the last one.
    for lost in [8, chunks - 1] {
        let tables = MemoryTables::new(params.geometry, None);
        let (port, server) = serve_losing(tables, (lost * CHUNK) as u32);
        let mut g = Ground::connect(port, Duration::from_secs(3)).expect("connect");
        let info = g
            .upload_table(&table, CHUNK, 8)
            .unwrap_or_else(|e| panic!("acceptance of chunk {lost} lost: {e}"));
        assert_eq!(
            (info.len_bytes, info.crc32),
            (table.len() as u32, CRC32.checksum(&table))
        );
        assert!(
            g.resumes > 0,
            "chunk {lost}: the lost acceptance was noticed"
        );
        drop(g);
        let tables = server.join().expect("server");
        let active = startrack_core::link::TableUpload::active(&tables, p::TABLE_KIND_CALIBRATION);
        assert_eq!(active, Some(info), "chunk {lost}: the table in force");
    }
}
