//! The width fit's Gauss-Newton driver: from the start through the steps, the wings' refit
//! and the error estimate to the reported [`PsfFit`], free or with a prior on the width
//! (and the prior's mismatch test). Cost: the steps' normal equations (`normal.rs`) and the
//! border passes (`border.rs`); the driver's own arithmetic is a few dozen flops a step.

use super::border::{border_residuals, border_walk, clipped_variance, wings_on_border};
use super::limits::{chi2_dof_limit_border, sigma_unreliable};
use super::normal::{Ldl4, Profiles, normal};
use super::params::{
    M, MAX_WIDTH_FIT_SIDE, MIN_SIGMA_PX, MIN_START_SIGMA_PX, Prior, PsfFit, S_TOLERANCE_FACTOR,
    SQRT_031, WidthFitParams,
};
use super::start::{Start, start};
use crate::centroid::Background;
use crate::centroid::CentroidFlags;
use crate::centroid::cog::cog_in_box;
use crate::centroid::gauss_fit::step_usable;
use crate::centroid::math;
use crate::centroid::prepared::{Measured, Prepared};
use crate::clamp::clamp;
use crate::table::pixcorr::CogPower;

/// The width fit of a prepared window (see the module docs), free or with a prior.
pub(super) fn fit<const CLEAN: bool>(
    p: &Prepared<'_>,
    params: &WidthFitParams,
    prior: Option<Prior>,
) -> PsfFit {
    fit_z::<CLEAN>(p, params, prior).0
}

/// [`fit`] and, with a prior, the mismatch statistic `|z|` of the star's own width against
/// the model's (0 without a prior or a converged fit).
pub(super) fn fit_z<const CLEAN: bool>(
    p: &Prepared<'_>,
    params: &WidthFitParams,
    prior: Option<Prior>,
) -> (PsfFit, f32) {
    let give_up = |peak: Option<(u16, u16)>, extra: CentroidFlags| {
        let c = peak.and_then(|(pc, pr)| {
            let (bx, _) = p.box_around(pc, pr, params.start_box);
            cog_in_box(p, bx, (pc, pr), CogPower::One)
        });
        let f = PsfFit::unfitted(match c {
            Some(m) => p.finish(m, extra | CentroidFlags::NOT_CONVERGED),
            None => p.degenerate(extra),
        });
        (f, 0.0)
    };
    let Some(Start {
        peak,
        theta: (x0, y0, flux0, s0),
        clipped,
    }) = start::<CLEAN>(p, p.bg.level_e(), params.start_box)
    else {
        return give_up(p.peak(), CentroidFlags::empty());
    };
    let mut extra = if clipped {
        CentroidFlags::EDGE_CLIPPED
    } else {
        CentroidFlags::empty()
    };
    if p.width > MAX_WIDTH_FIT_SIDE || p.height > MAX_WIDTH_FIT_SIDE {
        return give_up(Some(peak), extra);
    }
    let max_s = 0.5 * f32::from(p.width.max(p.height));
    let mut prof = [[0.0f32; M]; 6];
    // The border's median is robust; its MAD's variance is noisy: the variance from the
    // border's clipped sample variance instead.
    // `border`: the pixels the variance came from (0: given), for the chi2's limit.
    let (bg, mut border) = match params.background {
        Background::PerimeterMedian => clipped_variance::<CLEAN>(p, &prof, 0.0, p.bg),
        Background::PerimeterMean => {
            let mut k = 0u16;
            border_walk::<CLEAN>(p, &prof, 0.0, |_| k += 1);
            (p.bg, k)
        }
        Background::Given { .. } => (p.bg, 0),
    };
    let (mut level_e, mut var1) = (bg.level_e(), bg.variance_e2 + 1.0);
    // With a prior the model's width starts the fit (and the moments' only the free one).
    let s_start = match prior {
        Some(pr) => clamp(pr.s_model, MIN_SIGMA_PX, max_s),
        None => clamp(s0, MIN_START_SIGMA_PX, max_s),
    };
    let it = Iteration {
        params,
        prior,
        max_s,
    };
    let Some(mut sol) = it.run::<CLEAN>(p, (level_e, var1), (x0, y0, flux0, s_start), &mut prof)
    else {
        return give_up(Some(peak), extra);
    };
    // The border (the background's source when not given) holds the star's wings: its
    // median was biased high and its spread taken for noise. Once, the background from the
    // border's residuals to the fitted star, and the fit again from where it stopped.
    if sol.converged
        && !matches!(params.background, Background::Given { .. })
        && wings_on_border(p, &prof, sol.theta.2) > WINGS_REFIT * math::sqrt(var1)
        && let Some((bg, k)) = border_residuals::<CLEAN>(p, &prof, sol.theta.2)
    {
        (level_e, var1, border) = (bg.level_e(), bg.variance_e2 + 1.0, k);
        let one = Iteration {
            params: &WidthFitParams {
                max_iterations: 1,
                ..*params
            },
            ..it
        };
        let Some(again) = one.run::<CLEAN>(p, (level_e, var1), sol.theta, &mut prof) else {
            return give_up(Some(peak), extra);
        };
        // One Gauss-Newton step from the solution (the new background moves it little):
        // the covariance from the step's start.
        let Solved {
            theta,
            last,
            prev,
            pinned,
            ..
        } = again;
        sol = Solved {
            theta,
            converged: true,
            last: last.or(prev),
            prev: None,
            pinned,
        };
    }
    let Solved {
        theta,
        converged,
        mut last,
        mut pinned,
        ..
    } = sol;
    if !converged {
        extra |= CentroidFlags::NOT_CONVERGED;
    }
    if last.is_none() {
        let mut nrm = normal::<CLEAN>(p, level_e, var1, theta, &mut prof);
        if let Some(pr) = prior {
            nrm.add_prior(pr, theta.3);
        }
        pinned = theta.3 <= MIN_SIGMA_PX && nrm.b[3] <= 0.0;
        if pinned {
            nrm.pin_width();
        }
        last = Ldl4::new(nrm.a).map(|f| (f, nrm.chi2, nrm.n));
    }
    let Some((f, chi2, n)) = last else {
        return give_up(Some(peak), extra);
    };
    let [vx, vy, vn, vs] = f.inverse_diagonal();
    let dof = n.saturating_sub(4);
    let chi2_dof = if dof > 0 { chi2 / f32::from(dof) } else { 0.0 };
    if chi2_dof > chi2_dof_limit_border(dof, border, params.chi2_flag_z) || !chi2_dof.is_finite() {
        extra |= CentroidFlags::POOR_FIT;
    }
    let (x, y, flux, s) = theta;
    let snr = flux / math::sqrt(vn).max(f32::MIN_POSITIVE);
    if sigma_unreliable(s, math::sqrt(vs), snr, prior.is_some()) {
        extra |= CentroidFlags::SIGMA_UNRELIABLE;
    }
    let m = Measured {
        col: x,
        row: y,
        flux_e: flux,
        snr,
        sigma_col: math::sqrt(vx),
        sigma_row: math::sqrt(vy),
    };
    let finite = |v: f32| if v.is_finite() { v } else { 0.0 };
    let z = match prior {
        Some(pr) if converged => mismatch_z(pr, s, vs, pinned),
        _ => 0.0,
    };
    let f = PsfFit {
        centroid: p.finish(m, extra),
        psf_a_px: finite(s / SQRT_031),
        sigma_psf_a_px: finite(math::sqrt(vs) / SQRT_031),
        chi2_dof: finite(chi2_dof),
    };
    (f, finite(z))
}

/// The border's brightest pixel's share of the fitted star over the background's noise
/// above which the background is estimated again from the border's residuals (0.5: a wing
/// of half the noise moves the border's median and widens its MAD by a few per cent).
const WINGS_REFIT: f32 = 0.5;

/// The Gauss-Newton iteration's fixed inputs.
struct Iteration<'a> {
    params: &'a WidthFitParams,
    prior: Option<Prior>,
    max_s: f32,
}

/// Where [`Iteration::run`] stopped: the parameters, whether it converged, the last
/// factor with its `chi2` and usable pixels (when converged) and whether `s` was pinned.
struct Solved {
    theta: (f32, f32, f32, f32),
    converged: bool,
    last: Option<(Ldl4, f32, u16)>,
    /// The last step's factor, converged or not.
    prev: Option<(Ldl4, f32, u16)>,
    pinned: bool,
}

impl Iteration<'_> {
    /// Gauss-Newton steps from `theta` with the background `(level_e, var1)` held; `None`
    /// when a step leaves the window or the matrix is not positive definite (give up). The
    /// profiles are left at the last step's start.
    fn run<const CLEAN: bool>(
        &self,
        p: &Prepared<'_>,
        (level_e, var1): (f32, f32),
        mut theta: (f32, f32, f32, f32),
        prof: &mut Profiles,
    ) -> Option<Solved> {
        let (wmax, hmax) = (f32::from(p.width) - 0.5, f32::from(p.height) - 0.5);
        let tol = self.params.tolerance_px;
        let mut pinned = false;
        let mut prev = None;
        for _ in 0..self.params.max_iterations {
            let mut nrm = normal::<CLEAN>(p, level_e, var1, theta, prof);
            if let Some(pr) = self.prior {
                nrm.add_prior(pr, theta.3);
            }
            // A star narrower than the floor: `s` held there while chi2 wants it lower.
            pinned = theta.3 <= MIN_SIGMA_PX && nrm.b[3] <= 0.0;
            if pinned {
                nrm.pin_width();
            }
            let f = Ldl4::new(nrm.a)?;
            let [dx, dy, dn, ds] = f.solve(nrm.b);
            let (sx, sy) = (dx.clamp(-1.0, 1.0), dy.clamp(-1.0, 1.0));
            let half = 0.5 * theta.3;
            let s_new = clamp(theta.3 + clamp(ds, -half, half), MIN_SIGMA_PX, self.max_s);
            let ss = s_new - theta.3;
            theta = (theta.0 + sx, theta.1 + sy, theta.2 + dn, s_new);
            let (x, y, flux, s) = theta;
            if !step_usable(x, y, flux, wmax, hmax) || !s.is_finite() {
                return None;
            }
            let done = if sx.abs() < tol && sy.abs() < tol && ss.abs() < S_TOLERANCE_FACTOR * tol {
                true
            } else if self.params.tolerance_sigmas > 0.0 {
                // Faint stars: Gauss-Newton converges only linearly (the noise's curvature
                // term it leaves out), so stop once every step is a small fraction of its own
                // error.
                let [vx, vy, _, vs] = f.inverse_diagonal();
                let t2 = self.params.tolerance_sigmas * self.params.tolerance_sigmas;
                sx * sx < t2 * vx && sy * sy < t2 * vy && ss * ss < t2 * vs
            } else {
                false
            };
            if done {
                return Some(Solved {
                    theta,
                    converged: true,
                    last: Some((f, nrm.chi2, nrm.n)),
                    prev: None,
                    pinned,
                });
            }
            // The chi2 the linearised model predicts after the full step (`chi2 - b . d`):
            // the one-step refit's goodness of fit at its end, not at its start.
            let [b0, b1, b2, b3] = nrm.b;
            let fall = b0 * dx + b1 * dy + b2 * dn + b3 * ds;
            prev = Some((f, (nrm.chi2 - fall).max(0.0), nrm.n));
        }
        Some(Solved {
            theta,
            converged: false,
            last: None,
            prev,
            pinned,
        })
    }
}

/// `|z|` of the star's own width against the model's, from the MAP fit: with `I` the
/// data's information on `s` (the last pivot of the normal matrix less the prior's) and
/// `I_p` the prior's, the width-free fit's `s` would differ from the model's by
/// `(s_map - s_model) (I + I_p) / I`, whose variance (fit and model) is `1 / I + 1 / I_p`:
/// `z^2 = (s_map - s_model)^2 I I_p / (I + I_p)`. A width held at the floor (`pinned`: the
/// data wants it narrower still) counts as fully determined (`I` infinite).
fn mismatch_z(pr: Prior, s: f32, vs: f32, pinned: bool) -> f32 {
    let d = s - pr.s_model;
    let data = if pinned {
        f32::INFINITY
    } else {
        1.0 / vs - pr.info
    };
    let z2 = if data.is_nan() || data <= 0.0 {
        0.0
    } else if data.is_infinite() {
        d * d * pr.info
    } else {
        d * d * data * pr.info / (data + pr.info)
    };
    math::sqrt(z2)
}
