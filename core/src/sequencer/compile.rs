//! The compiler: a [`ReadoutPlan`] and its [`Ticks`] into BSRR word segments and a program of
//! `(segment, repeat)` steps, both in caller-provided buffers ([`compile`]).
//!
//! Seven segments, each a short run of ticks (one BSRR word each):
//!
//! | segment | what it does | ticks |
//! |---|---|---|
//! | `FrameTransfer` | image and store one row (P12 -> P23 -> P31 -> P12), dump gate high | 3 `ft_state` |
//! | `LineTransfer` | store one row into the register, image held at P12 (integrating) | 3 `line_state` |
//! | `RowDump` | store one row with the dump gate high (the row is drained) | 3 `dump_row_state` |
//! | `ReadPixel` | `binning` register shifts into the summing well (reset gate high), reset settle, CONVST (reset level), summing well low, signal settle, CONVST (signal level) | `read_px_ticks(b)` |
//! | `SkipPixel` | one register shift, summing well low, reset gate high (charge drained at the node) | 3 `skip_state` |
//! | `RegisterDump` | dump gate high: the rest of the register is drained | `dump_register` |
//! | `Idle` | the rest state (exposure padding) | 1 |
//!
//! A frame's program: `FrameTransfer` x store rows (the exposure ends, the next begins), then
//! per row group either `RowDump` x rows (runs of groups not read) or `LineTransfer` x
//! binning, then per digitised run `SkipPixel` x gap elements and `ReadPixel` x run, and
//! `RegisterDump` when the run does not reach the register's end; last `Idle` x the ticks
//! that make the exposure. Rows after the last read group are not clocked: the next frame
//! transfer flushes them through the register with the dump gate high.
//!
//! Each segment's states last its own number of ticks ([`Ticks`]: at 1 MHz on the CCD47-20's
//! limits a 50 ns tick, a skipped element 150 ns, a read pixel 1 us, a dumped row 3 us, a line
//! transfer 40 us). Every phase change of a three-phase group shares a high phase with the
//! state before (the overlap); [`super::check`] verifies it on the words. Cost: O(words +
//! steps) to write; the segments are ~1,100 words at 1 MHz, a full frame ~2,100 steps, a
//! tracking frame with 30 windows ~1,700.

use super::lines::{Line, LineSet, Phases, PinMap};
use super::plan::{ReadoutPlan, ShiftRuns};
use super::timing::Ticks;

/// A segment of the word table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum SegmentId {
    /// Image and store one row, dump gate high.
    FrameTransfer = 0,
    /// Store one row into the register.
    LineTransfer,
    /// Store one row, dumped.
    RowDump,
    /// One (binned) pixel digitised with its two CDS samples.
    ReadPixel,
    /// One register element shifted out unsampled.
    SkipPixel,
    /// The register drained.
    RegisterDump,
    /// The rest state.
    Idle,
}

/// Number of segments.
pub(crate) const SEGMENTS: usize = 7;

impl SegmentId {
    /// Every segment, in table order.
    pub const ALL: [Self; SEGMENTS] = [
        Self::FrameTransfer,
        Self::LineTransfer,
        Self::RowDump,
        Self::ReadPixel,
        Self::SkipPixel,
        Self::RegisterDump,
        Self::Idle,
    ];
}

/// One program step: play `segment` `repeat` times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Step {
    /// Which segment.
    pub segment: SegmentId,
    /// How many times in a row (at least 1).
    pub repeat: u32,
}

impl Step {
    /// A placeholder for step buffers (all zero bits, so a static buffer of them stays in
    /// `.bss`).
    pub const EMPTY: Self = Self {
        segment: SegmentId::FrameTransfer,
        repeat: 0,
    };
}

/// Why a plan could not be compiled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CompileError {
    /// The word buffer is too small.
    Words {
        /// Words the segments need.
        needed: usize,
    },
    /// The step buffer is too small.
    Steps {
        /// Steps the program needs.
        needed: usize,
    },
    /// The pin map is invalid.
    Pins(super::lines::PinMapError),
    /// A count overflows u32 (an exposure of more than ~4e9 ticks).
    Overflow,
}

impl core::fmt::Display for CompileError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Words { needed } => write!(f, "sequencer: word table needs {needed} words"),
            Self::Steps { needed } => write!(f, "sequencer: program needs {needed} steps"),
            Self::Pins(e) => write!(f, "sequencer: {e}"),
            Self::Overflow => f.write_str("sequencer: a tick count overflows u32"),
        }
    }
}

impl core::error::Error for CompileError {}

/// A compiled frame: the word table, the segments in it, and the program.
#[derive(Clone, Copy, Debug)]
pub struct Program<'w, 's> {
    words: &'w [u32],
    spans: [(u32, u32); SEGMENTS],
    steps: &'s [Step],
    tick_ps: u32,
    outputs: u8,
    binning: u16,
    exposure_us: u32,
}

impl<'w, 's> Program<'w, 's> {
    /// All segments' words, back to back.
    pub const fn words(&self) -> &'w [u32] {
        self.words
    }

    /// The words of one segment.
    pub fn segment(&self, id: SegmentId) -> &'w [u32] {
        let (start, len) = self.spans.get(id as usize).copied().unwrap_or((0, 0));
        self.words
            .get(start as usize..(start + len) as usize)
            .unwrap_or(&[])
    }

    /// The steps.
    pub const fn steps(&self) -> &'s [Step] {
        self.steps
    }

    /// Where each segment lies in [`Self::words`]: (first word, words), indexed by
    /// `SegmentId as usize`.
    pub(crate) const fn spans(&self) -> [(u32, u32); SEGMENTS] {
        self.spans
    }

    /// The tick, ps.
    pub const fn tick_ps(&self) -> u32 {
        self.tick_ps
    }

    /// Outputs digitised by each CONVST.
    pub(crate) const fn outputs(&self) -> u8 {
        self.outputs
    }

    /// The binning factor.
    pub(crate) const fn binning(&self) -> u16 {
        self.binning
    }

    /// The same program over a copy of its words (in DMA-reachable RAM, or an edited copy to
    /// check); `None` when the lengths differ.
    pub fn relocated<'x>(&self, words: &'x [u32]) -> Option<Program<'x, 's>> {
        (words.len() == self.words.len()).then_some(Program {
            words,
            spans: self.spans,
            steps: self.steps,
            tick_ps: self.tick_ps,
            outputs: self.outputs,
            binning: self.binning,
            exposure_us: self.exposure_us,
        })
    }

    /// The program without its borrows ([`ProgramParts`]): what a firmware keeps to play
    /// tables it compiled in one task from another, the buffers passed by ownership.
    pub const fn parts(&self) -> ProgramParts {
        ProgramParts {
            words_len: self.words.len(),
            spans: self.spans,
            steps_len: self.steps.len(),
            tick_ps: self.tick_ps,
            outputs: self.outputs,
            binning: self.binning,
            exposure_us: self.exposure_us,
        }
    }

    /// Every word of the frame in play order (what the DMA writes), without allocating.
    pub fn ticks(&self) -> impl Iterator<Item = u32> + '_ {
        self.steps.iter().flat_map(move |s| {
            core::iter::repeat_n(self.segment(s.segment), s.repeat as usize)
                .flatten()
                .copied()
        })
    }
}

/// A compiled program's shape without its buffers ([`Program::parts`]); [`Self::view`]
/// puts it back over the word and step buffers it was compiled into. Cost: 80 bytes, `Copy`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProgramParts {
    words_len: usize,
    spans: [(u32, u32); SEGMENTS],
    steps_len: usize,
    tick_ps: u32,
    outputs: u8,
    binning: u16,
    exposure_us: u32,
}

impl ProgramParts {
    /// The program over `words` and `steps` (the buffers given to [`compile`], unchanged
    /// since); `None` when they are shorter than the program.
    pub fn view<'w, 's>(&self, words: &'w [u32], steps: &'s [Step]) -> Option<Program<'w, 's>> {
        Some(Program {
            words: words.get(..self.words_len)?,
            spans: self.spans,
            steps: steps.get(..self.steps_len)?,
            tick_ps: self.tick_ps,
            outputs: self.outputs,
            binning: self.binning,
            exposure_us: self.exposure_us,
        })
    }
}

/// The rest state with two outputs: image and store at P12 (phase 3 low: the barrier
/// between sections), register at P31, reset gate high, everything else low.
pub const REST: LineSet = rest(2);

/// The rest state for `outputs`. With one output the right half rests at P12 and shifts
/// backward ([`Phases::BACKWARD_FROM_P12`]) so that its packets cross the split into the
/// left half on the same tick as the left half moves towards its output (the phase relation
/// at the split: check against datasheet).
pub(crate) const fn rest(outputs: u8) -> LineSet {
    let right = if outputs == 1 {
        Phases::P12
    } else {
        Phases::P31
    };
    LineSet::EMPTY
        .phases(Line::IMAGE, Phases::P12)
        .phases(Line::STORE, Phases::P12)
        .phases(Line::REG_LEFT, Phases::P31)
        .phases(Line::REG_RIGHT, right)
        .with(Line::Rg)
}

struct Writer<'b, T> {
    buf: &'b mut [T],
    len: usize,
}

impl<T: Copy> Writer<'_, T> {
    fn push(&mut self, v: T) {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = v;
        }
        self.len += 1;
    }
    fn fits(&self) -> bool {
        self.len <= self.buf.len()
    }
}

/// One register shift's three states (the right half reversed with one output, so the whole
/// line leaves through the left amplifier).
fn register_shift(base: LineSet, outputs: u8) -> [LineSet; 3] {
    let right = if outputs == 2 {
        Phases::FORWARD_FROM_P31
    } else {
        Phases::BACKWARD_FROM_P12
    };
    let mut states = [base; 3];
    for (i, s) in states.iter_mut().enumerate() {
        let l = Phases::FORWARD_FROM_P31
            .get(i)
            .copied()
            .unwrap_or(Phases::P31);
        let r = right.get(i).copied().unwrap_or(Phases::P31);
        *s = s.phases(Line::REG_LEFT, l).phases(Line::REG_RIGHT, r);
    }
    states
}

fn segment_words(
    id: SegmentId,
    t: &Ticks,
    pins: &PinMap,
    outputs: u8,
    binning: u16,
    w: &mut Writer<'_, u32>,
) {
    let rest = rest(outputs);
    let mut emit = |state: LineSet, n: u32| {
        let word = pins.bsrr(state);
        for _ in 0..n {
            w.push(word);
        }
    };
    match id {
        SegmentId::FrameTransfer => {
            for p in Phases::FORWARD_FROM_P12 {
                let s = rest
                    .phases(Line::IMAGE, p)
                    .phases(Line::STORE, p)
                    .with(Line::Dg);
                emit(s, t.ft_state);
            }
        }
        SegmentId::LineTransfer | SegmentId::RowDump => {
            let (dg, n) = if id == SegmentId::RowDump {
                (true, t.dump_row_state)
            } else {
                (false, t.line_state)
            };
            for p in Phases::FORWARD_FROM_P12 {
                emit(rest.phases(Line::STORE, p).set(Line::Dg, dg), n);
            }
        }
        SegmentId::ReadPixel => {
            let shifting = rest.with(Line::Sw);
            for _ in 0..binning {
                for s in register_shift(shifting, outputs) {
                    emit(s, t.serial_state);
                }
            }
            let settle = shifting.without(Line::Rg);
            emit(settle, t.reset_settle);
            emit(settle.with(Line::Convst), 1);
            let signal = settle.without(Line::Sw);
            emit(signal, t.signal_settle);
            emit(signal.with(Line::Convst), 1);
        }
        SegmentId::SkipPixel => {
            for s in register_shift(rest, outputs) {
                emit(s, t.skip_state);
            }
        }
        SegmentId::RegisterDump => emit(rest.with(Line::Dg), t.dump_register),
        SegmentId::Idle => emit(rest, 1),
    }
}

/// Ticks of one play of each segment (without writing words).
pub(crate) fn segment_ticks(id: SegmentId, t: &Ticks, binning: u16) -> u32 {
    match id {
        SegmentId::FrameTransfer => 3 * t.ft_state,
        SegmentId::LineTransfer => 3 * t.line_state,
        SegmentId::RowDump => 3 * t.dump_row_state,
        SegmentId::ReadPixel => t.read_px_ticks(u32::from(binning)),
        SegmentId::SkipPixel => 3 * t.skip_state,
        SegmentId::RegisterDump => t.dump_register,
        SegmentId::Idle => 1,
    }
}

/// Compiles `plan` with `ticks` for the port wired as `pins` into `words` (the segments) and
/// `steps` (the program). On a too-small buffer the error says how much is needed.
pub fn compile<'w, 's>(
    plan: &ReadoutPlan<'_>,
    ticks: &Ticks,
    pins: &PinMap,
    words: &'w mut [u32],
    steps: &'s mut [Step],
) -> Result<Program<'w, 's>, CompileError> {
    pins.validate().map_err(CompileError::Pins)?;
    let outputs = plan.geometry().outputs;
    let b = plan.binning().factor();
    let mut spans = [(0u32, 0u32); SEGMENTS];
    let mut w = Writer { buf: words, len: 0 };
    for (id, span) in SegmentId::ALL.iter().zip(spans.iter_mut()) {
        let start = w.len;
        segment_words(*id, ticks, pins, outputs, b, &mut w);
        let len = w.len - start;
        *span = (
            u32::try_from(start).map_err(|_| CompileError::Overflow)?,
            u32::try_from(len).map_err(|_| CompileError::Overflow)?,
        );
    }
    if !w.fits() {
        return Err(CompileError::Words { needed: w.len });
    }
    let words_len = w.len;

    let mut p = Writer { buf: steps, len: 0 };
    let mut readout_ticks: u64 = 0;
    let mut step = |p: &mut Writer<'_, Step>, segment: SegmentId, repeat: u32| {
        if repeat > 0 {
            readout_ticks += u64::from(segment_ticks(segment, ticks, b)) * u64::from(repeat);
            p.push(Step { segment, repeat });
        }
    };
    step(
        &mut p,
        SegmentId::FrameTransfer,
        u32::from(plan.frame_transfer_rows()),
    );
    let n = plan.shifts_per_line();
    let mut runs = ShiftRuns::new();
    let mut pending_dump: u32 = 0;
    for g in 0..plan.row_groups() {
        if !plan.group_read(g) {
            pending_dump += u32::from(b);
            continue;
        }
        step(&mut p, SegmentId::RowDump, pending_dump);
        pending_dump = 0;
        step(&mut p, SegmentId::LineTransfer, u32::from(b));
        plan.shift_runs(g, &mut runs);
        let mut pos = 0u16;
        for &(s, e) in runs.iter() {
            step(
                &mut p,
                SegmentId::SkipPixel,
                u32::from(s.saturating_sub(pos)) * u32::from(b),
            );
            step(
                &mut p,
                SegmentId::ReadPixel,
                u32::from(e.saturating_sub(s.max(pos))),
            );
            pos = pos.max(e);
        }
        if pos < n {
            step(&mut p, SegmentId::RegisterDump, 1);
        }
    }
    // Exposure padding: the image integrates from the end of the frame transfer to the start
    // of the next one.
    let ft_ticks = u64::from(segment_ticks(SegmentId::FrameTransfer, ticks, b))
        * u64::from(plan.frame_transfer_rows());
    let exposure_ticks =
        u64::from(plan.exposure_us()) * 1_000_000 / u64::from(ticks.tick_ps.max(1));
    let integrating = readout_ticks - ft_ticks;
    if exposure_ticks > integrating {
        let pad =
            u32::try_from(exposure_ticks - integrating).map_err(|_| CompileError::Overflow)?;
        p.push(Step {
            segment: SegmentId::Idle,
            repeat: pad,
        });
    }
    if !p.fits() {
        return Err(CompileError::Steps { needed: p.len });
    }
    let steps_len = p.len;
    let words: &'w [u32] = w.buf;
    let steps: &'s [Step] = p.buf;
    Ok(Program {
        words: words.get(..words_len).unwrap_or(&[]),
        spans,
        steps: steps.get(..steps_len).unwrap_or(&[]),
        tick_ps: ticks.tick_ps,
        outputs,
        binning: b,
        exposure_us: plan.exposure_us(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::ReadoutGeometry;
    use crate::readout::ReadoutRequest;
    use crate::sequencer::{Binning, Limits, Timing};

    #[test]
    fn parts_view_gives_back_the_same_program() {
        let plan = ReadoutPlan::new(
            ReadoutGeometry::CCD47_20_DUAL,
            ReadoutRequest::FullFrame,
            Binning::X1,
            1000,
        );
        let ticks = Timing::at_pixel_rate(1_000_000).validate(&Limits::CCD47_20);
        assert!(plan.is_ok() && ticks.is_ok());
        let (Ok(plan), Ok(ticks)) = (plan, ticks) else {
            return;
        };
        let mut words = [0u32; 4096];
        let mut steps = [Step::EMPTY; 5120];
        let compiled = compile(&plan, &ticks, &PinMap::IN_ORDER, &mut words, &mut steps);
        assert!(compiled.is_ok());
        let Ok(parts) = compiled.map(|p| p.parts()) else {
            return;
        };
        let again = parts.view(&words, &steps);
        assert!(again.is_some_and(|p| p.parts() == parts && p.steps().len() > 1000));
        // Buffers shorter than the program give nothing.
        assert!(parts.view(&words[..10], &steps).is_none());
    }
}
