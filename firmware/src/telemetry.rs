//! The board's telemetry port: the core tracker's records ([`LineSummary`],
//! [`StarRecord`], [`FrameSummary`], [`Event`]) written to the defmt log, which `probe-rs
//! run` reads over RTT. The records are the core's, so the command link that replaces the
//! log sends the same ones; logging a record does not block the frame loop (RTT in
//! non-blocking mode drops what the host does not read in time).

use startrack_core::tracker::{Event, FrameSummary, LineSummary, StarRecord, TelemetrySink};

/// The defmt log as the tracker's telemetry port.
pub struct DefmtTelemetry;

impl TelemetrySink for DefmtTelemetry {
    fn line(&mut self, summary: &LineSummary) {
        defmt::info!("line {}", summary);
    }

    fn star(&mut self, frame: u32, s: &StarRecord) {
        defmt::info!(
            "frame {} star x {=f32} px y {=f32} px flux {=f32} e- snr {=f32} sigma {=f32}/{=f32} px flags {=u32:#x}",
            frame,
            s.x_px,
            s.y_px,
            s.flux_e,
            s.snr,
            s.sigma_x_px,
            s.sigma_y_px,
            s.flags.bits()
        );
    }

    fn frame(&mut self, summary: &FrameSummary) {
        defmt::info!("frame {}", summary);
    }

    fn event(&mut self, event: &Event) {
        defmt::info!("event {}", event);
    }
}
