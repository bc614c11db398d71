//! The command set: a telecommand's service, subtype and application data read into a typed
//! [`Command`], or a [`Rejection`] saying why not. Reading checks lengths and values only;
//! what the tracker or the table store then refuse is a rejection too (`service.rs`).
//!
//! Cost: a match and a few big-endian reads; nothing is copied but a chunk's borrow.

use super::protocol::{self as p, MessageType};
use super::upload::UploadRefusal;
use crate::table::AmendError;
use crate::time::{Cuc, CucError};
use crate::tracker::{ConfigError, Mode};

/// A configuration change of [`Command::SetParams`]: parameter id and raw value.
pub type ParamValue = (u8, u32);

/// Most parameters in one [`Command::SetParams`].
pub const MAX_PARAMS: usize = 8;

/// Which window data [`Command::Window`] asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WindowKind {
    /// Raw samples, ADU.
    Raw,
    /// Calibrated pixels, e- x 64 (the I26F6 bits).
    Calibrated,
}

/// A window of the active area to read for diagnostics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WindowRequest {
    /// Left column, px.
    pub x0: u16,
    /// Top row, px.
    pub y0: u16,
    /// Side, px (1 to [`p::MAX_WINDOW_PX`]).
    pub side_px: u16,
    /// Raw or calibrated.
    pub kind: WindowKind,
}

/// A telecommand, read.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Command<'a> {
    /// `TC[17,1]`.
    Ping,
    /// `TC[3,27]`.
    Housekeeping,
    /// `TC[3,31]`: period, frames (0: on request only).
    HousekeepingPeriod(u16),
    /// `TC[130,1]`.
    SetMode(Mode),
    /// `TC[130,2]`: `count` valid entries.
    SetParams {
        /// The parameters.
        params: [ParamValue; MAX_PARAMS],
        /// How many of `params` are set.
        count: usize,
    },
    /// `TC[130,3]`.
    Reset,
    /// `TC[131,1]`: frames (0: stop, 65535: every frame).
    Stars(u16),
    /// `TC[132,1]`.
    Window(WindowRequest),
    /// `TC[133,1]`.
    TableBegin {
        /// Table kind.
        kind: u8,
        /// Whole length, bytes.
        total_len: u32,
        /// CRC-32/ISO-HDLC of the whole table.
        crc32: u32,
    },
    /// `TC[133,2]`.
    TableChunk {
        /// Byte offset in the table.
        offset: u32,
        /// The bytes.
        data: &'a [u8],
    },
    /// `TC[133,3]`.
    TableCommit,
    /// `TC[133,4]`.
    TableAbort,
    /// `TC[133,5]`.
    TableReport(u8),
    /// `TC[133,7]`.
    TableCommitDefects,
    /// `TC[9,128]`: the spacecraft time of the next sync pulse.
    TimeSet(Cuc),
    /// `TC[134,1]`: the spacecraft's velocity.
    Velocity(Velocity),
}

/// The spacecraft's velocity at a time (`TC[134,1]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Velocity {
    /// ICRF, barycentric, m/s (finite, at most [`p::MAX_SPEED_M_S`]).
    pub v_m_s: [f64; 3],
    /// The spacecraft time it holds at.
    pub at: Cuc,
}

/// Why a telecommand was not executed. Codes ([`Self::code`]) and parameters are stable:
/// they go to the ground in `TM[1,2]` and in the anomaly event.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Rejection {
    /// The packet's CRC-16 is wrong.
    Checksum,
    /// Not a readable PUS-C telecommand (too short, its length field disagrees with the
    /// frame, not a telecommand, not PUS version 2).
    Malformed,
    /// The APID is not [`p::APID_CONTROL`].
    UnknownApid(u16),
    /// No command has this service and subtype.
    UnknownCommand(MessageType),
    /// The application data's length is wrong for the command.
    BadLength,
    /// A value is out of range (a mode number, a parameter id, a window outside the area).
    BadValue,
    /// Tracking was asked for with no star from the last frame.
    NothingToTrack,
    /// The configuration would fail its checks (the one in force is kept).
    Config(ConfigError),
    /// The table store refused.
    Upload(UploadRefusal),
    /// The window cannot be read (no source, or one window is already being sent).
    WindowUnavailable,
    /// The tracker application is not running (the safe standby after a set-up fault, which
    /// housekeeping's `setup_faults` names): mode and configuration commands have nothing to
    /// act on. Housekeeping, tables and reset are still served.
    Standby,
    /// The in-flight defects could not be put into a table update (nothing new to add, the
    /// table in force unreadable, no room in its directory).
    Amend(AmendError),
    /// The time-set command's time code is not the tracker's (its P-field is not
    /// [`crate::time::CUC_P_FIELD`]).
    TimeCode(u8),
}

impl Rejection {
    /// The reason code in `TM[1,2]`.
    pub const fn code(self) -> u16 {
        match self {
            Self::Checksum => 1,
            Self::Malformed => 2,
            Self::UnknownApid(_) => 3,
            Self::UnknownCommand(_) => 4,
            Self::BadLength => 5,
            Self::BadValue => 6,
            Self::NothingToTrack => 7,
            Self::Config(_) => 8,
            Self::Upload(_) => 9,
            Self::WindowUnavailable => 10,
            Self::Standby => 11,
            Self::Amend(_) => 12,
            Self::TimeCode(_) => 13,
        }
    }

    /// The reason's parameter in `TM[1,2]`: the APID, the service << 8 | subtype, the upload
    /// refusal's code << 16 | (its expected offset's low 16 bits), the amendment error's
    /// code, the P-field received, or 0.
    pub fn parameter(self) -> u32 {
        match self {
            Self::UnknownApid(a) => u32::from(a),
            Self::UnknownCommand(m) => u32::from(m.service) << 8 | u32::from(m.subtype),
            Self::Upload(r) => {
                let low = match r {
                    UploadRefusal::OutOfOrder { expected } => expected & 0xFFFF,
                    _ => 0,
                };
                u32::from(r.code()) << 16 | low
            }
            Self::Amend(e) => u32::from(e.code()),
            Self::TimeCode(p) => u32::from(p),
            _ => 0,
        }
    }

    /// The name the ground tool prints for a code.
    pub const fn name_of(code: u16) -> &'static str {
        match code {
            1 => "checksum error",
            2 => "malformed packet",
            3 => "unknown APID",
            4 => "unknown command",
            5 => "wrong data length",
            6 => "value out of range",
            7 => "nothing to track",
            8 => "configuration refused",
            9 => "table upload refused",
            10 => "window unavailable",
            11 => "tracker not running (safe standby)",
            12 => "in-flight defects not committed",
            13 => "time code not CUC 4+2 (P-field 0x1E)",
            _ => "unknown reason",
        }
    }
}

impl core::fmt::Display for Rejection {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(Self::name_of(self.code()))?;
        match self {
            Self::Config(e) => write!(f, ": {e:?}"),
            Self::Upload(r) => write!(f, ": {r}"),
            Self::Amend(e) => write!(f, ": {e:?}"),
            Self::TimeCode(p) => write!(f, ": P-field {p:#04x}"),
            Self::UnknownApid(a) => write!(f, " {a:#x}"),
            Self::UnknownCommand(m) => write!(f, " [{},{}]", m.service, m.subtype),
            _ => Ok(()),
        }
    }
}

impl core::error::Error for Rejection {}

/// The mode of its telecommand number.
pub const fn mode_of(n: u8) -> Option<Mode> {
    match n {
        0 => Some(Mode::Standby),
        1 => Some(Mode::Acquisition),
        2 => Some(Mode::Tracking),
        _ => None,
    }
}

/// A mode's telecommand and telemetry number.
pub const fn mode_number(m: Mode) -> u8 {
    match m {
        Mode::Standby => 0,
        Mode::Acquisition => 1,
        Mode::Tracking => 2,
    }
}

fn be16(d: &[u8], at: usize) -> Option<u16> {
    let b = d.get(at..at + 2)?;
    Some(u16::from_be_bytes([*b.first()?, *b.get(1)?]))
}

fn be32(d: &[u8], at: usize) -> Option<u32> {
    let b = d.get(at..at + 4)?;
    Some(u32::from_be_bytes([
        *b.first()?,
        *b.get(1)?,
        *b.get(2)?,
        *b.get(3)?,
    ]))
}

fn exact(d: &[u8], n: usize) -> Result<(), Rejection> {
    if d.len() == n {
        Ok(())
    } else {
        Err(Rejection::BadLength)
    }
}

impl<'a> Command<'a> {
    /// Reads a telecommand of type `kind` with application data `d`.
    pub fn parse(kind: MessageType, d: &'a [u8]) -> Result<Self, Rejection> {
        let short = Rejection::BadLength;
        Ok(match kind {
            p::TC_PING => exact(d, 0).map(|()| Self::Ping)?,
            p::TC_HOUSEKEEPING => exact(d, 0).map(|()| Self::Housekeeping)?,
            p::TC_HOUSEKEEPING_PERIOD => {
                exact(d, 2)?;
                Self::HousekeepingPeriod(be16(d, 0).ok_or(short)?)
            }
            p::TC_SET_MODE => {
                exact(d, 1)?;
                let n = *d.first().ok_or(short)?;
                Self::SetMode(mode_of(n).ok_or(Rejection::BadValue)?)
            }
            p::TC_SET_PARAMS => {
                let count = d.len() / 5;
                if !d.len().is_multiple_of(5) || count == 0 || count > MAX_PARAMS {
                    return Err(short);
                }
                let mut params = [(0u8, 0u32); MAX_PARAMS];
                for (i, slot) in params.iter_mut().enumerate().take(count) {
                    let id = *d.get(i * 5).ok_or(short)?;
                    if !p::PARAMS.iter().any(|q| q.id == id) {
                        return Err(Rejection::BadValue);
                    }
                    *slot = (id, be32(d, i * 5 + 1).ok_or(short)?);
                }
                Self::SetParams { params, count }
            }
            p::TC_RESET => exact(d, 0).map(|()| Self::Reset)?,
            p::TC_STARS => {
                exact(d, 2)?;
                Self::Stars(be16(d, 0).ok_or(short)?)
            }
            p::TC_WINDOW => {
                exact(d, 7)?;
                let side_px = be16(d, 4).ok_or(short)?;
                if side_px == 0 || side_px > p::MAX_WINDOW_PX {
                    return Err(Rejection::BadValue);
                }
                let kind = match d.get(6) {
                    Some(0) => WindowKind::Raw,
                    Some(1) => WindowKind::Calibrated,
                    _ => return Err(Rejection::BadValue),
                };
                Self::Window(WindowRequest {
                    x0: be16(d, 0).ok_or(short)?,
                    y0: be16(d, 2).ok_or(short)?,
                    side_px,
                    kind,
                })
            }
            p::TC_TABLE_BEGIN => {
                exact(d, 9)?;
                Self::TableBegin {
                    kind: *d.first().ok_or(short)?,
                    total_len: be32(d, 1).ok_or(short)?,
                    crc32: be32(d, 5).ok_or(short)?,
                }
            }
            p::TC_TABLE_CHUNK => {
                let data = d.get(4..).ok_or(short)?;
                if data.is_empty() || data.len() > p::MAX_CHUNK_BYTES {
                    return Err(short);
                }
                Self::TableChunk {
                    offset: be32(d, 0).ok_or(short)?,
                    data,
                }
            }
            p::TC_TABLE_COMMIT => exact(d, 0).map(|()| Self::TableCommit)?,
            p::TC_TABLE_ABORT => exact(d, 0).map(|()| Self::TableAbort)?,
            p::TC_TABLE_REPORT => {
                exact(d, 1)?;
                Self::TableReport(*d.first().ok_or(short)?)
            }
            p::TC_TABLE_COMMIT_DEFECTS => exact(d, 0).map(|()| Self::TableCommitDefects)?,
            p::TC_VELOCITY => {
                exact(d, 18)?;
                let f = |at: usize| be32(d, at).map(|b| f64::from(f32::from_bits(b)));
                let v_m_s = [f(0).ok_or(short)?, f(4).ok_or(short)?, f(8).ok_or(short)?];
                let speed = libm::sqrt(v_m_s.iter().map(|c| c * c).sum());
                if speed.is_nan() || speed > p::MAX_SPEED_M_S {
                    return Err(Rejection::BadValue);
                }
                let at = Cuc::from_t_field(d.get(12..).ok_or(short)?).map_err(|_| short)?;
                Self::Velocity(Velocity { v_m_s, at })
            }
            p::TC_TIME_SET => match Cuc::from_p_and_t(d) {
                Ok(c) => Self::TimeSet(c),
                Err(CucError::PField(p)) => return Err(Rejection::TimeCode(p)),
                Err(CucError::Length { .. }) => return Err(short),
            },
            other => return Err(Rejection::UnknownCommand(other)),
        })
    }
}
