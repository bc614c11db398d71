//! Telemetry: what the firmware reports about the lines it processes, and how often.
//!
//! For now the defmt log (over RTT, read by `probe-rs run`) *is* the telemetry: there is no
//! telemetry link, packet format or ground-side decoder yet. This module holds the records
//! that are reported and the rate at which line summaries are logged, so that a real link
//! can later send the same records.

use crate::stars::{FrameStats, Mode, StarRecord};
use fixed::types::I28F4;
use startrack_core::calib::PixelFlags;
use startrack_core::geometry::MAX_OUTPUTS;
use startrack_core::units::{BiasAdu, Electrons};

/// A line summary is logged for every line whose index is a multiple of this.
pub const LINE_SUMMARY_EVERY: u16 = 64;

/// Whether the summary of raw line `line` is logged.
pub const fn is_summary_line(line: u16) -> bool {
    line.is_multiple_of(LINE_SUMMARY_EVERY)
}

/// What was made of a line's pixels.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub enum LineOutcome {
    /// An active row calibrated with the checked table.
    Calibrated {
        /// Mean of the row's active pixels that are not excluded, electrons.
        mean_e: Electrons,
        /// The dark scale the row was calibrated with, electrons.
        dark_scale_e: Electrons,
        /// Flags of the row's pixels, OR-ed.
        flags: PixelFlags,
        /// Pixels at or above the table's saturation level.
        saturated: u16,
    },
    /// An active row of an acquisition frame off the background rows: streamed raw through
    /// the pre-filtered scan, which calibrated only the chunks that may hold a star, so there
    /// is no row mean (the background rows, every `stars::ACQ_BACKGROUND_STRIDE`th, which
    /// are the summary lines, are calibrated whole and reported as `Calibrated`).
    Scanned {
        /// The dark scale the row's calibrated chunks used, electrons.
        dark_scale_e: Electrons,
    },
    /// An active row with no usable table: only the over-scan bias is taken off.
    Uncalibrated {
        /// Mean of the row's active samples minus their output's bias, ADU.
        mean_above_bias_adu: I28F4,
    },
    /// An active row of a tracking frame: only the rows of the stars' windows were copied.
    Tracked {
        /// The dark scale the windows are calibrated with, electrons.
        dark_scale_e: Electrons,
        /// Windows whose last row this was (calibrated, checked and centroided).
        windows_done: u8,
    },
    /// A line that holds no active row (store-section rows read after the image).
    NotActive,
    /// The line could not be used; the error was logged when it happened.
    Failed,
}

/// What is reported about one processed line.
#[derive(Clone, Copy, Debug, defmt::Format)]
pub struct LineSummary {
    /// Frame number since boot.
    pub frame: u32,
    /// Raw line index within the frame.
    pub line: u16,
    /// Bias level of each output from the line's over-scan, ADU.
    pub bias_adu: [BiasAdu; MAX_OUTPUTS],
    /// What was made of the line's pixels.
    pub outcome: LineOutcome,
}

/// Logs one line summary.
pub fn report_line(summary: &LineSummary) {
    defmt::info!("line {}", summary);
}

/// Logs the end of a frame: how many lines were processed and the frame's dark scale.
pub fn report_frame(frame: u32, lines: u16, dark_scale_e: Option<Electrons>) {
    defmt::info!(
        "frame {} done: {} lines processed, dark scale {} e-",
        frame,
        lines,
        dark_scale_e
    );
}

/// Logs a frame's stars: one summary record (mode, counts, losses), then one record per star
/// (position, flux, SNR, position errors, flags; see [`StarRecord`] for the flag layout).
pub fn report_stars(frame: u32, mode: Mode, stars: &[StarRecord], stats: &FrameStats) {
    let centroids = stars.iter().filter(|s| s.is_centroid()).count();
    defmt::info!(
        "frame {} {}: {} stars ({} centroids), {}",
        frame,
        mode,
        stars.len(),
        centroids,
        stats
    );
    for s in stars {
        defmt::info!(
            "frame {} star x {=f32} px y {=f32} px flux {=f32} e- snr {=f32} sigma {=f32}/{=f32} px flags {=u32:#x}",
            frame,
            s.x_px,
            s.y_px,
            s.flux_e,
            s.snr,
            s.sigma_x_px,
            s.sigma_y_px,
            s.flags
        );
    }
}
