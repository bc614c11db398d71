//! Dark drift: the covered pixels' dark signal measured each frame against what the lab's
//! dark law predicts at the frame's temperature and exposure, kept as a running ratio for
//! housekeeping.
//!
//! What it is for: the relative dark map is normalised to the covered pixels, so a uniform
//! change of the dark rate (radiation damage, a drifting temperature sensor) is calibrated
//! away frame by frame and never seen. The ratio shows it: 1 while the sensor follows its
//! lab law, rising as the dark current grows. A ratio outside the configured band sets the
//! `DARK_DRIFT` status bit of housekeeping.
//!
//! What it costs: one `exp2f` and a few integer operations a frame (in `end_frame`), under
//! 32 B in the tracker.
//!
//! # The law and the statistic
//! [`DarkLaw`]: the covered pixels' mean dark rate `rate` at `reference_k` and its doubling
//! temperature, as the lab set measured them (`startrack calib frames` fits it from the
//! covered rate per temperature and writes it into the table's section 11, which the
//! tracker takes with the table): `predicted_e = rate x exposure x 2^((T - T_ref) / doubling)`.
//! A frame with a dark scale, a measured temperature and a prediction of at least
//! [`MIN_PREDICTED_E`] gives `x = measured / predicted`, clamped to `0..=255`; the running
//! ratio `r` (U16F16 in a `u32`, 0 to 255.99998) is the first such `x`, then
//! `r += (x - r) / 16`: an exponentially weighted mean with a 16-frame time constant, so a
//! single odd frame moves it by at most 1/16 of its excess.

use crate::table::DarkLaw;
use crate::units::{Electrons, Kelvin};

/// A frame whose predicted dark is below this many electrons is not compared (the ratio of
/// two small numbers is noise), e-.
pub(crate) const MIN_PREDICTED_E: f32 = 1.0;
/// Weight of a new frame in the running ratio: 1 / 2^this.
pub(crate) const DRIFT_WEIGHT_LOG2: u32 = 4;

/// The running ratio as housekeeping reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DarkDrift {
    /// Running ratio measured/predicted, U8F8 bits (1/256 to 255.996, saturating; a ratio
    /// below 1/256 reads 1); 0: not measured (no law, no sensor temperature, or no frame
    /// compared yet).
    pub ratio_u8f8: u16,
    /// Frames compared since the law was set.
    pub frames: u32,
    /// The running ratio is outside the law's band.
    pub out_of_band: bool,
}

/// The monitor: the law and the running ratio.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct DriftMonitor {
    law: Option<DarkLaw>,
    /// U16F16 bits.
    ratio: u32,
    frames: u32,
}

impl DriftMonitor {
    pub(crate) const fn new() -> Self {
        Self {
            law: None,
            ratio: 0,
            frames: 0,
        }
    }

    /// Sets (or clears) the law and restarts the statistic.
    pub(crate) fn set_law(&mut self, law: Option<DarkLaw>) {
        *self = Self {
            law,
            ratio: 0,
            frames: 0,
        };
    }

    pub(crate) fn law(&self) -> Option<DarkLaw> {
        self.law
    }

    /// Takes one frame's dark scale, measured at `temperature_k` (`None`: not measured)
    /// with `exposure_ms`.
    pub(crate) fn frame(
        &mut self,
        dark_scale_e: Electrons,
        temperature_k: Option<Kelvin>,
        exposure_ms: u32,
    ) {
        let (Some(law), Some(t)) = (self.law, temperature_k) else {
            return;
        };
        let Some(predicted) = law.predicted_e(t, exposure_ms) else {
            return;
        };
        if predicted.is_nan() || predicted < MIN_PREDICTED_E {
            return;
        }
        let x = dark_scale_e.to_num::<f32>() / predicted;
        // 0..=255 in U16F16: below 2^24, exact in the u32; NaN cannot arise (predicted >= 1).
        let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 255.0) };
        let x_bits = (x * 65_536.0) as u32;
        self.ratio = if self.frames == 0 {
            x_bits
        } else {
            // |x - r| < 2^24, so the signed step fits an i64 with room.
            let step = (i64::from(x_bits) - i64::from(self.ratio)) >> DRIFT_WEIGHT_LOG2;
            u32::try_from(i64::from(self.ratio) + step).unwrap_or(0)
        };
        self.frames = self.frames.saturating_add(1);
    }

    /// The statistic now.
    pub(crate) fn report(&self) -> DarkDrift {
        let Some(law) = self.law.filter(|_| self.frames > 0) else {
            return DarkDrift::default();
        };
        // U16F16 to U8F8: drop 8 fraction bits, rounding; at most 255.996 fits a u16.
        let ratio_u8f8 = u16::try_from((self.ratio + 0x80) >> 8).unwrap_or(u16::MAX);
        let low = u32::from(law.band_low.to_bits()) << 8;
        let high = u32::from(law.band_high.to_bits()) << 8;
        DarkDrift {
            ratio_u8f8: ratio_u8f8.max(1),
            frames: self.frames,
            out_of_band: self.ratio < low || self.ratio > high,
        }
    }
}
