//! The windows of the next tracking frame as the attitude stage predicts them: the typed
//! interface through which a home's attitude stage (the frame cycle's, [`crate::predict`])
//! hands the tracker the catalog stars it expects, without the tracker knowing the catalog,
//! the camera or the solver.
//!
//! Each [`PredictedStar`] is one catalog star at its predicted position at the next frame's
//! mid-exposure, the bound within which it must be found, and its image's velocity there.
//! The tracker places one window per star ([`predicted_window_side`]: the centroid window,
//! the bound on each side and the trail over the configured exposure), measures a trailed
//! star with the trailed-star fit from its trail over the frame's own integration (the
//! velocity times the integration the line source reports, [`super::Integration`]) in its
//! first tracked frame (no settling: its motion comes from the attitude, not from its own
//! last positions), and reports each star with the prediction it was measured for
//! ([`super::Tracker::identities`]), so that the attitude stage can check the star against
//! its prediction and use its identity.
//!
//! Cost: a copy of at most [`super::TRACK_WINDOWS`] entries of 28 bytes a frame.

use crate::detect::capture::CAPTURE_MAX_SIDE;

/// One catalog star the attitude stage predicts in the next frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PredictedStar {
    /// The star's index in the on-board catalog: its identity.
    pub catalog: u16,
    /// Predicted position at mid-exposure, column, px.
    pub x_px: f32,
    /// Predicted position at mid-exposure, row, px.
    pub y_px: f32,
    /// The prediction's bound, px: the measured star must lie within this of the predicted
    /// position (a multiple of the prediction's sigma plus the model's error floor).
    pub bound_px: f32,
    /// The star's image velocity over the exposure (column, row), px/s: its trail over an
    /// integration of `T` s, from its start to its end, is `T` times this.
    pub rate_px_s: (f32, f32),
    /// The star's predicted motion from this frame's mid-exposure to the next one's (column,
    /// row), px: what the tracker places the next window by if the attitude stage gives no
    /// prediction then.
    pub motion_px: (f32, f32),
}

impl PredictedStar {
    /// Whether every field is finite and the bound positive: a star the tracker places.
    pub fn is_valid(&self) -> bool {
        [
            self.x_px,
            self.y_px,
            self.bound_px,
            self.rate_px_s.0,
            self.rate_px_s.1,
            self.motion_px.0,
            self.motion_px.1,
        ]
        .iter()
        .all(|v| v.is_finite())
            && self.bound_px > 0.0
    }

    /// The star's trail over an integration of `integration_s` s, px (column, row).
    pub fn trail_px(&self, integration_s: f32) -> (f32, f32) {
        (
            self.rate_px_s.0 * integration_s,
            self.rate_px_s.1 * integration_s,
        )
    }

    /// Whether a star measured at (`x_px`, `y_px`) matches the prediction: within
    /// [`Self::bound_px`] of it.
    pub fn matches(&self, x_px: f32, y_px: f32) -> bool {
        let (dx, dy) = (x_px - self.x_px, y_px - self.y_px);
        let d = libm::sqrtf(dx * dx + dy * dy);
        d.is_finite() && d <= self.bound_px
    }
}

/// The side of a predicted star's tracking window, px: the centroid window `window_px`,
/// the bound on each side (rounded up) and the trail's larger component (rounded up), kept
/// odd, at most [`CAPTURE_MAX_SIDE`] and at least `window_px`.
pub fn predicted_window_side(window_px: u16, bound_px: f32, trail_px: (f32, f32)) -> u16 {
    let up = |v: f32| -> u16 {
        if v.is_finite() && v > 0.0 {
            libm::ceilf(v.min(f32::from(CAPTURE_MAX_SIDE))) as u16
        } else {
            0
        }
    };
    let extent = up(trail_px.0.abs().max(trail_px.1.abs()));
    (window_px
        .saturating_add(up(bound_px).saturating_mul(2))
        .saturating_add(extent)
        | 1)
    .min(CAPTURE_MAX_SIDE)
    .max(window_px)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sides_hold_the_bound_and_the_trail_within_the_capture() {
        assert_eq!(predicted_window_side(7, 1.5, (0.0, 0.0)), 11);
        assert_eq!(predicted_window_side(7, 0.2, (0.0, 0.0)), 9);
        assert_eq!(predicted_window_side(7, 1.5, (3.4, -0.2)), 15);
        assert_eq!(predicted_window_side(7, 1.5, (13.6, 0.0)), CAPTURE_MAX_SIDE);
        assert_eq!(predicted_window_side(7, f32::NAN, (f32::INFINITY, 0.0)), 7);
        assert_eq!(predicted_window_side(7, -3.0, (0.0, 0.0)), 7);
    }

    #[test]
    fn a_star_matches_within_its_bound_only() {
        let p = PredictedStar {
            catalog: 3,
            x_px: 100.0,
            y_px: 200.0,
            bound_px: 1.5,
            ..PredictedStar::default()
        };
        assert!(p.is_valid());
        assert!(p.matches(101.0, 201.0));
        assert!(!p.matches(101.2, 201.2));
        assert!(!p.matches(f32::NAN, 200.0));
        assert!(
            !PredictedStar {
                x_px: f32::NAN,
                ..p
            }
            .is_valid()
        );
    }
}
