//! The tracker's angular rate: the body's rate in the camera frame and its covariance, as the
//! attitude report carries it ([`Rate`]).

/// An angular rate and its covariance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rate {
    /// Angular rate of the camera frame against ICRS, in the camera frame, rad/s (x, y across
    /// the boresight, z roll): `q(t + dt) = exp(w dt) q(t)`.
    pub w_rad_s: [f64; 3],
    /// Its covariance, rad^2/s^2.
    pub cov_rad2_s2: [[f64; 3]; 3],
}

impl Rate {
    /// Magnitude of the rate, rad/s.
    pub fn magnitude_rad_s(&self) -> f64 {
        libm::sqrt(self.w_rad_s.iter().map(|v| v * v).sum())
    }
}
