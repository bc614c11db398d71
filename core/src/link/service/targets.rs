//! What the link's commands act on: the tracker application ([`TrackerControl`]), the table
//! store and the diagnostic window source ([`WindowReader`]), bundled for one call as
//! [`Targets`]. Traits and references only, no cost of their own.

use super::super::command::WindowRequest;
use super::super::upload::TableUpload;
use crate::calib::refresh::Defect;
use crate::tracker::{CommandError, ConfigError, Mode, Tracker, TrackerConfig};

/// Reads a diagnostic window for [`Command::Window`](super::super::Command::Window) (the
/// board has no source and serves [`NoWindows`]; the SIL reads the simulated frame).
pub trait WindowReader {
    /// Whether `request` can be read (inside the area, a source there).
    fn check(&mut self, request: &WindowRequest) -> bool;
    /// Row `row` (0-based within the window) into `out` (`side_px` values: raw ADU, or
    /// calibrated e- x 64); `false` if it cannot be read.
    fn read_row(&mut self, request: &WindowRequest, row: u16, out: &mut [i32]) -> bool;
}

/// A window reader that has no source (every window request is rejected).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoWindows;

impl WindowReader for NoWindows {
    fn check(&mut self, _request: &WindowRequest) -> bool {
        false
    }

    fn read_row(&mut self, _request: &WindowRequest, _row: u16, _out: &mut [i32]) -> bool {
        false
    }
}

/// What the link's mode and configuration commands act on: the tracker application
/// ([`Tracker`] implements it). A trait so that the same service also runs with no tracker
/// at all (the safe standby, [`LinkService::receive_standby`]).
///
/// [`LinkService::receive_standby`]: super::LinkService::receive_standby
pub trait TrackerControl {
    /// Asks for `mode` from the next frame ([`Tracker::command_mode`]).
    fn command_mode(&mut self, mode: Mode) -> Result<(), CommandError>;
    /// The configuration in force.
    fn config(&self) -> TrackerConfig;
    /// Replaces the configuration if it passes its checks ([`Tracker::set_config`]).
    fn set_config(&mut self, config: TrackerConfig) -> Result<(), ConfigError>;
    /// The pixels confirmed in flight that the table in force does not list
    /// ([`Tracker::new_defects`]; none by default).
    fn new_defects(&self) -> &[Defect] {
        &[]
    }
}

impl<const N: usize> TrackerControl for Tracker<'_, '_, N> {
    fn command_mode(&mut self, mode: Mode) -> Result<(), CommandError> {
        Tracker::command_mode(self, mode)
    }

    fn config(&self) -> TrackerConfig {
        *Tracker::config(self)
    }

    fn set_config(&mut self, config: TrackerConfig) -> Result<(), ConfigError> {
        Tracker::set_config(self, config)
    }

    fn new_defects(&self) -> &[Defect] {
        Tracker::new_defects(self)
    }
}

/// What a command acts on inside the service: the tracker if one runs.
pub(super) struct Ctx<'a> {
    pub(super) tracker: Option<&'a mut dyn TrackerControl>,
    pub(super) tables: &'a mut dyn TableUpload,
    pub(super) windows: &'a mut dyn WindowReader,
}

/// What commands act on, for one call.
pub struct Targets<'a, 't, 'b, const N: usize> {
    /// The tracker application.
    pub tracker: &'a mut Tracker<'t, 'b, N>,
    /// The table store.
    pub tables: &'a mut dyn TableUpload,
    /// The diagnostic window source.
    pub windows: &'a mut dyn WindowReader,
}
