//! The CCD's clock lines, one state of all of them ([`LineSet`]), the three-phase patterns
//! ([`Phases`]), and where each line sits on the clock port ([`PinMap`]).
//!
//! Every clock line and the ADC's convert start live on one 16-bit GPIO port, so one BSRR
//! word (one `u32` a timer tick) sets the whole state: bit `p` sets pin `p`, bit `p + 16`
//! resets it. Cost: [`PinMap::bsrr`] is 16 shifts and ors; it runs once per distinct state
//! when a plan is compiled, never per tick.

/// One clock line of the CCD47-20 (or the ADC's convert start).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Line {
    /// Image section phase 1.
    I1 = 0,
    /// Image section phase 2.
    I2,
    /// Image section phase 3 (the phase next to the store section).
    I3,
    /// Store section phase 1.
    S1,
    /// Store section phase 2.
    S2,
    /// Store section phase 3 (the phase next to the serial register).
    S3,
    /// Serial register phase 1, left half.
    R1L,
    /// Serial register phase 2, left half.
    R2L,
    /// Serial register phase 3, left half (the phase next to the left summing well).
    R3L,
    /// Serial register phase 1, right half.
    R1R,
    /// Serial register phase 2, right half.
    R2R,
    /// Serial register phase 3, right half (the phase next to the right summing well).
    R3R,
    /// Reset gate: high empties the output nodes into the reset drain.
    Rg,
    /// Summing well: high collects charge from the register; going low moves it onto the
    /// output node.
    Sw,
    /// Dump gate: high drains the whole serial register into the dump drain.
    Dg,
    /// ADC convert start: a tick with it high is one sample of both outputs.
    Convst,
}

/// Number of lines.
pub(crate) const LINE_COUNT: usize = 16;

impl Line {
    /// Every line, in bit order.
    pub(crate) const ALL: [Self; LINE_COUNT] = [
        Self::I1,
        Self::I2,
        Self::I3,
        Self::S1,
        Self::S2,
        Self::S3,
        Self::R1L,
        Self::R2L,
        Self::R3L,
        Self::R1R,
        Self::R2R,
        Self::R3R,
        Self::Rg,
        Self::Sw,
        Self::Dg,
        Self::Convst,
    ];
    /// The image phases, in transfer order (towards the store).
    pub const IMAGE: [Self; 3] = [Self::I1, Self::I2, Self::I3];
    /// The store phases, in transfer order (towards the serial register).
    pub const STORE: [Self; 3] = [Self::S1, Self::S2, Self::S3];
    /// The left register phases, in transfer order (towards the left output).
    pub const REG_LEFT: [Self; 3] = [Self::R1L, Self::R2L, Self::R3L];
    /// The right register phases, in transfer order (towards the right output).
    pub const REG_RIGHT: [Self; 3] = [Self::R1R, Self::R2R, Self::R3R];

    /// The line's bit in a [`LineSet`].
    pub(crate) const fn bit(self) -> u16 {
        1 << self as u8
    }

    /// The name as the clock-driver board labels it.
    pub(crate) const fn name(self) -> &'static str {
        match self {
            Self::I1 => "I1",
            Self::I2 => "I2",
            Self::I3 => "I3",
            Self::S1 => "S1",
            Self::S2 => "S2",
            Self::S3 => "S3",
            Self::R1L => "R1L",
            Self::R2L => "R2L",
            Self::R3L => "R3L",
            Self::R1R => "R1R",
            Self::R2R => "R2R",
            Self::R3R => "R3R",
            Self::Rg => "RG",
            Self::Sw => "SW",
            Self::Dg => "DG",
            Self::Convst => "CONVST",
        }
    }
}

/// Which phases of a three-phase group are high: bit 0 = phase 1, bit 1 = phase 2,
/// bit 2 = phase 3.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Phases(pub u8);

impl Phases {
    /// Phases 1 and 2 high: the rest state of the image and store sections.
    pub const P12: Self = Self(0b011);
    /// Phases 2 and 3 high.
    pub(crate) const P23: Self = Self(0b110);
    /// Phases 3 and 1 high: the rest state of the serial register.
    pub const P31: Self = Self(0b101);
    /// One element forward (towards the output): three states, each sharing a high phase
    /// with the one before (the overlap that keeps the packet whole), from and back to P12.
    pub(crate) const FORWARD_FROM_P12: [Self; 3] = [Self::P23, Self::P31, Self::P12];
    /// One element forward from and back to P31 (the packet crosses into the next element
    /// at the first state).
    pub const FORWARD_FROM_P31: [Self; 3] = [Self::P12, Self::P23, Self::P31];
    /// One element backward (away from the output) from and back to P31.
    pub const BACKWARD_FROM_P31: [Self; 3] = [Self::P23, Self::P12, Self::P31];
    /// One element backward from and back to P12 (the packet crosses into the next element
    /// at the first state, in step with [`Self::FORWARD_FROM_P31`]).
    pub(crate) const BACKWARD_FROM_P12: [Self; 3] = [Self::P31, Self::P23, Self::P12];
}

/// The level of every line at one tick: bit `l` is [`Line`] `l`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LineSet(pub u16);

impl LineSet {
    /// Every line low.
    pub(crate) const EMPTY: Self = Self(0);

    /// With `line` high.
    #[must_use]
    pub const fn with(self, line: Line) -> Self {
        Self(self.0 | line.bit())
    }

    /// With `line` low.
    #[must_use]
    pub(crate) const fn without(self, line: Line) -> Self {
        Self(self.0 & !line.bit())
    }

    /// With `line` at `high`.
    #[must_use]
    pub const fn set(self, line: Line, high: bool) -> Self {
        if high {
            self.with(line)
        } else {
            self.without(line)
        }
    }

    /// Whether `line` is high.
    pub const fn is_high(self, line: Line) -> bool {
        self.0 & line.bit() != 0
    }

    /// With the three lines of `group` set to `phases`.
    #[must_use]
    pub const fn phases(self, group: [Line; 3], phases: Phases) -> Self {
        self.set(group[0], phases.0 & 1 != 0)
            .set(group[1], phases.0 & 2 != 0)
            .set(group[2], phases.0 & 4 != 0)
    }

    /// The phases of `group` that are high.
    pub const fn phases_of(self, group: [Line; 3]) -> Phases {
        Phases(
            self.is_high(group[0]) as u8
                | (self.is_high(group[1]) as u8) << 1
                | (self.is_high(group[2]) as u8) << 2,
        )
    }
}

/// Why a pin map cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum PinMapError {
    /// A line's pin is past bit 15 of the port.
    PinOutOfRange(Line),
    /// Two lines share a pin.
    SharedPin(Line, Line),
}

impl core::fmt::Display for PinMapError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::PinOutOfRange(l) => write!(f, "pin map: {} is past pin 15", l.name()),
            Self::SharedPin(a, b) => {
                write!(f, "pin map: {} and {} share a pin", a.name(), b.name())
            }
        }
    }
}

impl core::error::Error for PinMapError {}

/// Where each line sits on the clock port: `pins[l]` is the port bit (0-15) of [`Line`] `l`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PinMap {
    /// Port bit of each line, indexed by `Line as usize`.
    pub pins: [u8; LINE_COUNT],
}

impl PinMap {
    /// Line `l` on pin `l` (PE0..PE15 on the reference board, see docs/hardware.md).
    pub const IN_ORDER: Self = Self {
        pins: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15],
    };

    /// The pin of `line`.
    pub(crate) fn pin(&self, line: Line) -> u8 {
        self.pins.get(line as usize).copied().unwrap_or(u8::MAX)
    }

    /// Checks that every pin is on the port and no two lines share one.
    pub(crate) fn validate(&self) -> Result<(), PinMapError> {
        let mut used: [Option<Line>; 16] = [None; 16];
        for line in Line::ALL {
            let pin = self.pin(line);
            let slot = used
                .get_mut(usize::from(pin))
                .ok_or(PinMapError::PinOutOfRange(line))?;
            if let Some(other) = *slot {
                return Err(PinMapError::SharedPin(other, line));
            }
            *slot = Some(line);
        }
        Ok(())
    }

    /// The BSRR word that puts every line at its level in `state` (set bits for the high
    /// lines, reset bits for the low ones). Pins past 15 (an invalid map) are left out.
    pub fn bsrr(&self, state: LineSet) -> u32 {
        let mut word = 0u32;
        for line in Line::ALL {
            let pin = u32::from(self.pin(line));
            if pin > 15 {
                continue;
            }
            if state.is_high(line) {
                word |= 1 << pin;
            } else {
                word |= 1 << (pin + 16);
            }
        }
        word
    }

    /// The port's output after `word` is written to BSRR with the port at `port` (set wins
    /// over reset, as on the STM32).
    pub const fn apply(port: u16, word: u32) -> u16 {
        let set = word as u16;
        let reset = (word >> 16) as u16;
        (port & !reset) | set
    }

    /// The line levels that a port output shows.
    pub fn lines_of_port(&self, port: u16) -> LineSet {
        let mut s = LineSet::EMPTY;
        for line in Line::ALL {
            let pin = self.pin(line);
            if pin <= 15 && port & (1 << pin) != 0 {
                s = s.with(line);
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bsrr_round_trip_and_validation() {
        let map = PinMap {
            pins: [15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0],
        };
        assert_eq!(map.validate(), Ok(()));
        let s = LineSet::EMPTY.with(Line::I1).with(Line::Convst);
        let port = PinMap::apply(0xffff, map.bsrr(s));
        assert_eq!(port, 1 << 15 | 1);
        assert_eq!(map.lines_of_port(port), s);
        let mut bad = map;
        bad.pins[3] = 15;
        assert_eq!(
            bad.validate(),
            Err(PinMapError::SharedPin(Line::I1, Line::S1))
        );
        bad.pins[3] = 16;
        assert_eq!(bad.validate(), Err(PinMapError::PinOutOfRange(Line::S1)));
    }
}
