//! Hamilton quaternions, scalar first, as rotations taking ICRS vectors to camera vectors:
//! `v_cam = q v_icrs q*`. Small 3-vector helpers for the rest of the crate.

/// A rotation as a unit Hamilton quaternion `[w, x, y, z]`, taking ICRS vectors to camera
/// vectors. `w >= 0` after [`Quat::normalized`] (q and -q are the same rotation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quat(pub [f64; 4]);

impl Quat {
    /// The identity rotation.
    pub const IDENTITY: Self = Self([1.0, 0.0, 0.0, 0.0]);

    /// Unit norm and `w >= 0`; `None` for a zero or non-finite quaternion.
    pub fn normalized(self) -> Option<Self> {
        let n = libm::sqrt(self.0.iter().map(|c| c * c).sum::<f64>());
        if !n.is_finite() || n == 0.0 {
            return None;
        }
        let s = if self.0[0] < 0.0 { -1.0 / n } else { 1.0 / n };
        Some(Self(self.0.map(|c| c * s)))
    }

    /// The rotation of `angle_rad` about the unit `axis`.
    pub fn from_axis_angle(axis: [f64; 3], angle_rad: f64) -> Self {
        let (s, c) = (libm::sin(angle_rad / 2.0), libm::cos(angle_rad / 2.0));
        Self([c, axis[0] * s, axis[1] * s, axis[2] * s])
    }

    /// The rotation `small` (a rotation vector, rad: axis times angle).
    pub fn from_rotation_vector(small: [f64; 3]) -> Self {
        let angle = norm(small);
        if angle == 0.0 {
            return Self::IDENTITY;
        }
        Self::from_axis_angle(small.map(|c| c / angle), angle)
    }

    /// The inverse rotation (camera to ICRS).
    pub(crate) fn conj(self) -> Self {
        let [w, x, y, z] = self.0;
        Self([w, -x, -y, -z])
    }

    /// The rotation matrix: `v_cam = M v_icrs`, rows are camera axes in ICRS.
    pub(crate) fn matrix(self) -> [[f64; 3]; 3] {
        let [w, x, y, z] = self.0;
        [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - w * z),
                2.0 * (x * z + w * y),
            ],
            [
                2.0 * (x * y + w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - w * x),
            ],
            [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ]
    }

    /// An ICRS vector in the camera frame.
    pub fn rotate(self, v: [f64; 3]) -> [f64; 3] {
        mat_vec(&self.matrix(), v)
    }

    /// A camera vector in ICRS.
    pub fn rotate_inv(self, v: [f64; 3]) -> [f64; 3] {
        mat_t_vec(&self.matrix(), v)
    }

    /// The rotation vector (rad, camera frame) of the error `self * truth^-1`: the small
    /// rotation that takes the true camera frame to this one. Its x and y components are the
    /// boresight (cross-axis) error, z the roll error.
    pub fn error_vector(self, truth: Self) -> [f64; 3] {
        let e = (self * truth.conj()).normalized().unwrap_or(Self::IDENTITY);
        let [w, x, y, z] = e.0;
        let s = libm::sqrt(x * x + y * y + z * z);
        if s == 0.0 {
            return [0.0; 3];
        }
        let angle = 2.0 * libm::atan2(s, w);
        [x / s * angle, y / s * angle, z / s * angle]
    }
}

/// Hamilton product `a * b`: apply `b` first, then `a`.
impl core::ops::Mul for Quat {
    type Output = Self;

    fn mul(self, other: Self) -> Self {
        let [a0, a1, a2, a3] = self.0;
        let [b0, b1, b2, b3] = other.0;
        Self([
            a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
        ])
    }
}

/// Dot product.
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Cross product.
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Euclidean norm.
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    libm::sqrt(dot(a, a))
}

/// The angle between two vectors, rad (atan2 of |a x b| and a . b: accurate at any angle).
pub fn angle_between(a: [f64; 3], b: [f64; 3]) -> f64 {
    libm::atan2(norm(cross(a, b)), dot(a, b))
}

/// `m v`.
pub(crate) fn mat_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}

/// `m^T v`.
pub(crate) fn mat_t_vec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [
        m[0][0] * v[0] + m[1][0] * v[1] + m[2][0] * v[2],
        m[0][1] * v[0] + m[1][1] * v[1] + m[2][1] * v[2],
        m[0][2] * v[0] + m[1][2] * v[1] + m[2][2] * v[2],
    ]
}
