//! What a compiled frame costs, read off its program ([`Cost::of`]): ticks by segment, rows
//! clocked, pixels digitised, the frame time (the store's readout) and the update rate
//! (frame transfer + readout or exposure). Nothing here is
//! estimated from the plan: each number is a sum over the steps the DMA will play, so it
//! stays true when the compiler changes. Cost: O(steps).

use super::compile::{Program, SEGMENTS, SegmentId};

/// The cost of one compiled frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cost {
    /// Ticks spent in each segment, indexed by `SegmentId as usize`.
    pub ticks_by_segment: [u64; SEGMENTS],
    /// One tick, ps.
    pub tick_ps: u32,
    /// Store rows clocked after the frame transfer (line transfers and dumped rows).
    pub rows_clocked: u64,
    /// Pixel values digitised (binned pixels read x outputs).
    pub pixels_digitised: u64,
    /// Register elements skipped unsampled.
    pub pixels_skipped: u64,
}

impl Cost {
    /// Walks `program`.
    pub fn of(program: &Program<'_, '_>) -> Self {
        let mut ticks_by_segment = [0u64; SEGMENTS];
        let mut rows_clocked = 0;
        let mut pixels_digitised = 0;
        let mut pixels_skipped = 0;
        for s in program.steps() {
            let per = program.segment(s.segment).len() as u64;
            if let Some(t) = ticks_by_segment.get_mut(s.segment as usize) {
                *t += per * u64::from(s.repeat);
            }
            match s.segment {
                SegmentId::LineTransfer | SegmentId::RowDump => {
                    rows_clocked += u64::from(s.repeat);
                }
                SegmentId::ReadPixel => {
                    pixels_digitised += u64::from(s.repeat) * u64::from(program.outputs());
                }
                SegmentId::SkipPixel => pixels_skipped += u64::from(s.repeat),
                _ => {}
            }
        }
        Self {
            ticks_by_segment,
            tick_ps: program.tick_ps(),
            rows_clocked,
            pixels_digitised,
            pixels_skipped,
        }
    }

    /// Time in `segment`, ns.
    pub fn segment_ns(&self, segment: SegmentId) -> u64 {
        self.ticks_by_segment
            .get(segment as usize)
            .copied()
            .unwrap_or(0)
            * u64::from(self.tick_ps)
            / 1000
    }

    /// The frame time: the store's readout from the first line transfer to the last sample,
    /// ns. The frame transfer before it and the exposure padding after it are not in it;
    /// the next exposure runs all through it.
    pub fn frame_time_ns(&self) -> u64 {
        let ticks: u64 = SegmentId::ALL
            .iter()
            .filter(|id| !matches!(id, SegmentId::FrameTransfer | SegmentId::Idle))
            .map(|&id| self.ticks_by_segment.get(id as usize).copied().unwrap_or(0))
            .sum();
        ticks * u64::from(self.tick_ps) / 1000
    }

    /// One frame cycle when the program repeats back to back, ns: the frame transfer, then
    /// the readout or the exposure, whichever is longer.
    pub fn cycle_ns(&self) -> u64 {
        self.segment_ns(SegmentId::FrameTransfer)
            + self.frame_time_ns()
            + self.segment_ns(SegmentId::Idle)
    }

    /// Frames per second when the program repeats back to back, mHz: `1 / cycle`. The
    /// exposure overlaps the store's readout, so with an exposure no longer than the readout
    /// this is the best rate.
    pub fn update_rate_mhz(&self) -> u64 {
        1_000_000_000_000u64
            .checked_div(self.cycle_ns())
            .unwrap_or(0)
    }

    /// The segment that takes the most time (what bounds the update rate).
    pub fn bound_by(&self) -> SegmentId {
        let mut best = SegmentId::FrameTransfer;
        for id in SegmentId::ALL {
            if self.segment_ns(id) > self.segment_ns(best) {
                best = id;
            }
        }
        best
    }
}
