//! Byte-level access to a written table: the format's CRC (CRC-32/ISO-HDLC from the `crc`
//! crate, named independently of the core's constant), little-endian fields, the directory's
//! entries, and re-sealing the header and section CRCs after a patch so that the checks
//! behind them are reached. Cost: one CRC pass over the bytes re-sealed.

use startrack_core::table::{DIR_ENTRY_LEN, HEADER_LEN, SectionKind};

/// The format's CRC, from the `crc` crate (the same algorithm the core uses, named
/// independently here so the tests do not read the core's own constant).
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Running CRC-32/ISO-HDLC over several slices.
pub fn crc32_parts(parts: &[&[u8]]) -> u32 {
    let mut d = CRC.digest();
    for p in parts {
        d.update(p);
    }
    d.finalize()
}

/// CRC-32/ISO-HDLC of one slice.
pub fn crc32(b: &[u8]) -> u32 {
    crc32_parts(&[b])
}

// ---------------------------------------------------------------------------------------------
// Little-endian field access.

pub fn rd16(b: &[u8], off: usize) -> u16 {
    u16::from_le_bytes([b[off], b[off + 1]])
}

pub fn rd32(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

pub fn wr16(b: &mut [u8], off: usize, v: u16) {
    b[off..off + 2].copy_from_slice(&v.to_le_bytes());
}

pub fn wr32(b: &mut [u8], off: usize, v: u32) {
    b[off..off + 4].copy_from_slice(&v.to_le_bytes());
}

/// Directory index of the section of `kind`.
pub fn dir_index(bytes: &[u8], kind: SectionKind) -> usize {
    let n = usize::from(rd16(bytes, 6));
    (0..n)
        .find(|i| rd16(bytes, HEADER_LEN + i * DIR_ENTRY_LEN) == kind as u16)
        .unwrap_or_else(|| panic!("no {} section", kind.name()))
}

/// (offset, length) of the section of `kind`.
pub fn section_range(bytes: &[u8], kind: SectionKind) -> (usize, usize) {
    let e = HEADER_LEN + dir_index(bytes, kind) * DIR_ENTRY_LEN;
    (rd32(bytes, e + 4) as usize, rd32(bytes, e + 8) as usize)
}

/// Recomputes the header CRC over bytes 0..28 and the directory, as far as both are present
/// (the section count is clamped to the bytes available). Does nothing for fewer than 32 bytes.
pub fn reseal_header(b: &mut [u8]) {
    if b.len() < HEADER_LEN {
        return;
    }
    let n = usize::from(rd16(b, 6));
    let dir_end = (HEADER_LEN + DIR_ENTRY_LEN * n).min(b.len());
    let crc = crc32_parts(&[&b[..28], &b[HEADER_LEN..dir_end]]);
    wr32(b, 28, crc);
}

/// Recomputes the CRC of directory entry `i` if the entry and its section are in bounds.
pub fn reseal_section(b: &mut [u8], i: usize) {
    let e = HEADER_LEN + i * DIR_ENTRY_LEN;
    if e + DIR_ENTRY_LEN > b.len() {
        return;
    }
    let off = rd32(b, e + 4) as usize;
    let len = rd32(b, e + 8) as usize;
    if let Some(end) = off.checked_add(len).filter(|&end| end <= b.len()) {
        let crc = crc32(&b[off..end]);
        wr32(b, e + 12, crc);
    }
}

/// Re-seals every in-bounds section, then the header (whose CRC covers the section CRCs).
pub fn reseal_all(b: &mut [u8]) {
    if b.len() < HEADER_LEN {
        return;
    }
    let n = usize::from(rd16(b, 6)).min(16);
    for i in 0..n {
        reseal_section(b, i);
    }
    reseal_header(b);
}

/// Copies `bytes`, applies `patch`, re-seals everything and parses.
pub fn patched(bytes: &[u8], patch: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
    let mut b = bytes.to_vec();
    patch(&mut b);
    reseal_all(&mut b);
    b
}
