//! Stages of the centroid methods on a calibrated window, per star: the general path's
//! corrected CoG (`centroid_cog1c_7x7`: power 1, 7x7 box, perimeter median, then the
//! pixel-phase curve; the fused CoG replaces it in tracking) and each of [`METHOD_NAMES`] on
//! the 7x7 window and on its central 5x5, the box filling the window
//! (`centroid_<method>_<n>x<n>`). The windows come from [`crate::window`]'s
//! `calibrate_window`; with them the particle-hit test every measured star gets
//! (`particle_hit_7x7`). Cost: seventeen centroids and a hit test a window.

use crate::harness::{Bench, Out};
use crate::inputs::PSF_SIGMA_PX;
use core::fmt::Write;
use core::hint::black_box;
use startrack_core::calib::PixelFlags;
use startrack_core::centroid::cog::{CogParams, cog};
use startrack_core::centroid::gauss_fit::{
    GaussFitParams, WidthFitParams, WidthPrior, gauss_fit, gauss_fit_width, gauss_fit_width_prior,
};
use startrack_core::centroid::trail_fit::{TrailFitParams, trail_fit};
use startrack_core::centroid::{Background, CentroidInput};
use startrack_core::detect::{HitLimits, is_particle_hit};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::PixCorr;
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};

const METHODS: usize = 8;
/// The methods timed on both window sizes, as they appear in the stage names.
pub const METHOD_NAMES: [&str; METHODS] = [
    "cog1",
    "cog2",
    "cog1_given_bg",
    "gauss_fit",
    "gauss_fit_given_bg",
    "gauss_fit_width",
    "gauss_fit_width_model",
    "trail_fit",
];

/// Ticks summed over the windows: the corrected CoG, the particle-hit test, and every
/// method on 5x5 and 7x7.
pub struct CentroidTimes {
    cog1c: u64,
    hit: u64,
    methods: [[u64; METHODS]; 2],
}

impl CentroidTimes {
    pub const fn new() -> Self {
        Self {
            cog1c: 0,
            hit: 0,
            methods: [[0; METHODS]; 2],
        }
    }

    /// Times the methods on one calibrated 7x7 window (`we`, `wf` over `rect`) and on its
    /// central 5x5.
    pub fn add_window(
        &mut self,
        bench: &Bench,
        rect: Rect,
        we: &[Electrons; 49],
        wf: &[PixelFlags; 49],
        curve: &PixCorr<'_>,
    ) -> Result<(), &'static str> {
        let mut we5 = [Electrons::ZERO; 25];
        let mut wf5 = [PixelFlags::empty(); 25];
        for r in 0..5 {
            we5[5 * r..5 * r + 5].copy_from_slice(&we[7 * (r + 1) + 1..7 * (r + 1) + 6]);
            wf5[5 * r..5 * r + 5].copy_from_slice(&wf[7 * (r + 1) + 1..7 * (r + 1) + 6]);
        }
        let rect5 = Rect {
            x0: rect.x0 + 1,
            y0: rect.y0 + 1,
            width: 5,
            height: 5,
        };
        let w7 = Window::new(rect, we).ok_or("window 7")?;
        let w5 = Window::new(rect5, &we5).ok_or("window 5")?;
        let inputs = [
            CentroidInput::new(w5).with_pixel_flags(&wf5),
            CentroidInput::new(w7).with_pixel_flags(wf),
        ];
        // The general path's corrected CoG: power 1, 7x7 box, perimeter median, then the curve.
        let input7 = black_box(&inputs[1]);
        self.cog1c += bench.measure(|| {
            let c = curve.apply(cog(input7, &CogParams::new(CogPower::One, 7)));
            black_box(c.x_px + c.y_px);
        });
        // The particle-hit test every measured star gets (the flight limits: half the
        // configured PSF's 80 % radius).
        let limits = HitLimits::of_min_a(0.6);
        self.hit += bench.measure(|| {
            black_box(is_particle_hit(input7, black_box(&limits)));
        });
        for (input, acc) in inputs.iter().zip(self.methods.iter_mut()) {
            let side = input.window.rect.width as u8;
            for (m, slot) in acc.iter_mut().enumerate() {
                let input = black_box(input);
                *slot += bench.measure(|| {
                    black_box(run_method(m, side, input));
                });
            }
        }
        Ok(())
    }

    /// Prints `centroid_cog1c_7x7` and `particle_hit_7x7` over `reps` windows.
    pub fn print_corrected(&self, out: &mut Out, bench: &Bench, reps: u64) {
        bench.row(out, "centroid_cog1c_7x7", "star", self.cog1c, reps);
        bench.row(out, "particle_hit_7x7", "star", self.hit, reps);
    }

    /// Prints every method's row, 5x5 then 7x7, over `reps` windows.
    pub fn print_methods(
        &self,
        out: &mut Out,
        bench: &Bench,
        reps: u64,
    ) -> Result<(), &'static str> {
        for (side, acc) in [5u8, 7].iter().zip(self.methods.iter()) {
            for (m, t) in acc.iter().enumerate() {
                let mut name = Out::new();
                let _ = write!(name, "centroid_{}_{side}x{side}", METHOD_NAMES[m]);
                bench.row(out, name.as_str()?, "star", *t, reps);
            }
        }
        Ok(())
    }
}

/// Runs centroid method `m` (an index into [`METHOD_NAMES`]) over the whole window
/// (box = window side).
#[inline(never)]
fn run_method(m: usize, side: u8, input: &CentroidInput<'_>) -> f32 {
    // The detector's background estimate, as `startrack accuracy` and the trade-off chart
    // give it to the `_given_bg` stages.
    let given = Background::Given {
        level_e: 10.0,
        variance_e2: 40.0,
    };
    let c = match m {
        0 => cog(input, &CogParams::new(CogPower::One, side)),
        1 => cog(input, &CogParams::new(CogPower::Two, side)),
        2 => cog(
            input,
            &CogParams {
                background: given,
                ..CogParams::new(CogPower::One, side)
            },
        ),
        3 => gauss_fit(input, &GaussFitParams::new(PSF_SIGMA_PX)),
        // The width-free fit, background given and held like the stage before, start
        // box the window's side capped at 5: the near-CRLB method when the width is unknown.
        5 => {
            gauss_fit_width(
                input,
                &WidthFitParams {
                    background: given,
                    start_box: side.min(5),
                    ..WidthFitParams::new()
                },
            )
            .centroid
        }
        // The same with a field PSF model's width as a prior that agrees with the star (the
        // synthetic star is point-sampled: its pixel-integrated width is sqrt(s^2 - 1/12);
        // scatter 0.1 px): the flight method when the table holds a model.
        6 => {
            gauss_fit_width_prior(
                input,
                &WidthFitParams {
                    background: given,
                    start_box: side.min(5),
                    ..WidthFitParams::new()
                },
                &WidthPrior {
                    a_px: 1.719_6 * PSF_SIGMA_PX,
                    scatter_px: 0.1,
                },
            )
            .centroid
        }
        // The trailed-star fit, background given and held, a trail of (1.0, 0.5) px held (the
        // bench's star is not trailed: the cost per pixel and step does not depend on it).
        7 => {
            trail_fit(
                input,
                &TrailFitParams {
                    fit_background: false,
                    background: given,
                    ..TrailFitParams::new(PSF_SIGMA_PX, 1.0, 0.5)
                },
            )
            .centroid
        }
        // The near-CRLB method as `startrack accuracy` runs it: background given and held
        // (not fitted), start box the window's side capped at 5.
        _ => gauss_fit(
            input,
            &GaussFitParams {
                fit_background: false,
                background: given,
                start_box: side.min(5),
                ..GaussFitParams::new(PSF_SIGMA_PX)
            },
        ),
    };
    c.x_px + c.y_px
}
