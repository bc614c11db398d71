//! A frame's attitude report `TM[134,2]`, format [`ATTITUDE_FORMAT`]: the attitude stage's
//! result as the link carries it ([`AttitudeReport`]), tagged at mid-exposure in spacecraft
//! time (CCSDS CUC, [`crate::time`]), with the angular rate, both covariances and the
//! validity flags ([`Validity`]); its field table ([`ATTITUDE_FIELDS`]) and its encoder. A
//! few stores a field, [`ATTITUDE_LEN`] bytes.

use super::fields::{Writer, type_len};
use crate::attitude::Rate;
use crate::time::{SpacecraftTime, TimeError};

/// The attitude report's format, its eighth byte. Format 1 (76 bytes) had 0 there and no
/// spacecraft time, rate or flags.
pub const ATTITUDE_FORMAT: u8 = 2;

/// Above this rate the report flags [`Validity::RATE_TOO_HIGH`], rad/s: 3 deg/s, the rate up
/// to which tracking is to hold (docs/tracker.md); beyond it stars trail past their windows.
pub const RATE_LIMIT_RAD_S: f64 = 3.0 * core::f64::consts::PI / 180.0;

/// The attitude report's fields (`TM[134,2]`), in order: name, type, meaning.
pub const ATTITUDE_FIELDS: [(&str, &str, &str); 31] = [
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
    ("format", "u8", "2 (format 1 had 0 here)"),
    (
        "flags",
        "u16",
        "validity bits: 0 time not synchronised, 1 no velocity (attitude apparent), 2 too few stars, 3 rate too high, 4 no rate, 5 Moon in the field, 6 Earth in the field, 7 Sun stray light, 8 radiation (particle hits): what took stars from the frame",
    ),
    (
        "time_coarse",
        "u32",
        "mid-exposure, spacecraft time: CUC T-field, seconds (P-field 0x1E: TAI, 1958 epoch; 0 when not synchronised)",
    ),
    ("time_fine", "u16", "its fraction, 2^-16 s"),
    (
        "time_bound_us",
        "u32",
        "bound on the time's error, us (0 when not synchronised)",
    ),
    (
        "latency_us",
        "u32",
        "from mid-exposure to the report, us of the tracker's counter",
    ),
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
        "wx",
        "f32",
        "angular rate, camera frame, rad/s (0 with flag 4)",
    ),
    ("wy", "f32", ""),
    ("wz", "f32", ""),
    ("rate_cov_xx", "f32", "its covariance, rad^2/s^2"),
    ("rate_cov_xy", "f32", ""),
    ("rate_cov_xz", "f32", ""),
    ("rate_cov_yy", "f32", ""),
    ("rate_cov_yz", "f32", ""),
    ("rate_cov_zz", "f32", ""),
    (
        "false_probability",
        "f32",
        "upper bound on the probability that the identification is false",
    ),
    (
        "time_us",
        "u64",
        "mid-exposure on the tracker's counter, us",
    ),
];

/// Length of the attitude report, bytes.
#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time: a bad index fails the build, never the program"
)]
pub const ATTITUDE_LEN: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < ATTITUDE_FIELDS.len() {
        n += type_len(ATTITUDE_FIELDS[i].1);
        i += 1;
    }
    n
};

bitflags::bitflags! {
    /// What a report's attitude, time and rate can be trusted for; 0: all of it. The bit
    /// numbers are stable (the report's `flags`).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub struct Validity: u16 {
        /// The spacecraft time is not synchronised (no time-set and pulse yet, or the last
        /// pulse is older than the holdover): the time fields are 0, `time_us` alone holds.
        const TIME_NOT_SYNCHRONISED = 1 << 0;
        /// No velocity for the mid-exposure time: the quaternion is of the apparent
        /// directions (stellar aberration uncorrected, up to ~20" at 30 km/s), not the ICRF.
        const NO_VELOCITY = 1 << 1;
        /// Fewer usable stars than identification needs: no attitude.
        const TOO_FEW_STARS = 1 << 2;
        /// The rate is above what the tracker follows: the attitude and rate are suspect.
        const RATE_TOO_HIGH = 1 << 3;
        /// No rate yet (fewer than two attitudes in the filter's window): the rate fields
        /// are 0.
        const NO_RATE = 1 << 4;
        /// The Moon took stars from the frame (its saturated, bloomed columns masked): the
        /// attitude rests on the stars left, or there is none for want of them.
        const MOON_IN_FIELD = 1 << 5;
        /// The Earth took stars from the frame (its saturated region masked).
        const EARTH_IN_FIELD = 1 << 6;
        /// The Sun's stray light raised the sky background above its limit: faint stars lost.
        const SUN_STRAY_LIGHT = 1 << 7;
        /// Particle hits above the radiation limit were counted in the frame.
        const RADIATION = 1 << 8;
    }
}

impl Validity {
    /// The validity bits of a frame's [`crate::tracker::Obstructions`].
    pub fn of_obstructions(o: crate::tracker::Obstructions) -> Self {
        use crate::tracker::Obstructions as O;
        let mut v = Self::empty();
        v.set(Self::MOON_IN_FIELD, o.contains(O::MOON));
        v.set(Self::EARTH_IN_FIELD, o.contains(O::EARTH));
        v.set(Self::SUN_STRAY_LIGHT, o.contains(O::SUN));
        v.set(Self::RADIATION, o.contains(O::RADIATION));
        v
    }
}

/// A frame's attitude as the link carries it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AttitudeReport {
    /// The frame.
    pub frame: u32,
    /// The attitude stage's result: the fix, or why there is none.
    pub fix: Result<crate::solver::Fix, AttitudeMissing>,
    /// The validity flags.
    pub flags: Validity,
    /// Mid-exposure on the tracker's counter, us.
    pub mid_exposure_us: u64,
    /// Mid-exposure in spacecraft time (`None` with [`Validity::TIME_NOT_SYNCHRONISED`]).
    pub time: Option<SpacecraftTime>,
    /// From mid-exposure to the report, us of the counter.
    pub latency_us: u32,
    /// The angular rate (`None` with [`Validity::NO_RATE`]).
    pub rate: Option<Rate>,
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
    /// The report of the attitude stage's `result` for `frame`, at mid-exposure
    /// `mid_exposure_us` (the counter) whose spacecraft time is `time`, with `rate`; the
    /// flags follow from them, [`Validity::NO_VELOCITY`] from `velocity_applied`.
    pub fn of(
        frame: u32,
        result: &Result<crate::solver::Fix, crate::solver::SolveError>,
        mid_exposure_us: u64,
        time: Result<SpacecraftTime, TimeError>,
        rate: Option<Rate>,
        velocity_applied: bool,
    ) -> Self {
        use crate::solver::SolveError;
        let mut flags = Validity::empty();
        let fix = match *result {
            Ok(f) => Ok(f),
            Err(SolveError::TooFewStars { usable }) => {
                flags |= Validity::TOO_FEW_STARS;
                Err(AttitudeMissing::TooFewStars { used: usable })
            }
            Err(SolveError::Ident { usable, .. }) => {
                Err(AttitudeMissing::NotIdentified { used: usable })
            }
        };
        flags.set(Validity::TIME_NOT_SYNCHRONISED, time.is_err());
        flags.set(Validity::NO_VELOCITY, !velocity_applied);
        flags.set(Validity::NO_RATE, rate.is_none());
        flags.set(
            Validity::RATE_TOO_HIGH,
            rate.is_some_and(|r| {
                let m = r.magnitude_rad_s();
                m.is_nan() || m > RATE_LIMIT_RAD_S
            }),
        );
        Self {
            frame,
            fix,
            flags,
            mid_exposure_us,
            time: time.ok(),
            latency_us: 0,
            rate,
        }
    }

    /// Writes the report ([`ATTITUDE_FIELDS`]); `None` if `out` is shorter than
    /// [`ATTITUDE_LEN`].
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        use crate::solver::SolveMode;
        let mut w = Writer::new(out);
        w.u32(self.frame);
        let (status, used, matched) = match &self.fix {
            Ok(f) => {
                let status = match f.mode {
                    SolveMode::Tracking => 2,
                    SolveMode::LostInSpace => 3,
                };
                (status, f.used, f.matched)
            }
            Err(AttitudeMissing::TooFewStars { used }) => (0, *used, 0),
            Err(AttitudeMissing::NotIdentified { used }) => (1, *used, 0),
        };
        w.u8(status)
            .u8(used)
            .u8(matched)
            .u8(ATTITUDE_FORMAT)
            .u16(self.flags.bits());
        let (cuc, bound) = self.time.map_or((crate::time::Cuc::default(), 0), |t| {
            (t.cuc, t.error_bound_us)
        });
        w.bytes(&cuc.t_field()).u32(bound).u32(self.latency_us);
        let sym = |c: &[[f64; 3]; 3], w: &mut Writer<'_>| {
            for (i, j) in [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)] {
                let v = c.get(i).and_then(|r| r.get(j)).copied().unwrap_or(0.0);
                w.f32(v as f32);
            }
        };
        match &self.fix {
            Ok(f) => {
                for v in f.attitude.q.0 {
                    w.f64(v);
                }
                sym(&f.attitude.cov_rad2, &mut w);
            }
            Err(_) => {
                for _ in 0..4 {
                    w.f64(0.0);
                }
                sym(&[[0.0; 3]; 3], &mut w);
            }
        }
        match &self.rate {
            Some(r) => {
                for v in r.w_rad_s {
                    w.f32(v as f32);
                }
                sym(&r.cov_rad2_s2, &mut w);
            }
            None => {
                for _ in 0..3 {
                    w.f32(0.0);
                }
                sym(&[[0.0; 3]; 3], &mut w);
            }
        }
        let p = self.fix.as_ref().map_or(0.0, |f| f.false_probability);
        w.f32(p as f32).u64(self.mid_exposure_us);
        w.finish()
    }
}
