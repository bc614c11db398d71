//! One star's measurement, the same in both modes: a window of raw samples and their row
//! levels is calibrated, and the configured centroid method ([`Policy`]) measures it.
//!
//! - [`Policy`]: the method, box and PSF width of a mode, with the pixel-phase curve the
//!   table holds for them, chosen once per frame by one rule ([`select_curve`]): the curve
//!   of the CoG's power and box and of the method's background whose width is nearest the
//!   configured `psf_a_px`, used only within `pixcorr_tolerance` of it; otherwise the CoG
//!   is reported uncorrected and flagged.
//! - [`Scratch`]: one window's buffers (raw, levels, electrons, flags, and the centroid
//!   sub-window of a tracking window), ~2.8 KB.
//!
//! Cost per star: the window's calibration (~95 M7 instructions a pixel, `cargo m7-bench`
//! stage `window_calibrate`), then the method (the width-free Gauss fit 7x7 ~13,700, with
//! the table's field PSF model as a prior ~10,000 plus the model's polynomial, ~40;
//! the Gauss fit of a given width ~7,000, the CoG a few hundred plus ~140 for the curve).

use super::config::{CentroidMethod, TrackerConfig};
use super::record::{StarFlags, StarRecord};
use crate::calib::{FrameCalibration, LineLevels, PixelFlags};
use crate::centroid::cog::{CogParams, cog, sigma_unreliable as cog_sigma_unreliable};
use crate::centroid::gauss_fit::{CHI2_FLAG_Z, chi2_dof_limit_border};
use crate::centroid::gauss_fit::{
    GaussFitParams, PsfFit, WidthFitParams, WidthPrior, gauss_fit, gauss_fit_width,
    gauss_fit_width_prior,
};
use crate::centroid::trail_fit::{FreeTrailParams, TrailFitParams, trail_fit, trail_fit_free};
use crate::centroid::{Background, Centroid, CentroidInput, estimate_background};
use crate::detect::capture::{CAPTURE_MAX_PX, CAPTURE_MAX_SIDE};
use crate::detect::{HitLimits, is_particle_hit};
use crate::table::pixcorr::CogPower;
use crate::table::pixcorr::{PixCorr, PixCorrBackground};
use crate::table::{CalibTable, PsfModel};
use crate::units::{BiasAdu, Electrons};
use crate::window::{Rect, Window};

/// A trailed star's fitted trail must end at least this far inside its window's border
/// pixel centres, px (else it is flagged [`StarFlags::TRAIL_UNKNOWN`]): 1.5 px, about two
/// PSF sigmas of the flight's `a = 1.2 px`, so a 15 px window holds an 11 px trail.
pub const TRAIL_END_MARGIN_PX: f32 = 1.5;

/// `sigma / a` of a Gaussian PSF (`sqrt(0.31)`).
const SIGMA_PER_A: f32 = 0.556_776_4;

/// Largest centroid window, px (the configuration's limit).
pub(crate) const MAX_WINDOW_PX: usize = 13;

/// A star's background as last measured (the border median of its centroid window): what
/// the fused CoG takes as given in the next tracking frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct StarBackground {
    /// Level, e- per pixel.
    pub(crate) level_e: f32,
    /// Per-pixel variance, e-^2.
    pub(crate) variance_e2: f32,
}

/// The pixel-phase curve `config` uses for a CoG of `power` in a `box_px` box with
/// `background`: of the table's curves for that power, box and background, the one whose
/// width is nearest `config.psf_a_px`, if within `config.pixcorr_tolerance` of it.
pub fn select_curve<'t>(
    table: &CalibTable<'t>,
    config: &TrackerConfig,
    power: CogPower,
    box_px: u8,
    background: PixCorrBackground,
) -> Option<PixCorr<'t>> {
    let a = config.psf_a_px;
    table
        .pixcorr()
        .find(power, box_px, background, a)
        .filter(|c| {
            let ca = c.header().a_px.to_num::<f32>();
            (ca - a).abs() <= config.pixcorr_tolerance * a
        })
}

/// How one mode measures a star, fixed for a frame.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Policy<'t> {
    pub(crate) method: CentroidMethod,
    pub(crate) box_px: u8,
    pub(crate) sigma_px: f32,
    /// The configured PSF 80 % radius, px (where a CoG's sigma holds).
    pub(crate) psf_a_px: f32,
    /// The curve of the general path (perimeter-median CoG).
    pub(crate) curve: Option<PixCorr<'t>>,
    /// The curve of the fused CoG (given background).
    pub(crate) fused_curve: Option<PixCorr<'t>>,
    /// The table's CTI correction (section 8), applied to every centroid [`Self::record`]
    /// makes.
    pub(crate) cti: Option<crate::calib::cti::CtiCorrection>,
    /// The table's field PSF model (section 9) and the active area it is normalised to
    /// (columns, rows): the width-free fit takes its width at each star as a prior.
    pub(crate) psf_model: Option<(PsfModel, u16, u16)>,
    /// The particle-hit test's limits: the narrowest star the optics make,
    /// [`HIT_WIDTH_FRACTION`] of the configured PSF.
    pub(crate) hit_limits: HitLimits,
    /// The radiation monitor's: [`HIT_MONITOR_FRACTION`] of the configured PSF.
    pub(crate) monitor_limits: HitLimits,
}

/// The narrowest star image the optics make, as a fraction of the configured PSF's 80 %
/// radius `psf_a_px`: an image sharper than one of this width is a particle hit
/// ([`crate::detect::is_particle_hit`]), flagged `POOR_FIT`. 0.4: the field's PSF varies, and the host tests'
/// fields hold real stars of half the configured width (the accuracy Monte Carlo's 0.6 px
/// about a configured 1.2; the tracker tests' 0.8 about 1.4), none of which may be taken
/// for a hit; a proton's charge spreads over ~0.3 px, so a hit that crossed the silicon
/// near the normal is often as wide as the limit and is left to the fit's chi-square and
/// the lists' ranking. The fit's own width is no hit test: on stars of 0.6 px
/// (under-sampled) the width-free fit reports widths below 0.48 px at SNR 20 and more (13 of
/// the accuracy Monte Carlo's 860 isolated stars were rejected so).
pub const HIT_WIDTH_FRACTION: f32 = 0.4;

/// A window sharper than a star of this fraction of the configured PSF's width could make
/// is counted as a particle hit (the radiation monitor, `hits`) whether or not it is
/// flagged: half, a PSF no star tracker's optics make; a field with real stars that narrow
/// (the accuracy Monte Carlo's) counts some of them.
pub const HIT_MONITOR_FRACTION: f32 = 0.5;

impl<'t> Policy<'t> {
    /// The policy of `method` under `config` with `table`'s curves.
    pub(crate) fn new(
        method: CentroidMethod,
        config: &TrackerConfig,
        table: &CalibTable<'t>,
    ) -> Self {
        let box_px = config.box_px();
        let curve = method.cog_power().and_then(|p| {
            select_curve(table, config, p, box_px, PixCorrBackground::PerimeterMedian)
        });
        let fused_curve = (method == CentroidMethod::FusedCog1)
            .then(|| {
                select_curve(
                    table,
                    config,
                    CogPower::One,
                    box_px,
                    PixCorrBackground::Given,
                )
            })
            .flatten();
        Self {
            method,
            box_px,
            sigma_px: config.psf_sigma_px(),
            psf_a_px: config.psf_a_px,
            curve,
            fused_curve,
            cti: crate::calib::cti::CtiCorrection::from_table(table, config.psf_sigma_px()),
            psf_model: table.psf_model().map(|m| {
                let g = table.geometry();
                (m, g.active_cols, g.active_rows)
            }),
            hit_limits: HitLimits::of_min_a(HIT_WIDTH_FRACTION * config.psf_a_px),
            monitor_limits: HitLimits::of_min_a(HIT_MONITOR_FRACTION * config.psf_a_px),
        }
    }

    /// True for a CoG method (whose position needs the pixel-phase correction).
    fn is_cog(&self) -> bool {
        self.method.cog_power().is_some()
    }

    /// The star's record from `input` by the method (the fused CoG's general path is the
    /// CoG), a CoG corrected with the curve (flagged [`StarFlags::UNCORRECTED`] without
    /// one), the width fit with the field PSF model's width at the window's centre as a
    /// prior when the table has a model ([`StarFlags::PSF_MISMATCH`] and the width-free
    /// result when the star disagrees with it), `flags` added.
    pub(crate) fn record(&self, input: &CentroidInput<'_>, flags: StarFlags) -> StarRecord {
        if self.method == CentroidMethod::GaussFitWidth {
            let params = WidthFitParams {
                start_box: self.box_px,
                background: Background::PerimeterMedian,
                ..WidthFitParams::new()
            };
            let f = match self.psf_model {
                Some((m, cols, rows)) => {
                    let r = input.window.rect;
                    let at = |p0: u16, n: u16| f32::from(p0) + 0.5 * f32::from(n.saturating_sub(1));
                    let prior = WidthPrior {
                        a_px: m.a_px(at(r.x0, r.width), at(r.y0, r.height), cols, rows),
                        scatter_px: m.scatter_px.to_num::<f32>(),
                    };
                    gauss_fit_width_prior(input, &params, &prior)
                }
                None => gauss_fit_width(input, &params),
            };
            let f = PsfFit {
                centroid: self.cti.map_or(f.centroid, |k| k.corrected(f.centroid)),
                ..f
            };
            return StarRecord::from_psf_fit(&f, flags);
        }
        let (c, uncorrected) = self.centroid(input);
        let c = self.cti.map_or(c, |k| k.corrected(c));
        StarRecord::from_centroid(&c, flags | uncorrected)
    }

    /// The star's record from the trailed-star fit of `input` (the trail `trail_px`, px
    /// from exposure start to end; the PSF at rest of the configured width; residual
    /// background fitted over the border median), CTI-corrected, `flags` and the window's
    /// pixel flags added, with the covariance of its column and row errors. Its `psf_a_px`
    /// and `chi2_dof` are 0 (not fitted).
    pub(crate) fn trailed_record(
        &self,
        input: &CentroidInput<'_>,
        flags: StarFlags,
        trail_px: (f32, f32),
    ) -> StarRecord {
        let pixel_flags = input
            .pixel_flags
            .iter()
            .fold(PixelFlags::empty(), |m, f| m | *f);
        let f = trail_fit(
            input,
            &TrailFitParams::new(self.sigma_px, trail_px.0, trail_px.1),
        );
        let c = self.cti.map_or(f.centroid, |k| k.corrected(f.centroid));
        StarRecord {
            cov_xy_px2: f.cov_xy_px2,
            ..StarRecord::from_centroid(&c, flags | StarFlags::from_pixels(pixel_flags))
        }
    }

    /// The star's record from the trailed-star fit with the trail unknown
    /// ([`trail_fit_free`]: length, angle and width fitted, started from `start_trail_px`)
    /// when the test calls the star trailed, its position at mid-exposure
    /// ([`Provenance::TRAILED`](super::Provenance::TRAILED)), CTI-corrected, `flags` and the
    /// window's pixel flags added; [`StarFlags::POOR_FIT`] when the trailed model does not
    /// describe the window either, [`StarFlags::TRAIL_UNKNOWN`] when the fitted trail comes
    /// within [`TRAIL_END_MARGIN_PX`] of the window's edge (a trail the window may cut).
    /// Detection's [`StarFlags::DETECT_BLENDED`] is taken off a trail the model describes:
    /// the blob's elongation was the trail. `None` when the star is not trailed (or the
    /// fit failed).
    pub(crate) fn free_trailed_record(
        &self,
        input: &CentroidInput<'_>,
        flags: StarFlags,
        start_trail_px: (f32, f32),
    ) -> Option<StarRecord> {
        let f = trail_fit_free(input, &FreeTrailParams::new(self.sigma_px, start_trail_px));
        if !f.is_trailed() {
            return None;
        }
        let pixel_flags = input
            .pixel_flags
            .iter()
            .fold(PixelFlags::empty(), |m, f| m | *f);
        let c = self.cti.map_or(f.centroid, |k| k.corrected(f.centroid));
        let mut flags = flags | StarFlags::from_pixels(pixel_flags);
        let poor = f.chi2_dof() > chi2_dof_limit_border(f.dof, f.border, CHI2_FLAG_Z);
        if poor {
            flags |= StarFlags::POOR_FIT;
        } else {
            flags -= StarFlags::DETECT_BLENDED;
        }
        // The trail's ends, window-relative: inside the margin, or the window may cut it.
        let r = input.window.rect;
        let (cx, cy) = (
            f.centroid.x_px - f32::from(r.x0),
            f.centroid.y_px - f32::from(r.y0),
        );
        let (hx, hy) = (0.5 * f.trail_px.0.abs(), 0.5 * f.trail_px.1.abs());
        let m = TRAIL_END_MARGIN_PX;
        let inside = |c: f32, h: f32, n: u16| c - h >= m && c + h <= f32::from(n) - 1.0 - m;
        if !(inside(cx, hx, r.width) && inside(cy, hy, r.height)) {
            flags |= StarFlags::TRAIL_UNKNOWN;
        }
        let mut record = StarRecord::from_centroid(&c, flags);
        record.cov_xy_px2 = f.cov_xy_px2;
        record.provenance = super::Provenance::TRAILED;
        record.psf_a_px = f.psf_sigma_px / SIGMA_PER_A;
        record.chi2_dof = f.chi2_dof();
        Some(record)
    }

    /// The centroid of `input` by a method of a given width (the fused CoG's general path
    /// is the CoG), corrected with the curve; the flag says when a CoG had none.
    pub(crate) fn centroid(&self, input: &CentroidInput<'_>) -> (Centroid, StarFlags) {
        let c = match self.method {
            CentroidMethod::GaussFit | CentroidMethod::GaussFitWidth => gauss_fit(
                input,
                &GaussFitParams {
                    start_box: self.box_px,
                    fit_background: false,
                    background: Background::PerimeterMedian,
                    ..GaussFitParams::new(self.sigma_px)
                },
            ),
            CentroidMethod::Cog2 => cog(input, &CogParams::new(CogPower::Two, self.box_px)),
            CentroidMethod::Cog1 | CentroidMethod::FusedCog1 => {
                cog(input, &CogParams::new(CogPower::One, self.box_px))
            }
        };
        let unreliable = |corrected: bool, c: &Centroid| {
            let power = self.method.cog_power().unwrap_or(CogPower::One);
            if cog_sigma_unreliable(power, self.box_px, self.psf_a_px, corrected, c.snr) {
                StarFlags::SIGMA_UNRELIABLE
            } else {
                StarFlags::empty()
            }
        };
        match (self.curve, self.is_cog()) {
            (Some(k), true) => {
                let c = k.apply(c);
                (c, unreliable(true, &c))
            }
            (None, true) => (c, StarFlags::UNCORRECTED | unreliable(false, &c)),
            _ => (c, StarFlags::empty()),
        }
    }
}

/// One window's buffers.
pub(crate) struct Scratch {
    raw: [u16; CAPTURE_MAX_PX],
    levels: [LineLevels; CAPTURE_MAX_SIDE as usize],
    electrons: [Electrons; CAPTURE_MAX_PX],
    flags: [PixelFlags; CAPTURE_MAX_PX],
    sub_e: [Electrons; MAX_WINDOW_PX * MAX_WINDOW_PX],
    sub_f: [PixelFlags; MAX_WINDOW_PX * MAX_WINDOW_PX],
}

/// Why a window gave no centroid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum MeasureError {
    /// The window does not fit the buffers, or its calibration failed.
    Calibration,
}

/// A calibrated window and the measurement made of it.
pub(crate) struct Measured {
    pub(crate) record: StarRecord,
    pub(crate) background: Option<StarBackground>,
    /// The window is sharper than any star ([`HIT_WIDTH_FRACTION`]): a particle hit, or a star
    /// beside a hot pixel the table does not list; flagged `POOR_FIT` where it is kept.
    pub(crate) hit: bool,
    /// The window is sharper than the radiation monitor's limit: counted as a hit.
    pub(crate) hit_like: bool,
}

impl Scratch {
    pub(crate) const fn new() -> Self {
        Self {
            raw: [0; CAPTURE_MAX_PX],
            levels: [LineLevels {
                bias_adu: [BiasAdu::ZERO; crate::geometry::MAX_OUTPUTS],
            }; CAPTURE_MAX_SIDE as usize],
            electrons: [Electrons::ZERO; CAPTURE_MAX_PX],
            flags: [PixelFlags::empty(); CAPTURE_MAX_PX],
            sub_e: [Electrons::ZERO; MAX_WINDOW_PX * MAX_WINDOW_PX],
            sub_f: [PixelFlags::empty(); MAX_WINDOW_PX * MAX_WINDOW_PX],
        }
    }

    /// The raw and level buffers for a window of `rect`, to be filled by the caller.
    pub(crate) fn inputs(&mut self, rect: Rect) -> Option<(&mut [u16], &mut [LineLevels])> {
        Some((
            self.raw.get_mut(..rect.len())?,
            self.levels.get_mut(..usize::from(rect.height))?,
        ))
    }

    /// Calibrates the window held in the raw and level buffers.
    pub(crate) fn calibrate(
        &mut self,
        cal: &FrameCalibration<'_>,
        rect: Rect,
    ) -> Result<(), MeasureError> {
        let n = rect.len();
        let (Some(raw), Some(levels), Some(e), Some(f)) = (
            self.raw.get(..n),
            self.levels.get(..usize::from(rect.height)),
            self.electrons.get_mut(..n),
            self.flags.get_mut(..n),
        ) else {
            return Err(MeasureError::Calibration);
        };
        cal.calibrate_window(rect, raw, levels, e, f)
            .map(|_| ())
            .map_err(|_| MeasureError::Calibration)
    }

    /// The calibrated pixels and flags of `rect`, to be amended in place (the in-flight
    /// defect overlay).
    pub(crate) fn calibrated_mut(
        &mut self,
        rect: Rect,
    ) -> Option<(&mut [Electrons], &mut [PixelFlags])> {
        let n = rect.len();
        Some((self.electrons.get_mut(..n)?, self.flags.get_mut(..n)?))
    }

    /// The calibrated window of `rect` as a centroid input.
    pub(crate) fn window(&self, rect: Rect, clipped: bool) -> Option<CentroidInput<'_>> {
        let n = rect.len();
        Some(
            CentroidInput::new(Window::new(rect, self.electrons.get(..n)?)?)
                .with_pixel_flags(self.flags.get(..n)?)
                .with_clipped(clipped),
        )
    }

    /// Copies the part `sub` of the calibrated window `rect` into the sub-window buffers
    /// and gives it as a centroid input.
    pub(crate) fn sub_window(
        &mut self,
        rect: Rect,
        sub: Rect,
        clipped: bool,
    ) -> Option<CentroidInput<'_>> {
        let (w, sw) = (usize::from(rect.width), usize::from(sub.width));
        let dx = usize::from(sub.x0.checked_sub(rect.x0)?);
        let dy = usize::from(sub.y0.checked_sub(rect.y0)?);
        if dx + sw > w || dy + usize::from(sub.height) > usize::from(rect.height) {
            return None;
        }
        let n = sub.len();
        let (dst_e, dst_f) = (self.sub_e.get_mut(..n)?, self.sub_f.get_mut(..n)?);
        for (r, (de, df)) in dst_e
            .chunks_exact_mut(sw.max(1))
            .zip(dst_f.chunks_exact_mut(sw.max(1)))
            .enumerate()
        {
            let start = (dy + r) * w + dx;
            de.copy_from_slice(self.electrons.get(start..start + sw)?);
            df.copy_from_slice(self.flags.get(start..start + sw)?);
        }
        Some(
            CentroidInput::new(Window::new(sub, self.sub_e.get(..n)?)?)
                .with_pixel_flags(self.sub_f.get(..n)?)
                .with_clipped(clipped),
        )
    }
}

/// Measures a calibrated centroid window: the policy's centroid with `flags` added, and
/// (when `want_background`) the border median it used, for the fused CoG of the next frame.
pub(crate) fn measure(
    policy: &Policy<'_>,
    input: &CentroidInput<'_>,
    flags: StarFlags,
    want_background: bool,
) -> Measured {
    let pixel_flags = input
        .pixel_flags
        .iter()
        .fold(PixelFlags::empty(), |m, f| m | *f);
    let background = want_background
        .then(|| estimate_background(input, Background::PerimeterMedian))
        .flatten()
        .map(|b| StarBackground {
            level_e: b.level_e(),
            variance_e2: b.variance_e2,
        });
    let (hit_like, hit) = hit_test(policy, input);
    Measured {
        record: policy.record(input, flags | StarFlags::from_pixels(pixel_flags)),
        background,
        hit,
        hit_like,
    }
}

/// The particle-hit test of a calibrated window: whether the radiation monitor counts it
/// (`.0`) and whether it is sharper than any star (`.1`). The second's limit is the
/// stricter: tested only on a window the monitor counts.
pub(crate) fn hit_test(policy: &Policy<'_>, input: &CentroidInput<'_>) -> (bool, bool) {
    let hit_like = is_particle_hit(input, &policy.monitor_limits);
    (
        hit_like,
        hit_like && is_particle_hit(input, &policy.hit_limits),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use fixed::types::{I16F16, U8F8};

    /// A noise-free star of 80 %-energy radius `a_px` and 20,000 e- on 100 e-/px, centred
    /// at active pixel (100.3, 200.2) in the 7x7 window around (100, 200).
    fn star(a_px: f32) -> [Electrons; 49] {
        let s = a_px * 0.556_776_4;
        let mut e = [Electrons::ZERO; 49];
        for (k, v) in e.iter_mut().enumerate() {
            let (c, r) = ((k % 7) as f32, (k / 7) as f32);
            let f = crate::centroid::math::pixel_fraction(c, 3.3, s)
                * crate::centroid::math::pixel_fraction(r, 3.2, s);
            *v = Electrons::from_num(100.0 + 20_000.0 * f);
        }
        e
    }

    fn policy(model_a_px: Option<f32>) -> Policy<'static> {
        let psf_model = model_a_px.map(|a| {
            let mut coeffs = [I16F16::ZERO; crate::table::psfmodel::MAX_PSF_TERMS];
            if let Some(c) = coeffs.first_mut() {
                *c = I16F16::from_num(a);
            }
            let m = PsfModel {
                degree: 0,
                scatter_px: U8F8::from_num(0.02),
                stars: 100,
                coeffs,
            };
            (m, 1024, 1024)
        });
        Policy {
            method: CentroidMethod::GaussFitWidth,
            box_px: 5,
            sigma_px: 0.67,
            psf_a_px: 1.2,
            curve: None,
            fused_curve: None,
            cti: None,
            psf_model,
            hit_limits: HitLimits::of_min_a(0.48),
            monitor_limits: HitLimits::of_min_a(0.6),
        }
    }

    fn record(model_a_px: Option<f32>, e: &[Electrons]) -> Option<StarRecord> {
        let rect = Rect {
            x0: 97,
            y0: 197,
            width: 7,
            height: 7,
        };
        let input = CentroidInput::new(Window::new(rect, e)?);
        Some(policy(model_a_px).record(&input, StarFlags::empty()))
    }

    #[test]
    fn the_field_model_holds_the_width_and_flags_a_star_it_does_not_describe() {
        let e = star(1.5);
        let (free, agrees, wrong) = (
            record(None, &e),
            record(Some(1.5), &e),
            record(Some(1.0), &e),
        );
        assert!(free.is_some() && agrees.is_some() && wrong.is_some());
        let (Some(free), Some(agrees), Some(wrong)) = (free, agrees, wrong) else {
            return;
        };
        // The model agrees: the width stays at it, no flag, the position the free fit's.
        assert!(!agrees.flags.contains(StarFlags::PSF_MISMATCH));
        assert!((agrees.psf_a_px - 1.5).abs() < 0.01, "{}", agrees.psf_a_px);
        assert!((agrees.x_px - 100.3).abs() < 1e-3 && (agrees.y_px - 200.2).abs() < 1e-3);
        // A model of a = 1 px for an a = 1.5 px star: flagged, the width-free result.
        assert!(wrong.flags.contains(StarFlags::PSF_MISMATCH));
        assert_eq!(wrong.x_px, free.x_px);
        assert_eq!(wrong.psf_a_px, free.psf_a_px);
        assert!(!free.flags.contains(StarFlags::PSF_MISMATCH));
    }
}
