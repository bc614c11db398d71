//! The mode rules, all of them: which mode a frame runs in and why, from the last frame's
//! outcome, the commands received and whether a calibration table is in force. The frame
//! loop asks twice a frame: [`Modes::begin`] at its start, [`Modes::end`] at its end.
//!
//! - a command takes effect at the next frame; a commanded standby holds until the next
//!   command; tracking needs stars from the last frame;
//! - no calibration table: standby ([`ModeReason::NoTable`]), then acquisition when one is
//!   in force ([`ModeReason::TableAvailable`]);
//! - acquisition -> tracking with at least `min_track_stars` usable centroids, unless the
//!   attitude stage asks for one more acquisition frame ([`Modes::acquire_again`]: an
//!   attitude with no rate yet, which a second lost-in-space attitude gives);
//! - tracking -> acquisition with fewer, or after `reacquire_every` tracking frames in a row
//!   whose windows the tracker placed on its own last stars;
//! - with a prediction from the attitude stage (the catalog's stars at the next frame,
//!   [`super::PredictedStar`]) the next frame tracks its windows
//!   ([`ModeReason::Predicted`] when the rules above would have acquired): a full frame
//!   comes only when the attitude stage stops predicting (no attitude for some frames, too
//!   few stars predicted), and tracking frames on a prediction never count towards
//!   `reacquire_every`.
//!
//! Cost: a few compares a frame.

use super::config::TrackerConfig;
use super::record::{Mode, ModeReason};

/// Why a mode command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CommandError {
    /// Tracking was asked for with no star from the last frame to track.
    NothingToTrack,
}

impl core::fmt::Display for CommandError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::NothingToTrack => "tracking needs stars from the last frame",
        })
    }
}

impl core::error::Error for CommandError {}

/// The mode state between frames.
#[derive(Clone, Copy, Debug)]
pub(super) struct Modes {
    /// The current (or last) frame's mode.
    mode: Mode,
    /// What the rules gave the next frame, and why.
    next: (Mode, ModeReason),
    /// A command waiting for the next frame.
    commanded: Option<Mode>,
    /// A commanded standby, held until the next command.
    standby_held: bool,
    /// Tracking frames in a row up to the current one.
    tracking_run: u32,
    /// The attitude stage asked for one more acquisition frame after this one.
    again: bool,
}

impl Modes {
    /// Before the first frame: standby, acquisition next.
    pub(super) const fn new() -> Self {
        Self {
            mode: Mode::Standby,
            next: (Mode::Acquisition, ModeReason::Start),
            commanded: None,
            standby_held: false,
            tracking_run: 0,
            again: false,
        }
    }

    /// After an acquisition frame that would hand over to tracking: the next frame
    /// acquires once more instead (no mode change, so no event). A command, a prediction
    /// or too few stars take precedence.
    pub(super) fn acquire_again(&mut self) {
        self.again =
            self.mode == Mode::Acquisition && self.next == (Mode::Tracking, ModeReason::Acquired);
    }

    /// The current (or last) frame's mode.
    pub(super) fn mode(&self) -> Mode {
        self.mode
    }

    /// Takes a command for the next frame; `have_stars`: the last frame left stars to
    /// track.
    pub(super) fn command(&mut self, mode: Mode, have_stars: bool) -> Result<(), CommandError> {
        if mode == Mode::Tracking && !have_stars {
            return Err(CommandError::NothingToTrack);
        }
        self.commanded = Some(mode);
        Ok(())
    }

    /// A frame starts: its mode, and `(from, reason)` when that is a change;
    /// `predicted`: the attitude stage predicted this frame's stars.
    pub(super) fn begin(
        &mut self,
        have_stars: bool,
        have_table: bool,
        predicted: bool,
    ) -> (Mode, Option<(Mode, ModeReason)>) {
        let (mut to, mut reason) = self.next;
        if core::mem::take(&mut self.again) && !predicted {
            (to, reason) = (Mode::Acquisition, ModeReason::Acquired);
        }
        if predicted
            && to == Mode::Acquisition
            && matches!(reason, ModeReason::TooFewStars | ModeReason::Reacquire)
        {
            (to, reason) = (Mode::Tracking, ModeReason::Predicted);
        }
        if let Some(m) = self.commanded.take() {
            (to, reason) = (m, ModeReason::Command);
            self.standby_held = m == Mode::Standby;
        }
        if to == Mode::Tracking && !have_stars {
            (to, reason) = (Mode::Acquisition, ModeReason::TooFewStars);
        }
        if to != Mode::Standby && !have_table {
            (to, reason) = (Mode::Standby, ModeReason::NoTable);
        }
        let from = self.mode;
        self.mode = to;
        (to, (to != from).then_some((from, reason)))
    }

    /// The frame ended with `centroids` usable centroids: the rules' next mode;
    /// `predicted`: its windows came from the attitude stage's prediction.
    pub(super) fn end(&mut self, centroids: u16, config: &TrackerConfig, predicted: bool) -> Mode {
        let enough = centroids >= config.min_track_stars;
        self.tracking_run = match self.mode {
            Mode::Tracking if predicted => 0,
            Mode::Tracking => self.tracking_run.saturating_add(1),
            _ => 0,
        };
        self.next = match self.mode {
            Mode::Standby if self.standby_held => (Mode::Standby, ModeReason::Command),
            Mode::Standby => (Mode::Acquisition, ModeReason::TableAvailable),
            Mode::Acquisition if enough => (Mode::Tracking, ModeReason::Acquired),
            Mode::Acquisition => (Mode::Acquisition, ModeReason::TooFewStars),
            Mode::Tracking if !enough => (Mode::Acquisition, ModeReason::TooFewStars),
            Mode::Tracking if self.tracking_run >= config.reacquire_every => {
                (Mode::Acquisition, ModeReason::Reacquire)
            }
            Mode::Tracking => (Mode::Tracking, ModeReason::Acquired),
        };
        self.next.0
    }
}
