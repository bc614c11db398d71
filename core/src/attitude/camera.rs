//! The camera model that turns a centroid into a direction and back: a pinhole with radial
//! (`k1`, `k2`) and tangential (`p1`, `p2`) distortion (Brown-Conrady, the OpenCV
//! convention) and a lateral colour term that scales the image with each star's B-V.
//!
//! Camera frame: +z along the boresight towards the sky, +x along increasing column, +y along
//! increasing row; pixel centres at integers, 0-based. A direction `(X, Y, Z)` (Z > 0) has
//! normalised coordinates `(x, y) = (X/Z, Y/Z)`, `r^2 = x^2 + y^2`, distorted to
//!
//! ```text
//! x_d = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)
//! y_d = y (1 + k1 r^2 + k2 r^4) + p1 (r^2 + 2 y^2) + 2 p2 x y
//! ```
//!
//! and imaged at column `cx + f s x_d`, row `cy + f s y_d`, with the colour scale
//! `s = 1 + c (B-V - B-V_ref)`: lateral colour is a focal length that depends on the star's
//! colour, so a star is moved along the radius by `c (B-V - B-V_ref)` times its distance from
//! the principal point. At the reference colour (and for the uncoloured [`Camera::project`]
//! and [`Camera::direction`]) `s = 1`.
//!
//! Cost: the forward model is about 25 flops. The inverse solves the distortion by Newton's
//! method on the 2x2 system (at most [`UNDISTORT_ITERATIONS`] steps of about 45 flops;
//! three reach 1e-12 in normalised units, 4e-9 px, for the CCD47-20's 15 degree field with
//! percent-level distortion) and reports [`CameraError::NoInverse`] when it does not
//! converge, which happens only where the distortion folds the image (outside any field a
//! real lens is used over; [`Camera::check_over`] proves a model invertible over a frame).
//! Everything is f64: the Cortex-M7 of the STM32H743 has a double-precision FPU.

/// Most Newton steps of the undistortion.
pub(crate) const UNDISTORT_ITERATIONS: usize = 10;

/// The undistortion has converged when the distorted point is matched to this, normalised
/// units (4e-9 px at a 3,889 px focal length).
pub(crate) const UNDISTORT_TOLERANCE: f64 = 1e-12;

/// A camera model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Focal length, px (> 0).
    pub focal_length_px: f64,
    /// Principal point (column, row), px.
    pub principal_point_px: [f64; 2],
    /// Radial distortion, coefficient of `r^2`, normalised units (0 = none).
    pub k1: f64,
    /// Radial distortion, coefficient of `r^4`, normalised units.
    pub k2: f64,
    /// Tangential (decentring) distortion, normalised units.
    pub p1: f64,
    /// Tangential (decentring) distortion, normalised units.
    pub p2: f64,
    /// Lateral colour: relative image scale per magnitude of B-V from
    /// [`Self::colour_ref_bv_mag`], per mag (0 = none).
    pub colour_scale_per_mag: f64,
    /// The B-V at which the colour scale is 1, mag.
    pub colour_ref_bv_mag: f64,
}

/// Why the camera model could not map a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CameraError {
    /// A parameter or an input is not finite, or the focal length is not positive.
    BadParameter,
    /// The colour scale `1 + c (B-V - B-V_ref)` is not positive.
    BadColour,
    /// The point is behind the camera (`Z <= 0`).
    BehindCamera,
    /// The undistortion did not converge: the distortion folds the image there.
    NoInverse,
}

impl core::fmt::Display for CameraError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::BadParameter => "camera model: a parameter or input is not valid",
            Self::BadColour => "camera model: the colour scale is not positive",
            Self::BehindCamera => "camera model: the direction is behind the camera",
            Self::NoInverse => "camera model: the distortion has no inverse there",
        })
    }
}

impl core::error::Error for CameraError {}

impl Camera {
    /// A pinhole camera: no distortion, no lateral colour (reference B-V 0.6 mag, near the
    /// sky's median).
    pub const fn pinhole(focal_length_px: f64, principal_point_px: [f64; 2]) -> Self {
        Self {
            focal_length_px,
            principal_point_px,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            colour_scale_per_mag: 0.0,
            colour_ref_bv_mag: 0.6,
        }
    }

    fn params_ok(&self) -> bool {
        self.focal_length_px > 0.0
            && [
                self.focal_length_px,
                self.principal_point_px[0],
                self.principal_point_px[1],
                self.k1,
                self.k2,
                self.p1,
                self.p2,
                self.colour_scale_per_mag,
                self.colour_ref_bv_mag,
            ]
            .iter()
            .all(|v| v.is_finite())
    }

    /// The colour scale `1 + c (B-V - B-V_ref)` of a star of colour `bv_mag`.
    pub(crate) fn colour_scale(&self, bv_mag: f64) -> Result<f64, CameraError> {
        let s = 1.0 + self.colour_scale_per_mag * (bv_mag - self.colour_ref_bv_mag);
        if !s.is_finite() {
            return Err(CameraError::BadParameter);
        }
        if s <= 0.0 {
            return Err(CameraError::BadColour);
        }
        Ok(s)
    }

    /// The distorted normalised point of the undistorted `(x, y)`.
    pub fn distort(&self, x: f64, y: f64) -> [f64; 2] {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + self.k2 * r2);
        [
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        ]
    }

    /// The Jacobian `d(x_d, y_d) / d(x, y)` of [`Self::distort`], rows `x_d`, `y_d`.
    pub(crate) fn distort_jacobian(&self, x: f64, y: f64) -> [[f64; 2]; 2] {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + self.k2 * r2);
        // d(radial)/dx = (2 k1 + 4 k2 r^2) x, likewise for y.
        let dr = 2.0 * self.k1 + 4.0 * self.k2 * r2;
        [
            [
                radial + x * dr * x + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
                x * dr * y + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            ],
            [
                y * dr * x + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
                radial + y * dr * y + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
            ],
        ]
    }

    /// The undistorted normalised point whose distortion is `(xd, yd)`, by Newton's method
    /// from `(xd, yd)`.
    pub(crate) fn undistort(&self, xd: f64, yd: f64) -> Result<[f64; 2], CameraError> {
        if !(xd.is_finite() && yd.is_finite() && self.params_ok()) {
            return Err(CameraError::BadParameter);
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let [fx, fy] = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if !(ex.is_finite() && ey.is_finite()) {
                return Err(CameraError::NoInverse);
            }
            if ex.abs() <= UNDISTORT_TOLERANCE && ey.abs() <= UNDISTORT_TOLERANCE {
                return Ok([x, y]);
            }
            let [[a, b], [c, d]] = self.distort_jacobian(x, y);
            let det = a * d - b * c;
            if !(det > 0.0 && det.is_finite()) {
                // A fold (det <= 0) or a blown-up step: no unique inverse here.
                return Err(CameraError::NoInverse);
            }
            x -= (d * ex - b * ey) / det;
            y -= (a * ey - c * ex) / det;
        }
        let [fx, fy] = self.distort(x, y);
        if (fx - xd).abs() <= UNDISTORT_TOLERANCE && (fy - yd).abs() <= UNDISTORT_TOLERANCE {
            Ok([x, y])
        } else {
            Err(CameraError::NoInverse)
        }
    }

    /// The unit camera-frame direction of a star of colour `bv_mag` at pixel position
    /// (`x_px` column, `y_px` row): the colour scale removed, then the distortion.
    pub fn direction_of(&self, x_px: f64, y_px: f64, bv_mag: f64) -> Result<[f64; 3], CameraError> {
        if !self.params_ok() {
            return Err(CameraError::BadParameter);
        }
        let fs = self.focal_length_px * self.colour_scale(bv_mag)?;
        let xd = (x_px - self.principal_point_px[0]) / fs;
        let yd = (y_px - self.principal_point_px[1]) / fs;
        let [x, y] = self.undistort(xd, yd)?;
        let n = libm::sqrt(x * x + y * y + 1.0);
        Ok([x / n, y / n, 1.0 / n])
    }

    /// The pixel position (column, row) of a camera-frame direction seen in a star of colour
    /// `bv_mag`.
    pub fn project_of(&self, dir: [f64; 3], bv_mag: f64) -> Result<[f64; 2], CameraError> {
        if !(self.params_ok() && dir.iter().all(|c| c.is_finite())) {
            return Err(CameraError::BadParameter);
        }
        if dir[2] <= 0.0 {
            return Err(CameraError::BehindCamera);
        }
        let fs = self.focal_length_px * self.colour_scale(bv_mag)?;
        let [xd, yd] = self.distort(dir[0] / dir[2], dir[1] / dir[2]);
        let p = [
            self.principal_point_px[0] + fs * xd,
            self.principal_point_px[1] + fs * yd,
        ];
        if p.iter().all(|c| c.is_finite()) {
            Ok(p)
        } else {
            Err(CameraError::BadParameter)
        }
    }

    /// The unit camera-frame direction of pixel position (`x_px` column, `y_px` row) at the
    /// reference colour. Where the model has no inverse (a fold, non-finite input) it
    /// returns the pinhole direction of the undistorted model, so identification still has
    /// a direction; [`Self::direction_of`] reports the error instead.
    pub fn direction(&self, x_px: f64, y_px: f64) -> [f64; 3] {
        self.direction_of(x_px, y_px, self.colour_ref_bv_mag)
            .unwrap_or_else(|_| {
                let f = if self.focal_length_px > 0.0 {
                    self.focal_length_px
                } else {
                    1.0
                };
                let x = (x_px - self.principal_point_px[0]) / f;
                let y = (y_px - self.principal_point_px[1]) / f;
                let n = libm::sqrt(x * x + y * y + 1.0);
                if n.is_finite() {
                    [x / n, y / n, 1.0 / n]
                } else {
                    [0.0, 0.0, 1.0]
                }
            })
    }

    /// The pixel position (column, row) of a camera-frame direction at the reference colour,
    /// or `None` behind the camera or for non-finite input.
    pub fn project(&self, dir: [f64; 3]) -> Option<[f64; 2]> {
        self.project_of(dir, self.colour_ref_bv_mag).ok()
    }

    /// Checks that the model is invertible and round-trips over a `cols` x `rows` frame (with
    /// a 5 % margin) for every colour in `bv_range_mag`: on a 9 x 9 grid of points (each
    /// corner and edge included), each colour end, the inverse converges and projects back
    /// within 1e-6 px. About 160 inversions.
    pub fn check_over(
        &self,
        cols: u16,
        rows: u16,
        bv_range_mag: [f64; 2],
    ) -> Result<(), CameraError> {
        if !self.params_ok() {
            return Err(CameraError::BadParameter);
        }
        let (w, h) = (f64::from(cols), f64::from(rows));
        for bv in bv_range_mag {
            for i in 0..9u8 {
                for j in 0..9u8 {
                    let x = -0.05 * w + 1.1 * w * f64::from(i) / 8.0 - 0.5;
                    let y = -0.05 * h + 1.1 * h * f64::from(j) / 8.0 - 0.5;
                    let d = self.direction_of(x, y, bv)?;
                    let p = self.project_of(d, bv)?;
                    if (p[0] - x).abs() > 1e-6 || (p[1] - y).abs() > 1e-6 {
                        return Err(CameraError::NoInverse);
                    }
                }
            }
        }
        Ok(())
    }
}
