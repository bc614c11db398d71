//! UART framing: COBS (Consistent Overhead Byte Stuffing, the `cobs` crate), each packet
//! encoded without zero bytes and followed by one `0x00`. A receiver that starts mid-stream,
//! or loses or corrupts bytes, resynchronises at the next `0x00`; the overhead is one byte in
//! 254 plus the delimiter, whatever the data (HDLC-style byte stuffing doubles the worst
//! case, and a CCSDS sync marker would need a search and a length field trusted before its
//! CRC is checked).
//!
//! Cost: a byte's push is a compare and a store; a frame's decode is one pass in place.

/// Frames on the wire end with this byte, which no encoded byte equals.
pub const DELIMITER: u8 = 0x00;

/// Encoded length bound of a `len`-byte packet, delimiter included.
pub const fn encoded_len_max(len: usize) -> usize {
    len + len / 254 + 2
}

/// What [`Deframer::push`] made of a byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pushed {
    /// Nothing yet.
    Pending,
    /// A frame ended and decoded: its packet is [`Deframer::packet`]'s first `len` bytes.
    Packet(usize),
    /// A frame ended but was not valid COBS, or overran the buffer (dropped).
    Error,
}

/// Collects bytes into frames and decodes them, in a buffer of `CAP` bytes (a longer frame
/// is dropped whole and counted).
#[derive(Clone, Debug)]
pub struct Deframer<const CAP: usize> {
    buf: [u8; CAP],
    len: usize,
    overrun: bool,
}

impl<const CAP: usize> Default for Deframer<CAP> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const CAP: usize> Deframer<CAP> {
    /// Empty, waiting for a frame.
    pub const fn new() -> Self {
        Self {
            buf: [0; CAP],
            len: 0,
            overrun: false,
        }
    }

    /// Takes one received byte.
    pub fn push(&mut self, byte: u8) -> Pushed {
        if byte != DELIMITER {
            match self.buf.get_mut(self.len) {
                Some(slot) => {
                    *slot = byte;
                    self.len += 1;
                }
                None => self.overrun = true,
            }
            return Pushed::Pending;
        }
        let (len, overrun) = (self.len, self.overrun);
        self.len = 0;
        self.overrun = false;
        if overrun {
            return Pushed::Error;
        }
        if len == 0 {
            // Back-to-back delimiters (a sender's resynchronisation): no frame.
            return Pushed::Pending;
        }
        match self.buf.get_mut(..len).map(cobs::decode_in_place) {
            Some(Ok(n)) if n > 0 && n <= len => Pushed::Packet(n),
            _ => Pushed::Error,
        }
    }

    /// The last decoded packet's bytes (valid after [`Pushed::Packet`] until the next push).
    pub fn packet(&self, len: usize) -> &[u8] {
        self.buf.get(..len).unwrap_or(&[])
    }
}

/// Encodes `packet` into `out` as one frame (delimiter included); `None` if `out` is too
/// small ([`encoded_len_max`] is always enough).
pub fn encode(packet: &[u8], out: &mut [u8]) -> Option<usize> {
    let n = cobs::try_encode(packet, out).ok()?;
    let slot = out.get_mut(n)?;
    *slot = DELIMITER;
    Some(n + 1)
}
