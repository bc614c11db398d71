//! Accuracy against body rate of each centroid method on a trailed star, against the
//! Cramer-Rao bound of that star ([`startrack_sim::trail::crlb`], the background fitted):
//! the star trailed along a line over the exposure (the simulator's exact integration,
//! [`startrack_sim::trail`]), Poisson and read noise, at random pixel phases and trail
//! angles; per rate and method the RMS position error over the stars the method does not
//! flag, the fraction it flags, and its pull (error over its own sigma).
//!
//! The star: the flight PSF (`a` = 1.2 px, sigma 0.668 px), 8,000 e- (a 6th-magnitude star in
//! 100 ms on the SIL's sky, [`startrack_sim::sky::scene`]), 100 e-/px background, read
//! noise 5 e-; 100 ms exposures on the SIL's 15-degree 1024-px field (68.3 px a degree); the
//! window the trail's extent plus 2.5 sigma and a border pixel each side, odd, at least
//! 7 px (acquisition's rule, without its 15 px cap so that every method sees the whole
//! trail). The methods, each with the background from the window's border:
//! - `trail-known`: [`trail_fit`], the trail given (from a rate the home knows);
//! - `trail-free`: [`trail_fit_free`], the trail fitted (acquisition's); flagged when the
//!   test does not call the star trailed or the fit fails;
//! - `gauss-width`: the width-free Gauss fit on the window_px = 7 window around the peak
//!   (acquisition's round method); flagged as acquisition flags it: not converged, poor
//!   fit, or wider than [`SMEARED_WIDTH_RATIO`] times the PSF;
//! - `gauss`: the Gauss fit of the configured width, same window, flagged when not
//!   converged;
//! - `cog1`: the power-1 centre of gravity of the whole window (no pixel-phase curve: a
//!   trail has none).
//!
//! Cost: ~2 s in the test profile for the default points (the bound's numeric Fisher
//! matrix on one star in eight dominates).

use startrack_core::centroid::cog::{CogParams, cog};
use startrack_core::centroid::gauss_fit::{
    GaussFitParams, WidthFitParams, gauss_fit, gauss_fit_width,
};
use startrack_core::centroid::trail_fit::{
    FreeTrailParams, TrailFitParams, trail_fit, trail_fit_free,
};
use startrack_core::centroid::{Background, Centroid, CentroidFlags, CentroidInput};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::tracker::SMEARED_WIDTH_RATIO;
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};
use startrack_sim::trail::{TrailedStar, crlb, mean_window, noisy_window};

/// The PSF's `a`, px (the flight configuration's).
pub const PSF_A_PX: f64 = 1.2;
/// `sigma = sqrt(0.31) a`.
const SIGMA_PER_A: f64 = 0.556_776_4;
/// The star's signal over the exposure, e-.
pub const FLUX_E: f64 = 8_000.0;
/// Background, e-/px.
pub const BACKGROUND_E: f64 = 100.0;
/// Read noise, e-.
pub const READ_NOISE_E: f64 = 5.0;
/// Exposure, s.
pub const EXPOSURE_S: f64 = 0.1;
/// Image scale, px per degree (1024 px over 15 degrees).
pub const PX_PER_DEG: f64 = 1024.0 / 15.0;
/// The rates of the chart, deg/s.
pub const RATES_DEG_S: [f64; 7] = [0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0];
/// The methods, in the CSV's order.
pub const METHODS: [&str; 5] = ["trail-known", "trail-free", "gauss-width", "gauss", "cog1"];

/// One point of the chart.
#[derive(Clone, Debug, PartialEq)]
pub struct TrailPoint {
    /// Body rate, deg/s.
    pub rate_deg_s: f64,
    /// The trail over the exposure, px.
    pub trail_px: f64,
    /// The method.
    pub method: &'static str,
    /// Stars measured.
    pub stars: usize,
    /// Stars the method flagged (left out of the RMS).
    pub flagged: usize,
    /// RMS position error over both axes of the unflagged stars, px (per axis).
    pub rms_px: f64,
    /// RMS of the bound over both axes, px (per axis).
    pub bound_px: f64,
    /// RMS of error / own sigma over both axes of the unflagged stars.
    pub pull: f64,
}

impl TrailPoint {
    /// RMS error over the bound.
    pub fn ratio(&self) -> f64 {
        self.rms_px / self.bound_px
    }
}

fn side(extent_px: f64, sigma_px: f64) -> usize {
    let n = (extent_px.abs() + 5.0 * sigma_px + 2.0).ceil() as usize;
    (n | 1).max(7)
}

fn electrons(v: &[f64]) -> Vec<Electrons> {
    v.iter()
        .map(|&x| Electrons::saturating_from_num(x))
        .collect()
}

/// A small deterministic generator (xorshift64*), so the chart needs no other seed stream.
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Whether a method flagged a result.
fn bad(c: &Centroid) -> bool {
    c.flags.intersects(
        CentroidFlags::NOT_CONVERGED
            | CentroidFlags::DEGENERATE
            | CentroidFlags::POOR_FIT
            | CentroidFlags::CLAMPED,
    )
}

/// The method `m` on the window `input` of `star` (window-relative truth); `None` when it
/// flags the star.
fn measure(m: &str, input: &CentroidInput<'_>, star: &TrailedStar) -> Option<Centroid> {
    let sigma = (PSF_A_PX * SIGMA_PER_A) as f32;
    let bg = Background::PerimeterMedian;
    let r = input.window.rect;
    // The 7x7 window around the brightest pixel, for the round methods.
    let sub = |f: &dyn Fn(&CentroidInput<'_>) -> Option<Centroid>| -> Option<Centroid> {
        let w = usize::from(r.width);
        let (pi, _) = input
            .window
            .pixels_e
            .iter()
            .enumerate()
            .max_by_key(|(_, e)| e.to_bits())?;
        let (pc, pr) = ((pi % w) as u16, (pi / w) as u16);
        let (rel, clipped) = Rect::centred_clipped(pc, pr, 7, r.width, r.height);
        let mut e = Vec::with_capacity(rel.len());
        for row in rel.y0..rel.y0 + rel.height {
            for col in rel.x0..rel.x0 + rel.width {
                e.push(
                    *input
                        .window
                        .pixels_e
                        .get(usize::from(row) * w + usize::from(col))?,
                );
            }
        }
        let rect = Rect {
            x0: r.x0 + rel.x0,
            y0: r.y0 + rel.y0,
            ..rel
        };
        f(&CentroidInput::new(Window::new(rect, &e)?).with_clipped(clipped))
    };
    let c = match m {
        "trail-known" => {
            trail_fit(
                input,
                &TrailFitParams {
                    background: bg,
                    ..TrailFitParams::new(sigma, star.trail_dx_px as f32, star.trail_dy_px as f32)
                },
            )
            .centroid
        }
        "trail-free" => {
            // Started as acquisition starts it: the trail 30 % short and 10 degrees off (the
            // blob's moments), 1.5 px along the columns for a star that did not move.
            let l = star.trail_dx_px.hypot(star.trail_dy_px);
            let a = star.trail_dy_px.atan2(star.trail_dx_px) + 10f64.to_radians();
            let start = if l > 0.0 {
                ((0.7 * l * a.cos()) as f32, (0.7 * l * a.sin()) as f32)
            } else {
                (1.5, 0.0)
            };
            let f = trail_fit_free(input, &FreeTrailParams::new(sigma, start));
            if !f.is_trailed() {
                return None;
            }
            f.centroid
        }
        "gauss-width" => sub(&|i| {
            let f = gauss_fit_width(
                i,
                &WidthFitParams {
                    background: bg,
                    ..WidthFitParams::new()
                },
            );
            let smeared = f64::from(f.psf_a_px) > f64::from(SMEARED_WIDTH_RATIO) * PSF_A_PX;
            (!smeared).then_some(f.centroid)
        })?,
        "gauss" => sub(&|i| {
            Some(gauss_fit(
                i,
                &GaussFitParams {
                    background: bg,
                    fit_background: false,
                    ..GaussFitParams::new(sigma)
                },
            ))
        })?,
        _ => cog(
            input,
            &CogParams::new(CogPower::One, r.width.min(r.height) as u8),
        ),
    };
    (!bad(&c)).then_some(c)
}

/// The chart's points: `stars` seeded stars a rate, each measured by every method.
pub fn run(stars: usize, seed: u64) -> Vec<TrailPoint> {
    let mut out = Vec::new();
    let sigma = PSF_A_PX * SIGMA_PER_A;
    for (ri, &rate) in RATES_DEG_S.iter().enumerate() {
        let l = rate * EXPOSURE_S * PX_PER_DEG;
        let mut rng = Rng(seed ^ (0x9e37_79b9_7f4a_7c15u64.wrapping_mul(ri as u64 + 1)));
        // Per method: stars, flagged, error^2, bound^2 (over its stars), pull^2.
        let mut acc = vec![(0usize, 0usize, 0.0f64, 0.0f64, 0.0f64); METHODS.len()];
        for k in 0..stars {
            let angle = rng.uniform() * std::f64::consts::PI;
            let (tx, ty) = (l * angle.cos(), l * angle.sin());
            let (w, h) = (side(tx, sigma), side(ty, sigma));
            let star = TrailedStar {
                x_px: (w / 2) as f64 + rng.uniform() - 0.5,
                y_px: (h / 2) as f64 + rng.uniform() - 0.5,
                flux_e: FLUX_E,
                trail_dx_px: tx,
                trail_dy_px: ty,
                psf_sigma_px: sigma,
            };
            let mean = mean_window(w, h, &star, BACKGROUND_E);
            let px = noisy_window(&mean, READ_NOISE_E, seed + ri as u64, k as u64);
            let b = crlb(w, h, &star, BACKGROUND_E, READ_NOISE_E, true);
            let bound2 = b.sigma_x_px.powi(2) + b.sigma_y_px.powi(2);
            let e = electrons(&px);
            let rect = Rect {
                x0: 500,
                y0: 500,
                width: w as u16,
                height: h as u16,
            };
            let Some(window) = Window::new(rect, &e) else {
                continue;
            };
            let input = CentroidInput::new(window);
            for (m, a) in METHODS.iter().zip(acc.iter_mut()) {
                a.0 += 1;
                let Some(c) = measure(m, &input, &star) else {
                    a.1 += 1;
                    continue;
                };
                let ex = f64::from(c.x_px) - 500.0 - star.x_px;
                let ey = f64::from(c.y_px) - 500.0 - star.y_px;
                a.2 += ex * ex + ey * ey;
                a.3 += bound2;
                a.4 +=
                    (ex / f64::from(c.sigma_x_px)).powi(2) + (ey / f64::from(c.sigma_y_px)).powi(2);
            }
        }
        for (m, a) in METHODS.iter().zip(acc) {
            let used = (a.0 - a.1).max(1) as f64;
            out.push(TrailPoint {
                rate_deg_s: rate,
                trail_px: l,
                method: m,
                stars: a.0,
                flagged: a.1,
                rms_px: (a.2 / (2.0 * used)).sqrt(),
                bound_px: (a.3 / (2.0 * used)).sqrt(),
                pull: (a.4 / (2.0 * used)).sqrt(),
            });
        }
    }
    out
}

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "rate_deg_s,trail_px,method,stars,flagged,rms_px,bound_px,ratio,pull";

/// The points as CSV, after `comment` lines (each prefixed `# `); a method that flagged
/// every star has NaN figures.
pub fn csv(points: &[TrailPoint], comment: &[&str]) -> String {
    let mut out = crate::figures::csv::csv_head(comment, CSV_HEADER);
    for p in points {
        let nan = p.flagged == p.stars;
        let f = |v: f64| {
            if nan {
                "NaN".to_string()
            } else {
                format!("{v:.4}")
            }
        };
        out.push_str(&format!(
            "{},{:.1},{},{},{},{},{},{},{}\n",
            p.rate_deg_s,
            p.trail_px,
            p.method,
            p.stars,
            p.flagged,
            f(p.rms_px),
            f(p.bound_px),
            if nan {
                "NaN".into()
            } else {
                format!("{:.3}", p.ratio())
            },
            if nan {
                "NaN".into()
            } else {
                format!("{:.3}", p.pull)
            },
        ));
    }
    out
}

/// The chart's PNG: each method's RMS error (per axis, over the stars it does not flag)
/// against the rate, and the bound; log y.
pub fn plot(
    points: &[TrailPoint],
    out: &std::path::Path,
    name: &str,
) -> Result<crate::figures::Written, String> {
    use crate::figures::Written;
    use crate::figures::plot::{Chart, Series, lines};
    let mut series: Vec<Series> = METHODS
        .iter()
        .enumerate()
        .map(|(i, m)| {
            Series::solid(
                (*m).to_string(),
                points
                    .iter()
                    .filter(|p| p.method == *m && p.flagged < p.stars)
                    .map(|p| (p.rate_deg_s, p.rms_px))
                    .collect(),
                i,
            )
        })
        .collect();
    series.push(Series {
        dashed: true,
        ..Series::solid(
            "Cramer-Rao bound".into(),
            points
                .iter()
                .filter(|p| p.method == "trail-known")
                .map(|p| (p.rate_deg_s, p.bound_px))
                .collect(),
            7,
        )
    });
    let chart = Chart {
        title: "Trailed star: position error against body rate (100 ms)".into(),
        x_label: "body rate, deg/s".into(),
        y_label: "RMS error per axis, px".into(),
        log_x: false,
        log_y: true,
    };
    let mut written = Written::default();
    lines(out, name, &chart, &series, &mut written).map_err(|e| format!("{e:?}"))?;
    Ok(written)
}
