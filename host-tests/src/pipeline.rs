//! The host pipeline from a raw frame to a star list: the one path both `startrack process`
//! and the demo run, built only from the core's functions, in the firmware's order.
//!
//! 1. Levels: each raw line's bias per output from its over-scan ([`LineLevels::measure`]).
//! 2. Dark scale: the covered columns' mean dark signal over the frame
//!    ([`DarkScaleEstimator`]; the firmware uses the previous frame's, here the frame's own).
//! 3. Calibration of each active line ([`FrameCalibration::calibrate_span`]) streamed into
//!    the [`LineDetector`].
//! 4. For each candidate, a `window` x `window` window centred on its brightest pixel (clipped
//!    at the active area's edge), calibrated with [`FrameCalibration::calibrate_window`] and
//!    centroided with the chosen [`Method`]. Methods that use a box (CoG, and the starting
//!    CoG of the Gauss fit) use `window - 2`, so the window's one-pixel perimeter
//!    measures the background (median).
//!
//! Cost: one pass over the frame (levels, calibration and detection of 1033 x 1072 samples)
//! plus one window per star; the frame is held in memory (2.2 MB), the core's state is not.
//!
//! 5. Methods `cog1` and `cog2` then apply the table's pixel-phase correction
//!    ([`startrack_core::centroid::pixcorr`], section 7) for their power, box (`window - 2`),
//!    median-perimeter background and the PSF's 80 %-energy radius `a = psf_sigma_px /
//!    sqrt(0.31)`: the curve of that power, box and background whose `a` is nearest, if it
//!    is within [`PIXCORR_A_TOLERANCE`] (relative) of the configured `a` ([`select_curve`]).
//!    Without such a curve the CoG is reported uncorrected and flag bit [`UNCORRECTED_BIT`]
//!    says so: a user who asked for a CoG never gets an uncorrected one silently. The other
//!    methods have no pixelisation bias to correct and never set it.
//!
//! Output rows are [`StarRow`]s, written as CSV by [`write_csv`]:
//! `x_px,y_px,flux_e,snr,sigma_x_px,sigma_y_px,flags`, active-area coordinates (0-based,
//! pixel centres at integers). `flags` is the bitmask of [`FLAG_BITS`] (stable bit numbers,
//! independent of the core's internal ones; the README's output table lists them).

use startrack_core::calib::{
    CalibError, DarkScaleEstimator, FrameCalibration, FrameConditions, LineError, LineLevels,
    PixelFlags,
};
use startrack_core::centroid::cog::{CogParams, CogPower, cog};
use startrack_core::centroid::gauss_fit::{GaussFitParams, gauss_fit};
use startrack_core::centroid::pixcorr::{PixCorr, PixCorrBackground, PixCorrSet};
use startrack_core::centroid::{Centroid, CentroidFlags, CentroidInput, MAX_SIDE};
use startrack_core::detect::{DetectConfig, DetectError, Detection, DetectionFlags, LineDetector};
use startrack_core::table::CalibTable;
use startrack_core::units::{Electrons, Kelvin};
use startrack_core::window::{Rect, Window};
use std::fmt;

/// Candidate list capacity on the host (the firmware keeps 32): room for any field, so that
/// a miss is a detection miss, not a full list; losses are still counted.
pub const MAX_CANDIDATES: usize = 1024;

/// Default window side, px.
pub const DEFAULT_WINDOW_PX: u16 = 7;

/// A centroid method of the core.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Centre of gravity, power 1 (paper eq. 2).
    Cog1,
    /// Centre of gravity, power 2, noise-unbiased (paper eq. 6).
    Cog2,
    /// Gauss-Newton fit of a pixel-integrated Gaussian.
    GaussFit,
}

/// What the pipeline needs besides the frame and the table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PipelineConfig {
    /// Centroid method.
    pub method: Method,
    /// Window side, px: odd, 3..=31.
    pub window_px: u16,
    /// PSF Gaussian sigma, px (Gauss-fit model; `sqrt(0.31) a`).
    pub psf_sigma_px: f32,
    /// Detection settings.
    pub detect: DetectConfig,
    /// Exposure, ms (hot-pixel dark law).
    pub exposure_ms: u32,
    /// Sensor temperature, K (hot-pixel dark law).
    pub temperature_k: f64,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            method: Method::GaussFit,
            window_px: DEFAULT_WINDOW_PX,
            psf_sigma_px: 0.8,
            detect: DetectConfig::default(),
            exposure_ms: 1000,
            temperature_k: 293.0,
        }
    }
}

/// Why a frame could not be processed.
#[derive(Clone, Debug, PartialEq)]
pub enum PipelineError {
    /// The window side is even or outside 3..=31.
    Window(u16),
    /// The frame's size does not match the table's geometry.
    FrameSize {
        /// Samples given.
        got: usize,
        /// Lines x line length of the table's geometry.
        expected: usize,
    },
    /// A raw line was rejected.
    Line(LineError),
    /// Calibration failed.
    Calib(CalibError),
    /// Detection failed.
    Detect(DetectError),
}

impl fmt::Display for PipelineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Window(n) => write!(f, "window {n}: must be odd, 3 to {MAX_SIDE}"),
            Self::FrameSize { got, expected } => write!(
                f,
                "frame has {got} samples, the table's geometry needs {expected}"
            ),
            Self::Line(e) => write!(f, "{e}"),
            Self::Calib(e) => write!(f, "calibration: {e}"),
            Self::Detect(e) => write!(f, "detection: {e}"),
        }
    }
}

impl std::error::Error for PipelineError {}

/// The `flags` column's bits: (bit number, source: detection, centroid or calibration, meaning).
/// Bit numbers are stable.
pub const FLAG_BITS: [(u32, &str, &str); 15] = [
    (0, "detection", "saturated pixel in the blob"),
    (1, "detection", "blob touches the active area's edge"),
    (2, "detection", "blended: probably a close pair"),
    (
        3,
        "detection",
        "SNR between the detection minimum and the low-SNR level",
    ),
    (4, "detection", "blob truncated (run or blob table full)"),
    (8, "centroid", "saturated pixel in the window"),
    (9, "centroid", "window or box clipped at the edge"),
    (
        10,
        "centroid",
        "window holds an excluded (hot or telegraph) pixel",
    ),
    (11, "centroid", "SNR below 3"),
    (
        12,
        "centroid",
        "degenerate: no position, window centre reported",
    ),
    (13, "centroid", "not converged (iterative methods)"),
    (
        14,
        "centroid",
        "reserved, set by no method (was the removed 3-point peak's: brightest pixel on the window border)",
    ),
    (15, "centroid", "position clamped to the window"),
    (
        16,
        "calibration",
        "window holds a hot pixel corrected by its own dark law",
    ),
    (
        17,
        "pipeline",
        "cog1/cog2 without a pixel-phase curve for its power, box and PSF width: uncorrected",
    ),
];

const DETECTION_MAP: [(DetectionFlags, u32); 5] = [
    (DetectionFlags::SATURATED, 0),
    (DetectionFlags::EDGE, 1),
    (DetectionFlags::BLENDED, 2),
    (DetectionFlags::LOW_SNR, 3),
    (DetectionFlags::TRUNCATED, 4),
];

const CENTROID_MAP: [(CentroidFlags, u32); 8] = [
    (CentroidFlags::SATURATED, 8),
    (CentroidFlags::EDGE_CLIPPED, 9),
    (CentroidFlags::EXCLUDED_PIXEL, 10),
    (CentroidFlags::LOW_SNR, 11),
    (CentroidFlags::DEGENERATE, 12),
    (CentroidFlags::NOT_CONVERGED, 13),
    (CentroidFlags::PEAK_AT_EDGE, 14),
    (CentroidFlags::CLAMPED, 15),
];

/// Bit of [`FLAG_BITS`] set when a window holds a corrected hot pixel.
pub const HOT_CORRECTED_BIT: u32 = 16;

/// Bit of [`FLAG_BITS`] set on a `cog1`/`cog2` star when the table has no matching
/// pixel-phase curve (the position is the plain CoG's).
pub const UNCORRECTED_BIT: u32 = 17;

/// Largest relative difference between a curve's PSF width `a` and the configured one for
/// the curve to be used. A curve for another width leaves a residual proportional to the
/// difference of the two curves; 10 % keeps a 5x5 curve's residual well under its own
/// size at the widths the builder accepts (a stated rule, not a measured optimum).
pub const PIXCORR_A_TOLERANCE: f32 = 0.1;

/// The 80 %-energy radius of a Gaussian PSF of sigma `sigma_px`: `a = sigma / sqrt(0.31)`.
pub fn a_of_sigma(sigma_px: f32) -> f32 {
    sigma_px / 0.31f32.sqrt()
}

/// The Gaussian sigma of a PSF of 80 %-energy radius `a_px`: `sqrt(0.31) a`.
pub fn sigma_of_a(a_px: f32) -> f32 {
    0.31f32.sqrt() * a_px
}

/// The CoG power and box side of a method that uses a pixel-phase curve (`None` for the
/// others), with windows of `window_px`.
pub fn corrected_cog(method: Method, window_px: u16) -> Option<(CogPower, u8)> {
    let inner = u8::try_from(window_px.saturating_sub(2).max(1)).unwrap_or(u8::MAX);
    match method {
        Method::Cog1 => Some((CogPower::One, inner)),
        Method::Cog2 => Some((CogPower::Two, inner)),
        _ => None,
    }
}

/// The pixel-phase curve `config` uses from `curves`: for [`corrected_cog`]'s power and box,
/// the median-perimeter background, and the `a` nearest the configured one if within
/// [`PIXCORR_A_TOLERANCE`]. `None` for a method without correction or when none matches.
pub fn select_curve<'a>(curves: &PixCorrSet<'a>, config: &PipelineConfig) -> Option<PixCorr<'a>> {
    let (power, box_side) = corrected_cog(config.method, config.window_px)?;
    let a = a_of_sigma(config.psf_sigma_px);
    curves
        .find(power, box_side, PixCorrBackground::PerimeterMedian, a)
        .filter(|c| {
            let ca = c.header().a_px.to_num::<f32>();
            a.is_finite() && a > 0.0 && (ca - a).abs() <= PIXCORR_A_TOLERANCE * a
        })
}

/// The output bitmask of a star's detection, centroid and window calibration flags.
pub fn flags_bitmask(d: DetectionFlags, c: CentroidFlags, p: PixelFlags) -> u32 {
    let mut m = 0;
    for (f, bit) in DETECTION_MAP {
        if d.contains(f) {
            m |= 1 << bit;
        }
    }
    for (f, bit) in CENTROID_MAP {
        if c.contains(f) {
            m |= 1 << bit;
        }
    }
    if p.contains(PixelFlags::HOT_CORRECTED) {
        m |= 1 << HOT_CORRECTED_BIT;
    }
    m
}

/// One star of the output.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StarRow {
    /// What the detector found.
    pub detection: Detection,
    /// The window centroided.
    pub rect: Rect,
    /// The centroid (position in active-area px).
    pub centroid: Centroid,
    /// Calibration flags of the window's pixels, OR-ed.
    pub pixel_flags: PixelFlags,
    /// The output bitmask ([`FLAG_BITS`]).
    pub flags: u32,
}

/// Levels of every line and the frame's dark scale, for one table.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameLevels {
    /// Bias levels of every raw line.
    pub lines: Vec<LineLevels>,
    /// Covered columns' mean dark, or `None` without covered columns.
    pub dark_scale_e: Option<Electrons>,
}

/// What the pipeline measured on a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameResult {
    /// Stars, in the detector's order.
    pub stars: Vec<StarRow>,
    /// Levels of the frame.
    pub levels: FrameLevels,
    /// Conditions the frame was calibrated with.
    pub conditions: FrameConditions,
    /// Candidates lost because the list was full.
    pub dropped: u32,
    /// The pixel-phase curve applied to every centroid (`None`: no correction, either
    /// because the method needs none or because no curve matched; see [`UNCORRECTED_BIT`]).
    pub pixcorr: Option<startrack_core::centroid::pixcorr::CurveHeader>,
}

/// Measures every line's bias and the frame's dark scale. `raw` holds the frame row-major
/// (`lines x line_len` samples of the table's geometry).
pub fn measure_levels(table: &CalibTable<'_>, raw: &[u16]) -> Result<FrameLevels, PipelineError> {
    let g = *table.geometry();
    let expected = usize::from(g.lines) * g.line_len();
    if raw.len() != expected {
        return Err(PipelineError::FrameSize {
            got: raw.len(),
            expected,
        });
    }
    let mut est = DarkScaleEstimator::new();
    let mut lines = Vec::with_capacity(usize::from(g.lines));
    for line in raw.chunks_exact(g.line_len()) {
        let lv = LineLevels::measure(&g, line).map_err(PipelineError::Line)?;
        est.add_line(table, line, &lv)
            .map_err(PipelineError::Line)?;
        lines.push(lv);
    }
    Ok(FrameLevels {
        lines,
        dark_scale_e: est.estimate(),
    })
}

/// The frame conditions of `levels` under `config`.
pub fn conditions(levels: &FrameLevels, config: &PipelineConfig) -> FrameConditions {
    FrameConditions {
        dark_scale_e: levels.dark_scale_e.unwrap_or(Electrons::ZERO),
        exposure_ms: config.exposure_ms,
        temperature_k: Kelvin::saturating_from_num(config.temperature_k),
    }
}

/// Calibrates window `rect` of the frame `raw`: electrons, per-pixel flags, OR-ed flags.
pub fn calibrate_window(
    cal: &FrameCalibration<'_>,
    raw: &[u16],
    levels: &FrameLevels,
    rect: Rect,
) -> Result<(Vec<Electrons>, Vec<PixelFlags>, PixelFlags), PipelineError> {
    let g = *cal.table().geometry();
    let len = g.line_len();
    let (x0, y0) = (usize::from(rect.x0), usize::from(rect.y0));
    let (w, h) = (usize::from(rect.width), usize::from(rect.height));
    let mut win = Vec::with_capacity(rect.len());
    for y in y0..y0 + h {
        let start = g.raw_line_of_y(y) * len + g.raw_col_of_x(x0);
        let row = raw.get(start..start + w).ok_or(PipelineError::FrameSize {
            got: raw.len(),
            expected: usize::from(g.lines) * len,
        })?;
        win.extend_from_slice(row);
    }
    let lv_start = g.raw_line_of_y(y0);
    let lv = levels
        .lines
        .get(lv_start..lv_start + h)
        .ok_or(PipelineError::Calib(CalibError::BufferLength))?;
    let mut e = vec![Electrons::ZERO; rect.len()];
    let mut f = vec![PixelFlags::empty(); rect.len()];
    let flags = cal
        .calibrate_window(rect, &win, lv, &mut e, &mut f)
        .map_err(PipelineError::Calib)?;
    Ok((e, f, flags))
}

/// Centroids one calibrated window with `config`'s method.
pub fn centroid(input: &CentroidInput<'_>, config: &PipelineConfig) -> Centroid {
    let inner = u8::try_from(config.window_px.saturating_sub(2).max(1)).unwrap_or(u8::MAX);
    match config.method {
        Method::Cog1 => cog(input, &CogParams::new(CogPower::One, inner)),
        Method::Cog2 => cog(input, &CogParams::new(CogPower::Two, inner)),
        Method::GaussFit => gauss_fit(
            input,
            &GaussFitParams {
                start_box: inner,
                ..GaussFitParams::new(config.psf_sigma_px)
            },
        ),
    }
}

/// Runs the whole pipeline on the frame `raw` (row-major, `lines x line_len` samples of the
/// table's geometry) with `table`.
pub fn process(
    table: CalibTable<'_>,
    raw: &[u16],
    config: &PipelineConfig,
) -> Result<FrameResult, PipelineError> {
    let n = config.window_px;
    if !(3..=MAX_SIDE).contains(&n) || n.is_multiple_of(2) {
        return Err(PipelineError::Window(n));
    }
    let g = *table.geometry();
    let levels = measure_levels(&table, raw)?;
    let cond = conditions(&levels, config);
    let cal = FrameCalibration::new(table, cond);
    let curve = select_curve(&table.pixcorr(), config);
    let uncorrected = corrected_cog(config.method, n).is_some() && curve.is_none();

    let mut detector =
        LineDetector::<MAX_CANDIDATES>::new(config.detect, g.active_cols, g.active_rows);
    let mut e_line = vec![Electrons::ZERO; usize::from(g.active_cols)];
    let mut f_line = vec![PixelFlags::empty(); e_line.len()];
    for y in 0..g.active_rows {
        let line_no = g.raw_line_of_y(usize::from(y));
        let start = line_no * g.line_len();
        let (Some(raw_line), Some(lv)) = (
            raw.get(start..start + g.line_len()),
            levels.lines.get(line_no),
        ) else {
            break;
        };
        cal.calibrate_span(y, 0, raw_line, lv, &mut e_line, &mut f_line)
            .map_err(PipelineError::Calib)?;
        detector
            .push_line(y, &e_line, &f_line)
            .map_err(PipelineError::Detect)?;
    }
    detector.finish();

    let mut stars = Vec::with_capacity(detector.candidates().len());
    for det in detector.candidates() {
        let (rect, clipped) =
            Rect::centred_clipped(det.peak_x, det.peak_y, n, g.active_cols, g.active_rows);
        let (e, f, pixel_flags) = calibrate_window(&cal, raw, &levels, rect)?;
        let c = match Window::new(rect, &e) {
            Some(w) => centroid(
                &CentroidInput::new(w)
                    .with_pixel_flags(&f)
                    .with_clipped(clipped),
                config,
            ),
            None => return Err(PipelineError::Calib(CalibError::BufferLength)),
        };
        let c = curve.map_or(c, |k| k.apply(c));
        let mut flags = flags_bitmask(det.flags, c.flags, pixel_flags);
        if uncorrected {
            flags |= 1 << UNCORRECTED_BIT;
        }
        stars.push(StarRow {
            detection: *det,
            rect,
            centroid: c,
            pixel_flags,
            flags,
        });
    }
    Ok(FrameResult {
        stars,
        levels,
        conditions: cond,
        dropped: detector.dropped(),
        pixcorr: curve.map(|k| k.header()),
    })
}

/// The CSV header line of [`write_csv`].
pub const CSV_HEADER: &str = "x_px,y_px,flux_e,snr,sigma_x_px,sigma_y_px,flags";

/// Writes `stars` as CSV (header, then one star per line).
pub fn write_csv(out: &mut dyn std::io::Write, stars: &[StarRow]) -> std::io::Result<()> {
    writeln!(out, "{CSV_HEADER}")?;
    for s in stars {
        let c = &s.centroid;
        writeln!(
            out,
            "{:.4},{:.4},{:.1},{:.2},{:.4},{:.4},{}",
            c.x_px, c.y_px, c.flux_e, c.snr, c.sigma_x_px, c.sigma_y_px, s.flags
        )?;
    }
    Ok(())
}
