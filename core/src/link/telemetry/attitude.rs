//! A frame's attitude report `TM[134,2]`: the attitude stage's result as the link carries it
//! ([`AttitudeReport`]), its field table ([`ATTITUDE_FIELDS`]) and its encoder. A few
//! stores a field, [`ATTITUDE_LEN`] bytes.

use super::fields::Writer;

/// The attitude report's fields (`TM[134,2]`), in order: name, type, meaning.
pub const ATTITUDE_FIELDS: [(&str, &str, &str); 17] = [
    ("frame", "u32", "the frame"),
    (
        "status",
        "u8",
        "0 no attitude: too few usable stars, 1 no attitude: not identified, 2 tracking (from the last attitude), 3 lost in space",
    ),
    (
        "used",
        "u8",
        "usable stars given to identification (at most 32)",
    ),
    (
        "matched",
        "u8",
        "stars identified and in the attitude (0 without one)",
    ),
    ("reserved", "u8", "0"),
    (
        "qw",
        "f64",
        "attitude quaternion, ICRS to camera, Hamilton, scalar first (0 without one)",
    ),
    ("qx", "f64", ""),
    ("qy", "f64", ""),
    ("qz", "f64", ""),
    (
        "cov_xx",
        "f32",
        "covariance of the error rotation vector, camera frame, rad^2 (x, y across the boresight, z roll)",
    ),
    ("cov_xy", "f32", ""),
    ("cov_xz", "f32", ""),
    ("cov_yy", "f32", ""),
    ("cov_yz", "f32", ""),
    ("cov_zz", "f32", ""),
    (
        "false_probability",
        "f32",
        "upper bound on the probability that the identification is false",
    ),
    ("time_us", "u64", "time of the frame, us"),
];

/// Length of the attitude report, bytes.
pub const ATTITUDE_LEN: usize = 4 + 4 + 4 * 8 + 7 * 4 + 8;

/// A frame's attitude as the link carries it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeReport {
    /// The frame.
    pub frame: u32,
    /// The attitude stage's result: the fix, or why there is none.
    pub fix: Result<crate::solver::Fix, AttitudeMissing>,
}

/// Why a frame's attitude report carries no attitude.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AttitudeMissing {
    /// Fewer usable stars than identification needs.
    TooFewStars {
        /// Usable stars.
        used: u8,
    },
    /// Identification found no solution.
    NotIdentified {
        /// Usable stars.
        used: u8,
    },
}

impl AttitudeReport {
    /// The report of the attitude stage's `result` for `frame`.
    pub fn of(frame: u32, result: &Result<crate::solver::Fix, crate::solver::SolveError>) -> Self {
        use crate::solver::SolveError;
        Self {
            frame,
            fix: match *result {
                Ok(f) => Ok(f),
                Err(SolveError::TooFewStars { usable }) => {
                    Err(AttitudeMissing::TooFewStars { used: usable })
                }
                Err(SolveError::Ident { usable, .. }) => {
                    Err(AttitudeMissing::NotIdentified { used: usable })
                }
            },
        }
    }

    /// Writes the report ([`ATTITUDE_FIELDS`]); `time_us` is used when there is no fix.
    pub fn encode(&self, time_us: u64, out: &mut [u8]) -> Option<usize> {
        use crate::solver::SolveMode;
        let mut w = Writer::new(out);
        w.u32(self.frame);
        match &self.fix {
            Ok(f) => {
                let status = match f.mode {
                    SolveMode::Tracking => 2,
                    SolveMode::LostInSpace => 3,
                };
                w.u8(status).u8(f.used).u8(f.matched).u8(0);
                for v in f.attitude.q.0 {
                    w.f64(v);
                }
                let c = &f.attitude.cov_rad2;
                for (i, j) in [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)] {
                    let v = c.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0);
                    w.f32(v as f32);
                }
                w.f32(f.false_probability as f32).u64(f.time_us);
            }
            Err(m) => {
                let (status, used) = match *m {
                    AttitudeMissing::TooFewStars { used } => (0, used),
                    AttitudeMissing::NotIdentified { used } => (1, used),
                };
                w.u8(status).u8(used).u8(0).u8(0);
                for _ in 0..4 {
                    w.f64(0.0);
                }
                for _ in 0..7 {
                    w.f32(0.0);
                }
                w.u64(time_us);
            }
        }
        w.finish()
    }
}
