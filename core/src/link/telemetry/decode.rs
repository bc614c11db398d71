//! The ground's decoders: each telemetry layout read back into its type, with the same
//! field tables as the encoders (the host ground tool and the tests use them; the board
//! only encodes). `None` for a report of the wrong length or an unknown code. A bounds
//! check and a load a field.

use super::super::command::mode_of;
use super::super::protocol::{STAR_BYTES, STAR_LIST_FORMAT};
use super::super::upload::TableInfo;
use super::attitude::{ATTITUDE_FORMAT, ATTITUDE_LEN, AttitudeMissing, AttitudeReport, Validity};
use super::fields::Reader;
use super::housekeeping::{FrameTotals, HK_LEN, Housekeeping, LinkCounters};
use super::stars::{CHI2_DOF_UNIT, PSF_A_UNIT_PX};
use crate::tracker::{Mode, Provenance, StarFlags, StarRecord, TemperatureSource};

const fn source_of(n: u8) -> Option<TemperatureSource> {
    match n {
        0 => Some(TemperatureSource::Sensor),
        1 => Some(TemperatureSource::TableReference),
        2 => Some(TemperatureSource::None),
        _ => None,
    }
}

impl Housekeeping {
    /// Reads a report written by [`Self::encode`].
    pub fn decode(d: &[u8]) -> Option<Self> {
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
            hits: 0,
            masked: 0,
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
        let hits = r.u16()?;
        let masked = r.u16()?;
        let obstructions = r.u8()?;
        let totals = FrameTotals {
            hits: r.u32()?,
            masked: r.u32()?,
            ..totals
        };
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
            hits,
            masked,
            obstructions,
        })
    }
}

/// A star list read back: frame, mode, and the stars in `out` (their count returned);
/// `None` for another format than [`STAR_LIST_FORMAT`] or a length that does not match.
pub fn decode_stars(d: &[u8], out: &mut [StarRecord]) -> Option<(u32, Mode, usize)> {
    let mut r = Reader::new(d);
    let frame = r.u32()?;
    let mode = mode_of(r.u8()?)?;
    if r.u8()? != STAR_LIST_FORMAT {
        return None;
    }
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
            // Not on the link.
            cov_xy_px2: 0.0,
            flags: StarFlags::from_bits_retain(r.u32()?),
            provenance: Provenance::from_bits_retain(r.u8()?),
            psf_a_px: f32::from(r.u16()?) * PSF_A_UNIT_PX,
            chi2_dof: f32::from(r.u16()?) * CHI2_DOF_UNIT,
        };
    }
    Some((frame, mode, count))
}

impl AttitudeReport {
    /// Reads a report back (`None`: wrong length, another format than
    /// [`ATTITUDE_FORMAT`], an unknown status or flag bit).
    pub fn decode(d: &[u8]) -> Option<Self> {
        use crate::attitude::{Attitude, Quat, Rate};
        use crate::solver::{Fix, SolveMode};
        use crate::time::{Cuc, SpacecraftTime};
        if d.len() != ATTITUDE_LEN {
            return None;
        }
        let mut r = Reader::new(d);
        let frame = r.u32()?;
        let (status, used, matched, format) = (r.u8()?, r.u8()?, r.u8()?, r.u8()?);
        if format != ATTITUDE_FORMAT {
            return None;
        }
        let flags = Validity::from_bits(r.u16()?)?;
        let cuc = Cuc::from_t_field(r.bytes(6)?).ok()?;
        let error_bound_us = r.u32()?;
        let latency_us = r.u32()?;
        let q = Quat([r.f64()?, r.f64()?, r.f64()?, r.f64()?]);
        let sym = |r: &mut Reader<'_>| -> Option<[[f64; 3]; 3]> {
            let mut c = [0f32; 6];
            for v in &mut c {
                *v = r.f32()?;
            }
            let [xx, xy, xz, yy, yz, zz] = c.map(f64::from);
            Some([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
        };
        let cov_rad2 = sym(&mut r)?;
        let w = [r.f32()?, r.f32()?, r.f32()?].map(f64::from);
        let rate_cov = sym(&mut r)?;
        let false_probability = f64::from(r.f32()?);
        let mid_exposure_us = r.u64()?;
        let fix = match status {
            0 => Err(AttitudeMissing::TooFewStars { used }),
            1 => Err(AttitudeMissing::NotIdentified { used }),
            2 | 3 => Ok(Fix {
                attitude: Attitude { q, cov_rad2 },
                mode: if status == 2 {
                    SolveMode::Tracking
                } else {
                    SolveMode::LostInSpace
                },
                used,
                matched,
                false_probability,
                time_us: mid_exposure_us,
            }),
            _ => return None,
        };
        Some(Self {
            frame,
            fix,
            flags,
            mid_exposure_us,
            time: (!flags.contains(Validity::TIME_NOT_SYNCHRONISED)).then_some(SpacecraftTime {
                cuc,
                error_bound_us,
            }),
            latency_us,
            rate: (!flags.contains(Validity::NO_RATE)).then_some(Rate {
                w_rad_s: w,
                cov_rad2_s2: rate_cov,
            }),
        })
    }
}
