//! Where a centroid puts a star whose image accelerates during the exposure: the offset
//! from its position at mid-exposure, as a fraction `k` of `a T^2` (`a` the image's
//! acceleration, px/s^2, `T` the integration, s), for the attitude stage to take out of a
//! slew's attitudes ([`crate::attitude::Acceleration::mid_exposure`]).
//!
//! A star at `s(t) = v t + a t^2 / 2` over `t` in `[-T/2, T/2]` leaves a trail whose ends
//! are `a T^2 / 8` past the mid-exposure position and whose light is the denser at its slow
//! end; its centre of light is `a T^2 / 24` past. A centroid of a round or short image (the
//! Gaussian fit, a CoG, the trail fit of a trail much shorter than the PSF) finds the centre
//! of light, `k` = 1/24; the trail fit of [`super`] (the segment held from the predicted
//! trail) follows the trail's edges more the longer the trail is against the PSF, `k`
//! rising towards 1/8. The table is the trail fit's response measured noise-free on the
//! simulator's exactly integrated trails (`startrack_sim::trail`, the path cut into 400
//! equal-time straight pieces), a PSF of sigma 0.67 px (the flight PSF), the middle of the
//! responses of stars of 500 to 100,000 e- (a faint star's weights are the background's,
//! flat, a bright one's its own light's, which lean on the trail's dense end less)
//! (`cargo test -p startrack-host --test centroids
//! centroid_trail_accel:: -- --nocapture` prints the response and asserts the table within
//! [`ACCEL_OFFSET_SIGMA`] of it at PSF sigmas 0.67 and 1 px), against the trail's length
//! over `s = sqrt(sigma^2 + 1/12)`, the fit's own width. Past the table `1/8 - k` falls as
//! `1/x`, the edges' share of the light.
//!
//! Cost: a scan of 9 entries and one interpolation.

/// The 1-sigma uncertainty the attitude stage gives a table value: the largest distance of
/// the fit's response from the table over the stars of the test (500 to 100,000 e-, PSF
/// sigmas 0.67 and 1 px, two angles; 0.0120 measured, about half the spread between a faint
/// star's background-weighted fit and a bright star's), rounded up.
pub const ACCEL_OFFSET_SIGMA: f64 = 0.013;

/// `(L / s, k)`: the table of the module docs.
const TABLE: [(f64, f64); 9] = [
    (0.0, 1.0 / 24.0),
    (1.37, 0.0398),
    (2.74, 0.0360),
    (4.11, 0.0373),
    (5.48, 0.0436),
    (8.22, 0.0590),
    (10.97, 0.0710),
    (13.71, 0.0788),
    (19.19, 0.0902),
];

/// The offset of a centroid from the mid-exposure position as a fraction of `a T^2`, for a
/// trail of `trail_px` (the displacement over the integration, px) fitted with the width
/// `width_px` (`s`); 1/24 for a trail or width that is not finite or not positive.
pub fn accel_offset_fraction(trail_px: f64, width_px: f64) -> f64 {
    let x = trail_px / width_px;
    if !(x.is_finite() && x > 0.0) {
        return TABLE[0].1;
    }
    let mut prev = TABLE[0];
    for &(xi, ki) in &TABLE[1..] {
        if x <= xi {
            let f = (x - prev.0) / (xi - prev.0);
            return prev.1 + f * (ki - prev.1);
        }
        prev = (xi, ki);
    }
    0.125 - (0.125 - prev.1) * prev.0 / x
}
