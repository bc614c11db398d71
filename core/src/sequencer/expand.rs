//! The program played out in chunks ([`Cursor`]): what the firmware's feeder runs to keep the
//! DMA's ring of BSRR words full. A DMA stream cannot jump from one `(segment, repeat)` step
//! to the next within one tick, so the CPU writes the words of the program, in play order,
//! into the half of the ring the DMA has just played; the cursor remembers where it stopped
//! (step, repeat, word). Cost: one word copy per tick played (a tick of 50 ns at 1 MHz
//! pixels is 24 core cycles of the 480 MHz M7); 5.2 instructions a word on QEMU's M7 for a
//! 30-window tracking frame (`cargo m7-bench`, `sequencer_feed_words`).

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
            if self.repeat >= step.repeat || seg.is_empty() || self.word >= seg.len() {
                self.step += 1;
                self.repeat = 0;
                self.word = 0;
                continue;
            }
            let len = seg.len();
            // Words left in the step: the rest of this repeat and the repeats after it.
            let left =
                (len - self.word) as u64 + u64::from(step.repeat - self.repeat - 1) * len as u64;
            let dst = out.get_mut(n..).unwrap_or(&mut []);
            let k = dst.len().min(usize::try_from(left).unwrap_or(usize::MAX));
            let Some((dst, _)) = dst.split_at_mut_checked(k) else {
                break;
            };
            // The rest of the current repeat, then whole repeats and the start of one
            // (segments are 1 to ~320 words, repeated up to thousands of times).
            let head = seg.get(self.word..).unwrap_or(&[]);
            let (first, rest) = dst
                .split_at_mut_checked(head.len().min(dst.len()))
                .unwrap_or((&mut [], &mut []));
            for (d, s) in first.iter_mut().zip(head) {
                *d = *s;
            }
            // Whole repeats: one copy of the segment, then the written part copied after
            // itself (memmove, doubling), so a short segment costs what a long one does.
            for (d, s) in rest.iter_mut().zip(seg) {
                *d = *s;
            }
            let mut filled = len.min(rest.len());
            while filled < rest.len() {
                let c = filled.min(rest.len() - filled);
                rest.copy_within(0..c, filled);
                filled += c;
            }
            n += k;
            let pos = self.word + k;
            self.repeat += u32::try_from(pos / len).unwrap_or(u32::MAX);
            self.word = pos % len;
        }
        n
    }
}
