//! The CCD clock sequencer: from what a frame reads to the GPIO words that clock the
//! CCD47-20, and what that costs.
//!
//! A frame-transfer CCD is read by clocking: the frame transfer moves the image into the
//! store (ending one exposure, starting the next), then the store is read row by row while
//! the image integrates. Which rows are digitised, which are dumped, which register elements
//! are sampled and which skipped sets both the update rate and the noise, so the firmware
//! plays a table compiled here rather than hand-written waveforms.
//!
//! ```text
//! ReadoutRequest + geometry + binning + exposure --ReadoutPlan::new--> plan   (plan.rs)
//! Timing + Limits --validate--> Ticks                                         (timing.rs)
//! plan + Ticks + PinMap --compile--> word segments + (segment, repeat) steps  (compile.rs)
//! program --Cost::of--> rows clocked, pixels digitised, frame time, rate       (cost.rs)
//! program --check_program--> overlaps, phase counts, samples out of reset     (check.rs)
//! program --Cursor::fill--> the words in play order, chunk by chunk (DMA ring) (expand.rs)
//! program --Chain::new, links--> (block, repeats) descriptors for a linked-list DMA (chain.rs)
//! program --LineJobs--> per line: rows, read runs, ADC words, last tick   (lines_out.rs)
//! ADC words --LineJob::unpack--> the raw line in the core's layout         (lines_out.rs)
//! ```
//! Each tick is one `u32` BSRR word for the clock port ([`PinMap`]); the firmware's
//! timer-paced DMA writes the words of each step `repeat` times. The compiler writes into
//! buffers the caller owns (no allocation) and says how large they must be when they are
//! not. Costs: compiling a tracking frame with 30 windows is O(row groups x windows); the
//! tables are ~1,000 words (4 KB) and up to ~2,100 steps (17 KB) for a full frame.
//!
//! The host crate runs the words through a charge-transfer model of the CCD47-20
//! (`startrack_sim::ccd_model`) to prove that they deliver the line layout of
//! [`crate::geometry`] and exactly the windows' pixels.

/// RAM the firmware sets aside for one compiled frame (word table + program), bytes: 64 KB
/// of the 512 KB AXI SRAM, which the DMA reaches (DTCM it does not). The host test
/// `sequencer_targets` compiles the largest plans `readout-plan` offers and checks that
/// they fit.
pub const TABLE_RAM_BYTES: usize = 64 * 1024;

mod chain;
mod check;
mod compile;
mod cost;
mod expand;
mod lines;
mod lines_out;
mod plan;
mod timing;

pub use chain::{Chain, ChainError, Link, Links, MAX_BLOCK_WORDS, MAX_BLOCKS};
pub use check::{SequenceError, check_program};
pub use compile::{CompileError, Program, ProgramParts, REST, SegmentId, Step, compile};
pub use cost::Cost;
pub use expand::Cursor;
pub use lines::{Line, LineSet, Phases, PinMap, PinMapError};
pub use lines_out::{LineJob, LineJobs, UnpackError};
pub use plan::{Binning, MAX_WINDOWS, PlanError, ReadoutPlan, ShiftRuns};
pub use timing::{Limit, Limits, Ticks, Timing, TimingError};
