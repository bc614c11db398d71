//! Where the width fit starts: the peak, and the power-1 CoG, flux and second moments of the
//! box around it. One pass over the box's pixels.

use crate::centroid::math;
use crate::centroid::prepared::Prepared;

/// The start: the peak, the power-1 CoG, flux and second moments of the `start_box` around
/// it. `None`: no usable peak or no positive flux in the box. `CLEAN` (no excluded pixel):
/// the peak by one walk of the pixel bits and the box by row slices, as the held path's
/// start; else [`Prepared::peak`] and the box's usable pixels.
pub(super) fn start<const CLEAN: bool>(
    p: &Prepared<'_>,
    level_e: f32,
    start_box: u8,
) -> Option<Start> {
    let peak = if CLEAN {
        crate::centroid::gauss_fit::peak_clean(p)?
    } else {
        p.peak()?
    };
    let (bx, clipped) = p.box_around(peak.0, peak.1, start_box);
    // Moments about the peak pixel, so the sums keep their precision.
    let (pc, pr) = (f32::from(peak.0), f32::from(peak.1));
    let (mut s0, mut sc, mut sr, mut scc, mut srr) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    if CLEAN {
        let w = usize::from(p.width).max(1);
        let mut dr = f32::from(bx.row0) - pr;
        for row in bx.row0..=bx.row1 {
            let first = usize::from(row) * w;
            let line = p
                .pixels
                .get(first + usize::from(bx.col0)..=first + usize::from(bx.col1))?;
            let (mut rs, mut rc, mut rcc, mut dc) =
                (0.0f32, 0.0f32, 0.0f32, f32::from(bx.col0) - pc);
            for e in line {
                let f = e.to_bits() as f32 * (1.0 / 64.0) - level_e;
                let fc = f * dc;
                rs += f;
                rc += fc;
                rcc += fc * dc;
                dc += 1.0;
            }
            s0 += rs;
            sc += rc;
            scc += rcc;
            let fr = rs * dr;
            sr += fr;
            srr += fr * dr;
            dr += 1.0;
        }
    } else {
        for (c, r, f) in p.box_pixels(bx) {
            let (dc, dr) = (f32::from(c) - pc, f32::from(r) - pr);
            let (fc, fr) = (f * dc, f * dr);
            s0 += f;
            sc += fc;
            sr += fr;
            scc += fc * dc;
            srr += fr * dr;
        }
    }
    if s0.is_nan() || s0 <= 0.0 {
        return None;
    }
    let inv = 1.0 / s0;
    let (mx, my) = (sc * inv, sr * inv);
    let var = 0.5 * (scc * inv - mx * mx + srr * inv - my * my) - 1.0 / 12.0;
    Some(Start {
        peak,
        theta: (pc + mx, pr + my, s0, math::sqrt(var)),
        clipped,
    })
}

/// [`start`]'s result: the peak pixel, `(x, y, N, s)` (`s` 0 when the moments gave no
/// positive variance) and whether the box was clipped.
pub(super) struct Start {
    pub(super) peak: (u16, u16),
    pub(super) theta: (f32, f32, f32, f32),
    pub(super) clipped: bool,
}
