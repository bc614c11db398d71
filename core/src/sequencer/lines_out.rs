//! What each line of a compiled program digitises ([`LineJobs`]), and the ADC's words of a
//! line put back where the core expects them ([`LineJob::unpack`]).
//!
//! A line job is read off the program alone: a line-transfer step opens it (its repeat is
//! the rows binned into it), the skip and read steps after it say which register element
//! each digitised pixel came from, and the job ends at the tick of its last sample. The
//! firmware hands a job to the ADC reader once the DMA has played past `end_tick`, and
//! `unpack` turns the words (one per read pixel and output, left then right) into a raw
//! line in physical column order, as `geometry` lays it out. Cost: O(steps) to walk, O(words)
//! to unpack; a job is ~0.6 KB (its runs).

use super::compile::{Program, SegmentId};
use super::plan::ShiftRuns;

/// One digitised line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LineJob {
    /// Raw line (store row) of its first row.
    pub line: u16,
    /// Rows binned into it.
    pub rows: u16,
    /// Read runs: (first register element from the output, elements) of each run of read
    /// pixels, in readout order.
    pub runs: ShiftRuns,
    /// Words the ADC delivers for it: read pixels x outputs.
    pub words: u32,
    /// Tick (from the program's start) just after its last sample.
    pub end_tick: u64,
}

/// Why a line cannot be unpacked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum UnpackError {
    /// Fewer words than the job digitises.
    ShortInput,
    /// A run reaches past the output line.
    LineTooShort,
    /// Binned lines are not unpacked into raw lines.
    Binned,
}

impl core::fmt::Display for UnpackError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::ShortInput => "unpack: fewer words than the line digitises",
            Self::LineTooShort => "unpack: a run reaches past the line",
            Self::Binned => "unpack: binned lines have no raw layout",
        })
    }
}

impl core::error::Error for UnpackError {}

impl LineJob {
    /// Writes the job's `words` into `line` (the raw line, `line_len` samples): with two
    /// outputs word `2i` is the left output's pixel at element `d` (raw column `d`) and
    /// `2i + 1` the right one's (raw column `line_len - 1 - d`); with one output word `i` is
    /// raw column `d`. Columns not read are left as they are. Returns the words used.
    pub fn unpack(
        &self,
        outputs: u8,
        binning: u16,
        words: &[u16],
        line: &mut [u16],
    ) -> Result<usize, UnpackError> {
        if binning != 1 {
            return Err(UnpackError::Binned);
        }
        let len = line.len();
        let per = usize::from(outputs.max(1));
        let mut w = words.iter();
        let mut used = 0;
        for &(start, n) in self.runs.iter() {
            for d in usize::from(start)..usize::from(start) + usize::from(n) {
                let left = *w.next().ok_or(UnpackError::ShortInput)?;
                *line.get_mut(d).ok_or(UnpackError::LineTooShort)? = left;
                if per == 2 {
                    let right = *w.next().ok_or(UnpackError::ShortInput)?;
                    let col = len.checked_sub(1 + d).ok_or(UnpackError::LineTooShort)?;
                    *line.get_mut(col).ok_or(UnpackError::LineTooShort)? = right;
                }
                used += per;
            }
        }
        Ok(used)
    }
}

/// The line jobs of a program, in order.
#[derive(Clone, Debug)]
pub struct LineJobs<'p, 'w, 's> {
    program: &'p Program<'w, 's>,
    step: usize,
    tick: u64,
    row: u32,
}

impl<'p, 'w, 's> LineJobs<'p, 'w, 's> {
    /// From the program's start.
    pub const fn new(program: &'p Program<'w, 's>) -> Self {
        Self {
            program,
            step: 0,
            tick: 0,
            row: 0,
        }
    }

    fn ticks(&self, segment: SegmentId, repeat: u32) -> u64 {
        self.program.segment(segment).len() as u64 * u64::from(repeat)
    }
}

impl Iterator for LineJobs<'_, '_, '_> {
    type Item = LineJob;

    fn next(&mut self) -> Option<LineJob> {
        let steps = self.program.steps();
        // Up to the next line transfer.
        loop {
            let s = steps.get(self.step)?;
            if s.segment == SegmentId::LineTransfer {
                break;
            }
            if s.segment == SegmentId::RowDump {
                self.row += s.repeat;
            }
            self.tick += self.ticks(s.segment, s.repeat);
            self.step += 1;
        }
        let open = steps.get(self.step)?;
        let rows = open.repeat;
        let mut job = LineJob {
            line: u16::try_from(self.row).unwrap_or(u16::MAX),
            rows: u16::try_from(rows).unwrap_or(u16::MAX),
            runs: ShiftRuns::new(),
            words: 0,
            end_tick: 0,
        };
        self.row += rows;
        self.tick += self.ticks(open.segment, open.repeat);
        self.step += 1;
        let binning = u32::from(self.program.binning().max(1));
        let mut element: u32 = 0;
        let mut end = self.tick;
        while let Some(s) = steps.get(self.step) {
            match s.segment {
                SegmentId::SkipPixel => element += s.repeat,
                SegmentId::ReadPixel => {
                    let start = u16::try_from(element / binning).unwrap_or(u16::MAX);
                    let n = u16::try_from(s.repeat).unwrap_or(u16::MAX);
                    let _ = job.runs.push((start, n));
                    job.words += s.repeat * u32::from(self.program.outputs());
                    element += s.repeat * binning;
                    end = self.tick + self.ticks(s.segment, s.repeat);
                }
                SegmentId::RegisterDump => {}
                _ => break,
            }
            self.tick += self.ticks(s.segment, s.repeat);
            self.step += 1;
        }
        job.end_tick = end;
        Some(job)
    }
}
