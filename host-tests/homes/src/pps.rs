//! The host's sync pulse: a model of the spacecraft's PPS line as the tracker's counter sees
//! it ([`PpsModel`], the host binding of the core's [`SyncPulse`] port).
//!
//! The spacecraft's time runs from `epoch` (its time at counter 0); the tracker's counter
//! runs `rate_ppm` fast against it (a crystal's error) and the capture of each edge lands
//! up to [`PULSE_JITTER_US`] late, drawn from a seeded generator. A pulse is on every whole
//! second of spacecraft time; the port hands over those whose counter value the home's
//! clock has reached ([`PpsModel::advance_to`]). The truth is at hand for the tests:
//! [`PpsModel::spacecraft_us_at`] is the spacecraft time of any counter value.
//!
//! Cost: a multiplication and a division a pulse.

use rand::{RngExt, SeedableRng};
use startrack_core::time::{Cuc, PULSE_JITTER_US, SyncPulse};

/// The PPS line and the counter's drift against spacecraft time.
#[derive(Clone, Debug)]
pub struct PpsModel {
    /// Spacecraft time at counter 0, us since the CUC epoch.
    pub epoch_us: u64,
    /// The counter's frequency error, ppm (positive: the counter runs fast).
    pub rate_ppm: f64,
    /// The next pulse not handed over: its spacecraft second.
    next_s: u64,
    /// The counter the home's clock has reached, us.
    now_us: u64,
    rng: rand_chacha::ChaCha8Rng,
}

impl PpsModel {
    /// A line whose spacecraft time is `epoch_us` at counter 0, the counter `rate_ppm` fast,
    /// the capture jitter seeded by `seed`.
    pub fn new(epoch_us: u64, rate_ppm: f64, seed: u64) -> Self {
        Self {
            epoch_us,
            rate_ppm,
            next_s: epoch_us.div_ceil(1_000_000),
            now_us: 0,
            rng: rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5050_5300),
        }
    }

    /// Spacecraft time at counter value `counter_us`, us since the epoch (the truth).
    pub fn spacecraft_us_at(&self, counter_us: f64) -> f64 {
        self.epoch_us as f64 + counter_us / (1.0 + self.rate_ppm * 1e-6)
    }

    /// The counter value at spacecraft time `sc_us` (us since the epoch).
    pub fn counter_at(&self, sc_us: f64) -> f64 {
        (sc_us - self.epoch_us as f64) * (1.0 + self.rate_ppm * 1e-6)
    }

    /// The spacecraft time of the next pulse not yet handed over: what a time-set command
    /// sent now says.
    pub fn next_pulse_time(&self) -> Cuc {
        Cuc {
            coarse_s: u32::try_from(self.next_s).unwrap_or(u32::MAX),
            fine: 0,
        }
    }

    /// The home's clock reached `counter_us`.
    pub fn advance_to(&mut self, counter_us: u64) {
        self.now_us = self.now_us.max(counter_us);
    }

    /// Drops the pulses up to the counter reached, unseen (a line not yet connected).
    pub fn skip_pending(&mut self) {
        while self.counter_at(self.next_s as f64 * 1e6) <= self.now_us as f64 {
            self.next_s += 1;
        }
    }
}

impl SyncPulse for PpsModel {
    fn take_pulse(&mut self) -> Option<u64> {
        let edge = self.counter_at(self.next_s as f64 * 1e6);
        if edge > self.now_us as f64 {
            return None;
        }
        self.next_s += 1;
        let late = self.rng.random_range(0.0..PULSE_JITTER_US as f64);
        Some((edge + late).floor().max(0.0) as u64)
    }
}
