//! What the simulated sensor and scene are made of.

use super::effects::Effects;
use startrack_core::geometry::ReadoutGeometry;

/// A star: position in active-area pixels (centres at integers), total signal in electrons,
/// and the paper's image size `a_px` (radius holding 80 % of the signal).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Star {
    /// Active column of the photocentre.
    pub x_px: f64,
    /// Active row of the photocentre.
    pub y_px: f64,
    /// Total signal, e-.
    pub signal_e: f64,
    /// 80 % radius, px.
    pub a_px: f64,
}

/// The sensor's parameters. Defaults describe a CCD47-20 read at ~1 MHz on both outputs,
/// uncooled, as in the paper's dark non-uniformity experiment.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorParams {
    /// Readout geometry.
    pub geometry: ReadoutGeometry,
    /// Seed of every random draw.
    pub seed: u64,
    /// Bias of each output, ADU.
    pub bias_adu: [f64; 2],
    /// Standard deviation of the per-column bias pattern, ADU.
    pub column_bias_sigma_adu: f64,
    /// Gain of each output, e-/ADU.
    pub gain_e_per_adu: [f64; 2],
    /// Read noise, e- rms.
    pub read_noise_e: f64,
    /// Mean dark charge of a covered pixel in this exposure, e-.
    pub dark_mean_e: f64,
    /// Dark signal non-uniformity: per-pixel relative dark ~ 1 + dsnu N(0,1), clipped at 0.
    pub dsnu: f64,
    /// Photo-response non-uniformity: flat ~ 1 + prnu N(0,1).
    pub prnu: f64,
    /// Full well, e-: a pixel never holds more.
    pub full_well_e: f64,
    /// Response non-linearity of each output chain (output node, amplifier, CDS), as the
    /// fraction a charge packet of [`Self::full_well_e`] reads low: a packet of `e` electrons
    /// reads as `e (1 - k e / full_well_e)` (a quadratic term; its deficit is `k` at full well,
    /// `k / 4` at half). Deterministic, no draw. `[0, 0]` (linear) by default, and then every
    /// sample is bit for bit the linear sensor's.
    pub nonlinearity_at_full_well: [f64; 2],
    /// Add shot and read noise (off: the expected value, rounded to ADU).
    pub noise: bool,
    /// Uniform illumination (sky background, or a flat-field lamp), e- per active pixel
    /// before the flat; 0 by default.
    pub sky_e: f64,
    /// Optional physics (non-Gaussian PSF, temperature laws, hot and telegraph pixels,
    /// cosmic rays, CTI): all off by default.
    pub effects: Effects,
}

impl Default for SensorParams {
    fn default() -> Self {
        Self {
            geometry: ReadoutGeometry::CCD47_20_DUAL,
            seed: 1,
            bias_adu: [1000.0, 1100.0],
            column_bias_sigma_adu: 2.0,
            gain_e_per_adu: [1.5, 1.6],
            read_noise_e: 5.0,
            dark_mean_e: 250.0,
            dsnu: 0.1,
            prnu: 0.02,
            full_well_e: 100_000.0,
            nonlinearity_at_full_well: [0.0, 0.0],
            noise: true,
            sky_e: 0.0,
            effects: Effects::default(),
        }
    }
}
