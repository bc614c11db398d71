//! The simulator's optional physics beyond the basic sensor, each switched on by its field of
//! [`Effects`] (all off by default, and then the samples are bit for bit those of the basic
//! sensor):
//!
//! - [`PsfShape`]: a non-Gaussian star image, defocused (a ring) or with coma (a tail), built
//!   from pixel-integrated Gaussians so every pixel stays exact (erf products).
//! - [`DarkLaw`]: dark charge scaled by `2^((T - T_ref) / doubling)`, covered pixels too.
//! - [`HotPixels`]: a random fraction of pixels with their own dark rate and their own
//!   temperature law (the paper: hot pixels "have a different temperature dependence").
//! - [`TelegraphPixels`]: pixels whose dark switches between two levels from frame to frame.
//! - [`CosmicRays`]: hits that deposit charge in a pixel and its four neighbours.
//! - [`Cti`]: a simple parallel charge-transfer-inefficiency trail: a fraction of each
//!   pixel's expected charge is released over the next lines read.
//! - [`ChargeTraps`]: charge traps along both transfer directions, parallel (lines) and serial
//!   (the register, away from each output), each deferring a fraction that grows with the
//!   number of transfers and shrinks with the pixel's charge.
//!
//! This module describes the effects; [`super::render`] draws them per pixel when it renders
//! (the `Simulator` methods `hot_rate_e_per_s`, `telegraph_e`, `cosmic_e` and the like).
//! Every effect is a pure function of (seed, frame, pixel) and of the neighbouring pixels'
//! own pure functions, so a window rendered alone still equals the same pixels of a full
//! frame. Fixed defects draw from the pixel's `Defect` stream, per-frame events from its
//! `Event` stream ([`super::rng::Purpose`]).
//!
//! Cost: nothing when off. When on, per rendered pixel: a star's [`RING_PARTS`] or
//! [`COMA_PARTS`] Gaussian parts instead of one, one ChaCha8 stream for a hot pixel's draw
//! (two for a telegraph pixel: its defect and its state in the frame), five for cosmic rays
//! (the pixel and its four neighbours), and `trail_lines` more evaluations of the expected
//! charge for CTI.

use super::psf::sigma_of_a;

/// The optional effects; `Default` is all off.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Effects {
    /// Star image shape.
    pub psf: PsfShape,
    /// Sensor temperature, K: used by [`DarkLaw`] and [`HotPixels`] (ignored when both are
    /// off).
    pub temperature_k: f64,
    /// Temperature law of the regular dark charge.
    pub dark_law: Option<DarkLaw>,
    /// Hot pixels.
    pub hot: Option<HotPixels>,
    /// Telegraph (random telegraph signal) pixels.
    pub telegraph: Option<TelegraphPixels>,
    /// Cosmic-ray hits.
    pub cosmics: Option<CosmicRays>,
    /// Parallel CTI trails.
    pub cti: Option<Cti>,
    /// Parallel and serial charge traps (applied after [`Cti`] when both are on).
    pub traps: Option<ChargeTraps>,
}

/// A star image's shape; the star's `a_px` sets the width of each Gaussian part.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum PsfShape {
    /// The paper's Gaussian (eq. 5).
    #[default]
    Gaussian,
    /// Defocused: [`RING_PARTS`] Gaussians evenly on a circle of `ring_radius_px`, each of
    /// the star's sigma (a donut once the radius exceeds about 1.5 sigma).
    Defocus {
        /// Radius of the ring, px.
        ring_radius_px: f64,
    },
    /// Coma: [`COMA_PARTS`] Gaussians along `angle_rad`, offsets `length (j/4)^2`, weights
    /// `1 - 0.15 j` and widths `sigma (1 + j/8)`, j = 0..4, shifted so that the photocentre
    /// stays at the star's position.
    Coma {
        /// Length of the tail, px.
        length_px: f64,
        /// Direction of the tail from the core, radians from +x towards +y.
        angle_rad: f64,
    },
}

/// Gaussians on a defocus ring.
pub const RING_PARTS: usize = 12;
/// Gaussians along a coma tail.
pub const COMA_PARTS: usize = 5;

/// One Gaussian part of a star image: offset from the photocentre (px), sigma (px) and
/// fraction of the signal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PsfPart {
    /// Column offset, px.
    pub dx_px: f64,
    /// Row offset, px.
    pub dy_px: f64,
    /// Gaussian sigma, px.
    pub sigma_px: f64,
    /// Fraction of the signal (the parts sum to 1).
    pub weight: f64,
}

impl PsfShape {
    /// The Gaussian parts of a star of 80 % radius `a_px`.
    pub fn parts(&self, a_px: f64) -> Vec<PsfPart> {
        let s = sigma_of_a(a_px);
        match *self {
            Self::Gaussian => vec![PsfPart {
                dx_px: 0.0,
                dy_px: 0.0,
                sigma_px: s,
                weight: 1.0,
            }],
            Self::Defocus { ring_radius_px: r } => (0..RING_PARTS)
                .map(|k| {
                    let t = std::f64::consts::TAU * k as f64 / RING_PARTS as f64;
                    PsfPart {
                        dx_px: r * t.cos(),
                        dy_px: r * t.sin(),
                        sigma_px: s,
                        weight: 1.0 / RING_PARTS as f64,
                    }
                })
                .collect(),
            Self::Coma {
                length_px,
                angle_rad,
            } => {
                let raw: Vec<(f64, f64, f64)> = (0..COMA_PARTS)
                    .map(|j| {
                        let j = j as f64;
                        (
                            length_px * (j / 4.0).powi(2),
                            1.0 - 0.15 * j,
                            s * (1.0 + j / 8.0),
                        )
                    })
                    .collect();
                let wsum: f64 = raw.iter().map(|p| p.1).sum();
                let mean: f64 = raw.iter().map(|p| p.0 * p.1).sum::<f64>() / wsum;
                let (c, sn) = (angle_rad.cos(), angle_rad.sin());
                raw.iter()
                    .map(|&(d, w, sg)| PsfPart {
                        dx_px: (d - mean) * c,
                        dy_px: (d - mean) * sn,
                        sigma_px: sg,
                        weight: w / wsum,
                    })
                    .collect()
            }
        }
    }
}

/// Temperature law of the regular dark: the sensor's `dark_mean_e` holds at `reference_k`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DarkLaw {
    /// Temperature at which `dark_mean_e` holds, K.
    pub reference_k: f64,
    /// Temperature rise that doubles the dark, K (about 6-7 K for a CCD47-20).
    pub doubling_k: f64,
}

/// Hot pixels: each pixel (active or covered) is hot with probability `fraction`, with a
/// rate drawn log-uniformly in `rate_min..rate_max` e-/s at `reference_k`, doubling every
/// `doubling_k` (its own law, not the regular dark's), over `exposure_s`. A hot pixel's dark
/// is its own law alone (it replaces the regular dark), as the core's hot-pixel correction
/// assumes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HotPixels {
    /// Probability that a pixel is hot.
    pub fraction: f64,
    /// Lowest rate at the reference temperature, e-/s.
    pub rate_min_e_per_s: f64,
    /// Highest rate at the reference temperature, e-/s.
    pub rate_max_e_per_s: f64,
    /// Reference temperature of the rates, K.
    pub reference_k: f64,
    /// Doubling temperature of the hot pixels, K.
    pub doubling_k: f64,
    /// Exposure, s.
    pub exposure_s: f64,
}

/// Telegraph pixels: each pixel is one with probability `fraction`; in each frame it is in
/// its high state with probability `p_high`, adding `amplitude_e` times a per-pixel factor
/// in 0.5..1.5 to its dark.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TelegraphPixels {
    /// Probability that a pixel is a telegraph pixel.
    pub fraction: f64,
    /// Typical step between the levels, e-.
    pub amplitude_e: f64,
    /// Probability of the high level in a frame.
    pub p_high: f64,
}

/// Cosmic-ray hits: each pixel is hit in a frame with probability `rate_per_px`, with a
/// deposit drawn uniformly in `0.5..1.5 x mean_e`; [`COSMIC_CORE`] of it stays in the pixel
/// and the rest is shared by its four direct neighbours.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CosmicRays {
    /// Probability of a hit centred on a given pixel in a frame.
    pub rate_per_px: f64,
    /// Mean deposit, e-.
    pub mean_e: f64,
}

/// Fraction of a cosmic-ray deposit kept by the hit pixel.
pub const COSMIC_CORE: f64 = 0.6;

/// Parallel CTI: `fraction` of every pixel's expected charge is left behind and released
/// into the next `trail_lines` lines read, with weights decaying by `decay` per line
/// (normalised): `out(l) = (1 - f) q(l) + f sum_k w_k q(l - k)`. Charge is conserved
/// except for what trails beyond the last line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cti {
    /// Fraction of the charge deferred.
    pub fraction: f64,
    /// Lines over which it is released.
    pub trail_lines: usize,
    /// Ratio of successive release weights (0..1).
    pub decay: f64,
}

impl Cti {
    /// Release weights of lines 1..=trail_lines after the pixel, summing to 1.
    pub fn weights(&self) -> Vec<f64> {
        let raw: Vec<f64> = (0..self.trail_lines)
            .map(|k| self.decay.powi(k as i32))
            .collect();
        let sum: f64 = raw.iter().sum();
        raw.iter()
            .map(|w| if sum > 0.0 { w / sum } else { 0.0 })
            .collect()
    }
}

/// Charge traps, parallel then serial. A pixel holding `q` e- (its expected charge) that
/// makes `n` transfers defers the fraction
/// `f = min(1, n eps (q / reference_e)^-alpha)` of it (the volume-driven trap law: a faint
/// pixel loses a larger fraction), released into the next [`Self::trail_px`] elements read,
/// with the weights of [`Cti::weights`]. Parallel: `n = line + 1`, trail into later lines.
/// Serial, after the parallel step and on its result: `n = c + 1` for the left output (raw
/// column `c`, trail into higher columns), `n = line_len - c` for the right one (trail into
/// lower columns), the trail never crossing into the other output's half. Charge is conserved
/// except for what trails past the last line or the end of the half line.
///
/// Cost: `(1 + trail_px)^2` evaluations of the trap-free expected charge per sample.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ChargeTraps {
    /// Fraction deferred per parallel transfer at `reference_e`.
    pub parallel_per_transfer: f64,
    /// Fraction deferred per serial transfer at `reference_e`.
    pub serial_per_transfer: f64,
    /// Charge at which the per-transfer fractions hold, e-.
    pub reference_e: f64,
    /// Signal exponent of the deferred fraction (0 <= alpha < 1).
    pub alpha: f64,
    /// Elements over which deferred charge is released.
    pub trail_px: usize,
    /// Ratio of successive release weights (0..1).
    pub decay: f64,
}

impl ChargeTraps {
    /// The fraction of a pixel's `q_e` deferred over `transfers` transfers at `eps` per
    /// transfer (0 for no charge).
    pub fn deferred_fraction(&self, eps: f64, transfers: f64, q_e: f64) -> f64 {
        if q_e <= 0.0 || eps <= 0.0 {
            return 0.0;
        }
        (transfers * eps * (q_e / self.reference_e).powf(-self.alpha)).clamp(0.0, 1.0)
    }

    /// Release weights of elements 1..=trail_px after the pixel, summing to 1.
    pub fn weights(&self) -> Vec<f64> {
        Cti {
            fraction: 0.0,
            trail_lines: self.trail_px,
            decay: self.decay,
        }
        .weights()
    }

    /// Mean release delay, elements: `sum k w_k`.
    pub fn mean_delay(&self) -> f64 {
        self.weights()
            .iter()
            .enumerate()
            .map(|(k, w)| (k + 1) as f64 * w)
            .sum()
    }
}
