//! Time to the first attitude after power-on, from its parts: the frames the tracker reads
//! before it (a standby frame, the start's first: its compiled program's cycle, the frame
//! transfer then the full frame's readout or the flight exposure, whichever is longer; then
//! the acquisition frame to its last sample: `startrack readout-plan --mode full
//! --pixel-rate-hz 1000000 --exposure-us E --breakdown`), the acquisition frame's M7 work and the lost-in-space
//! identification from `cargo m7-bench` (`host-tests/m7-costs.csv`: QEMU Cortex-M7
//! instructions, counted here at one instruction a cycle of the 480 MHz core, which the
//! board's caches and wait states do not promise). The acquisition's work is counted after
//! its readout, whole (on the board it streams with the lines, so this is a bound); the
//! identification at the bench's largest field (`ident_lost_in_space_max`). Boot (clocks, the
//! flash store's tables, the catalog) is not measured: what is left of the 1.5 s target is
//! its budget.

use super::readout_plan::{Mode, ReadoutPlanArgs, plan_cost};
use startrack_core::tracker::TrackerConfig;

/// The target, ms.
pub const TARGET_MS: f64 = 1500.0;

/// The M7's clock, Hz (one QEMU instruction counted a cycle).
pub const M7_HZ: f64 = 480e6;

/// One part of the time.
#[derive(Clone, Debug, PartialEq)]
pub struct Part {
    /// What it is.
    pub step: &'static str,
    /// Its time, ms.
    pub ms: f64,
    /// Where the number comes from.
    pub from: String,
}

/// One stage's instructions a unit from `m7_costs` (the text of `host-tests/m7-costs.csv`).
fn m7_stage(m7_costs: &str, stage: &str) -> Result<f64, String> {
    let prefix = format!("{stage},");
    m7_costs
        .lines()
        .find_map(|l| l.strip_prefix(prefix.as_str()))
        .and_then(|rest| rest.rsplit(',').next())
        .and_then(|v| v.trim().parse().ok())
        .ok_or_else(|| format!("m7-costs.csv: no stage {stage}"))
}

/// The parts with `exposure_ms` and the M7 costs `m7_costs`, then their sum after boot and
/// what the 1.5 s target leaves for the boot.
pub fn parts(exposure_ms: u32, m7_costs: &str) -> Result<Vec<Part>, String> {
    let full = ReadoutPlanArgs {
        mode: Mode::Full,
        pixel_rate_hz: 1_000_000,
        windows: 0,
        window_px: 11,
        outputs: 2,
        binning: 1,
        exposure_us: exposure_ms.saturating_mul(1000),
        seed: 1,
        breakdown: false,
    };
    let cost = plan_cost(&full).map_err(|e| e.to_string())?.cost;
    let frame_ms = cost.cycle_ns() as f64 / 1e6;
    let read_ms = (cost.segment_ns(startrack_core::sequencer::SegmentId::FrameTransfer)
        + cost.frame_time_ns()) as f64
        / 1e6;
    let work =
        |stage: &str| -> Result<f64, String> { Ok(m7_stage(m7_costs, stage)? / M7_HZ * 1e3) };
    let mut out = vec![
        Part {
            step: "standby frame",
            ms: frame_ms,
            from: format!(
                "compiled full frame at 1 MHz, both outputs, exposure {exposure_ms} ms: frame transfer + max(readout, exposure)"
            ),
        },
        Part {
            step: "acquisition frame",
            ms: read_ms,
            from: "the same program to its last sample: frame transfer + readout".into(),
        },
        Part {
            step: "acquisition processing",
            ms: work("tracker_acquisition_frame")?,
            from: "m7-costs.csv tracker_acquisition_frame at 480 MHz".into(),
        },
        Part {
            step: "identification",
            ms: work("ident_lost_in_space_max")?,
            from: "m7-costs.csv ident_lost_in_space_max at 480 MHz".into(),
        },
    ];
    let total: f64 = out.iter().map(|p| p.ms).sum();
    out.push(Part {
        step: "after boot",
        ms: total,
        from: "the sum".into(),
    });
    out.push(Part {
        step: "boot budget",
        ms: TARGET_MS - total,
        from: "1.5 s target less the sum (boot not measured)".into(),
    });
    Ok(out)
}

/// A long exposure the time is also given at, ms (1 s: the standby frame is then padded
/// to it).
pub const LONG_EXPOSURE_MS: u32 = 1000;

/// The exposures the time is given at: [`LONG_EXPOSURE_MS`] and the flight configuration's.
pub fn exposures_ms() -> [u32; 2] {
    [LONG_EXPOSURE_MS, TrackerConfig::FLIGHT.exposure_ms]
}

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "exposure_ms,step,ms,from";

/// The parts at each of [`exposures_ms`] as CSV, after `comment` lines (each prefixed `# `).
pub fn csv(m7_costs: &str, comment: &[&str]) -> Result<String, String> {
    let mut out = startrack_analysis::figures::csv::csv_head(comment, CSV_HEADER);
    for e in exposures_ms() {
        for p in parts(e, m7_costs)? {
            out.push_str(&format!(
                "{e},{},{:.1},{}\n",
                p.step,
                p.ms,
                p.from.replace(',', ";")
            ));
        }
    }
    Ok(out)
}
