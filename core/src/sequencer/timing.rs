//! The clocking's timing as typed config ([`Timing`]: what the plan asks for), the limits it
//! must respect ([`Limits`]: the sensor's and the board's), and their check
//! ([`Timing::validate`]) into whole timer ticks ([`Ticks`]).
//!
//! One tick is one BSRR word, so every duration is a whole number of ticks. The tick is set
//! by the pixel rate: an unbinned read pixel is [`Ticks::read_px_ticks`] ticks (three
//! register states, the reset settle, the reset sample, the signal settle, the signal
//! sample). Each segment holds its states for its own number of ticks, at its own limit:
//! the skipped register element's states at the serial minimum, the dumped row's at the
//! parallel minimum, the line and frame transfers at their steps' minima. Cost: a few
//! integer divisions, once per plan.

/// The sensor's and the board's limits. The CCD47-20 notes the project works from
/// (`sensor-ccd47-20.md`: facts gathered from public sources, its clocking section marked
/// "verify against the datasheet") give no clock timing minimum of the sensor's own; the
/// two row steps are the gcam controller's operating values those notes quote. Every field
/// says where its value comes from and is to be checked on hardware (the HIL steps in
/// docs/hardware.md).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Limits {
    /// Fastest pixel rate of the output amplifier and ADC, Hz. The notes: "maximum pixel
    /// rate a few MHz" (Signal chain, marked verify); 3 MHz taken. To check on hardware.
    pub max_pixel_rate_hz: u32,
    /// Shortest tick the timer-paced DMA can write to the GPIO port, ps (board: 20 MHz
    /// assumed for DMA1 into AHB4 GPIO, not in the notes; to check on hardware with the
    /// logic analyser).
    pub min_tick_ps: u32,
    /// Shortest state of a serial register phase pattern, ns: 40 ns assumed (typical CCD
    /// practice, not in the notes; to check on hardware). The skipped elements run at it.
    pub min_serial_state_ns: u32,
    /// Shortest reset gate pulse, ns (assumed, not in the notes; to check on hardware).
    pub min_reset_gate_ns: u32,
    /// Settling of the video after the reset gate falls, before the reset-level sample, ns
    /// (assumed, not in the notes; to check on hardware with the preamp's bandwidth).
    pub min_reset_settle_ns: u32,
    /// Settling after the summing well falls, before the signal-level sample, ns (assumed,
    /// not in the notes; to check on hardware with the preamp's bandwidth).
    pub min_signal_settle_ns: u32,
    /// Shortest image/store phase state, ns: 1 us assumed (not in the notes; to check on
    /// hardware). The dumped rows run at it (three states a row); that a row clocked this
    /// fast leaves no charge behind for the next row read is part of the check.
    pub min_parallel_state_ns: u32,
    /// Shortest frame-transfer step (one row, three states), ns. The notes: gcam "holds
    /// about 10 us per frame-transfer step" (Clocking, marked verify); the sensor's own
    /// minimum is not in them. To check on hardware.
    pub min_ft_step_ns: u32,
    /// Shortest line-transfer step into the serial register, ns. The notes: gcam holds
    /// "40 us per parallel (line) step" (Clocking, marked verify); the sensor's own minimum
    /// is not in them. To check on hardware.
    pub min_line_step_ns: u32,
    /// Shortest dump gate pulse that empties the serial register, ns. The notes: the dump
    /// gate "drains the serial register in a few states" (Clocking, marked verify); 1 us
    /// assumed. To check on hardware.
    pub min_dump_ns: u32,
}

impl Limits {
    /// The CCD47-20 on the reference board (sources as marked on each field).
    pub const CCD47_20: Self = Self {
        max_pixel_rate_hz: 3_000_000,
        min_tick_ps: 50_000,
        min_serial_state_ns: 40,
        min_reset_gate_ns: 100,
        min_reset_settle_ns: 50,
        min_signal_settle_ns: 100,
        min_parallel_state_ns: 1_000,
        min_ft_step_ns: 10_000,
        min_line_step_ns: 40_000,
        min_dump_ns: 1_000,
    };
}

/// The clocking a plan asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Timing {
    /// Unbinned read pixels per second on each output, Hz.
    pub pixel_rate_hz: u32,
    /// Ticks per serial register state of a read pixel (three states move a packet one
    /// element).
    pub serial_state_ticks: u8,
    /// Ticks per serial register state of a skipped element (shifted to the reset drain
    /// unsampled: nothing settles, so it runs at the serial minimum).
    pub skip_state_ticks: u8,
    /// Ticks from the reset gate falling to the reset-level sample.
    pub reset_settle_ticks: u8,
    /// Ticks from the summing well falling to the signal-level sample.
    pub signal_settle_ticks: u8,
    /// One frame-transfer step (image and store one row), ns.
    pub ft_step_ns: u32,
    /// One line transfer (store one row into the register), ns.
    pub line_step_ns: u32,
    /// One row dumped (store one row with the dump gate high), ns.
    pub dump_row_step_ns: u32,
    /// The dump gate pulse that empties the register after a line's last window, ns.
    pub dump_register_ns: u32,
}

impl Timing {
    /// The defaults at `pixel_rate_hz`: the read pixel cut into as many ticks as the
    /// CCD47-20 board's shortest DMA tick allows (20 of 50 ns at 1 MHz: register states of
    /// 150 ns, reset settle 150 ns, signal settle 300 ns, each CONVST one tick), the skipped
    /// elements one tick a state, the gcam row steps for the line and frame transfers, dumped
    /// rows at three parallel minimum states. Below 8 ticks a pixel (above 2.5 MHz) the
    /// 8-tick pixel, which [`Self::validate`] then holds to the limits.
    pub const fn at_pixel_rate(pixel_rate_hz: u32) -> Self {
        let limits = Limits::CCD47_20;
        let px_ps = if pixel_rate_hz == 0 {
            0
        } else {
            1_000_000_000_000u64 / pixel_rate_hz as u64
        };
        let n = px_ps / limits.min_tick_ps as u64;
        let (serial, reset, signal) = if n < 8 || n > 200 {
            (1, 1, 2)
        } else {
            let third = if n * 3 / 20 > 1 { n * 3 / 20 } else { 1 };
            (third, third, n - 4 * third - 2)
        };
        Self {
            pixel_rate_hz,
            serial_state_ticks: serial as u8,
            skip_state_ticks: 1,
            reset_settle_ticks: reset as u8,
            signal_settle_ticks: signal as u8,
            ft_step_ns: limits.min_ft_step_ns,
            line_step_ns: limits.min_line_step_ns,
            dump_row_step_ns: 3 * limits.min_parallel_state_ns,
            dump_register_ns: limits.min_dump_ns,
        }
    }

    /// Ticks of an unbinned read pixel.
    pub(crate) const fn read_px_ticks(&self) -> u32 {
        3 * self.serial_state_ticks as u32
            + self.reset_settle_ticks as u32
            + 1
            + self.signal_settle_ticks as u32
            + 1
    }

    /// Checks every limit and converts the durations into ticks.
    pub fn validate(&self, limits: &Limits) -> Result<Ticks, TimingError> {
        if self.pixel_rate_hz == 0 || self.pixel_rate_hz > limits.max_pixel_rate_hz {
            return Err(TimingError::PixelRate {
                hz: self.pixel_rate_hz,
                max_hz: limits.max_pixel_rate_hz,
            });
        }
        if self.serial_state_ticks == 0
            || self.skip_state_ticks == 0
            || self.reset_settle_ticks == 0
        {
            return Err(TimingError::ZeroTicks);
        }
        let px_ps = 1_000_000_000_000u64 / u64::from(self.pixel_rate_hz);
        let tick_ps = px_ps / u64::from(self.read_px_ticks());
        let tick_ps = u32::try_from(tick_ps).map_err(|_| TimingError::TooSlow)?;
        if tick_ps < limits.min_tick_ps {
            return Err(TimingError::TickTooShort {
                tick_ps,
                min_ps: limits.min_tick_ps,
            });
        }
        let ns = |ticks: u32| u64::from(ticks) * u64::from(tick_ps) / 1000;
        let at_least = |what: Limit, got_ns: u64, min_ns: u32| {
            if got_ns < u64::from(min_ns) {
                Err(TimingError::TooShort {
                    what,
                    got_ns: u32::try_from(got_ns).unwrap_or(u32::MAX),
                    min_ns,
                })
            } else {
                Ok(())
            }
        };
        let serial_state = u32::from(self.serial_state_ticks);
        let skip_state = u32::from(self.skip_state_ticks);
        at_least(
            Limit::SerialState,
            ns(serial_state.min(skip_state)),
            limits.min_serial_state_ns,
        )?;
        // The reset gate is high over the register's three states of the pixel's shift.
        at_least(
            Limit::ResetGate,
            ns(3 * serial_state),
            limits.min_reset_gate_ns,
        )?;
        at_least(
            Limit::ResetSettle,
            ns(u32::from(self.reset_settle_ticks)),
            limits.min_reset_settle_ns,
        )?;
        at_least(
            Limit::SignalSettle,
            ns(u32::from(self.signal_settle_ticks)),
            limits.min_signal_settle_ns,
        )?;
        at_least(
            Limit::FtStep,
            u64::from(self.ft_step_ns),
            limits.min_ft_step_ns,
        )?;
        at_least(
            Limit::LineStep,
            u64::from(self.line_step_ns),
            limits.min_line_step_ns,
        )?;
        at_least(
            Limit::DumpRegister,
            u64::from(self.dump_register_ns),
            limits.min_dump_ns,
        )?;
        // A row step is three states; each must hold at least the parallel minimum.
        let state_ticks = |step_ns: u32| -> Result<u32, TimingError> {
            let t = (u64::from(step_ns) * 1000).div_ceil(3 * u64::from(tick_ps));
            u32::try_from(t).map_err(|_| TimingError::TooSlow)
        };
        let ft_state = state_ticks(self.ft_step_ns)?;
        let line_state = state_ticks(self.line_step_ns)?;
        let dump_row_state = state_ticks(self.dump_row_step_ns)?;
        for t in [ft_state, line_state, dump_row_state] {
            at_least(Limit::ParallelState, ns(t), limits.min_parallel_state_ns)?;
        }
        // A dumped row's charge goes to the drain: its step is held to three parallel
        // states, not to a transfer's step.
        at_least(
            Limit::DumpRowStep,
            u64::from(self.dump_row_step_ns),
            limits.min_parallel_state_ns.saturating_mul(3),
        )?;
        let dump_register =
            u32::try_from((u64::from(self.dump_register_ns) * 1000).div_ceil(u64::from(tick_ps)))
                .map_err(|_| TimingError::TooSlow)?;
        Ok(Ticks {
            tick_ps,
            serial_state: serial_state.max(1),
            skip_state: skip_state.max(1),
            reset_settle: u32::from(self.reset_settle_ticks),
            signal_settle: u32::from(self.signal_settle_ticks),
            ft_state,
            line_state,
            dump_row_state,
            dump_register: dump_register.max(1),
        })
    }
}

/// Which limit a [`TimingError::TooShort`] broke.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Limit {
    /// A serial register state.
    SerialState,
    /// The reset gate pulse.
    ResetGate,
    /// Settling before the reset-level sample.
    ResetSettle,
    /// Settling before the signal-level sample.
    SignalSettle,
    /// An image/store state.
    ParallelState,
    /// A frame-transfer step.
    FtStep,
    /// A line-transfer step.
    LineStep,
    /// A dumped row's step.
    DumpRowStep,
    /// The dump gate pulse.
    DumpRegister,
}

/// Why a timing cannot be used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum TimingError {
    /// Zero, or faster than the output and ADC allow.
    PixelRate {
        /// Asked for, Hz.
        hz: u32,
        /// The limit, Hz.
        max_hz: u32,
    },
    /// The tick the pixel rate needs is shorter than the DMA can write.
    TickTooShort {
        /// The tick, ps.
        tick_ps: u32,
        /// The limit, ps.
        min_ps: u32,
    },
    /// A duration is below its limit.
    TooShort {
        /// Which one.
        what: Limit,
        /// What the timing gives, ns.
        got_ns: u32,
        /// The limit, ns.
        min_ns: u32,
    },
    /// A state needs at least one tick.
    ZeroTicks,
    /// A duration does not fit the tick counters (u32).
    TooSlow,
}

impl core::fmt::Display for TimingError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::PixelRate { hz, max_hz } => {
                write!(f, "timing: pixel rate {hz} Hz not in 1..={max_hz} Hz")
            }
            Self::TickTooShort { tick_ps, min_ps } => {
                write!(
                    f,
                    "timing: tick {tick_ps} ps shorter than the DMA's {min_ps} ps"
                )
            }
            Self::TooShort {
                what,
                got_ns,
                min_ns,
            } => write!(f, "timing: {what:?} is {got_ns} ns, below {min_ns} ns"),
            Self::ZeroTicks => f.write_str("timing: a state of zero ticks"),
            Self::TooSlow => f.write_str("timing: a duration overflows the tick counter"),
        }
    }
}

impl core::error::Error for TimingError {}

/// A checked timing in ticks (what the compiler uses).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Ticks {
    /// One tick, ps.
    pub tick_ps: u32,
    /// Ticks per serial register state of a read pixel.
    pub serial_state: u32,
    /// Ticks per serial register state of a skipped element.
    pub skip_state: u32,
    /// Ticks from the reset gate falling to the reset sample.
    pub reset_settle: u32,
    /// Ticks from the summing well falling to the signal sample.
    pub signal_settle: u32,
    /// Ticks per frame-transfer state (three a row).
    pub ft_state: u32,
    /// Ticks per line-transfer state (three a row).
    pub line_state: u32,
    /// Ticks per dumped-row state (three a row).
    pub dump_row_state: u32,
    /// Ticks of the dump gate pulse that empties the register.
    pub dump_register: u32,
}

impl Ticks {
    /// Ticks of a read pixel of `binning` register elements.
    pub(crate) const fn read_px_ticks(&self, binning: u32) -> u32 {
        3 * self.serial_state * binning + self.reset_settle + 1 + self.signal_settle + 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_each_limit_fails() {
        let limits = Limits::CCD47_20;
        let t = Timing::at_pixel_rate(1_000_000).validate(&limits);
        let ticks = t.ok();
        assert_eq!(ticks.map(|t| t.tick_ps), Some(50_000));
        assert_eq!(ticks.map(|t| t.read_px_ticks(1)), Some(20));
        // 0.5 and 2 MHz keep the 50 ns tick; 2.5 MHz and above fall back to 8 ticks.
        for (hz, n) in [(500_000, 40), (2_000_000, 10), (3_000_000, 8)] {
            assert_eq!(Timing::at_pixel_rate(hz).read_px_ticks(), n, "{hz} Hz");
        }
        assert!(matches!(
            Timing::at_pixel_rate(4_000_000).validate(&limits),
            Err(TimingError::PixelRate { .. })
        ));
        let fast_dma = Limits {
            min_tick_ps: 200_000,
            ..limits
        };
        assert!(matches!(
            Timing::at_pixel_rate(2_000_000).validate(&fast_dma),
            Err(TimingError::TickTooShort { .. })
        ));
        let short_line = Timing {
            line_step_ns: 20_000,
            ..Timing::at_pixel_rate(1_000_000)
        };
        assert!(matches!(
            short_line.validate(&limits),
            Err(TimingError::TooShort {
                what: Limit::LineStep,
                ..
            })
        ));
        let unsettled = Timing {
            signal_settle_ticks: 0,
            ..Timing::at_pixel_rate(1_000_000)
        };
        assert!(matches!(
            unsettled.validate(&limits),
            Err(TimingError::TooShort {
                what: Limit::SignalSettle,
                ..
            })
        ));
    }
}
