//! Applying a plan to one frame's raw window: the staleness check, the fused sums (or the
//! general path for a box with a listed defect), one re-anchoring move when the CoG lands
//! more than half a pixel from its anchor, the output step and the pixel-phase curve; and
//! the one-shot [`raw_cog`], which builds the plan and applies it once.
//!
//! # Cost
//! `cargo m7-bench`, 7x7 box crossing 2x2 tiles, curve applied: an application
//! (`centroid_cog1c_raw_planned_7x7`) ~2,600 instructions, of which the fused sums ~2,000, the
//! curve ~280 and the rest (plan check, re-anchoring test, clamps) ~250; the one-shot
//! `raw_cog` (`centroid_cog1c_raw_7x7`) ~4,000. A re-anchoring move builds the moved box's
//! plan on the spot (one-shot cost); the general path calibrates the box and runs `cog`.

use super::plan::{BoxAt, MB2, PlanError, RawCogPlan, key_of};
use super::sums::{Meas, fused_cog};
use super::{RawCog, RawCogParams, RawWindow};
use crate::calib::{FrameCalibration, PixelFlags};
use crate::centroid::background::{level_to_bits, sanitize_var};
use crate::centroid::cog::{Anchor, CogParams, cog};
use crate::centroid::prepared::{Measured, finish_in};
use crate::centroid::{Background, Centroid, CentroidFlags, CentroidInput};
use crate::clamp::clamp;
use crate::table::pixcorr::CogPower;
use crate::units::Electrons;
use crate::window::{Rect, Window};

impl RawCogPlan {
    /// The corrected CoG of the plan's box in the raw window `win` (this frame's samples
    /// and line levels), as [`raw_cog`] gives it (bit for bit: `raw_cog` is `new` +
    /// `apply`). [`PlanError::Stale`] when `cal`, `win.rect` or `params.box_side` differ
    /// from the plan's; a window whose buffers do not match its rectangle gives a
    /// [`CentroidFlags::DEGENERATE`] centroid. A re-anchoring move builds the moved box's
    /// plan on the spot (one-shot cost).
    pub fn apply(
        &self,
        cal: &FrameCalibration<'_>,
        win: &RawWindow<'_>,
        params: &RawCogParams<'_>,
    ) -> Result<RawCog, PlanError> {
        let side = (params.box_side / 2).saturating_mul(2).saturating_add(1);
        if self.key != key_of(cal, win.rect, self.key.anchor, side) {
            return Err(PlanError::Stale);
        }
        Ok(self.apply_checked(cal, win, params))
    }

    fn apply_checked(
        &self,
        cal: &FrameCalibration<'_>,
        win: &RawWindow<'_>,
        params: &RawCogParams<'_>,
    ) -> RawCog {
        let side = self.key.side;
        let anchor = self.key.anchor;
        let (ax, ay) = anchor;
        let clip_flag = if self.clipped {
            CentroidFlags::EDGE_CLIPPED
        } else {
            CentroidFlags::empty()
        };
        if !buffers_ok(win) {
            return RawCog {
                centroid: degenerate(ax, ay, side, CentroidFlags::empty()),
                general_path: false,
                reanchored: false,
                anchor,
            };
        }
        let level_bits = level_to_bits(params.level_e);
        let var_bg = sanitize_var(params.variance_e2);
        let mut general_path = false;
        let mut measure = |p: &RawCogPlan| {
            if p.defects {
                general_path = true;
                let level_e = level_bits as i32 as f32 * (1.0 / 64.0);
                general_cog(cal, win, &p.b, side, level_e, var_bg)
            } else {
                fused_cog(cal, p, win, level_bits, var_bg)
            }
        };
        let Some(mut m) = measure(self) else {
            return RawCog {
                centroid: degenerate(ax, ay, side, clip_flag),
                general_path,
                reanchored: false,
                anchor,
            };
        };
        let (mut ax, mut ay) = (ax, ay);
        let mut reanchored = false;
        let far = |m: &Meas| !(m.ox.abs() <= 0.5 && m.oy.abs() <= 0.5);
        let mut flags = clip_flag;
        if far(&m) {
            // Move once to the CoG's pixel; offsets beyond the box are noise: at most h pixels.
            let h = f32::from(side / 2);
            let step = |o: f32| {
                let o = clamp(o, -h, h);
                (if o >= 0.0 { o + 0.5 } else { o - 0.5 }) as i32
            };
            let nx = i32::from(ax) + step(m.ox);
            let ny = i32::from(ay) + step(m.oy);
            let moved = u16::try_from(nx)
                .ok()
                .zip(u16::try_from(ny).ok())
                .and_then(|(nx, ny)| {
                    let mut np = Self::EMPTY;
                    np.rebuild(cal, win.rect, (nx, ny), side).ok()?;
                    Some(np)
                })
                .filter(|p| !p.clipped || self.clipped);
            match moved {
                Some(np) => match measure(&np) {
                    Some(m2) => {
                        (ax, ay) = (np.b.ax, np.b.ay);
                        m = m2;
                        reanchored = true;
                        if far(&m) {
                            flags |= CentroidFlags::NOT_CONVERGED;
                        }
                    }
                    None => flags |= CentroidFlags::NOT_CONVERGED,
                },
                None => flags |= CentroidFlags::NOT_CONVERGED,
            }
        }
        let c = finish(win.rect, ax, ay, side, &m, flags | m.flags);
        let centroid = match &params.curve {
            Some(curve) => curve.apply(c),
            None => c,
        };
        RawCog {
            centroid,
            general_path,
            reanchored,
            anchor: (ax, ay),
        }
    }
}

/// The general path on the box: calibrate it, `cog` with the given background over the whole
/// box; the result relative to the anchor.
#[inline(never)]
fn general_cog(
    cal: &FrameCalibration<'_>,
    win: &RawWindow<'_>,
    b: &BoxAt,
    side: u8,
    level_e: f32,
    var_bg: f32,
) -> Option<Meas> {
    let rect = b.rect();
    let n = rect.len();
    let mut raw = [0u16; MB2];
    let ww = usize::from(win.rect.width);
    let col_off = usize::from(b.x0 - win.rect.x0);
    let row_off = usize::from(b.y0 - win.rect.y0);
    let bw = usize::from(b.w);
    for (r, dst) in raw.chunks_exact_mut(bw).take(usize::from(b.h)).enumerate() {
        let start = (row_off + r) * ww + col_off;
        dst.copy_from_slice(win.raw.get(start..start + bw)?);
    }
    let levels = win.levels.get(row_off..row_off + usize::from(b.h))?;
    let mut e = [Electrons::ZERO; MB2];
    let mut f = [PixelFlags::empty(); MB2];
    let (raw, e, f) = (raw.get(..n)?, e.get_mut(..n)?, f.get_mut(..n)?);
    cal.calibrate_window(rect, raw, levels, e, f).ok()?;
    let window = Window::new(rect, e)?;
    let input = CentroidInput::new(window).with_pixel_flags(f);
    let c = cog(
        &input,
        &CogParams {
            power: CogPower::One,
            box_side: side,
            anchor: Anchor::WindowCentre,
            background: Background::Given {
                level_e,
                variance_e2: var_bg,
            },
        },
    );
    if c.flags.contains(CentroidFlags::DEGENERATE) {
        return None;
    }
    Some(Meas {
        ox: c.x_px - f32::from(b.ax),
        oy: c.y_px - f32::from(b.ay),
        flux_e: c.flux_e,
        snr: c.snr,
        sigma_x: c.sigma_x_px,
        sigma_y: c.sigma_y_px,
        // The window's own clip flag and LOW_SNR are set again below.
        flags: c.flags & !(CentroidFlags::LOW_SNR | CentroidFlags::CLAMPED),
    })
}

/// The anchor pixel as a degenerate centroid.
fn degenerate(ax: u16, ay: u16, side: u8, flags: CentroidFlags) -> Centroid {
    let half = f32::from(side) * 0.5;
    Centroid {
        x_px: f32::from(ax),
        y_px: f32::from(ay),
        flux_e: 0.0,
        snr: 0.0,
        sigma_x_px: half,
        sigma_y_px: half,
        flags: flags | CentroidFlags::DEGENERATE,
    }
}

/// True when the window's buffers match its rectangle.
fn buffers_ok(win: &RawWindow<'_>) -> bool {
    win.raw.len() == win.rect.len() && win.levels.len() == usize::from(win.rect.height)
}

/// The corrected CoG of the box of `params.box_side` around active pixel `anchor` of the raw
/// window `win` (see the module docs): [`RawCogPlan::new`] then [`RawCogPlan::apply`].
pub fn raw_cog(
    cal: &FrameCalibration<'_>,
    win: &RawWindow<'_>,
    anchor: (u16, u16),
    params: &RawCogParams<'_>,
) -> RawCog {
    let mut plan = RawCogPlan::EMPTY;
    match plan.rebuild(cal, win.rect, anchor, params.box_side) {
        Ok(()) => plan.apply_checked(cal, win, params),
        Err(_) => {
            let side = (params.box_side / 2).saturating_mul(2).saturating_add(1);
            RawCog {
                centroid: degenerate(anchor.0, anchor.1, side, CentroidFlags::empty()),
                general_path: false,
                reanchored: false,
                anchor,
            }
        }
    }
}

/// Active coordinates, clamped to the window (pixel edges), finite values, `LOW_SNR`.
fn finish(win: Rect, ax: u16, ay: u16, side: u8, m: &Meas, flags: CentroidFlags) -> Centroid {
    // The anchor relative to the window's corner (inside it: checked by the box set-up).
    let rel = |a: u16, o: u16| f32::from(a.saturating_sub(o));
    let rel_m = Measured {
        col: rel(ax, win.x0) + m.ox,
        row: rel(ay, win.y0) + m.oy,
        flux_e: m.flux_e,
        snr: m.snr,
        sigma_col: m.sigma_x,
        sigma_row: m.sigma_y,
    };
    finish_in(win, &rel_m, f32::from(side) * 0.5, flags)
        .unwrap_or_else(|| degenerate(ax, ay, side, flags))
}
