//! tradeoff.csv: every centroid method's cost per star against its accuracy at SNR 10, 30,
//! 100 and a = 0.7, 1, 1.5, 2 px, with the Pareto frontier of each scene ([`TradeRow`]s, which
//! [`super::png::tradeoff`] draws as tradeoff.png).
//!
//! Accuracy is [`crate::accuracy::run_cell`] (the seeded Monte Carlo of `startrack accuracy`:
//! RMS error against the truth and the Cramer-Rao bound over the same stars); cost is the M7
//! instruction count and the host time of [`super::cost`]. In each scene (a, SNR) a method is
//! on the frontier ([`super::pareto`]) when no other method is both cheaper and has a smaller
//! RMS error: `pareto_m7` on M7 instructions, `pareto_host` on host ns. Methods without an M7
//! count are left out of `pareto_m7` (and its chart).

use super::cost::{M7Table, host_ns_per_star, m7_cost};
use super::pareto::frontier;
use crate::accuracy::{Cell, Method, Noise, run_cell};
use crate::figures::{FigureError, Written, csv};
use std::path::Path;

/// One method in one scene.
#[derive(Clone, Debug)]
pub struct TradeRow {
    /// The accuracy cell.
    pub cell: Cell,
    /// M7 instructions per star, when known.
    pub m7_instructions: Option<f64>,
    /// How the M7 count was obtained ([`super::cost`]).
    pub m7_basis: String,
    /// Host ns per star, when measured.
    pub host_ns: Option<f64>,
    /// On the frontier of M7 instructions against RMS.
    pub pareto_m7: bool,
    /// On the frontier of host time against RMS.
    pub pareto_host: bool,
}

/// The scenes of the chart.
pub const WIDTHS_A_PX: [f64; 4] = [0.7, 1.0, 1.5, 2.0];
/// The SNRs of the chart (eq. 8 in a 5x5 box).
pub const SNRS: [f64; 3] = [10.0, 30.0, 100.0];

/// Costs per method: `(m7, basis, host_ns)`; `host_passes == 0` skips the host timing.
pub fn costs(
    methods: &[Method],
    m7: &M7Table,
    host_passes: usize,
) -> Vec<(Option<f64>, String, Option<f64>)> {
    methods
        .iter()
        .map(|m| {
            let (i, basis) = match m7_cost(m, m7) {
                Some((i, b)) => (Some(i), b),
                None => (None, "not in the M7 table".into()),
            };
            let host = (host_passes > 0)
                .then(|| host_ns_per_star(*m, 500, host_passes))
                .flatten();
            (i, basis, host)
        })
        .collect()
}

/// Runs the accuracy cells and marks the frontiers; `tick` is called once per cell.
pub fn rows(
    methods: &[Method],
    costs: &[(Option<f64>, String, Option<f64>)],
    noise: &Noise,
    mut tick: impl FnMut(),
) -> Vec<TradeRow> {
    let mut out = Vec::new();
    for &snr in &SNRS {
        for &a in &WIDTHS_A_PX {
            let mut scene: Vec<TradeRow> = Vec::new();
            for (m, (m7, basis, host)) in methods.iter().zip(costs) {
                tick();
                if let Some(cell) = run_cell(*m, a, snr, noise) {
                    scene.push(TradeRow {
                        cell,
                        m7_instructions: *m7,
                        m7_basis: basis.clone(),
                        host_ns: *host,
                        pareto_m7: false,
                        pareto_host: false,
                    });
                }
            }
            let nan = f64::NAN;
            let f_m7 = frontier(
                &scene
                    .iter()
                    .map(|r| (r.m7_instructions.unwrap_or(nan), r.cell.rms_px))
                    .collect::<Vec<_>>(),
            );
            let f_host = frontier(
                &scene
                    .iter()
                    .map(|r| (r.host_ns.unwrap_or(nan), r.cell.rms_px))
                    .collect::<Vec<_>>(),
            );
            for ((r, a), b) in scene.iter_mut().zip(f_m7).zip(f_host) {
                r.pareto_m7 = a;
                r.pareto_host = b;
            }
            out.extend(scene);
        }
    }
    out
}

/// tradeoff.csv's column names.
pub const COLUMNS: &str = "method,window,a_px,snr,m7_instructions,m7_basis,host_ns,rms_px,crlb_px,rms_over_crlb,failed,pareto_m7,pareto_host";

/// Writes tradeoff.csv.
pub fn write_csv(
    out: &Path,
    rows: &[TradeRow],
    noise: &Noise,
    m7_source: &str,
    written: &mut Written,
) -> Result<(), FigureError> {
    let opt = |v: Option<f64>, prec: usize| v.map_or(String::new(), |v| format!("{v:.prec$}"));
    let lines: Vec<String> = rows
        .iter()
        .map(|r| {
            let c = &r.cell;
            format!(
                "{},{},{},{},{},{},{},{:.5},{:.5},{:.3},{},{},{}",
                c.method.name(),
                c.method.window_side(),
                c.a_px,
                c.snr,
                opt(r.m7_instructions, 0),
                r.m7_basis,
                opt(r.host_ns, 0),
                c.rms_px,
                c.crlb_px,
                c.efficiency_ratio(),
                c.failures,
                u8::from(r.pareto_m7),
                u8::from(r.pareto_host)
            )
        })
        .collect();
    let header = vec![
        "Speed against accuracy of every centroid method (startrack tradeoff)".to_string(),
        format!(
            "accuracy: startrack accuracy's Monte Carlo, {} stars per cell, uniform pixel phase, background {} e-/px, read noise {} e-, seed {}; SNR by eq. 8 in 5x5; failed = results flagged degenerate or not converged (left out of rms)",
            noise.trials, noise.background_e, noise.read_noise_e, noise.seed
        ),
        format!(
            "m7_instructions: QEMU mps2-an500 instructions per star from {m7_source} (cargo m7-bench), mapped as m7_basis says; host_ns: this machine, fastest of repeated passes over 500 stars at a = 1 px SNR 30 (wall-clock, not deterministic)"
        ),
        "pareto_*: 1 when no other method of the same (a_px, snr) is both cheaper (M7 / host) and has a smaller rms_px".into(),
    ];
    csv::write_csv(out, "tradeoff.csv", &header, COLUMNS, &lines, written)
}
