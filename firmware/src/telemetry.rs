//! The board's telemetry port: the core tracker's records ([`LineSummary`],
//! [`StarRecord`], [`FrameSummary`], [`Event`]) written to the defmt log, which `probe-rs
//! run` reads over RTT. The records are the core's, so the command link that replaces the
//! log sends the same ones; logging a record does not block the frame loop (RTT in
//! non-blocking mode drops what the host does not read in time).
//!
//! Fixed-point fields go out as `f32` (`{=f32}`: four bytes, formatted on the host), so the
//! image carries no decimal formatting of its own (fixed's `defmt::Format` would link
//! `core::fmt`'s float printing, about 24 KB of flash).

use startrack_core::tracker::{
    Event, FrameSummary, LineOutcome, LineSummary, StarRecord, TelemetrySink,
};

/// The defmt log as the tracker's telemetry port.
pub struct DefmtTelemetry;

impl TelemetrySink for DefmtTelemetry {
    fn line(&mut self, s: &LineSummary) {
        let [b0, b1] = s.bias_adu;
        let dark = s.dark_scale_e.to_num::<f32>();
        match s.outcome {
            LineOutcome::Calibrated {
                mean_e,
                flags,
                saturated,
            } => defmt::info!(
                "line {} of frame {}: bias {=f32}/{=f32} ADU, dark scale {=f32} e-, calibrated: mean {=f32} e-, flags {=u8:#x}, {} saturated",
                s.line,
                s.frame,
                b0.to_num::<f32>(),
                b1.to_num::<f32>(),
                dark,
                mean_e.to_num::<f32>(),
                flags.bits(),
                saturated
            ),
            LineOutcome::Uncalibrated {
                mean_above_bias_adu,
            } => defmt::info!(
                "line {} of frame {}: bias {=f32}/{=f32} ADU, uncalibrated: mean {=f32} ADU above bias",
                s.line,
                s.frame,
                b0.to_num::<f32>(),
                b1.to_num::<f32>(),
                mean_above_bias_adu
            ),
            LineOutcome::Tracked { windows_done } => defmt::info!(
                "line {} of frame {}: bias {=f32}/{=f32} ADU, dark scale {=f32} e-, tracked: {} windows done",
                s.line,
                s.frame,
                b0.to_num::<f32>(),
                b1.to_num::<f32>(),
                dark,
                windows_done
            ),
            LineOutcome::Scanned | LineOutcome::Levels | LineOutcome::Refused => defmt::info!(
                "line {} of frame {}: bias {=f32}/{=f32} ADU, dark scale {=f32} e-, {=str}",
                s.line,
                s.frame,
                b0.to_num::<f32>(),
                b1.to_num::<f32>(),
                dark,
                match s.outcome {
                    LineOutcome::Scanned => "scanned",
                    LineOutcome::Levels => "levels only",
                    _ => "refused",
                }
            ),
        }
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

    fn frame(&mut self, s: &FrameSummary) {
        defmt::info!(
            "frame {} ({} -> {}) at {=u64} us: calibrated {=bool}, {=f32} K ({}), dark scale {=f32} e-; lines {} ({} refused); stars {} ({} centroids, {} dropped); lost: candidates {}, windows {}, ring {}, calibration {}; tracking windows {} ({} refused, {} lost); dark drift {}; defects pending {}",
            s.frame,
            s.mode,
            s.next_mode,
            s.start_us,
            s.calibrated,
            s.temperature_k.to_num::<f32>(),
            s.temperature_source,
            s.dark_scale_e.map_or(f32::NAN, |d| d.to_num::<f32>()),
            s.lines,
            s.lines_refused,
            s.stars,
            s.centroids,
            s.stars_dropped,
            s.candidates_dropped,
            s.windows_dropped,
            s.ring_lost,
            s.calib_failed,
            s.track_windows,
            s.track_refused,
            s.track_lost,
            s.dark_drift,
            s.defects_pending
        );
    }

    fn event(&mut self, event: &Event) {
        defmt::info!("event {}", event);
    }
}
