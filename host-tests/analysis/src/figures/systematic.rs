//! The noise-free systematic shift of the core's centre of gravity (paper eq. 4): a
//! pixel-integrated Gaussian (eq. 3 and 5) rendered without noise or background into an
//! n x n window centred on the pixel holding the true centre, measured by
//! [`startrack_core::centroid::cog::cog`] with the box filling the window, minus the truth.
//!
//! Cost: n^2 erf pairs and one core CoG per position. The signal (10^6 e-) makes the 1/64 e-
//! quantisation of calibrated pixels negligible (relative 1.6e-8); the core's f32 arithmetic
//! (positions near x = 100 px, where an f32 step is 7.6e-6 px) leaves up to ~1e-5 px, the
//! tolerance `figures_pixelisation` checks every shift to against an exact f64 computation.

use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::sim::psf::{pixel_fraction, sigma_of_a};

/// Total signal of the rendered star, e-.
pub const SIGNAL_E: f64 = 1.0e6;
/// Active-area pixel holding the true centre (x and y).
const CENTRE_PX: u16 = 100;

/// The power of the CoG as the paper numbers it (1: eq. 2, 2: eq. 6).
pub fn power_of(p: u8) -> CogPower {
    if p >= 2 { CogPower::Two } else { CogPower::One }
}

/// The core CoG's shift (estimate minus truth, px, x and y) for a star of 80 % radius
/// `a_px` at (`phase_x`, `phase_y`) from the centre of the central pixel, in a
/// `window` x `window` box, with `power` 1 or 2; `None` if the core flagged the window
/// degenerate or clamped.
pub fn core_shift(
    a_px: f64,
    window: u8,
    power: u8,
    phase_x: f64,
    phase_y: f64,
) -> Option<(f64, f64)> {
    let n = u16::from(window.max(1) | 1);
    let half = n / 2;
    let rect = Rect {
        x0: CENTRE_PX - half,
        y0: CENTRE_PX - half,
        width: n,
        height: n,
    };
    let s = sigma_of_a(a_px);
    let (cx, cy) = (
        f64::from(CENTRE_PX) + phase_x,
        f64::from(CENTRE_PX) + phase_y,
    );
    let px: Vec<f64> = (0..n)
        .map(|i| pixel_fraction(f64::from(rect.x0 + i), cx, s))
        .collect();
    let py: Vec<f64> = (0..n)
        .map(|j| pixel_fraction(f64::from(rect.y0 + j), cy, s))
        .collect();
    let pixels: Vec<Electrons> = py
        .iter()
        .flat_map(|fy| {
            px.iter()
                .map(move |fx| Electrons::saturating_from_num(SIGNAL_E * fx * fy))
        })
        .collect();
    let w = Window::new(rect, &pixels)?;
    let params = CogParams {
        power: power_of(power),
        box_side: window,
        anchor: Anchor::WindowCentre,
        background: Background::Given {
            level_e: 0.0,
            variance_e2: 0.0,
        },
    };
    let c = cog(&CentroidInput::new(w), &params);
    if c.flags
        .intersects(CentroidFlags::DEGENERATE | CentroidFlags::CLAMPED)
    {
        return None;
    }
    Some((f64::from(c.x_px) - cx, f64::from(c.y_px) - cy))
}

/// RMS over both axes of the shift for true positions on an `m` x `m` grid of cell
/// midpoints over the central pixel ([`super::phases`]): `sqrt(mean((dx^2 + dy^2) / 2))`,
/// which by symmetry is the RMS of one axis. Degenerate positions are skipped (none occur
/// for the figures' ranges; the tests check it).
pub fn rms_shift(a_px: f64, window: u8, power: u8, m: usize) -> f64 {
    let ph = super::phases(m);
    let (mut sum, mut n) = (0.0, 0usize);
    for &py in &ph {
        for &px in &ph {
            if let Some((dx, dy)) = core_shift(a_px, window, power, px, py) {
                sum += 0.5 * (dx * dx + dy * dy);
                n += 1;
            }
        }
    }
    if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }
}
