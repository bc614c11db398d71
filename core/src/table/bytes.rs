//! Little-endian field readers for the table's byte layout: a `u16` or `u32` at an offset,
//! `None` past the end. Every section decoder and the table parser read through them; each
//! read is a bounds check and a load.

/// The little-endian `u16` at `off`, `None` if `b` ends first.
pub(crate) fn u16_at(b: &[u8], off: usize) -> Option<u16> {
    let s = b.get(off..off.checked_add(2)?)?;
    Some(u16::from_le_bytes([*s.first()?, *s.get(1)?]))
}

/// The little-endian `u32` at `off`, `None` if `b` ends first.
pub(crate) fn u32_at(b: &[u8], off: usize) -> Option<u32> {
    let s = b.get(off..off.checked_add(4)?)?;
    let mut a = [0u8; 4];
    a.copy_from_slice(s);
    Some(u32::from_le_bytes(a))
}
