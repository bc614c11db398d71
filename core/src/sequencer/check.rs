//! The checker of compiled words ([`check_program`]): every state of each three-phase group
//! has one or two phases high, every change of a group shares a high phase with the state
//! before (the overlap that keeps a packet whole), and no sample is taken while the reset
//! gate is high. It looks at the words the DMA will write, within each segment and across
//! each join of the program (a segment repeated, one step to the next, the frame to the
//! next), so a wrong pin map or a hand-edited table fails here before a CCD sees it.
//! Cost: O(words + steps).

use super::compile::{Program, SegmentId};
use super::lines::{Line, LineSet, PinMap};

/// What a word sequence breaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SequenceError {
    /// A group has no phase or all three phases high (no well, or no barrier).
    Phases {
        /// First line of the group.
        group: Line,
        /// Index in the table's words.
        word: usize,
    },
    /// A group changes without a phase high in both states: the packet is lost.
    NoOverlap {
        /// First line of the group.
        group: Line,
        /// Index in the table's words of the later state, or for a change across a join of
        /// the program, the index of the step whose last word is the earlier state.
        word: usize,
    },
    /// CONVST with the reset gate high: the sample reads the reset drain.
    SampleInReset {
        /// Index in the table's words.
        word: usize,
    },
}

impl core::fmt::Display for SequenceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Phases { group, word } => {
                write!(
                    f,
                    "sequence: {} group not 1-2 phases high at word {word}",
                    group.name()
                )
            }
            Self::NoOverlap { group, word } => {
                write!(
                    f,
                    "sequence: {} group changes without overlap at word {word}",
                    group.name()
                )
            }
            Self::SampleInReset { word } => {
                write!(
                    f,
                    "sequence: CONVST with the reset gate high at word {word}"
                )
            }
        }
    }
}

impl core::error::Error for SequenceError {}

const GROUPS: [[Line; 3]; 4] = [Line::IMAGE, Line::STORE, Line::REG_LEFT, Line::REG_RIGHT];

fn check_state(s: LineSet, word: usize) -> Result<(), SequenceError> {
    for g in GROUPS {
        let n = s.phases_of(g).0.count_ones();
        if n == 0 || n == 3 {
            return Err(SequenceError::Phases { group: g[0], word });
        }
    }
    if s.is_high(Line::Convst) && s.is_high(Line::Rg) {
        return Err(SequenceError::SampleInReset { word });
    }
    Ok(())
}

fn check_change(a: LineSet, b: LineSet, word: usize) -> Result<(), SequenceError> {
    for g in GROUPS {
        let (pa, pb) = (a.phases_of(g), b.phases_of(g));
        if pa != pb && pa.0 & pb.0 == 0 {
            return Err(SequenceError::NoOverlap { group: g[0], word });
        }
    }
    Ok(())
}

/// Checks every word of `program` as the port wired by `pins` would show it.
pub fn check_program(program: &Program<'_, '_>, pins: &PinMap) -> Result<(), SequenceError> {
    let state = |w: u32| pins.lines_of_port(PinMap::apply(0, w));
    let mut base = 0;
    for id in SegmentId::ALL {
        let seg = program.segment(id);
        let mut prev: Option<LineSet> = None;
        for (i, &w) in seg.iter().enumerate() {
            let s = state(w);
            check_state(s, base + i)?;
            if let Some(p) = prev {
                check_change(p, s, base + i)?;
            }
            prev = Some(s);
        }
        base += seg.len();
    }
    // Joins: the last word of each step to the first of the next (and of itself when
    // repeated), and the frame's end to its start.
    let steps = program.steps();
    let first_of = |i: usize| {
        steps
            .get(i)
            .and_then(|s| program.segment(s.segment).first())
            .map(|&w| state(w))
    };
    for (i, s) in steps.iter().enumerate() {
        let seg = program.segment(s.segment);
        let (Some(&last), Some(&first)) = (seg.last(), seg.first()) else {
            continue;
        };
        let (last, first) = (state(last), state(first));
        if s.repeat > 1 {
            check_change(last, first, i)?;
        }
        let next = first_of(i + 1).or_else(|| first_of(0));
        if let Some(n) = next {
            check_change(last, n, i)?;
        }
    }
    Ok(())
}
