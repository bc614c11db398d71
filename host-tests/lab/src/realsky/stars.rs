//! The stars of a plain image: a background map that follows real skies, then the core's
//! detection and centroids on the background-subtracted pixels.
//!
//! - Background: the median of each 32 x 32 px tile (saturated pixels left out), bilinear
//!   between tile centres, subtracted from every pixel. Real skies are not flat (vignetting
//!   halves the level towards the corners of the shared frames, light pollution adds a
//!   gradient); the map takes out what varies over more than a tile, and the detector's own
//!   running estimate (64-column blocks) and each window's border take out the rest.
//! - Detection: [`LineDetector`] with the core's defaults (join at 2.5 sigma, a peak above
//!   5 sigma, 2 pixels, SNR 3), lines in row order as on the board. Values are ADU times
//!   `gain_e_per_adu`, taken as electrons in `I26F6` (the core's calibrated format; a value
//!   beyond its +-2^25 is clamped, flagged saturated). The detector holds 256 runs a line
//!   and 128 open blobs; an image whose noise crosses the threshold more often than that
//!   (8-bit frames a few ADU above zero, where quantised noise has a long tail) would lose
//!   the pixels to the right of where the budget ran out, so a scan that dropped pixels is
//!   done again on the [`SMOOTH_SIDE_PX`]-square box mean of the background-subtracted
//!   pixels (noise down by the box side, a star's peak by much less) and that scan is kept
//!   when it dropped fewer. Only the detection sees the mean: every centroid is measured on
//!   the image's own pixels.
//! - Centroids: the core's width-free Gaussian fit (`gauss_fit_width`) on a 9 x 9 window
//!   round the blob's peak, background from the window's border. A blob with a saturated
//!   pixel is not fitted: its position is the power-1 centre of gravity of a window sized to
//!   the blob, flagged [`CentroidFlags::SATURATED`] (a clipped core is symmetric for a
//!   round star, so its centre is still a usable, if less precise, direction).
//!
//! Cost: two passes for the background (a selection per tile), the detector's per-pixel
//! threshold test, and one fit per blob (a few thousand flops); tens of milliseconds for a
//! 1024 x 768 frame in the dev profile. A scan that overflows costs a box mean (9 additions
//! a pixel) and a second scan.

use super::picture::Picture;
use startrack_core::calib::PixelFlags;
use startrack_core::centroid::cog::{Anchor, CogParams, cog};
use startrack_core::centroid::gauss_fit::{WidthFitParams, gauss_fit_width};
use startrack_core::centroid::{Background, CentroidFlags, CentroidInput};
use startrack_core::detect::{DetectConfig, DetectionFlags, LineDetector};
use startrack_core::table::pixcorr::CogPower;
use startrack_core::units::Electrons;
use startrack_core::window::{Rect, Window};

/// Background tile side, px.
pub const TILE_PX: usize = 32;
/// Most blobs kept (the brightest).
pub const MAX_BLOBS: usize = 512;
/// Side of a fitted star's window, px.
pub const FIT_SIDE_PX: u16 = 9;
/// Side of the box mean detection falls back to, px.
pub const SMOOTH_SIDE_PX: usize = 3;

/// One measured star of an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageStar {
    /// Column, px.
    pub x_px: f64,
    /// Row, px.
    pub y_px: f64,
    /// The detector's background-subtracted blob signal, e- (a lower bound for a saturated
    /// star): the brightness order.
    pub flux_e: f64,
    /// The centroid's own 1-sigma error, px (the larger axis).
    pub sigma_px: f64,
    /// The detector's SNR (eq. 8).
    pub snr: f64,
    /// The centroid's flags (`SATURATED`: the CoG of a clipped core, not a fit).
    pub flags: CentroidFlags,
}

impl ImageStar {
    /// True when the blob has a saturated pixel.
    pub fn saturated(&self) -> bool {
        self.flags.contains(CentroidFlags::SATURATED)
    }
}

/// What the star finder saw.
#[derive(Clone, Debug, PartialEq)]
pub struct StarField {
    /// The stars, brightest first (degenerate windows left out).
    pub stars: Vec<ImageStar>,
    /// The background map, ADU, row-major like the image.
    pub background_adu: Vec<f32>,
    /// Blobs the candidate list had no room for.
    pub dropped: u32,
    /// Pixels the detector's line budget had no room for (runs per line, open blobs) in the
    /// scan whose stars these are.
    pub dropped_pixels: u32,
    /// True when the stars were detected on the box mean (see the module docs).
    pub smoothed: bool,
}

fn median(v: &mut [f32]) -> Option<f32> {
    if v.is_empty() {
        return None;
    }
    let n = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(n, f32::total_cmp);
    Some(*m)
}

/// The tile-median background map (see the module docs).
pub fn background_map(pic: &Picture) -> Vec<f32> {
    let (w, h) = (pic.width, pic.height);
    let (tx, ty) = (w.div_ceil(TILE_PX), h.div_ceil(TILE_PX));
    let sat = pic.saturation_adu.unwrap_or(f32::INFINITY);
    let mut tiles = vec![0.0f32; tx * ty];
    let mut buf = Vec::with_capacity(TILE_PX * TILE_PX);
    let overall = median(&mut pic.data_adu.clone()).unwrap_or(0.0);
    for j in 0..ty {
        for i in 0..tx {
            buf.clear();
            for y in j * TILE_PX..((j + 1) * TILE_PX).min(h) {
                for x in i * TILE_PX..((i + 1) * TILE_PX).min(w) {
                    let v = pic.at(x, y);
                    if v < sat {
                        buf.push(v);
                    }
                }
            }
            tiles[j * tx + i] = median(&mut buf).unwrap_or(overall);
        }
    }
    // Bilinear between tile centres, clamped at the outer half tiles.
    let axis = |p: usize, n: usize| -> (usize, usize, f32) {
        let t = (p as f32 + 0.5) / TILE_PX as f32 - 0.5;
        let t = t.clamp(0.0, (n - 1) as f32);
        let i0 = t.floor() as usize;
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, t - i0 as f32)
    };
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        let (j0, j1, fy) = axis(y, ty);
        for x in 0..w {
            let (i0, i1, fx) = axis(x, tx);
            let t = |i: usize, j: usize| tiles[j * tx + i];
            let top = t(i0, j0) * (1.0 - fx) + t(i1, j0) * fx;
            let bot = t(i0, j1) * (1.0 - fx) + t(i1, j1) * fx;
            out[y * w + x] = top * (1.0 - fy) + bot * fy;
        }
    }
    out
}

/// Finds and centroids the stars of `pic` (see the module docs).
pub fn find_stars(pic: &Picture, gain_e_per_adu: f64) -> StarField {
    let (w, h) = (pic.width, pic.height);
    let bg = background_map(pic);
    let sat = pic.saturation_adu.unwrap_or(f32::INFINITY);
    let limit = f64::from(1u32 << 25) - 1.0;
    let mut flags = vec![PixelFlags::empty(); w * h];
    let mut pix = vec![Electrons::ZERO; w * h];
    for ((p, f), (&v, &b)) in pix
        .iter_mut()
        .zip(flags.iter_mut())
        .zip(pic.data_adu.iter().zip(bg.iter()))
    {
        let e = (f64::from(v) - f64::from(b)) * gain_e_per_adu;
        *p = Electrons::saturating_from_num(e.clamp(-limit, limit));
        if v >= sat || e.abs() >= limit {
            *f = PixelFlags::SATURATED;
        }
    }
    let mut det = scan(&pix, &flags, w, h);
    let mut smoothed = false;
    if det.dropped_pixels() > 0 {
        // Noise beyond the detector's line budget: the same scan of the box mean.
        let boxed = scan(&box_mean(&pix, &flags, w, h), &flags, w, h);
        if boxed.dropped_pixels() < det.dropped_pixels() {
            det = boxed;
            smoothed = true;
        }
    }
    let mut stars = Vec::new();
    for d in det.candidates() {
        let saturated = d.flags.contains(DetectionFlags::SATURATED);
        let (cx, cy, side) = if saturated {
            // A window two pixels beyond the blob's extent on each side of its radius.
            let r = (f64::from(d.pixels) / std::f64::consts::PI).sqrt();
            let side = ((2.0 * r).ceil() as u16 + 6) | 1;
            (
                d.x_px.round().max(0.0) as u16,
                d.y_px.round().max(0.0) as u16,
                side.min(31),
            )
        } else {
            (d.peak_x, d.peak_y, FIT_SIDE_PX)
        };
        let (rect, clipped) = Rect::centred_clipped(cx, cy, side, w as u16, h as u16);
        let mut wpx = Vec::with_capacity(rect.len());
        let mut wfl = Vec::with_capacity(rect.len());
        for y in rect.y0..rect.y0 + rect.height {
            for x in rect.x0..rect.x0 + rect.width {
                let k = usize::from(y) * w + usize::from(x);
                wpx.push(pix[k]);
                wfl.push(flags[k]);
            }
        }
        let Some(window) = Window::new(rect, &wpx) else {
            continue;
        };
        let input = CentroidInput::new(window)
            .with_pixel_flags(&wfl)
            .with_clipped(clipped);
        let c = if saturated {
            cog(
                &input,
                &CogParams {
                    power: CogPower::One,
                    box_side: (side - 2) as u8,
                    anchor: Anchor::WindowCentre,
                    background: Background::PerimeterMedian,
                },
            )
        } else {
            gauss_fit_width(&input, &WidthFitParams::new()).centroid
        };
        if c.flags.contains(CentroidFlags::DEGENERATE) {
            continue;
        }
        let mut cflags = c.flags;
        if saturated {
            cflags |= CentroidFlags::SATURATED;
        }
        stars.push(ImageStar {
            x_px: f64::from(c.x_px),
            y_px: f64::from(c.y_px),
            flux_e: f64::from(d.flux_e),
            sigma_px: f64::from(c.sigma_x_px.max(c.sigma_y_px)),
            snr: f64::from(d.snr),
            flags: cflags,
        });
    }
    stars.sort_by(|a, b| b.flux_e.total_cmp(&a.flux_e));
    StarField {
        stars,
        background_adu: bg,
        dropped: det.dropped(),
        dropped_pixels: det.dropped_pixels(),
        smoothed,
    }
}

/// The core's line detector over the whole image, lines in row order.
fn scan(
    pix: &[Electrons],
    flags: &[PixelFlags],
    w: usize,
    h: usize,
) -> Box<LineDetector<MAX_BLOBS>> {
    let mut det: Box<LineDetector<MAX_BLOBS>> = Box::new(LineDetector::new(
        DetectConfig::default(),
        w as u16,
        h as u16,
    ));
    for y in 0..h {
        let row = y * w..(y + 1) * w;
        // Lines are pushed in row order with the detector's width: it cannot refuse them.
        let _ = det.push_line(y as u16, &pix[row.clone()], &flags[row]);
    }
    det.finish();
    det
}

/// The mean of each pixel's [`SMOOTH_SIDE_PX`]-square neighbourhood (the pixels inside the
/// image and not saturated; a saturated pixel keeps its value and its flag).
fn box_mean(pix: &[Electrons], flags: &[PixelFlags], w: usize, h: usize) -> Vec<Electrons> {
    let r = SMOOTH_SIDE_PX / 2;
    let mut out = pix.to_vec();
    for y in 0..h {
        for x in 0..w {
            let k = y * w + x;
            if flags[k].contains(PixelFlags::SATURATED) {
                continue;
            }
            let (mut sum, mut n) = (0.0f64, 0u32);
            for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                    let j = yy * w + xx;
                    if !flags[j].contains(PixelFlags::SATURATED) {
                        sum += pix[j].to_num::<f64>();
                        n += 1;
                    }
                }
            }
            out[k] = Electrons::saturating_from_num(sum / f64::from(n.max(1)));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Exp};

    /// An 8-bit frame a couple of counts above zero whose noise has an exponential tail (as
    /// the openstartracker frames of docs/attitude.md have), with round stars planted across
    /// the whole width.
    fn noisy_8bit(w: usize, h: usize, stars: &[(f64, f64)]) -> Picture {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let noise = Exp::new(0.5f64).unwrap();
        let mut data = vec![0.0f32; w * h];
        for (k, v) in data.iter_mut().enumerate() {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            let star: f64 = stars
                .iter()
                .map(|&(sx, sy)| {
                    60.0 * (-((x - sx).powi(2) + (y - sy).powi(2)) / (2.0 * 1.3f64.powi(2))).exp()
                })
                .sum();
            *v = (noise.sample(&mut rng) + star).floor().min(255.0) as f32;
        }
        Picture {
            width: w,
            height: h,
            data_adu: data,
            saturation_adu: Some(255.0),
        }
    }

    #[test]
    fn a_scan_that_overflows_is_done_again_on_the_box_mean_and_finds_stars_across_the_width() {
        let (w, h) = (1392, 160);
        let planted: Vec<(f64, f64)> = (0..8)
            .map(|i| (60.3 + 180.0 * f64::from(i), 40.6 + 80.0 * f64::from(i % 2)))
            .collect();
        let pic = noisy_8bit(w, h, &planted);
        // The raw scan runs out of its line budget (the right of the frame is lost)...
        let bg = background_map(&pic);
        let raw: Vec<Electrons> = pic
            .data_adu
            .iter()
            .zip(&bg)
            .map(|(&v, &b)| Electrons::saturating_from_num(f64::from(v - b)))
            .collect();
        let raw_scan = scan(&raw, &vec![PixelFlags::empty(); w * h], w, h);
        assert!(
            raw_scan.dropped_pixels() > 0,
            "the test must overflow the raw scan"
        );
        // ...so the stars come from the box mean, which drops fewer, and every planted star
        // is found within 0.5 px, on the image's own pixels.
        let field = find_stars(&pic, 1.0);
        assert!(field.smoothed);
        assert!(field.dropped_pixels < raw_scan.dropped_pixels());
        for &(x, y) in &planted {
            let near = field
                .stars
                .iter()
                .any(|s| (s.x_px - x).hypot(s.y_px - y) < 0.5);
            assert!(near, "planted star at ({x}, {y}) not found");
        }
    }

    #[test]
    fn a_frame_within_the_budget_is_scanned_as_it_is() {
        let (w, h) = (256, 128);
        let mut data = vec![1000.0f32; w * h];
        for (k, v) in data.iter_mut().enumerate() {
            let (x, y) = ((k % w) as f64, (k / w) as f64);
            *v += (5e4 * (-((x - 100.2).powi(2) + (y - 60.7).powi(2)) / 3.0).exp()) as f32;
            // Deterministic low-level texture: +-3 ADU.
            *v += ((k * 7919) % 7) as f32 - 3.0;
        }
        let pic = Picture {
            width: w,
            height: h,
            data_adu: data,
            saturation_adu: Some(65535.0),
        };
        let field = find_stars(&pic, 1.0);
        assert!(!field.smoothed);
        assert_eq!(field.dropped_pixels, 0);
        assert!(
            (field.stars[0].x_px - 100.2).abs() < 0.05 && (field.stars[0].y_px - 60.7).abs() < 0.05
        );
    }
}
