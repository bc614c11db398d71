//! The program as a DMA's linked list ([`Chain`]): what the board's DMA descriptors are made
//! from, so that a DMA repeats each segment itself and the CPU does not write every tick's
//! word.
//!
//! A [`Link`] is one descriptor: play `len_words` words of the chain's word table from
//! `first_word`, `blocks` times in a row. On the STM32H743 it is one node of the MDMA's
//! linked list: a block of `4 x len_words` bytes, one word per request, repeated `blocks`
//! times with the source address stepped back by the block after each (`CxBNDTR.BRC` =
//! `blocks - 1`, `CxBRUR.SUV` = the block's bytes, subtracted); at most [`MAX_BLOCKS`]
//! repeats and [`MAX_BLOCK_WORDS`] words a node (check both against RM0433).
//!
//! The chain's word table is the program's segments followed by a run of rest words
//! ([`Chain::new`]'s `rest_run`): the exposure padding is the one segment repeated millions
//! of times (an `Idle` tick repeated 20 M times for a second at 50 ns), so it is played as
//! blocks of that run (a run of 256 words makes a node of up to 1 M ticks, 52 ms) rather
//! than as thousands of one-word nodes. Every other step is one link, or one per
//! [`MAX_BLOCKS`] repeats.
//!
//! [`Chain::links`] yields the links in play order from the program's steps without a
//! buffer (the firmware writes them into a ring of descriptors as the DMA plays), and
//! [`Chain::ticks`] walks them as the DMA does, word by word, so the host can prove that the
//! links play exactly the program ([`super::Program::ticks`], the word feed's output).
//!
//! Cost: [`Chain::new`] copies the program's words and writes the run, O(words), ~1,300
//! words for the board's plans; each link is O(1) to make. A tracking frame of 30 windows
//! at 1 MHz is 1,681 links for 593,541 ticks (host test `sequencer_chain`); its table and
//! every link made into an MDMA node take 0.21 M instructions on QEMU's M7 (`cargo m7-bench`,
//! `sequencer_chain_nodes`), against 3.57 M for the word feed ([`super::Cursor`]).

use super::compile::{Program, SEGMENTS, SegmentId, Step};

/// Most repeats of a block in one link (the MDMA's 12-bit `CxBNDTR.BRC` counts 0 to 4095
/// repeats after the first: check against RM0433).
pub const MAX_BLOCKS: u32 = 4096;

/// Most words of a block (the MDMA's `CxBNDTR.BNDT` counts up to 65,535 bytes; and
/// `CxBRUR.SUV`, which steps the source back by the block, is 16 bits: check against RM0433).
pub const MAX_BLOCK_WORDS: u32 = 16_383;

/// One descriptor: `len_words` words from `first_word` of the chain's table, `blocks` times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Link {
    /// Index of the block's first word in [`Chain::words`].
    pub first_word: u32,
    /// Words of the block, 1 to [`MAX_BLOCK_WORDS`].
    pub len_words: u32,
    /// Plays of the block, 1 to [`MAX_BLOCKS`].
    pub blocks: u32,
}

impl Link {
    /// Ticks this link plays.
    pub const fn ticks(&self) -> u64 {
        self.len_words as u64 * self.blocks as u64
    }
}

/// Why a program cannot be made into a chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ChainError {
    /// The word buffer is too small.
    Words {
        /// Words the chain's table needs.
        needed: usize,
    },
    /// A segment is longer than a block may be.
    Block {
        /// The segment's words.
        len_words: usize,
    },
    /// The program has no rest word to make the run of (no `Idle` segment).
    NoRest,
}

impl core::fmt::Display for ChainError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Words { needed } => write!(f, "chain: word table needs {needed} words"),
            Self::Block { len_words } => {
                write!(f, "chain: a segment of {len_words} words exceeds a block")
            }
            Self::NoRest => f.write_str("chain: the program has no rest word"),
        }
    }
}

impl core::error::Error for ChainError {}

/// A program as linked descriptors: its word table (in a caller's buffer, which the DMA
/// must reach) and its steps.
#[derive(Clone, Copy, Debug)]
pub struct Chain<'w, 'p> {
    words: &'w [u32],
    steps: &'p [Step],
    spans: [(u32, u32); SEGMENTS],
    /// The rest run: (first word, words).
    run: (u32, u32),
}

impl<'w, 'p> Chain<'w, 'p> {
    /// Copies `program`'s words into `out` followed by `rest_run` (at most
    /// [`MAX_BLOCK_WORDS`]) copies of its rest word; with a run of 0 or 1 the exposure
    /// padding is linked as the one-word `Idle` segment, [`MAX_BLOCKS`] ticks a link. The
    /// links read the steps from the program's own buffer.
    pub fn new<'x>(
        program: &Program<'x, 'p>,
        rest_run: u32,
        out: &'w mut [u32],
    ) -> Result<Self, ChainError> {
        let words = program.words();
        let run = rest_run.min(MAX_BLOCK_WORDS) as usize;
        let needed = words.len() + run;
        if needed > out.len() {
            return Err(ChainError::Words { needed });
        }
        if let Some(id) = SegmentId::ALL
            .iter()
            .find(|&&id| program.segment(id).len() > MAX_BLOCK_WORDS as usize)
        {
            return Err(ChainError::Block {
                len_words: program.segment(*id).len(),
            });
        }
        let rest = *program
            .segment(SegmentId::Idle)
            .first()
            .ok_or(ChainError::NoRest)?;
        let (table, tail) = out
            .split_at_mut_checked(words.len())
            .ok_or(ChainError::Words { needed })?;
        table.copy_from_slice(words);
        for w in tail.iter_mut().take(run) {
            *w = rest;
        }
        let out: &'w [u32] = out;
        Ok(Self {
            words: out.get(..needed).unwrap_or(&[]),
            steps: program.steps(),
            spans: program.spans(),
            run: (
                u32::try_from(words.len()).map_err(|_| ChainError::Words { needed })?,
                run as u32,
            ),
        })
    }

    /// The word table the links index (the program's words, then the rest run).
    pub const fn words(&self) -> &'w [u32] {
        self.words
    }

    /// The links in play order.
    pub fn links(&self) -> Links<'p> {
        Links {
            steps: self.steps,
            spans: self.spans,
            idle: self
                .spans
                .get(SegmentId::Idle as usize)
                .copied()
                .unwrap_or((0, 0)),
            run: self.run,
            step: 0,
            left: 0,
        }
    }

    /// Every word the links play, in order, as the DMA reads them (block by block).
    pub fn ticks(&self) -> impl Iterator<Item = u32> + '_ {
        let words = self.words;
        self.links().flat_map(move |l| {
            let block = words
                .get(l.first_word as usize..(l.first_word + l.len_words) as usize)
                .unwrap_or(&[]);
            core::iter::repeat_n(block, l.blocks as usize)
                .flatten()
                .copied()
        })
    }
}

/// The links of a [`Chain`], made from its steps as they are asked for: the iterator is the
/// whole state of a partly played chain (a step index and the repeats left of it).
#[derive(Clone, Debug)]
pub struct Links<'p> {
    steps: &'p [Step],
    spans: [(u32, u32); SEGMENTS],
    idle: (u32, u32),
    run: (u32, u32),
    step: usize,
    /// Repeats of the current step not yet linked (0: the step has not started).
    left: u32,
}

impl Iterator for Links<'_> {
    type Item = Link;

    fn next(&mut self) -> Option<Link> {
        loop {
            let step = self.steps.get(self.step)?;
            let (first, len) = self
                .spans
                .get(step.segment as usize)
                .copied()
                .unwrap_or((0, 0));
            if self.left == 0 {
                self.left = step.repeat;
            }
            if len == 0 || self.left == 0 {
                self.step += 1;
                self.left = 0;
                continue;
            }
            // The rest run: one-word rest ticks as blocks of the run, the remainder as a
            // shorter block of it.
            let link = if (first, len) == self.idle && len == 1 && self.run.1 > 1 {
                let per = self.run.1;
                let whole = self.left / per;
                if whole > 0 {
                    let blocks = whole.min(MAX_BLOCKS);
                    self.left -= blocks * per;
                    Link {
                        first_word: self.run.0,
                        len_words: per,
                        blocks,
                    }
                } else {
                    let n = self.left;
                    self.left = 0;
                    Link {
                        first_word: self.run.0,
                        len_words: n,
                        blocks: 1,
                    }
                }
            } else {
                let blocks = self.left.min(MAX_BLOCKS);
                self.left -= blocks;
                Link {
                    first_word: first,
                    len_words: len,
                    blocks,
                }
            };
            if self.left == 0 {
                self.step += 1;
            }
            return Some(link);
        }
    }
}
