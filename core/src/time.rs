//! Spacecraft time: the CCSDS Unsegmented Time Code the attitude report is tagged with
//! ([`Cuc`]), and the clock model that turns the tracker's microsecond counter into it
//! ([`SpacecraftClock`]).
//!
//! # The time code
//!
//! CCSDS 301.0-B-4 (Time Code Formats), section 3.2, CUC with 4 coarse octets (seconds) and 2
//! fine octets (2^-16 s, 15.26 us): a T-field of [`CUC_T_LEN`] bytes, big-endian, coarse
//! first. Its preamble (P-field) is one octet, [`CUC_P_FIELD`] = `0x1E`:
//!
//! | bits (MSB first) | value | meaning |
//! |---|---|---|
//! | 0 | 0 | no P-field extension |
//! | 1-3 | 001 | time code identification: level 1, epoch 1958-01-01 TAI |
//! | 4-5 | 11 | 4 coarse octets (value + 1) |
//! | 6-7 | 10 | 2 fine octets |
//!
//! The attitude report carries the T-field only (the P-field is this fixed value, stated in
//! `docs/protocol.md`); the time-set command carries the P-field too, so a ground segment on
//! another format is refused instead of setting a wrong time. Range: 0 to 2^32 - 2^-16 s after
//! the epoch (year 2094).
//!
//! # The clock
//!
//! The spacecraft distributes its time as a command and a pulse: the time-set command says
//! "the next sync pulse is at T" ([`SpacecraftClock::command_set`]), and the pulse, once a
//! second on the spacecraft's time (a PPS line), marks it
//! ([`SpacecraftClock::pulse`], with the tracker's counter at the pulse's edge). From the
//! first set followed by a pulse the clock is synchronised: any counter value converts to
//! spacecraft time ([`SpacecraftClock::time_of`]) from the last pulse, its whole seconds
//! counted from the first, with the counter's frequency error measured between pulses
//! removed. Before that, or after [`HOLDOVER_US`] without a pulse, there is no spacecraft
//! time ([`TimeError`]): the attitude report then flags its time as not synchronised.
//!
//! A pulse is accepted only when it falls a whole number of seconds (1 to
//! [`HOLDOVER_US`] / 1 s) after the last one, within [`MAX_RATE_ERROR_PPM`] and
//! [`PULSE_JITTER_US`]; any other (a glitch on the line, a lost count) is refused and
//! counted, and the model is kept.
//!
//! # Drift between pulses
//!
//! The error of a converted time is bounded ([`SpacecraftTime::error_bound_us`]) by the
//! capture's jitter ([`PULSE_JITTER_US`]), the code's resolution (half a fine tick, 8 us)
//! and the counter's rate error over the time since the pulse: [`MAX_RATE_ERROR_PPM`]
//! before the rate was measured (after the first pulse: 200 us at 1 s), then the
//! measurement's residual [`RATE_RESIDUAL_PPM`] (a jitter of 2 us over a 1 s interval, and
//! the oscillator's change over a second: 5 ppm, 5 us at 1 s). At the holdover limit the
//! bound is 60 us: 0.2" of attitude at 1 deg/s.
//!
//! Cost: a few 64- and 128-bit multiplications and divisions a conversion or a pulse; 48
//! bytes of state. No allocation, no panic on any input.

/// The CUC P-field: level 1 (TAI, epoch 1958-01-01), 4 coarse octets, 2 fine octets.
pub const CUC_P_FIELD: u8 = 0x1E;
/// Length of the CUC T-field, bytes (4 coarse + 2 fine).
pub const CUC_T_LEN: usize = 6;
/// Fine ticks a second (2 fine octets).
pub const TICKS_PER_S: u64 = 1 << 16;
/// Microseconds a second.
const US_PER_S: u64 = 1_000_000;
/// Most ticks a CUC holds (48 bits).
const MAX_TICKS: u64 = (1 << 48) - 1;

/// The sync pulse's period, us of spacecraft time (a PPS).
pub const PULSE_PERIOD_US: u64 = US_PER_S;
/// Largest frequency error of the tracker's counter the clock accepts, ppm: a crystal's
/// tolerance, temperature and ageing (50 ppm and less for the NUCLEO's 8 MHz source) with
/// margin.
pub const MAX_RATE_ERROR_PPM: u64 = 200;
/// What is left of the counter's rate error once it is measured over a pulse interval, ppm:
/// twice the capture jitter over 1 s (2 ppm) and the oscillator's change within a few
/// seconds (3 ppm).
pub const RATE_RESIDUAL_PPM: u64 = 5;
/// The capture's jitter, us: a timer input capture at 1 MHz resolves the edge to 1 us (the
/// board's TIM5; the host model draws within it).
pub const PULSE_JITTER_US: u64 = 1;
/// How long after the last pulse the time stays synchronised, us of the counter.
pub const HOLDOVER_US: u64 = 10 * US_PER_S;

/// A CCSDS CUC time: seconds and 2^-16 s since the epoch of [`CUC_P_FIELD`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cuc {
    /// Whole seconds (the 4 coarse octets).
    pub coarse_s: u32,
    /// Fraction of a second, 2^-16 s (the 2 fine octets).
    pub fine: u16,
}

/// Why a CUC did not read or write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CucError {
    /// The bytes are not as long as the code (`want` bytes).
    Length {
        /// Bytes given.
        got: usize,
        /// Bytes the code takes.
        want: usize,
    },
    /// The P-field is not [`CUC_P_FIELD`].
    PField(u8),
}

impl core::fmt::Display for CucError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Length { got, want } => write!(f, "CUC of {got} bytes, not {want}"),
            Self::PField(p) => write!(f, "CUC P-field {p:#04x}, not {CUC_P_FIELD:#04x}"),
        }
    }
}

impl core::error::Error for CucError {}

impl Cuc {
    /// The time of `ticks` fine ticks since the epoch; `None` beyond 48 bits.
    pub const fn from_ticks(ticks: u64) -> Option<Self> {
        if ticks > MAX_TICKS {
            return None;
        }
        Some(Self {
            coarse_s: (ticks >> 16) as u32,
            fine: (ticks & 0xFFFF) as u16,
        })
    }

    /// Fine ticks since the epoch (48 bits).
    pub const fn ticks(self) -> u64 {
        (self.coarse_s as u64) << 16 | self.fine as u64
    }

    /// The time `us` microseconds since the epoch, to the nearest fine tick; `None` beyond
    /// the code's range.
    pub fn from_us(us: u64) -> Option<Self> {
        Self::from_ticks(us_to_ticks(us)?)
    }

    /// Microseconds since the epoch, to the nearest.
    pub fn to_us(self) -> u64 {
        ticks_to_us(self.ticks())
    }

    /// Seconds since the epoch (f64: 1e-10 s resolution over the code's range).
    pub fn to_seconds(self) -> f64 {
        self.ticks() as f64 / TICKS_PER_S as f64
    }

    /// The T-field (4 coarse octets, 2 fine, big-endian).
    pub const fn t_field(self) -> [u8; CUC_T_LEN] {
        let c = self.coarse_s.to_be_bytes();
        let f = self.fine.to_be_bytes();
        [c[0], c[1], c[2], c[3], f[0], f[1]]
    }

    /// Reads a T-field of exactly [`CUC_T_LEN`] bytes.
    pub fn from_t_field(d: &[u8]) -> Result<Self, CucError> {
        match *d {
            [c0, c1, c2, c3, f0, f1] => Ok(Self {
                coarse_s: u32::from_be_bytes([c0, c1, c2, c3]),
                fine: u16::from_be_bytes([f0, f1]),
            }),
            _ => Err(CucError::Length {
                got: d.len(),
                want: CUC_T_LEN,
            }),
        }
    }

    /// The P-field and the T-field.
    pub const fn with_p_field(self) -> [u8; 1 + CUC_T_LEN] {
        let t = self.t_field();
        [CUC_P_FIELD, t[0], t[1], t[2], t[3], t[4], t[5]]
    }

    /// Reads a P-field ([`CUC_P_FIELD`]) and its T-field, exactly 7 bytes.
    pub fn from_p_and_t(d: &[u8]) -> Result<Self, CucError> {
        match d.split_first() {
            Some((&p, t)) if t.len() == CUC_T_LEN => {
                if p == CUC_P_FIELD {
                    Self::from_t_field(t)
                } else {
                    Err(CucError::PField(p))
                }
            }
            _ => Err(CucError::Length {
                got: d.len(),
                want: 1 + CUC_T_LEN,
            }),
        }
    }
}

/// `us` in fine ticks, to the nearest (`us * 2^16 / 10^6`); `None` beyond 48 bits.
fn us_to_ticks(us: u64) -> Option<u64> {
    let t = (u128::from(us) * u128::from(TICKS_PER_S) + u128::from(US_PER_S / 2))
        / u128::from(US_PER_S);
    u64::try_from(t).ok().filter(|&t| t <= MAX_TICKS)
}

/// `ticks` in us, to the nearest (exact in u128 for 48-bit ticks).
fn ticks_to_us(ticks: u64) -> u64 {
    let us = (u128::from(ticks) * u128::from(US_PER_S) + u128::from(TICKS_PER_S / 2))
        / u128::from(TICKS_PER_S);
    u64::try_from(us).unwrap_or(u64::MAX)
}

/// A sync pulse's port: the counter value (us, the tracker's clock) of each pulse edge seen
/// since the last call. On the board a timer input capture on the PPS pin
/// (`firmware/src/pps.rs`); on the host a model of the line (`startrack-host`'s
/// `PpsModel`).
pub trait SyncPulse {
    /// The counter at the oldest pulse not yet taken, us; `None` when there is none.
    fn take_pulse(&mut self) -> Option<u64>;
}

/// A converted time and how far it may be off.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SpacecraftTime {
    /// The spacecraft time.
    pub cuc: Cuc,
    /// Bound on its error, us (jitter, resolution and the rate's error since the pulse).
    pub error_bound_us: u32,
}

/// Why a counter value has no spacecraft time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimeError {
    /// No time-set command was followed by a pulse yet.
    NotSynchronised,
    /// The last pulse is more than [`HOLDOVER_US`] away from the counter value.
    Stale {
        /// Counter time from the last pulse, us (saturating).
        age_us: u64,
    },
    /// The time falls outside the code's range (before the epoch or after 2^32 s).
    OutOfRange,
}

impl core::fmt::Display for TimeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::NotSynchronised => f.write_str("spacecraft time not synchronised"),
            Self::Stale { age_us } => write!(f, "last sync pulse {age_us} us away"),
            Self::OutOfRange => f.write_str("spacecraft time outside the CUC's range"),
        }
    }
}

impl core::error::Error for TimeError {}

/// What a pulse did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PulseOutcome {
    /// It marked the time of a pending time-set command: the clock is set.
    Set,
    /// It fell `seconds` whole seconds after the last pulse and moved the model on.
    Counted {
        /// Seconds since the last accepted pulse.
        seconds: u32,
    },
    /// No time was ever set: nothing to count from.
    Unset,
    /// It is not a whole number of seconds after the last pulse (a glitch), or the last is
    /// older than the holdover: refused, counted, the model kept.
    Refused,
}

/// The last accepted pulse: the counter and the spacecraft time at it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Anchor {
    counter_us: u64,
    ticks: u64,
}

/// The spacecraft clock model: the time-set command, the sync pulses, and the counter's
/// conversion to spacecraft time (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpacecraftClock {
    pending: Option<Cuc>,
    anchor: Option<Anchor>,
    /// The counter's frequency error measured over the last interval, parts per 10^9
    /// (positive: the counter runs fast).
    rate_ppb: Option<i64>,
    pulses: u32,
    refused: u32,
}

impl SpacecraftClock {
    /// A clock that is not synchronised.
    pub const fn new() -> Self {
        Self {
            pending: None,
            anchor: None,
            rate_ppb: None,
            pulses: 0,
            refused: 0,
        }
    }

    /// The time-set command: the next pulse is at `at_next_pulse`. A later command before
    /// that pulse replaces it; the model in force is kept until the pulse.
    pub fn command_set(&mut self, at_next_pulse: Cuc) {
        self.pending = Some(at_next_pulse);
    }

    /// A time-set command waits for its pulse.
    pub fn set_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Pulses accepted since start.
    pub fn pulses(&self) -> u32 {
        self.pulses
    }

    /// Pulses refused since start.
    pub fn refused_pulses(&self) -> u32 {
        self.refused
    }

    /// The counter's measured frequency error, parts per 10^9 (`None` before two pulses).
    pub fn rate_ppb(&self) -> Option<i64> {
        self.rate_ppb
    }

    /// A pulse whose edge the counter saw at `counter_us`.
    pub fn pulse(&mut self, counter_us: u64) -> PulseOutcome {
        if let Some(cuc) = self.pending.take() {
            // A new set restarts the model: the rate is measured again from here.
            self.anchor = Some(Anchor {
                counter_us,
                ticks: cuc.ticks(),
            });
            self.rate_ppb = None;
            self.pulses = self.pulses.wrapping_add(1);
            return PulseOutcome::Set;
        }
        let Some(a) = self.anchor else {
            return PulseOutcome::Unset;
        };
        let elapsed = counter_us.wrapping_sub(a.counter_us);
        let refuse = |s: &mut Self| {
            s.refused = s.refused.wrapping_add(1);
            PulseOutcome::Refused
        };
        if counter_us <= a.counter_us || elapsed > HOLDOVER_US + HOLDOVER_US / 10 {
            return refuse(self);
        }
        let seconds = (elapsed + US_PER_S / 2) / US_PER_S;
        let nominal = seconds * US_PER_S;
        let tolerance = nominal * MAX_RATE_ERROR_PPM / US_PER_S + PULSE_JITTER_US;
        if seconds == 0 || elapsed.abs_diff(nominal) > tolerance {
            return refuse(self);
        }
        let Some(ticks) = a
            .ticks
            .checked_add(seconds * TICKS_PER_S)
            .filter(|&t| t <= MAX_TICKS)
        else {
            return refuse(self);
        };
        let off = i64::try_from(elapsed).unwrap_or(i64::MAX) - nominal as i64;
        self.rate_ppb = Some(off * 1000 / seconds as i64);
        self.anchor = Some(Anchor { counter_us, ticks });
        self.pulses = self.pulses.wrapping_add(1);
        PulseOutcome::Counted {
            seconds: seconds as u32,
        }
    }

    /// Takes every pulse `port` has seen, in order.
    pub fn poll(&mut self, port: &mut dyn SyncPulse) {
        // Bounded: a port that never runs dry cannot hold the caller.
        for _ in 0..16 {
            match port.take_pulse() {
                Some(t) => {
                    self.pulse(t);
                }
                None => break,
            }
        }
    }

    /// The spacecraft time at counter value `counter_us` (before or after the last pulse,
    /// within [`HOLDOVER_US`]).
    pub fn time_of(&self, counter_us: u64) -> Result<SpacecraftTime, TimeError> {
        let a = self.anchor.ok_or(TimeError::NotSynchronised)?;
        let age_us = counter_us.abs_diff(a.counter_us);
        if age_us > HOLDOVER_US {
            return Err(TimeError::Stale { age_us });
        }
        // Counter us to spacecraft us: divided by (1 + rate), to first order (the square of
        // 200 ppm over 10 s is 0.4 ns).
        let rate = self.rate_ppb.unwrap_or(0);
        let age = age_us as i64;
        let corrected = age - age * rate / 1_000_000_000;
        let dt_us = if counter_us >= a.counter_us {
            corrected
        } else {
            -corrected
        };
        let dt_ticks = (i128::from(dt_us) * i128::from(TICKS_PER_S)
            + i128::from(dt_us.signum()) * i128::from(US_PER_S / 2))
            / i128::from(US_PER_S);
        let ticks = i128::from(a.ticks) + dt_ticks;
        let ticks = u64::try_from(ticks).map_err(|_| TimeError::OutOfRange)?;
        let cuc = Cuc::from_ticks(ticks).ok_or(TimeError::OutOfRange)?;
        let ppm = match self.rate_ppb {
            Some(_) => RATE_RESIDUAL_PPM,
            None => MAX_RATE_ERROR_PPM,
        };
        // Half a tick of resolution, rounded up: 8 us.
        let bound = PULSE_JITTER_US + 8 + age_us * ppm / US_PER_S + 1;
        Ok(SpacecraftTime {
            cuc,
            error_bound_us: u32::try_from(bound).unwrap_or(u32::MAX),
        })
    }
}
