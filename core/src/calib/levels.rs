//! Levels measured on the frame itself: each line's bias from its over-scan elements, and the
//! frame's dark scale from the covered (dark-reference) columns.
//!
//! Bias: the median of the over-scan elements an output read on that line (8 on the
//! CCD47-20; 16 with one output, which reads both strips). One cosmic-ray hit or a hot
//! register element moves the median by at most one rank, so the level stays robust. Cost:
//! sorting 8 (or 16) samples per output per line.
//!
//! Dark scale (the paper's dark pre-calculation): the mean dark signal of the covered pixels
//! in electrons, the quantity the stored relative dark map is normalised to. Each line's
//! covered pixels (bias-subtracted, converted with their output's gain) are sorted; values
//! further than [`REJECT_SIGMAS`] robust sigmas (interquartile range / 1.349, at least
//! 1 e-) from the line's median are rejected (a cosmic-ray hit cannot pull the estimate) and
//! the rest are averaged with those of every line fed so far. Unlike a trimmed mean this is
//! unbiased for the skewed Poisson distribution of dark charge: the rejection band is far
//! out in the tails. Cost: one sort of 32 values per line.

use super::formula::{offset_16ths, signal_bits};
use crate::geometry::{MAX_OUTPUTS, Output, ReadoutGeometry};
use crate::table::CalibTable;
use crate::units::{BiasAdu, DARK_SCALE_LIMIT_E, Electrons};

/// Most over-scan or covered elements one line may contribute per side (geometries with
/// wider strips use the first this many of each).
pub(crate) const MAX_STRIP_PX: usize = 64;

/// Why a line cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum LineError {
    /// The line does not have `geometry.line_len()` samples.
    Length {
        /// Samples expected.
        expected: u16,
        /// Samples given.
        got: u32,
    },
}

impl core::fmt::Display for LineError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Length { expected, got } => {
                write!(
                    f,
                    "raw line has {got} samples, the geometry needs {expected}"
                )
            }
        }
    }
}

impl core::error::Error for LineError {}

/// The bias level of each output on one line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineLevels {
    /// Bias of each output, ADU (U28F4, 0..=65535); unused outputs hold 0.
    pub bias_adu: [BiasAdu; MAX_OUTPUTS],
}

pub(crate) fn check_len(geometry: &ReadoutGeometry, raw_line: &[u16]) -> Result<(), LineError> {
    if raw_line.len() == geometry.line_len() {
        Ok(())
    } else {
        Err(LineError::Length {
            expected: geometry.line_len() as u16,
            got: u32::try_from(raw_line.len()).unwrap_or(u32::MAX),
        })
    }
}

/// Median of `v` in 1/16 ADU (the mean of the two middle values for an even count).
fn median_16ths(v: &mut [u16]) -> u32 {
    v.sort_unstable();
    let n = v.len();
    match (v.get(n.wrapping_sub(1) / 2), v.get(n / 2)) {
        (Some(a), Some(b)) => (u32::from(*a) + u32::from(*b)) * 8,
        _ => 0,
    }
}

impl LineLevels {
    /// Measures each output's bias on `raw_line` (a whole raw line of `geometry`).
    pub fn measure(geometry: &ReadoutGeometry, raw_line: &[u16]) -> Result<Self, LineError> {
        check_len(geometry, raw_line)?;
        let mut bias_adu = [BiasAdu::ZERO; MAX_OUTPUTS];
        for (o, slot) in bias_adu
            .iter_mut()
            .enumerate()
            .take(usize::from(geometry.outputs))
        {
            let mut buf = [0u16; 2 * MAX_STRIP_PX];
            let mut n = 0;
            let strips = [
                Some(geometry.overscan_cols(Output(o as u8))),
                geometry.overscan_cols_extra(),
            ];
            for (start, end) in strips.into_iter().flatten() {
                let take = (end - start).min(MAX_STRIP_PX);
                for s in raw_line.iter().skip(start).take(take) {
                    if let Some(b) = buf.get_mut(n) {
                        *b = *s;
                        n += 1;
                    }
                }
            }
            *slot = BiasAdu::from_bits(median_16ths(buf.get_mut(..n).unwrap_or(&mut [])));
        }
        Ok(Self { bias_adu })
    }

    /// The bias of `output` (0 for an output the geometry does not have).
    pub fn bias(&self, output: Output) -> BiasAdu {
        self.bias_adu
            .get(usize::from(output.0))
            .copied()
            .unwrap_or(BiasAdu::ZERO)
    }
}

/// Covered samples further than this many robust sigmas from their line's median are not
/// averaged.
pub(crate) const REJECT_SIGMAS: i64 = 5;

/// Accumulates the covered columns of the lines of a frame into the frame's dark scale.
///
/// Sum: at most 8192 lines x 128 samples x 2^27 (|value| in 1/64 e- units is below 2^27,
/// see [`crate::units`]) = 2^47, far inside i64.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DarkScaleEstimator {
    sum_bits: i64,
    count: u32,
}

impl DarkScaleEstimator {
    /// An estimator with no line fed yet.
    pub const fn new() -> Self {
        Self {
            sum_bits: 0,
            count: 0,
        }
    }

    /// Adds the covered pixels of one raw line, with that line's levels.
    pub fn add_line(
        &mut self,
        table: &CalibTable<'_>,
        raw_line: &[u16],
        levels: &LineLevels,
    ) -> Result<(), LineError> {
        self.add_line_cols(table, raw_line, levels, table.geometry().covered_cols())
    }

    /// Adds the covered pixels of one raw line in `strips` (raw column ranges, what the
    /// frame's readout reads: [`crate::readout::ReadoutRequest::covered_cols`]; each strip
    /// read by one output, as a covered strip at an end of the line is), with that line's
    /// levels.
    pub fn add_line_cols(
        &mut self,
        table: &CalibTable<'_>,
        raw_line: &[u16],
        levels: &LineLevels,
        strips: [(usize, usize); 2],
    ) -> Result<(), LineError> {
        let g = table.geometry();
        check_len(g, raw_line)?;
        let mut vals = [0i32; 2 * MAX_STRIP_PX];
        let mut n = 0;
        for (start, end) in strips {
            // A covered strip lies at one end of the line, so one output read all of it.
            let out = g.output_of_col(start);
            let (bias, gain) = (levels.bias(out), table.gain(out));
            for col in start..end.min(start + MAX_STRIP_PX) {
                let (Some(raw), Some(v)) = (raw_line.get(col), vals.get_mut(n)) else {
                    break;
                };
                *v = signal_bits(*raw, offset_16ths(bias, table.column_bias(col)), gain);
                n += 1;
            }
        }
        let v = vals.get_mut(..n).unwrap_or(&mut []);
        v.sort_unstable();
        let at = |i: usize| v.get(i).map_or(0, |x| i64::from(*x));
        let median = at(n / 2);
        // Robust sigma from the interquartile range, in 1/64 e-, at least 1 e-.
        let sigma = ((at(3 * n / 4) - at(n / 4)) * 1000 / 1349).max(64);
        let band = REJECT_SIGMAS * sigma;
        for x in v.iter().map(|x| i64::from(*x)) {
            if (x - median).abs() <= band {
                self.sum_bits += x;
                self.count += 1;
            }
        }
        Ok(())
    }

    /// The mean covered-pixel dark signal so far, clamped to ±[`DARK_SCALE_LIMIT_E`], or
    /// `None` before any covered sample (a geometry without covered columns).
    pub fn estimate(&self) -> Option<Electrons> {
        if self.count == 0 {
            return None;
        }
        let n = i64::from(self.count);
        // Round to nearest: the quotient of two i64 values in range.
        let q = (2 * self.sum_bits + n).div_euclid(2 * n);
        let lim = i64::from(DARK_SCALE_LIMIT_E.to_bits());
        Some(Electrons::from_bits(q.clamp(-lim, lim) as i32))
    }
}
