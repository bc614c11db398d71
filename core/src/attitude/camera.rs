//! The pinhole camera with radial distortion that turns a centroid into a direction and back.
//!
//! Camera frame: +z along the boresight towards the sky, +x along increasing column, +y along
//! increasing row; pixel centres at integers, 0-based. A direction `(X, Y, Z)` (Z > 0) has
//! normalised coordinates `(x_u, y_u) = (X/Z, Y/Z)`, distorted to
//! `(x_d, y_d) = (x_u, y_u) (1 + k1 r_u^2)` and imaged at column `cx + f x_d`, row
//! `cy + f y_d`. The inverse solves the distortion by fixed-point iteration (at most
//! [`UNDISTORT_ITERATIONS`], about 10 flops each).

/// Fixed-point iterations of the undistortion (the error shrinks by `3 k1 r^2` per step).
pub const UNDISTORT_ITERATIONS: usize = 8;

/// A camera model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Focal length, px.
    pub focal_length_px: f64,
    /// Principal point (column, row), px.
    pub principal_point_px: [f64; 2],
    /// Radial distortion, normalised units (0 = none).
    pub k1: f64,
}

impl Camera {
    /// The unit camera-frame direction of pixel position (`x_px` column, `y_px` row).
    pub fn direction(&self, x_px: f64, y_px: f64) -> [f64; 3] {
        let xd = (x_px - self.principal_point_px[0]) / self.focal_length_px;
        let yd = (y_px - self.principal_point_px[1]) / self.focal_length_px;
        let (mut xu, mut yu) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let f = 1.0 + self.k1 * (xu * xu + yu * yu);
            xu = xd / f;
            yu = yd / f;
        }
        let n = libm::sqrt(xu * xu + yu * yu + 1.0);
        [xu / n, yu / n, 1.0 / n]
    }

    /// The pixel position (column, row) of a camera-frame direction, or `None` behind the
    /// camera.
    pub fn project(&self, dir: [f64; 3]) -> Option<[f64; 2]> {
        if dir[2] <= 0.0 || !dir[2].is_finite() {
            return None;
        }
        let (xu, yu) = (dir[0] / dir[2], dir[1] / dir[2]);
        let f = 1.0 + self.k1 * (xu * xu + yu * yu);
        Some([
            self.principal_point_px[0] + self.focal_length_px * xu * f,
            self.principal_point_px[1] + self.focal_length_px * yu * f,
        ])
    }
}
