//! The spacecraft's turn during the exposure: a body-rate profile about a fixed axis (a
//! constant rate, or a slew from rest with an acceleration ramp), the frames' timing, and the
//! attitude and rate at any time, for scenes whose stars move while the shutter is open.
//!
//! # Conventions
//! The rate `w` is the camera's angular velocity relative to ICRS, in the camera frame, rad/s
//! (what a gyro on the camera reads: x and y across the boresight, z roll about it). A star's
//! camera-frame direction then moves as `dv/dt = -w x v`, and with `q(t)` taking ICRS to the
//! camera (scalar first, as `solve`'s), `q(t) = exp(-n theta(t)) q0` for the fixed unit axis
//! `n` and the angle turned `theta(t)`: exact for any rate history about a fixed axis, since
//! rotations about one axis commute. A turn about +y moves the field along -x, about +x
//! along +y.
//!
//! # Profile
//! `theta(t) = |w| t` at a constant rate; a slew from rest at `t = 0` with acceleration
//! `alpha` reaches `|w|` at `t_r = |w| / alpha`: `theta = alpha t^2 / 2` before it and
//! `|w| t - |w| t_r / 2` after.
//!
//! # Timing
//! Frame `k`'s exposure opens at `k period_s` and closes `exposure_s` later (frame transfer:
//! the next exposure opens at the next period; the transfer's own duration is not taken out
//! of the exposure). The truth of a frame is at mid-exposure.

use startrack_core::attitude::Quat;

/// A body-rate profile about a fixed axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateProfile {
    /// The rate (reached at once, or at the end of the ramp), camera frame, rad/s.
    pub rate_rad_s: [f64; 3],
    /// The slew's acceleration from rest at `t = 0`, rad/s^2; 0 for the constant rate.
    pub accel_rad_s2: f64,
}

impl RateProfile {
    /// A constant rate, rad/s.
    pub const fn constant(rate_rad_s: [f64; 3]) -> Self {
        Self {
            rate_rad_s,
            accel_rad_s2: 0.0,
        }
    }

    fn speed_rad_s(&self) -> f64 {
        let [x, y, z] = self.rate_rad_s;
        (x * x + y * y + z * z).sqrt()
    }

    /// When the ramp ends, s (0 at a constant rate).
    pub fn ramp_end_s(&self) -> f64 {
        if self.accel_rad_s2 > 0.0 {
            self.speed_rad_s() / self.accel_rad_s2
        } else {
            0.0
        }
    }

    /// The angle turned from `t = 0` to `t_s`, rad (`t_s >= 0`; earlier times are at rest).
    pub fn angle_rad(&self, t_s: f64) -> f64 {
        let (w, t) = (self.speed_rad_s(), t_s.max(0.0));
        let tr = self.ramp_end_s();
        if t < tr {
            0.5 * self.accel_rad_s2 * t * t
        } else {
            w * t - 0.5 * w * tr
        }
    }

    /// The rate at `t_s`, camera frame, rad/s.
    pub fn rate_at(&self, t_s: f64) -> [f64; 3] {
        let (t, tr) = (t_s.max(0.0), self.ramp_end_s());
        let f = if t < tr { t / tr } else { 1.0 };
        self.rate_rad_s.map(|c| c * f)
    }

    /// The attitude at `t_s` of a camera at `q0` at `t = 0`.
    pub fn attitude(&self, q0: Quat, t_s: f64) -> Quat {
        let w = self.speed_rad_s();
        if w == 0.0 {
            return q0;
        }
        let a = self.angle_rad(t_s) / w;
        Quat::from_rotation_vector(self.rate_rad_s.map(|c| -c * a)) * q0
    }
}

/// Why a motion cannot be simulated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotionError {
    /// A rate or acceleration component that is not finite, or a negative acceleration.
    Rate,
    /// An exposure that is not positive and finite, or longer than the frame period.
    Exposure,
}

impl std::fmt::Display for MotionError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Rate => "the rate and acceleration must be finite, the acceleration >= 0",
            Self::Exposure => "the exposure must be positive and no longer than the frame period",
        })
    }
}

impl std::error::Error for MotionError {}

/// The turn and the frames' timing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExposureMotion {
    /// The rate profile.
    pub profile: RateProfile,
    /// Frame period, s.
    pub period_s: f64,
    /// Exposure, s (at most the period).
    pub exposure_s: f64,
}

impl ExposureMotion {
    /// A checked motion.
    pub fn new(profile: RateProfile, period_s: f64, exposure_s: f64) -> Result<Self, MotionError> {
        let finite = profile.rate_rad_s.iter().all(|c| c.is_finite())
            && profile.accel_rad_s2.is_finite()
            && profile.accel_rad_s2 >= 0.0;
        if !finite {
            return Err(MotionError::Rate);
        }
        if !(exposure_s.is_finite() && exposure_s > 0.0 && period_s.is_finite())
            || exposure_s > period_s
        {
            return Err(MotionError::Exposure);
        }
        Ok(Self {
            profile,
            period_s,
            exposure_s,
        })
    }

    /// Frame `frame`'s exposure start, s.
    pub fn start_s(&self, frame: u32) -> f64 {
        f64::from(frame) * self.period_s
    }

    /// Frame `frame`'s exposure end, s.
    pub fn end_s(&self, frame: u32) -> f64 {
        self.start_s(frame) + self.exposure_s
    }

    /// Frame `frame`'s mid-exposure, s.
    pub fn mid_s(&self, frame: u32) -> f64 {
        self.start_s(frame) + 0.5 * self.exposure_s
    }

    /// The midpoints of `steps` equal time steps of frame `frame`'s exposure, s.
    pub fn step_times_s(&self, frame: u32, steps: usize) -> impl Iterator<Item = f64> + '_ {
        let (t0, n) = (self.start_s(frame), steps.max(1));
        (0..n).map(move |j| t0 + (j as f64 + 0.5) / n as f64 * self.exposure_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_is_continuous_and_reaches_the_rate() {
        let p = RateProfile {
            rate_rad_s: [0.0, 0.02, 0.0],
            accel_rad_s2: 0.01,
        };
        assert!((p.ramp_end_s() - 2.0).abs() < 1e-12);
        let (a, b) = (p.angle_rad(2.0 - 1e-9), p.angle_rad(2.0 + 1e-9));
        assert!(
            (a - 0.02).abs() < 1e-9 && (b - 0.02).abs() < 1e-9,
            "{a} {b}"
        );
        assert!((p.angle_rad(3.0) - 0.04).abs() < 1e-12);
        assert_eq!(p.rate_at(1.0), [0.0, 0.01, 0.0]);
        assert_eq!(p.rate_at(5.0), [0.0, 0.02, 0.0]);
    }

    #[test]
    fn a_turn_about_y_moves_the_boresight_star_along_minus_x() {
        let p = RateProfile::constant([0.0, 0.01, 0.0]);
        let q = p.attitude(Quat::IDENTITY, 1.0);
        let v = q.rotate([0.0, 0.0, 1.0]);
        assert!((v[0] + 0.01f64.sin()).abs() < 1e-12, "{v:?}");
        // The attitude error against the start is the angle turned, about -y.
        let e = q.error_vector(Quat::IDENTITY);
        assert!((e[1] + 0.01).abs() < 1e-12 && e[0].abs() < 1e-15, "{e:?}");
    }

    #[test]
    fn bad_motion_is_refused() {
        let p = RateProfile::constant([0.0; 3]);
        assert_eq!(ExposureMotion::new(p, 0.1, 0.2), Err(MotionError::Exposure));
        assert_eq!(ExposureMotion::new(p, 0.1, 0.0), Err(MotionError::Exposure));
        let bad = RateProfile::constant([f64::NAN, 0.0, 0.0]);
        assert_eq!(ExposureMotion::new(bad, 0.1, 0.1), Err(MotionError::Rate));
        let m = ExposureMotion::new(p, 0.1, 0.05).unwrap();
        assert!((m.mid_s(3) - 0.325).abs() < 1e-12);
        let t: Vec<f64> = m.step_times_s(0, 2).collect();
        assert!((t[0] - 0.0125).abs() < 1e-12 && (t[1] - 0.0375).abs() < 1e-12);
    }
}
