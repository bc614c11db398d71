//! The MDMA's linked-list nodes, made from the core's chain links
//! (`startrack_core::sequencer::Link`): what lets the DMA repeat each segment of the clock
//! program itself, so the CPU writes one 40-byte node per program step instead of one word per
//! tick.
//!
//! A node is the image of a channel's registers `CxTCR` to `CxMDR` (RM0433, MDMA linked-list
//! mode), which the MDMA loads from `CxLAR` at the end of the node before. Each node here:
//! one hardware request moves one 32-bit word (a buffer of 4 bytes, `TRGM` = 00) from the
//! chain's word table (source incremented) into the clock port's BSRR (destination fixed);
//! the block is the link's words, repeated `blocks` times with the source stepped back by the
//! block after each repeat (`BRSUM` = subtract, `SUV` = the block's bytes); then the write
//! of `CxMDR` to `CxMAR` after each request clears the request's flag. The request is the
//! transfer-complete flag of the DMA1 stream that TIM6 paces ([`NodeConfig::trigger`]), so
//! each tick moves one word, as the word ring's stream did.
//!
//! Pure bit-building (no peripheral access), so the Cortex-M7 cost bench includes this file
//! and times exactly what the board runs. The field positions are RM0433's (the same as
//! `stm32-metapac`'s `mdma_v1`); marked "check" where the behaviour is an assumption.
//! Cost: ~15 instructions a node.

use startrack_core::sequencer::Link;

/// One linked-list node: `CxTCR, CxBNDTR, CxSAR, CxDAR, CxBRUR, CxLAR, CxTBR`, a reserved
/// word, `CxMAR, CxMDR` (40 bytes; the MDMA wants the link address 8-byte aligned).
#[repr(C, align(8))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Node {
    /// Transfer configuration.
    pub ctcr: u32,
    /// Block bytes, repeat count and the repeat's address update modes.
    pub cbndtr: u32,
    /// Source address.
    pub csar: u32,
    /// Destination address.
    pub cdar: u32,
    /// Block repeat address update values.
    pub cbrur: u32,
    /// The next node's address (0: the list ends after this node).
    pub clar: u32,
    /// Trigger and bus selection.
    pub ctbr: u32,
    /// Reserved (loaded, unused).
    pub reserved: u32,
    /// Mask address: written with `cmdr` after each request.
    pub cmar: u32,
    /// Mask data.
    pub cmdr: u32,
}

impl Node {
    /// A zeroed node (in `.bss`).
    pub const ZERO: Self = Self {
        ctcr: 0,
        cbndtr: 0,
        csar: 0,
        cdar: 0,
        cbrur: 0,
        clar: 0,
        ctbr: 0,
        reserved: 0,
        cmar: 0,
        cmdr: 0,
    };
}

/// `CxTCR`: source incremented by words (SINC = 10, SSIZE = SINCOS = word), destination
/// fixed (DINC = 00, DSIZE = DINCOS = word), single beats, a buffer of 4 bytes (TLEN = 3),
/// each request one buffer (TRGM = 00), hardware requests (SWRM = 0).
pub const CTCR: u32 = 0b10 // SINC: increment
    | (0b10 << 4) // SSIZE: word
    | (0b10 << 6) // DSIZE: word
    | (0b10 << 8) // SINCOS: word
    | (0b10 << 10) // DINCOS: word
    | (3 << 18); // TLEN: 4 bytes a buffer (TRGM = 00 at bits 28-29)

/// `CxBNDTR.BRSUM`: the source address is decremented by `SUV` after each block.
const BRSUM_SUBTRACT: u32 = 1 << 18;

/// `CxTBR.SBUS` and `DBUS` are 0 (the AXI system bus: the table in AXI SRAM, the GPIO port
/// behind the D1-to-D3 bridge); `TSEL` is the request number.
const TSEL_MASK: u32 = 0x3f;

/// What every node of a frame shares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeConfig {
    /// Address of the chain's word table (word 0 of `Chain::words`).
    pub table: u32,
    /// The clock port's BSRR.
    pub bsrr: u32,
    /// The MDMA request: DMA1 stream `n`'s transfer-complete flag is request `n`
    /// (RM0433's MDMA request table: check).
    pub trigger: u8,
    /// Where the request's flag is cleared (DMA1's `LIFCR` or `HIFCR`).
    pub mask_addr: u32,
    /// The clear bit of the stream's transfer-complete flag there.
    pub mask_data: u32,
}

impl NodeConfig {
    /// The node that plays `link`, followed by the node at `next` (0: none).
    pub const fn node(&self, link: &Link, next: u32) -> Node {
        let bytes = link.len_words.wrapping_mul(4);
        Node {
            ctcr: CTCR,
            cbndtr: (bytes & 0x1_ffff)
                | BRSUM_SUBTRACT
                | ((link.blocks.saturating_sub(1) & 0xfff) << 20),
            csar: self.table.wrapping_add(link.first_word.wrapping_mul(4)),
            cdar: self.bsrr,
            cbrur: bytes & 0xffff,
            clar: next,
            ctbr: self.trigger as u32 & TSEL_MASK,
            reserved: 0,
            cmar: self.mask_addr,
            cmdr: self.mask_data,
        }
    }
}

/// What the ring needs of the MDMA channel: its state, read from its registers on the
/// board, from a model on the host.
pub trait MdmaChannel {
    /// The channel is enabled (it has nodes left to play).
    fn enabled(&self) -> bool;
    /// `CxLAR`: the link address of the node in play (0: the list ends with it).
    fn link_address(&self) -> u32;
}

/// The outcome of [`NodeRing::append`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Appended {
    /// Nodes written.
    pub nodes: usize,
    /// The list had ended, or ends with the node in play, before the new nodes were linked
    /// to it: once the channel is disabled it must be started at `first_slot`'s node.
    pub restart: bool,
    /// The ring slot of the first node written.
    pub first_slot: usize,
}

/// The bookkeeping of a ring of `N` nodes the CPU writes ahead of the MDMA: which node the
/// MDMA plays, where the next nodes go, and the linking of each batch to the last node
/// written (which ends the list until then). No hardware access: the caller gives the
/// channel's state ([`MdmaChannel`]) and the ring's memory, and starts the channel when
/// [`Appended::restart`] says so. Cost: O(nodes written) per append, O(1) otherwise.
#[derive(Clone, Debug)]
pub struct NodeRing<const N: usize> {
    /// Nodes written since the start.
    written: u64,
    /// Ticks linked since the start.
    queued: u64,
    /// The tick each slot's node starts at.
    starts: [u64; N],
    /// The slot of the last node written (its link address is 0).
    last: Option<usize>,
}

impl<const N: usize> NodeRing<N> {
    /// An empty ring.
    pub const fn new() -> Self {
        Self {
            written: 0,
            queued: 0,
            starts: [0; N],
            last: None,
        }
    }

    /// Nodes written since the start.
    pub const fn written(&self) -> u64 {
        self.written
    }

    /// Ticks linked since the start.
    pub const fn queued(&self) -> u64 {
        self.queued
    }

    /// The index (since the start) of the node the MDMA plays, or [`Self::written`] when it
    /// has played every node; `base` is the ring's address.
    pub fn progress(&self, ch: &impl MdmaChannel, base: u32) -> u64 {
        if !ch.enabled() {
            return self.written;
        }
        let lar = ch.link_address();
        if lar == 0 || self.written == 0 {
            return self.written.saturating_sub(1);
        }
        let size = core::mem::size_of::<Node>() as u32;
        let next = (lar.wrapping_sub(base) / size) as usize % N;
        let cur = (next + N - 1) % N;
        // The one index of that slot among the last N written.
        let newest = (self.written - 1) as usize % N;
        let back = (newest + N - cur) % N;
        self.written.saturating_sub(1 + back as u64)
    }

    /// Ticks played: the start of the node in play (all of them when the list has ended).
    pub fn played(&self, ch: &impl MdmaChannel, base: u32) -> u64 {
        let cur = self.progress(ch, base);
        if cur >= self.written {
            return self.queued;
        }
        self.starts
            .get(cur as usize % N)
            .copied()
            .unwrap_or(self.queued)
    }

    /// Writes up to `batch` nodes of `links` into `nodes` (the ring, at address `base`)
    /// while fewer than `ahead_ticks` are linked ahead of the node in play, never over a
    /// node the MDMA has not loaded; the last one written ends the list. Then links them
    /// to the last node written before (`fence` between the writes and the link, and
    /// after it: a `dsb` on the board). A batch that finds the list ended, or ending with
    /// the node in play, asks for a restart.
    #[allow(
        clippy::too_many_arguments,
        reason = "the ring's whole context, once a batch"
    )]
    pub fn append(
        &mut self,
        nodes: &mut [Node; N],
        base: u32,
        ch: &impl MdmaChannel,
        links: &mut impl Iterator<Item = Link>,
        config: &NodeConfig,
        batch: usize,
        ahead_ticks: u64,
        fence: impl Fn(),
    ) -> Appended {
        let size = core::mem::size_of::<Node>() as u32;
        let addr = |slot: usize| base.wrapping_add(((slot % N) as u32).wrapping_mul(size));
        let cur = self.progress(ch, base);
        let played = self.played(ch, base);
        // A slot may be rewritten once the MDMA has loaded the node after it.
        let limit = cur + N as u64 - 1;
        let first = self.written;
        let first_slot = first as usize % N;
        let mut i = first;
        let mut slot = None;
        while i < limit
            && i - first < batch as u64
            && self.queued.saturating_sub(played) < ahead_ticks
        {
            let Some(link) = links.next() else { break };
            let s = i as usize % N;
            if let Some(n) = nodes.get_mut(s) {
                // SAFETY: `n` is a valid, aligned node (volatile: the MDMA reads it).
                unsafe { core::ptr::write_volatile(n, config.node(&link, addr(s + 1))) };
            }
            if let Some(start) = self.starts.get_mut(s) {
                *start = self.queued;
            }
            self.queued += link.ticks();
            slot = Some(s);
            i += 1;
        }
        let Some(last) = slot else {
            return Appended {
                nodes: 0,
                restart: false,
                first_slot,
            };
        };
        if let Some(n) = nodes.get_mut(last) {
            // SAFETY: as above.
            unsafe { core::ptr::write_volatile(&raw mut n.clar, 0) };
        }
        fence();
        let mut restart = true;
        if let Some(prev) = self.last
            && ch.enabled()
        {
            if let Some(n) = nodes.get_mut(prev) {
                // SAFETY: as above; one aligned 32-bit store, which the MDMA reads whole.
                unsafe { core::ptr::write_volatile(&raw mut n.clar, addr(first_slot)) };
            }
            fence();
            // Linked in time unless the MDMA had already loaded the old last node (its
            // link address, now in CxLAR, is 0) or had finished it.
            restart = ch.link_address() == 0 || !ch.enabled();
        }
        self.written = i;
        self.last = Some(last);
        Appended {
            nodes: (i - first) as usize,
            restart,
            first_slot,
        }
    }
}

impl<const N: usize> Default for NodeRing<N> {
    fn default() -> Self {
        Self::new()
    }
}
