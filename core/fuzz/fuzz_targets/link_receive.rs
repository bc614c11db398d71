//! The link's receive side (framing, packet reading, command parsing and execution) on any
//! bytes. The first byte picks how the rest is used:
//! - even: a raw byte stream, fed in pieces whose sizes the next bytes give;
//! - odd: one telecommand packet with its length field and CRC-16 made right, COBS-framed,
//!   so the fuzzer reaches command parsing and execution, which random bytes would almost
//!   never pass the CRC to.
//!
//! Checked: no panic, and every decoded packet gets exactly one verification report.
#![no_main]

use libfuzzer_sys::fuzz_target;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::link::framing::{encode, encoded_len_max};
use startrack_core::link::protocol::MAX_TC_LEN;
use startrack_core::link::{
    LinkService, NoWindows, TableInfo, TableUpload, Targets, UploadRefusal,
};
use startrack_core::tracker::{Tracker, TrackerBuffers, TrackerConfig};

/// A table store that keeps nothing but the upload's position (the in-memory host store
/// needs std; this one is enough to drive every upload path).
#[derive(Default)]
struct Store {
    open: Option<(u32, u32)>,
}

impl TableUpload for Store {
    fn begin(&mut self, kind: u8, total_len: u32, _crc32: u32) -> Result<(), UploadRefusal> {
        if self.open.is_some() {
            return Err(UploadRefusal::Busy);
        }
        if kind != 1 {
            return Err(UploadRefusal::UnknownKind);
        }
        if total_len > 1 << 17 {
            return Err(UploadRefusal::TooLong);
        }
        self.open = Some((total_len, 0));
        Ok(())
    }

    fn chunk(&mut self, offset: u32, data: &[u8]) -> Result<(), UploadRefusal> {
        let (total, at) = self.open.as_mut().ok_or(UploadRefusal::NotStarted)?;
        if offset != *at {
            return Err(UploadRefusal::OutOfOrder { expected: *at });
        }
        let end = at.saturating_add(data.len() as u32);
        if end > *total {
            return Err(UploadRefusal::TooLong);
        }
        *at = end;
        Ok(())
    }

    fn commit(&mut self) -> Result<TableInfo, UploadRefusal> {
        let (total, at) = self.open.take().ok_or(UploadRefusal::NotStarted)?;
        if at != total {
            return Err(UploadRefusal::Incomplete);
        }
        Err(UploadRefusal::Invalid)
    }

    fn abort(&mut self) {
        self.open = None;
    }

    fn active(&self, _kind: u8) -> Option<TableInfo> {
        None
    }
}

static BUFFERS: std::sync::Mutex<Option<&'static mut TrackerBuffers>> = std::sync::Mutex::new(None);

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    // The tracker's 68 KB of buffers are allocated once; the tracker itself is made afresh
    // each run (it sets the buffers up again), so no run depends on the ones before it.
    let mut slot = BUFFERS.lock().unwrap_or_else(|e| e.into_inner());
    let buffers: &mut TrackerBuffers =
        slot.get_or_insert_with(|| Box::leak(Box::new(TrackerBuffers::new())));
    // The board's capacity (the flight configuration reports up to 32 stars).
    let Ok(mut tracker) = Tracker::<32>::new(
        TrackerConfig::FLIGHT,
        ReadoutGeometry::CCD47_20_DUAL,
        buffers,
    ) else {
        panic!("the flight configuration is refused");
    };
    let mut store = Store::default();
    let mut link = Box::new(LinkService::new());
    let mut out = [0u8; 512];
    let mut feed = |link: &mut LinkService, bytes: &[u8]| {
        let mut t = Targets {
            tracker: &mut tracker,
            tables: &mut store,
            windows: &mut NoWindows,
        };
        link.receive(bytes, &mut t);
        while link.transmit(&mut out) > 0 {}
    };
    if mode & 1 == 0 {
        let mut sizes = rest.iter().copied().cycle();
        let mut at = 0;
        while at < rest.len() {
            let n = usize::from(sizes.next().unwrap_or(1)).max(1);
            let end = rest.len().min(at + n);
            feed(&mut link, &rest[at..end]);
            at = end;
        }
    } else {
        if rest.len() < 13 || rest.len() > MAX_TC_LEN {
            return;
        }
        let mut pkt = rest.to_vec();
        let data_len = (pkt.len() - 7) as u16;
        pkt[4..6].copy_from_slice(&data_len.to_be_bytes());
        let n = pkt.len();
        let crc = spacepackets::crc::CRC_CCITT_FALSE.checksum(&pkt[..n - 2]);
        pkt[n - 2..].copy_from_slice(&crc.to_be_bytes());
        let mut framed = vec![0u8; encoded_len_max(pkt.len())];
        let Some(m) = encode(&pkt, &mut framed) else {
            return;
        };
        feed(&mut link, &framed[..m]);
    }
    let c = link.counters();
    assert_eq!(c.accepted + c.rejected, c.packets);
});
