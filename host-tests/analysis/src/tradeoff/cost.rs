//! Cost per star of each centroid method: Cortex-M7 instructions from a `cargo m7-bench` CSV,
//! and host nanoseconds timed in-process.
//!
//! # M7 instructions
//! `cargo m7-bench` prints `stage,unit,instructions_per_unit` (QEMU `-icount` instructions,
//! identical run to run; `host-tests/m7-costs.csv` is a committed copy, regenerated with
//! `cargo m7-bench > host-tests/m7-costs.csv`). The bench times each method with the whole
//! 5x5 or 7x7 window as its box and (except the `_given_bg` stages) a perimeter-median
//! background,
//! while the accuracy experiment runs a CoG box two pixels narrower than its window with the
//! background given. [`m7_cost`] maps each method to the
//! nearest measurement and says how in a `basis` string:
//! - `measured`: the stage of the same method, box and background;
//! - `perimeter bg`: the measured stage uses a perimeter-median background (an upper bound:
//!   the median of the ring is part of it);
//! - `perimeter bg + background fitted`: the Gauss fit's perimeter stage, which also fits the
//!   background (one more parameter per step; an upper bound), used only when the CSV lacks
//!   the `centroid_gauss_fit_given_bg` stages (the Monte Carlo's configuration: background
//!   given and held, start box `min(window, 5)`; basis `measured`);
//! - `extrapolated`: linear in the pixel count through the 5x5 and 7x7 stages (3x3 boxes);
//! - `power-2 extra added`: CoG power 2 with a given background = `cog1_given_bg` plus the
//!   measured difference `cog2 - cog1` of the perimeter stages;
//! - `correction added (7x7 measurement)`: a corrected CoG costs its uncorrected CoG plus
//!   the measured `centroid_cog1c_7x7 - centroid_cog1_7x7` (the curve's look-up and
//!   interpolation, independent of the box);
//! - `correction not counted`: the same with a bench CSV that lacks `centroid_cog1c_7x7`;
//! - `fused raw path (calibration included)`: a corrected power-1 CoG (given background) can
//!   also be computed by `centroid::raw_cog` from the raw window, calibration fused in (stage
//!   `centroid_cog1c_raw_<n>x<n>`, one-shot); the method is charged the cheaper of that and
//!   the path above (the fused path wins where its cost, calibration included, is below the
//!   CoG's on a calibrated window).
//!
//! # Host time
//! [`host_ns_per_star`] runs the method on a fixed set of noisy stars (seeded) in repeated
//! passes and keeps the fastest pass's mean: wall-clock, so it varies with the machine and
//! its load (on a shared machine, compare the `host_ns` column of two `startrack tradeoff`
//! runs) and is the one column of the outputs that is not deterministic.

use crate::accuracy::{Method, PreparedMethod, flux_for_snr};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Poisson, Uniform};
use startrack_core::centroid::CentroidInput;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::sim::psf::{pixel_fraction, sigma_of_a};
use std::collections::BTreeMap;
use std::time::Instant;

/// Instructions per unit by stage name, from a `cargo m7-bench` CSV.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct M7Table {
    /// `stage -> instructions_per_unit`.
    pub stages: BTreeMap<String, f64>,
}

/// Why an M7 CSV could not be read.
#[derive(Clone, Debug, PartialEq)]
pub struct M7ParseError {
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub msg: String,
}

impl std::fmt::Display for M7ParseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.msg)
    }
}

impl M7Table {
    /// Parses `stage,unit,instructions_per_unit` lines; `#` comments, blank lines and the
    /// column-name line are skipped.
    pub fn parse(text: &str) -> Result<Self, M7ParseError> {
        let mut stages = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') || line.starts_with("stage,") {
                continue;
            }
            let f: Vec<&str> = line.split(',').collect();
            let err = |msg: &str| M7ParseError {
                line: i + 1,
                msg: msg.into(),
            };
            if f.len() != 3 {
                return Err(err("expected stage,unit,instructions_per_unit"));
            }
            let v: f64 = f[2]
                .trim()
                .parse()
                .map_err(|_| err("instructions_per_unit is not a number"))?;
            if !(v.is_finite() && v >= 0.0) {
                return Err(err("instructions_per_unit must be finite and not negative"));
            }
            stages.insert(f[0].trim().to_string(), v);
        }
        if stages.is_empty() {
            return Err(M7ParseError {
                line: 0,
                msg: "no stage rows".into(),
            });
        }
        Ok(Self { stages })
    }

    fn get(&self, stage: &str) -> Option<f64> {
        self.stages.get(stage).copied()
    }

    /// `stage_<n>x<n>` at `n` pixels on a side, linear in `n^2` through the 5x5 and 7x7 rows.
    fn by_side(&self, stage: &str, n: u16) -> Option<(f64, bool)> {
        let s5 = self.get(&format!("{stage}_5x5"))?;
        let s7 = self.get(&format!("{stage}_7x7"))?;
        match n {
            5 => Some((s5, false)),
            7 => Some((s7, false)),
            _ => {
                let slope = (s7 - s5) / 24.0;
                Some(((s5 + slope * (f64::from(n * n) - 25.0)).max(0.0), true))
            }
        }
    }
}

/// M7 instructions per star of `method` and how they were obtained (module docs); `None`
/// when the table lacks the stages.
pub fn m7_cost(method: &Method, t: &M7Table) -> Option<(f64, String)> {
    match *method {
        Method::Cog {
            power,
            box_side,
            corrected,
        } => {
            let n = u16::from(box_side);
            // A corrected power-1 CoG with a given background is also what the fused
            // raw-window path computes (`centroid::raw_cog`: same position, calibration
            // included): the method costs the cheaper of the two paths.
            let fused = (power == CogPower::One && corrected)
                .then(|| t.by_side("centroid_cog1c_raw", n))
                .flatten()
                .map(|(c, ex)| (c, basis(ex, "fused raw path (calibration included)")));
            let general = general_cog_cost(t, power, n, corrected);
            match (fused, general) {
                (Some(f), Some(g)) => Some(if f.0 < g.0 { f } else { g }),
                (f, g) => f.or(g),
            }
        }
        Method::GaussFitWidth { window } => {
            let (c, ex) = t.by_side("centroid_gauss_fit_width", u16::from(window))?;
            Some((
                c,
                basis(
                    ex,
                    "measured (background given; the border median not counted)",
                ),
            ))
        }
        Method::GaussFitWidthModel { window, .. } => {
            let (c, ex) = t.by_side("centroid_gauss_fit_width_model", u16::from(window))?;
            Some((c, basis(ex, "measured, background given")))
        }
        Method::GaussFit { window } | Method::GaussFitAssumed { window, .. } => {
            // The given-background stage runs the Monte Carlo's configuration (background
            // given and held, start box min(window, 5)); older bench CSVs only have the
            // perimeter-median stage that also fits the background, an upper bound.
            let n = u16::from(window);
            match t.by_side("centroid_gauss_fit_given_bg", n) {
                Some((c, ex)) => Some((c, basis(ex, "measured"))),
                None => {
                    let (c, ex) = t.by_side("centroid_gauss_fit", n)?;
                    Some((c, basis(ex, "perimeter bg + background fitted")))
                }
            }
        }
    }
}

/// The `m7_basis` text: `what`, marked extrapolated when it is.
fn basis(extrapolated: bool, what: &str) -> String {
    match (extrapolated, what) {
        (true, "measured") => "extrapolated".to_string(),
        (true, _) => format!("extrapolated; {what}"),
        (false, _) => what.to_string(),
    }
}

/// A CoG's cost on a calibrated window: the given-background stage of its box, power 2's
/// extra and the correction's cost added as the module docs say.
fn general_cog_cost(
    t: &M7Table,
    power: CogPower,
    n: u16,
    corrected: bool,
) -> Option<(f64, String)> {
    let (c1, ex) = t.by_side("centroid_cog1_given_bg", n)?;
    let (cost, what) = match power {
        CogPower::One => (c1, basis(ex, "measured")),
        CogPower::Two => {
            let (p1, _) = t.by_side("centroid_cog1", n)?;
            let (p2, _) = t.by_side("centroid_cog2", n)?;
            (c1 + (p2 - p1).max(0.0), basis(ex, "power-2 extra added"))
        }
    };
    if corrected {
        // The correction's own cost: the bench's corrected CoG 7x7 less the plain one
        // (the curve look-up and interpolation do not depend on the box).
        match (t.get("centroid_cog1c_7x7"), t.get("centroid_cog1_7x7")) {
            (Some(c), Some(p)) => Some((
                cost + (c - p).max(0.0),
                format!("{what}; correction added (7x7 measurement)"),
            )),
            _ => Some((cost, format!("{what}; correction not counted"))),
        }
    } else {
        Some((cost, what))
    }
}

/// Noisy stars (a = 1 px, SNR 30, background 100 e-, read noise 5 e-) in `side x side`
/// windows at uniform phases, seeded.
fn timing_stars(side: u16, count: usize) -> Vec<Vec<Electrons>> {
    let (bg, read) = (100.0, 5.0);
    let sigma = sigma_of_a(1.0);
    let flux = flux_for_snr(30.0, 5.0, bg + read * read);
    let mut rng = ChaCha8Rng::seed_from_u64(0x71_3e);
    let (Ok(u), Ok(rn)) = (Uniform::new(-0.5, 0.5), Normal::new(0.0, read)) else {
        return Vec::new();
    };
    let c = f64::from(side / 2);
    (0..count)
        .map(|_| {
            let (x, y) = (c + u.sample(&mut rng), c + u.sample(&mut rng));
            (0..side * side)
                .map(|k| {
                    let (col, row) = (f64::from(k % side), f64::from(k / side));
                    let m =
                        bg + flux * pixel_fraction(col, x, sigma) * pixel_fraction(row, y, sigma);
                    let p = Poisson::new(m).map_or(m, |p| p.sample(&mut rng));
                    Electrons::from_num(p + rn.sample(&mut rng))
                })
                .collect()
        })
        .collect()
}

/// Host nanoseconds per star of `method` (a = 1 px, SNR 30): the fastest of `passes` passes
/// over `stars` stars; `None` when the method does not apply at a = 1 px.
pub fn host_ns_per_star(method: Method, stars: usize, passes: usize) -> Option<f64> {
    let p = PreparedMethod::new(method, 1.0, 100.0, 125.0)?;
    let side = method.window_side();
    let data = timing_stars(side, stars.max(1));
    let rect = Rect {
        x0: 0,
        y0: 0,
        width: side,
        height: side,
    };
    let inputs: Vec<CentroidInput<'_>> = data
        .iter()
        .filter_map(|d| Window::new(rect, d).map(CentroidInput::new))
        .collect();
    let mut best = f64::INFINITY;
    for _ in 0..passes.max(1) {
        let t0 = Instant::now();
        let mut sink = 0.0f32;
        for i in &inputs {
            let c = p.run(std::hint::black_box(i));
            sink += c.x_px;
        }
        std::hint::black_box(sink);
        let ns = t0.elapsed().as_nanos() as f64 / inputs.len().max(1) as f64;
        best = best.min(ns);
    }
    Some(best)
}
