//! Telemetry source data: the housekeeping report, a frame's star list, a frame's attitude,
//! the events and the verification reports, each a fixed big-endian layout written into a
//! slice (and read back by the ground tool with the same code). The layouts are tabled in
//! `docs/protocol.md`, generated from [`HK_FIELDS`], [`STAR_FIELDS`] and [`ATTITUDE_FIELDS`].
//!
//! Cost: a few stores per field; a 32-star list is 1,030 bytes.

use super::command::mode_number;
use super::protocol::{MAX_LINK_STARS, STAR_BYTES};
use super::upload::TableInfo;
use crate::tracker::{Event, Mode, ModeReason, StarFlags, StarRecord, TemperatureSource};

/// Writes big-endian fields into a slice; a field that does not fit marks it failed.
pub struct Writer<'a> {
    buf: &'a mut [u8],
    at: usize,
    ok: bool,
}

impl<'a> Writer<'a> {
    /// Writes from the start of `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Self {
            buf,
            at: 0,
            ok: true,
        }
    }

    /// Appends raw bytes.
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        match self.buf.get_mut(self.at..self.at + b.len()) {
            Some(dst) => {
                dst.copy_from_slice(b);
                self.at += b.len();
            }
            None => self.ok = false,
        }
        self
    }

    /// Appends a `u8`.
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.bytes(&[v])
    }

    /// Appends a `u16`.
    pub fn u16(&mut self, v: u16) -> &mut Self {
        self.bytes(&v.to_be_bytes())
    }

    /// Appends a `u32`.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.bytes(&v.to_be_bytes())
    }

    /// Appends a `u64`.
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.bytes(&v.to_be_bytes())
    }

    /// Appends an `f32` (IEEE 754 bits).
    pub fn f32(&mut self, v: f32) -> &mut Self {
        self.u32(v.to_bits())
    }

    /// Appends an `f64` (IEEE 754 bits).
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.u64(v.to_bits())
    }

    /// Bytes written, or `None` if something did not fit.
    pub fn finish(&self) -> Option<usize> {
        self.ok.then_some(self.at)
    }
}

/// Reads big-endian fields from a slice; reading past its end gives `None`.
pub struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    /// Reads from the start of `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf, at: 0 }
    }

    /// The next `n` bytes.
    pub fn bytes(&mut self, n: usize) -> Option<&'a [u8]> {
        let b = self.buf.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(b)
    }

    fn array<const K: usize>(&mut self) -> Option<[u8; K]> {
        self.bytes(K)?.try_into().ok()
    }

    /// A `u8`.
    pub fn u8(&mut self) -> Option<u8> {
        self.array::<1>().map(|[b]| b)
    }

    /// A `u16`.
    pub fn u16(&mut self) -> Option<u16> {
        self.array().map(u16::from_be_bytes)
    }

    /// A `u32`.
    pub fn u32(&mut self) -> Option<u32> {
        self.array().map(u32::from_be_bytes)
    }

    /// A `u64`.
    pub fn u64(&mut self) -> Option<u64> {
        self.array().map(u64::from_be_bytes)
    }

    /// An `f32`.
    pub fn f32(&mut self) -> Option<f32> {
        self.u32().map(f32::from_bits)
    }

    /// An `f64`.
    pub fn f64(&mut self) -> Option<f64> {
        self.u64().map(f64::from_bits)
    }

    /// Bytes left.
    pub fn rest(&self) -> &'a [u8] {
        self.buf.get(self.at..).unwrap_or(&[])
    }
}

/// The link's own counters, since start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkCounters {
    /// Bytes received.
    pub rx_bytes: u32,
    /// Frames decoded into a packet.
    pub packets: u32,
    /// Frames that were not valid COBS or overran the receive buffer.
    pub framing_errors: u32,
    /// Packets whose CRC-16 was wrong.
    pub crc_errors: u32,
    /// Telecommands executed (`TM[1,1]` sent or queued).
    pub accepted: u32,
    /// Telecommands rejected, for any reason (`TM[1,2]`).
    pub rejected: u32,
    /// Telemetry packets queued.
    pub tm_queued: u32,
    /// Telemetry packets dropped because their queue was full (a slow link).
    pub tm_dropped: u32,
    /// Stars not sent because a frame had more than a star list holds.
    pub stars_not_sent: u32,
}

/// The tracker's loss counters summed over every frame since start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameTotals {
    /// Frames ended.
    pub frames: u32,
    /// Lines refused.
    pub lines_refused: u32,
    /// Acquisition candidates lost by the detector's full list.
    pub candidates_dropped: u32,
    /// Acquisition windows that could not wait for their rows.
    pub windows_dropped: u32,
    /// Acquisition windows whose rows had left the line ring.
    pub ring_lost: u32,
    /// Windows that could not be calibrated.
    pub calib_failed: u32,
    /// Tracking windows that could not be placed.
    pub track_refused: u32,
    /// Tracking windows without a star.
    pub track_lost: u32,
    /// Stars not reported because the star list was full.
    pub stars_dropped: u32,
}

/// The housekeeping report `TM[3,25]` (structure id 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Housekeeping {
    /// The last frame's mode.
    pub mode: Mode,
    /// The mode the rules give the next frame.
    pub next_mode: Mode,
    /// The last frame had a calibration table.
    pub calibrated: bool,
    /// Where the temperature came from.
    pub temperature_source: TemperatureSource,
    /// Sensor temperature used, K (U16F16 bits in telemetry).
    pub temperature_k_bits: u32,
    /// The last frame's number.
    pub frame: u32,
    /// The last frame's reported stars.
    pub stars: u16,
    /// The last frame's usable centroids.
    pub centroids: u16,
    /// Loss counters since start.
    pub totals: FrameTotals,
    /// Link counters since start.
    pub link: LinkCounters,
    /// The calibration table in force.
    pub table: Option<TableInfo>,
    /// Time since start, us.
    pub uptime_us: u64,
    /// The set-up steps that failed at this boot (`safe::SetupFaults` bits 0-15; 0: none).
    pub setup_faults: u16,
    /// The running dark ratio, covered pixels measured / the dark law's prediction (U8F8
    /// bits; 0: not measured).
    pub dark_ratio_u8f8: u16,
    /// [`status`] bits.
    pub status: u8,
    /// Pixels confirmed in flight that the table in force does not list yet.
    pub defects_pending: u16,
}

/// Bits of housekeeping's `status` field.
pub mod status {
    /// The running dark ratio is outside the dark law's band.
    pub const DARK_DRIFT: u8 = 1;
}

/// Every housekeeping field in order: name, type, meaning.
pub const HK_FIELDS: [(&str, &str, &str); 37] = [
    ("sid", "u16", "structure id, 1"),
    (
        "mode",
        "u8",
        "last frame's mode (0 standby, 1 acquisition, 2 tracking)",
    ),
    ("next_mode", "u8", "the next frame's mode by the rules"),
    ("calibrated", "u8", "1: a calibration table was in force"),
    (
        "temperature_source",
        "u8",
        "0 sensor, 1 table reference, 2 none",
    ),
    (
        "temperature_k",
        "u32",
        "sensor temperature, K x 65536 (U16F16)",
    ),
    ("frame", "u32", "last frame's number"),
    ("stars", "u16", "last frame's reported stars"),
    ("centroids", "u16", "last frame's usable centroids"),
    ("frames", "u32", "frames since start"),
    ("lines_refused", "u32", "lines refused since start"),
    (
        "candidates_dropped",
        "u32",
        "acquisition candidates lost, since start",
    ),
    (
        "windows_dropped",
        "u32",
        "acquisition windows dropped, since start",
    ),
    (
        "ring_lost",
        "u32",
        "windows whose rows left the ring, since start",
    ),
    ("calib_failed", "u32", "windows not calibrated, since start"),
    (
        "track_refused",
        "u32",
        "tracking windows not placed, since start",
    ),
    (
        "track_lost",
        "u32",
        "tracking windows without a star, since start",
    ),
    (
        "stars_dropped",
        "u32",
        "stars over the star list, since start",
    ),
    ("rx_bytes", "u32", "link bytes received"),
    ("packets", "u32", "frames decoded into a packet"),
    ("framing_errors", "u32", "frames not COBS or too long"),
    ("crc_errors", "u32", "packets with a wrong CRC-16"),
    ("accepted", "u32", "telecommands executed"),
    ("rejected", "u32", "telecommands rejected"),
    ("tm_queued", "u32", "telemetry packets queued"),
    (
        "tm_dropped",
        "u32",
        "telemetry packets dropped (queue full)",
    ),
    ("stars_not_sent", "u32", "stars over a star-list packet"),
    ("table_kind", "u8", "kind of the table in force"),
    ("table_present", "u8", "1: a table is in force"),
    ("table_len", "u32", "its length, bytes"),
    ("table_crc32", "u32", "its CRC-32"),
    ("table_sequence", "u32", "its store sequence number"),
    ("uptime_us", "u64", "time since start, us"),
    (
        "setup_faults",
        "u16",
        "set-up steps that failed at this boot (SetupFaults bits, docs/storage.md); 0: none",
    ),
    (
        "dark_ratio",
        "u16",
        "running dark ratio, covered pixels / dark law, x 256 (U8F8); 0: not measured",
    ),
    (
        "status",
        "u8",
        "bit 0 DARK_DRIFT: dark ratio outside its band",
    ),
    (
        "defects_pending",
        "u16",
        "pixels confirmed in flight, not yet in the table",
    ),
];

/// Size of a field type of [`HK_FIELDS`] or [`STAR_FIELDS`], bytes.
pub const fn type_len(t: &str) -> usize {
    match t.as_bytes() {
        b"u8" => 1,
        b"u16" => 2,
        b"u32" | b"f32" => 4,
        b"u64" | b"f64" => 8,
        _ => 0,
    }
}

/// Length of the housekeeping source data, bytes.
#[allow(
    clippy::indexing_slicing,
    reason = "evaluated at compile time: a bad index fails the build, never the program"
)]
pub const HK_LEN: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < HK_FIELDS.len() {
        n += type_len(HK_FIELDS[i].1);
        i += 1;
    }
    n
};

/// Every field of one star in a star list: name, type, meaning.
pub const STAR_FIELDS: [(&str, &str, &str); 9] = [
    ("x_px", "f32", "column, px"),
    ("y_px", "f32", "row, px"),
    ("flux_e", "f32", "background-subtracted signal, e-"),
    ("snr", "f32", "SNR of flux_e"),
    ("sigma_x_px", "f32", "1-sigma error of x_px, px"),
    ("sigma_y_px", "f32", "1-sigma error of y_px, px"),
    ("flags", "u32", "StarFlags bits (docs/formats.md)"),
    (
        "psf_a_mpx",
        "u16",
        "the star's fitted PSF 80 % radius, 0.001 px (0 to 65.535 px, saturating; 0: not measured)",
    ),
    (
        "chi2_dof_centi",
        "u16",
        "the fit's chi2 per degree of freedom, 0.01 (0 to 655.35, saturating; 0: not measured)",
    ),
];

/// `v / unit` rounded to a `u16`, saturating (0 for NaN or negative): the star list's
/// fixed-point fields.
fn to_u16(v: f32, unit: f32) -> u16 {
    let q = v / unit + 0.5;
    if q.is_nan() || q < 0.0 {
        0
    } else if q >= 65_535.0 {
        u16::MAX
    } else {
        q as u16
    }
}

/// Units of the star list's fixed-point fields.
const PSF_A_UNIT_PX: f32 = 0.001;
const CHI2_DOF_UNIT: f32 = 0.01;

const fn source_number(s: TemperatureSource) -> u8 {
    match s {
        TemperatureSource::Sensor => 0,
        TemperatureSource::TableReference => 1,
        TemperatureSource::None => 2,
    }
}

const fn source_of(n: u8) -> Option<TemperatureSource> {
    match n {
        0 => Some(TemperatureSource::Sensor),
        1 => Some(TemperatureSource::TableReference),
        2 => Some(TemperatureSource::None),
        _ => None,
    }
}

impl Housekeeping {
    /// Writes the report; `None` if `out` is shorter than [`HK_LEN`].
    pub fn encode(&self, out: &mut [u8]) -> Option<usize> {
        let t = &self.totals;
        let l = &self.link;
        let table = self.table.unwrap_or(TableInfo {
            kind: 0,
            len_bytes: 0,
            crc32: 0,
            sequence: 0,
        });
        let mut w = Writer::new(out);
        w.u16(1)
            .u8(mode_number(self.mode))
            .u8(mode_number(self.next_mode))
            .u8(u8::from(self.calibrated))
            .u8(source_number(self.temperature_source))
            .u32(self.temperature_k_bits)
            .u32(self.frame)
            .u16(self.stars)
            .u16(self.centroids);
        for v in [
            t.frames,
            t.lines_refused,
            t.candidates_dropped,
            t.windows_dropped,
            t.ring_lost,
            t.calib_failed,
            t.track_refused,
            t.track_lost,
            t.stars_dropped,
            l.rx_bytes,
            l.packets,
            l.framing_errors,
            l.crc_errors,
            l.accepted,
            l.rejected,
            l.tm_queued,
            l.tm_dropped,
            l.stars_not_sent,
        ] {
            w.u32(v);
        }
        w.u8(table.kind)
            .u8(u8::from(self.table.is_some()))
            .u32(table.len_bytes)
            .u32(table.crc32)
            .u32(table.sequence)
            .u64(self.uptime_us)
            .u16(self.setup_faults)
            .u16(self.dark_ratio_u8f8)
            .u8(self.status)
            .u16(self.defects_pending);
        w.finish()
    }

    /// Reads a report written by [`Self::encode`].
    pub fn decode(d: &[u8]) -> Option<Self> {
        use super::command::mode_of;
        if d.len() != HK_LEN {
            return None;
        }
        let mut r = Reader::new(d);
        if r.u16()? != 1 {
            return None;
        }
        let mode = mode_of(r.u8()?)?;
        let next_mode = mode_of(r.u8()?)?;
        let calibrated = r.u8()? != 0;
        let temperature_source = source_of(r.u8()?)?;
        let temperature_k_bits = r.u32()?;
        let frame = r.u32()?;
        let stars = r.u16()?;
        let centroids = r.u16()?;
        let totals = FrameTotals {
            frames: r.u32()?,
            lines_refused: r.u32()?,
            candidates_dropped: r.u32()?,
            windows_dropped: r.u32()?,
            ring_lost: r.u32()?,
            calib_failed: r.u32()?,
            track_refused: r.u32()?,
            track_lost: r.u32()?,
            stars_dropped: r.u32()?,
        };
        let link = LinkCounters {
            rx_bytes: r.u32()?,
            packets: r.u32()?,
            framing_errors: r.u32()?,
            crc_errors: r.u32()?,
            accepted: r.u32()?,
            rejected: r.u32()?,
            tm_queued: r.u32()?,
            tm_dropped: r.u32()?,
            stars_not_sent: r.u32()?,
        };
        let kind = r.u8()?;
        let present = r.u8()? != 0;
        let info = TableInfo {
            kind,
            len_bytes: r.u32()?,
            crc32: r.u32()?,
            sequence: r.u32()?,
        };
        let uptime_us = r.u64()?;
        let setup_faults = r.u16()?;
        let dark_ratio_u8f8 = r.u16()?;
        let status = r.u8()?;
        let defects_pending = r.u16()?;
        Some(Self {
            mode,
            next_mode,
            calibrated,
            temperature_source,
            temperature_k_bits,
            frame,
            stars,
            centroids,
            totals,
            link,
            table: present.then_some(info),
            uptime_us,
            setup_faults,
            dark_ratio_u8f8,
            status,
            defects_pending,
        })
    }
}

/// Writes a star list's source data: frame u32, mode u8, count u8, the stars.
pub fn encode_stars(frame: u32, mode: Mode, stars: &[StarRecord], out: &mut [u8]) -> Option<usize> {
    let stars = stars.get(..stars.len().min(MAX_LINK_STARS))?;
    let mut w = Writer::new(out);
    w.u32(frame)
        .u8(mode_number(mode))
        .u8(u8::try_from(stars.len()).ok()?);
    for s in stars {
        w.f32(s.x_px)
            .f32(s.y_px)
            .f32(s.flux_e)
            .f32(s.snr)
            .f32(s.sigma_x_px)
            .f32(s.sigma_y_px)
            .u32(s.flags.bits())
            .u16(to_u16(s.psf_a_px, PSF_A_UNIT_PX))
            .u16(to_u16(s.chi2_dof, CHI2_DOF_UNIT));
    }
    w.finish()
}

/// A star list read back: frame, mode, and the stars in `out` (their count returned).
pub fn decode_stars(d: &[u8], out: &mut [StarRecord]) -> Option<(u32, Mode, usize)> {
    let mut r = Reader::new(d);
    let frame = r.u32()?;
    let mode = super::command::mode_of(r.u8()?)?;
    let count = usize::from(r.u8()?);
    if r.rest().len() != count * STAR_BYTES || count > out.len() {
        return None;
    }
    for slot in out.iter_mut().take(count) {
        *slot = StarRecord {
            x_px: r.f32()?,
            y_px: r.f32()?,
            flux_e: r.f32()?,
            snr: r.f32()?,
            sigma_x_px: r.f32()?,
            sigma_y_px: r.f32()?,
            flags: StarFlags::from_bits_retain(r.u32()?),
            psf_a_px: f32::from(r.u16()?) * PSF_A_UNIT_PX,
            chi2_dof: f32::from(r.u16()?) * CHI2_DOF_UNIT,
        };
    }
    Some((frame, mode, count))
}

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

    /// Reads a report back (`None`: wrong length or an unknown status).
    pub fn decode(d: &[u8]) -> Option<Self> {
        use crate::attitude::{Attitude, Quat};
        use crate::solver::{Fix, SolveMode};
        if d.len() != ATTITUDE_LEN {
            return None;
        }
        let mut r = Reader::new(d);
        let frame = r.u32()?;
        let (status, used, matched, _) = (r.u8()?, r.u8()?, r.u8()?, r.u8()?);
        let q = Quat([r.f64()?, r.f64()?, r.f64()?, r.f64()?]);
        let mut c = [0f32; 6];
        for v in &mut c {
            *v = r.f32()?;
        }
        let false_probability = f64::from(r.f32()?);
        let time_us = r.u64()?;
        let [xx, xy, xz, yy, yz, zz] = c.map(f64::from);
        let mode = match status {
            0 => {
                return Some(Self {
                    frame,
                    fix: Err(AttitudeMissing::TooFewStars { used }),
                });
            }
            1 => {
                return Some(Self {
                    frame,
                    fix: Err(AttitudeMissing::NotIdentified { used }),
                });
            }
            2 => SolveMode::Tracking,
            3 => SolveMode::LostInSpace,
            _ => return None,
        };
        Some(Self {
            frame,
            fix: Ok(Fix {
                attitude: Attitude {
                    q,
                    cov_rad2: [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]],
                },
                mode,
                used,
                matched,
                false_probability,
                time_us,
            }),
        })
    }
}

/// Event numbers of `TM[5,1]` and `TM[5,2]`.
pub mod event {
    /// Mode change: frame u32, from u8, to u8, reason u8.
    pub const MODE_CHANGE: u16 = 1;
    /// Table in force changed: frame u32, length u32.
    pub const TABLE_CHANGED: u16 = 2;
    /// Configuration applied: frame u32.
    pub const CONFIG_APPLIED: u16 = 3;
    /// A telecommand was rejected (anomaly): request id u32, reason u16, parameter u32.
    pub const COMMAND_REJECTED: u16 = 4;
    /// A table upload was committed: kind u8, length u32, CRC-32 u32, sequence u32.
    pub const TABLE_ACCEPTED: u16 = 5;
    /// A table upload was refused at commit (anomaly): kind u8, refusal u16.
    pub const TABLE_REFUSED: u16 = 6;
    /// The in-flight defects were committed into a new table: hot pixels added u16,
    /// telegraph pixels added u16, length u32, CRC-32 u32, sequence u32.
    pub const DEFECTS_COMMITTED: u16 = 7;
}

/// Bytes of event data after the event number (zero-padded).
pub const EVENT_DATA_LEN: usize = 16;

const fn reason_number(r: ModeReason) -> u8 {
    match r {
        ModeReason::Start => 0,
        ModeReason::Command => 1,
        ModeReason::Acquired => 2,
        ModeReason::TooFewStars => 3,
        ModeReason::Reacquire => 4,
        ModeReason::NoTable => 5,
        ModeReason::TableAvailable => 6,
    }
}

/// A tracker event's number and data.
pub fn tracker_event(e: &Event) -> (u16, [u8; EVENT_DATA_LEN]) {
    let mut d = [0u8; EVENT_DATA_LEN];
    let mut w = Writer::new(&mut d);
    let id = match *e {
        Event::ModeChange {
            frame,
            from,
            to,
            reason,
        } => {
            w.u32(frame)
                .u8(mode_number(from))
                .u8(mode_number(to))
                .u8(reason_number(reason));
            event::MODE_CHANGE
        }
        Event::TableChanged { frame, len_bytes } => {
            w.u32(frame).u32(len_bytes);
            event::TABLE_CHANGED
        }
        Event::ConfigApplied { frame } => {
            w.u32(frame);
            event::CONFIG_APPLIED
        }
    };
    (id, d)
}
