//! Per-line processing: turns each raw line from the readout into bias levels, feeds the
//! frame's dark-scale estimate, hands active rows to the star pipeline (which calibrates
//! what it needs with the core), and reports a summary (see [`crate::telemetry`]).
//!
//! Per line, with a checked table:
//! 1. bias of each output from the line's over-scan ([`LineLevels::measure`]);
//! 2. the line's covered columns into the frame's [`DarkScaleEstimator`];
//! 3. for an active row of an acquisition frame, the raw line and its levels into the star
//!    pipeline ([`crate::stars`]): the raw-line ring and the core's pre-filtered
//!    `ScanDetector`, which calibrates only the chunks of 16 pixels that may be above the
//!    detection threshold, and whole only the background rows (every
//!    [`crate::stars::ACQ_BACKGROUND_STRIDE`]th, which are the summary lines: their mean is
//!    reported); a centroid per star when its window's last row has streamed;
//! 4. in a tracking frame, step 3 is replaced by copying the rows of the predicted windows,
//!    which are calibrated, checked and centroided on their own. The frame's stars (at most
//!    [`crate::stars::MAX_STARS`], the brightest kept) are reported when the frame ends.
//!
//! Without a table (none in flash, or rejected) the firmware runs *uncalibrated*: the bias is
//! still measured and the summary reports the active pixels' mean above bias in ADU; no
//! dark scale is estimated, since the estimator needs the table's gains.
//!
//! Dark scale: a line is calibrated with the previous frame's complete dark scale (the dark
//! signal follows the temperature, which moves slowly against a ~2 s frame); during the very
//! first frame, with the running estimate of the current frame, which already holds the
//! covered pixels of the line itself.
//!
//! Placeholders until the hardware provides them: the sensor temperature is taken as the
//! table's hot-pixel reference temperature, and the exposure as one frame period of the
//! timer-paced readout. They affect only hot pixels with the `Correct` policy.
//!
//! The dark scale of a tracking frame still comes from every line's covered columns.

use crate::lines::{FILLED, FREE, GEOMETRY, LineBuf};
use crate::readout::LINE_PERIOD;
use crate::stars::{Capture, Mode, Ring, StarPipeline};
use crate::telemetry::{self, LineOutcome, LineSummary};
use fixed::types::I28F4;
use startrack_core::calib::{
    DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
};
use startrack_core::geometry::MAX_OUTPUTS;
use startrack_core::table::CalibTable;
use startrack_core::units::{BiasAdu, Electrons};

/// Active pixels per line (1024 on the CCD47-20).
const ACTIVE_COLS: usize = GEOMETRY.active_cols as usize;

/// Exposure assumed for the hot-pixel law: one frame period of the timer-paced readout.
const EXPOSURE_MS: u32 = (GEOMETRY.lines as u64 * LINE_PERIOD.as_millis()) as u32;

/// The processing state: the table, the dark-scale estimate, the output row and the
/// star pipeline.
pub struct Processor {
    table: Option<CalibTable<'static>>,
    /// The frame whose lines are being accumulated, and how many of its lines were seen.
    frame: Option<u32>,
    lines_in_frame: u16,
    estimator: DarkScaleEstimator,
    /// The last complete frame's dark scale.
    prev_dark_scale: Option<Electrons>,
    /// The conditions the current frame's rows were calibrated with.
    conditions: Option<FrameConditions>,
    stars: StarPipeline,
}

impl Processor {
    /// A processor that calibrates with `table`, or runs uncalibrated without one.
    pub fn new(table: Option<CalibTable<'static>>, stars: StarPipeline) -> Self {
        Self {
            table,
            frame: None,
            lines_in_frame: 0,
            estimator: DarkScaleEstimator::new(),
            prev_dark_scale: None,
            conditions: None,
            stars,
        }
    }

    /// Closes the previous frame when `frame` starts a new one.
    fn track_frame(&mut self, frame: u32) {
        if self.frame == Some(frame) {
            return;
        }
        if let Some(done) = self.frame {
            let estimate = self.estimator.estimate();
            telemetry::report_frame(done, self.lines_in_frame, estimate);
            let calibration = self
                .table
                .zip(self.conditions)
                .map(|(t, c)| FrameCalibration::new(t, c));
            let mode = self.stars.mode();
            let (stars, stats) = self.stars.end_frame(calibration.as_ref());
            telemetry::report_stars(done, mode, stars, &stats);
            if estimate.is_some() {
                self.prev_dark_scale = estimate;
            }
        }
        self.frame = Some(frame);
        self.lines_in_frame = 0;
        self.estimator = DarkScaleEstimator::new();
        self.conditions = None;
        self.stars.start_frame();
    }

    /// Processes raw line `line` of frame `frame`.
    pub fn process(&mut self, frame: u32, line: u16, samples: &LineBuf) -> LineSummary {
        self.track_frame(frame);
        self.lines_in_frame = self.lines_in_frame.saturating_add(1);
        let mut summary = LineSummary {
            frame,
            line,
            bias_adu: [BiasAdu::ZERO; MAX_OUTPUTS],
            outcome: LineOutcome::Failed,
        };
        let levels = match LineLevels::measure(&GEOMETRY, samples) {
            Ok(levels) => levels,
            Err(e) => {
                defmt::error!("process: frame {} line {}: {}", frame, line, e);
                return summary;
            }
        };
        summary.bias_adu = levels.bias_adu;
        summary.outcome = match self.table {
            Some(table) => self.calibrated(&table, line, samples, &levels),
            None if line < GEOMETRY.active_rows => Self::uncalibrated(samples, &levels),
            None => LineOutcome::NotActive,
        };
        summary
    }

    /// Dark-scale feed and, for an active row, calibration with the table.
    fn calibrated(
        &mut self,
        table: &CalibTable<'static>,
        line: u16,
        samples: &LineBuf,
        levels: &LineLevels,
    ) -> LineOutcome {
        if let Err(e) = self.estimator.add_line(table, samples, levels) {
            defmt::error!("process: dark scale, line {}: {}", line, e);
            return LineOutcome::Failed;
        }
        if line >= GEOMETRY.active_rows {
            return LineOutcome::NotActive;
        }
        // No covered columns at all would leave no estimate; the CCD47-20 always has them.
        let dark_scale_e = self
            .prev_dark_scale
            .or_else(|| self.estimator.estimate())
            .unwrap_or(Electrons::ZERO);
        let conditions = FrameConditions {
            dark_scale_e,
            exposure_ms: EXPOSURE_MS,
            temperature_k: table.hot_pixels().reference_temperature_k(),
        };
        let calibration = FrameCalibration::new(*table, conditions);
        self.conditions = Some(conditions);
        if self.stars.mode() == Mode::Tracking {
            let windows_done = self
                .stars
                .tracking_line(&calibration, line, samples, levels);
            return LineOutcome::Tracked {
                dark_scale_e,
                windows_done,
            };
        }
        if self
            .stars
            .acquisition_line(&calibration, line, samples, levels)
            .is_err()
        {
            // Logged by the star pipeline.
            return LineOutcome::Failed;
        }
        // Only the background rows (every `ACQ_BACKGROUND_STRIDE`th, the summary lines) were
        // calibrated whole: their mean is reported; the others saw only the chunks that may
        // hold a star.
        let Some((electrons, pixel_flags)) = self.stars.whole_line() else {
            return LineOutcome::Scanned { dark_scale_e };
        };
        let (mut sum, mut used, mut saturated) = (0i64, 0i64, 0u16);
        let mut flags = PixelFlags::empty();
        for (e, f) in electrons.iter().zip(pixel_flags.iter()) {
            flags |= *f;
            if !f.is_excluded() {
                sum += i64::from(e.to_bits());
                used += 1;
            }
            if f.contains(PixelFlags::SATURATED) {
                saturated = saturated.saturating_add(1);
            }
        }
        LineOutcome::Calibrated {
            mean_e: Electrons::from_bits(mean_bits(sum, used)),
            dark_scale_e,
            flags,
            saturated,
        }
    }

    /// The active samples' mean above their output's bias, in ADU.
    fn uncalibrated(samples: &LineBuf, levels: &LineLevels) -> LineOutcome {
        let first = GEOMETRY.first_active_col();
        let (mut sum, mut n) = (0i64, 0i64);
        for (col, raw) in samples.iter().enumerate().skip(first).take(ACTIVE_COLS) {
            let bias = levels.bias(GEOMETRY.output_of_col(col));
            // Both in 1/16 ADU: a sample is at most 2^20, the bias at most 2^20 as well.
            sum += (i64::from(*raw) << 4) - i64::from(bias.to_bits());
            n += 1;
        }
        LineOutcome::Uncalibrated {
            mean_above_bias_adu: I28F4::from_bits(mean_bits(sum, n)),
        }
    }
}

/// `sum / n` rounded to nearest, in the same fixed-point bits (0 when `n` is 0). The mean of
/// values that each fit an i32 fits an i32.
fn mean_bits(sum: i64, n: i64) -> i32 {
    if n == 0 {
        return 0;
    }
    let q = (2 * sum + n).div_euclid(2 * n);
    q.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

/// The processing task: each filled line is processed, its buffer goes straight back to
/// the readout, and every [`telemetry::LINE_SUMMARY_EVERY`]th line's summary is logged.
#[embassy_executor::task]
pub async fn process_task(
    table: Option<CalibTable<'static>>,
    ring: &'static mut Ring,
    capture: &'static mut Capture,
) -> ! {
    // Built here rather than passed in, so that the task's state holds one pipeline.
    let mut processor = Processor::new(table, StarPipeline::new(ring, capture));
    loop {
        let raw = FILLED.receive().await;
        let summary = processor.process(raw.frame, raw.line, raw.samples);
        if FREE.try_send(raw.samples).is_err() {
            // Cannot happen: FREE holds as many entries as there are buffers.
            defmt::error!("process: free-buffer channel full, a line buffer is lost");
        }
        if telemetry::is_summary_line(raw.line) {
            telemetry::report_line(&summary);
        }
    }
}
