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
