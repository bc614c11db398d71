//! `startrack readout-plan --mode full|windows --pixel-rate-hz R [--windows N --window-px W]
//! [--outputs 1|2]`: what one frame of the CCD sequencer costs, computed from its compiled
//! program (not estimated): one CSV row
//! `mode,pixel_rate_hz,outputs,windows,rows_clocked,pixels_digitised,frame_time_ms,update_rate_hz`.
//!
//! Windows are `window_px` squares placed from `--seed`: one in each of `N` horizontal bands
//! of the active area (a random row inside the band, a random column), so they spread over
//! the frame as tracked stars do and rows are shared only where bands are narrower than a
//! window.

use super::CliError;
use rand::{RngExt, SeedableRng};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::readout::ReadoutRequest;
use startrack_core::sequencer::{
    Binning, CompileError, Cost, Limits, PinMap, ReadoutPlan, SegmentId, Step, Timing, compile,
};
use startrack_core::window::Rect;

/// Full frame or windows.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Every line, every element.
    Full,
    /// The windows' rows, and of those the prefix columns and the windows' pixels.
    Windows,
}

/// Arguments of `startrack readout-plan`.
#[derive(clap::Args, Debug, Clone)]
pub struct ReadoutPlanArgs {
    /// Full frame or windows.
    #[arg(long, value_enum)]
    pub mode: Mode,
    /// Unbinned read pixels per second on each output, Hz.
    #[arg(long)]
    pub pixel_rate_hz: u32,
    /// Number of windows (windows mode).
    #[arg(long, default_value_t = 30)]
    pub windows: u16,
    /// Window side, pixels (windows mode).
    #[arg(long, default_value_t = 11)]
    pub window_px: u16,
    /// Output amplifiers, 1 or 2.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub outputs: u8,
    /// On-chip binning, 1, 2 or 4.
    #[arg(long, default_value_t = 1)]
    pub binning: u16,
    /// Exposure, us (0: the best rate, the exposure as long as the readout).
    #[arg(long, default_value_t = 0)]
    pub exposure_us: u32,
    /// Seed of the window placement.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Also print the time in each segment (`segment,ms` rows after the CSV row).
    #[arg(long)]
    pub breakdown: bool,
}

/// The CSV header.
pub const HEADER: &str =
    "mode,pixel_rate_hz,outputs,windows,rows_clocked,pixels_digitised,frame_time_ms,update_rate_hz";

/// One plan's numbers.
#[derive(Clone, Debug)]
pub struct PlanCost {
    /// The CSV row (without newline).
    pub row: String,
    /// The cost walked from the program.
    pub cost: Cost,
    /// Words of the segment table.
    pub words: usize,
    /// Program steps.
    pub steps: usize,
    /// The windows placed.
    pub rects: Vec<Rect>,
}

/// `n` windows of `px` placed from `seed`, one per horizontal band, sorted by row.
pub fn place_windows(geometry: &ReadoutGeometry, n: u16, px: u16, seed: u64) -> Vec<Rect> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5345_5150);
    let rows = geometry.active_rows;
    let cols = geometry.active_cols;
    let px = px.min(rows).min(cols).max(1);
    let n = n.max(1);
    let band = rows / n;
    let mut rects: Vec<Rect> = (0..n)
        .map(|i| {
            let y0 = if band >= px {
                i * band + r.random_range(0..=band - px)
            } else {
                r.random_range(0..=rows - px)
            };
            Rect {
                x0: r.random_range(0..=cols - px),
                y0,
                width: px,
                height: px,
            }
        })
        .collect();
    rects.sort_by_key(|r| r.y0);
    rects
}

/// Compiles the plan the arguments describe and walks its program.
pub fn plan_cost(args: &ReadoutPlanArgs) -> Result<PlanCost, CliError> {
    let geometry = if args.outputs == 1 {
        ReadoutGeometry::CCD47_20_SINGLE
    } else {
        ReadoutGeometry::CCD47_20_DUAL
    };
    let binning = Binning::from_factor(args.binning)
        .ok_or_else(|| CliError::Usage(format!("--binning {} is not 1, 2 or 4", args.binning)))?;
    let rects = match args.mode {
        Mode::Full => Vec::new(),
        Mode::Windows => place_windows(&geometry, args.windows, args.window_px, args.seed),
    };
    let request = match args.mode {
        Mode::Full => ReadoutRequest::FullFrame,
        Mode::Windows => ReadoutRequest::Windows(&rects),
    };
    let usage = |e: &dyn std::fmt::Display| CliError::Usage(e.to_string());
    let plan =
        ReadoutPlan::new(geometry, request, binning, args.exposure_us).map_err(|e| usage(&e))?;
    let ticks = Timing::at_pixel_rate(args.pixel_rate_hz)
        .validate(&Limits::CCD47_20)
        .map_err(|e| usage(&e))?;
    let pins = PinMap::IN_ORDER;
    // Start small; the compiler says how much it needs.
    let (mut words, mut steps) = (vec![0u32; 1024], vec![Step::EMPTY; 1024]);
    loop {
        match compile(&plan, &ticks, &pins, &mut words, &mut steps) {
            Ok(_) => break,
            Err(CompileError::Words { needed }) => words.resize(needed, 0),
            Err(CompileError::Steps { needed }) => steps.resize(needed, Step::EMPTY),
            Err(e) => return Err(usage(&e)),
        }
    }
    let program = compile(&plan, &ticks, &pins, &mut words, &mut steps).map_err(|e| usage(&e))?;
    let cost = Cost::of(&program);
    let mode = match args.mode {
        Mode::Full => "full",
        Mode::Windows => "windows",
    };
    let row = format!(
        "{mode},{},{},{},{},{},{:.3},{:.2}",
        args.pixel_rate_hz,
        args.outputs,
        rects.len(),
        cost.rows_clocked,
        cost.pixels_digitised,
        cost.frame_time_ns() as f64 / 1e6,
        cost.update_rate_mhz() as f64 / 1e3,
    );
    Ok(PlanCost {
        row,
        cost,
        words: program.words().len(),
        steps: program.steps().len(),
        rects,
    })
}

/// Name of a segment in the breakdown.
pub fn segment_name(id: SegmentId) -> &'static str {
    match id {
        SegmentId::FrameTransfer => "frame_transfer",
        SegmentId::LineTransfer => "line_transfer",
        SegmentId::RowDump => "row_dump",
        SegmentId::ReadPixel => "read_pixel",
        SegmentId::SkipPixel => "skip_pixel",
        SegmentId::RegisterDump => "register_dump",
        SegmentId::Idle => "exposure_pad",
    }
}

/// Runs the subcommand: the header and the row (and the breakdown when asked), as printed.
pub fn run(args: &ReadoutPlanArgs) -> Result<String, CliError> {
    let p = plan_cost(args)?;
    let mut out = format!("{HEADER}\n{}\n", p.row);
    if args.breakdown {
        out.push_str("segment,ms\n");
        for id in SegmentId::ALL {
            out.push_str(&format!(
                "{},{:.3}\n",
                segment_name(id),
                p.cost.segment_ns(id) as f64 / 1e6
            ));
        }
    }
    Ok(out)
}
