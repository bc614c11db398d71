//! The program played out in chunks ([`Cursor`]): what the firmware's feeder runs to keep the
//! DMA's ring of BSRR words full. A DMA stream cannot jump from one `(segment, repeat)` step
//! to the next within one tick, so the CPU writes the words of the program, in play order,
//! into the half of the ring the DMA has just played; the cursor remembers where it stopped
//! (step, repeat, word). Cost: one word copy per tick played (a tick of 125 ns at 1 MHz
//! pixels is 60 core cycles of the 480 MHz M7).

use super::compile::Program;

/// Where the next word of a program comes from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cursor {
    step: usize,
    repeat: u32,
    word: usize,
}

impl Cursor {
    /// At the program's first word.
    pub const START: Self = Self {
        step: 0,
        repeat: 0,
        word: 0,
    };

    /// Writes the next words of `program` into `out`, returns how many; fewer than
    /// `out.len()` means the program ended (the cursor then stays at its end).
    pub fn fill(&mut self, program: &Program<'_, '_>, out: &mut [u32]) -> usize {
        let mut n = 0;
        while n < out.len() {
            let Some(step) = program.steps().get(self.step) else {
                break;
            };
            let seg = program.segment(step.segment);
            if self.repeat >= step.repeat || seg.is_empty() {
                self.step += 1;
                self.repeat = 0;
                self.word = 0;
                continue;
            }
            let src = seg.get(self.word..).unwrap_or(&[]);
            let dst = out.get_mut(n..).unwrap_or(&mut []);
            let k = src.len().min(dst.len());
            if let (Some(d), Some(s)) = (dst.get_mut(..k), src.get(..k)) {
                d.copy_from_slice(s);
            }
            n += k;
            self.word += k;
            if self.word >= seg.len() {
                self.word = 0;
                self.repeat += 1;
            }
        }
        n
    }

    /// The index of the step the next word belongs to (the program's length at its end).
    pub const fn step(&self) -> usize {
        self.step
    }
}
