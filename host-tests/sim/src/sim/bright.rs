//! What a frame holds beyond stars, on the pixels: the Moon's disc, the Earth's limb, the
//! Sun's stray light, proton hits ([`super::protons`]), and the blooming of saturated
//! columns ([`bloom_column`]). [`crate::sky::bright`] places them from the sky; the
//! simulator adds their light to every pixel's before the flat
//! ([`super::Simulator::extended_e`]), the protons' charge after the shot noise, and
//! blooms the columns whose charge passes the full well.
//!
//! Blooming, as the CCD47-20 does it (no anti-blooming drain): a pixel holds
//! [`super::SensorParams::full_well_e`]; the charge above it spills along its column, half
//! up and half down, filling each pixel it passes to full well, never into the next column
//! (the channel stops hold); what passes the image section's ends is lost (to the store
//! section and the register, not modelled). A full pixel reads its full well exactly (no
//! shot noise: the well is full). The spill is computed on the expected charge of the
//! column (light through the flat, dark, protons), so it is deterministic per frame.
//!
//! Cost: nothing when a simulator has no bright scene. With one: the Moon, the Earth and the
//! stray light are a few arithmetic operations a pixel (the Moon's disc 16 sub-samples a
//! pixel within its box); a column that may bloom is evaluated whole once a frame
//! (1,024 pixels), unless its bright light alone overfills it.

use super::protons::ProtonHits;

/// The Moon's disc on the pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MoonDisc {
    /// Centre, active px (column, row).
    pub centre_px: [f64; 2],
    /// Radius, px.
    pub radius_px: f64,
    /// Phase angle (Sun-Moon-observer), deg: 0 full, 90 quarter, 180 new.
    pub phase_deg: f64,
    /// Direction of the Sun on the image from the disc's centre, rad from +x towards +y
    /// (the bright limb faces it).
    pub sun_direction_rad: f64,
    /// Surface brightness of the lit part, e- per px in the exposure.
    pub surface_e: f64,
}

impl MoonDisc {
    /// The lit fraction of the disc (the phase's illuminated fraction `(1 + cos a) / 2`).
    pub fn lit_fraction(&self) -> f64 {
        (1.0 + self.phase_deg.to_radians().cos()) / 2.0
    }

    /// Whether the disc's point (`x`, `y`) px is lit.
    fn lit(&self, x: f64, y: f64) -> bool {
        let (dx, dy) = (
            (x - self.centre_px[0]) / self.radius_px,
            (y - self.centre_px[1]) / self.radius_px,
        );
        let r2 = dx * dx + dy * dy;
        if r2 > 1.0 {
            return false;
        }
        let (c, s) = (self.sun_direction_rad.cos(), self.sun_direction_rad.sin());
        let (u, v) = (dx * c + dy * s, -dx * s + dy * c);
        u >= -self.phase_deg.to_radians().cos() * (1.0 - v * v).max(0.0).sqrt()
    }

    /// Light in active pixel (`x`, `y`), e- (4 x 4 sub-samples of the pixel).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let reach = self.radius_px + 1.0;
        if (x - self.centre_px[0]).abs() > reach || (y - self.centre_px[1]).abs() > reach {
            return 0.0;
        }
        let mut n = 0u32;
        for i in 0..4 {
            for j in 0..4 {
                let sx = x - 0.375 + 0.25 * f64::from(i);
                let sy = y - 0.375 + 0.25 * f64::from(j);
                n += u32::from(self.lit(sx, sy));
            }
        }
        self.surface_e * f64::from(n) / 16.0
    }
}

/// The Earth on the pixels: every pixel whose direction is within the Earth's angular
/// radius of its centre (the pinhole camera's directions).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EarthDisc {
    /// The Earth's centre, camera frame (unit vector; +z the boresight).
    pub centre_cam: [f64; 3],
    /// Its angular radius, rad.
    pub radius_rad: f64,
    /// Focal length, px, and principal point (column, row), px.
    pub focal_px: f64,
    /// Principal point.
    pub principal_px: [f64; 2],
    /// Surface brightness of the sunlit Earth, e- per px in the exposure.
    pub surface_e: f64,
}

impl EarthDisc {
    /// How far (`x`, `y`) is inside the limb, px (negative outside).
    pub fn inside_px(&self, x: f64, y: f64) -> f64 {
        let d = [
            (x - self.principal_px[0]) / self.focal_px,
            (y - self.principal_px[1]) / self.focal_px,
            1.0,
        ];
        let n = (d[0] * d[0] + d[1] * d[1] + 1.0).sqrt();
        let c = self.centre_cam;
        let cos = ((d[0] * c[0] + d[1] * c[1] + d[2] * c[2]) / n).clamp(-1.0, 1.0);
        (self.radius_rad - cos.acos()) * self.focal_px
    }

    /// Light in active pixel (`x`, `y`), e- (the pixel's covered fraction across the limb).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let cover = (self.inside_px(x, y) + 0.5).clamp(0.0, 1.0);
        self.surface_e * cover
    }
}

/// The Sun's stray light: a level at the active area's centre and a linear gradient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StrayLight {
    /// Level at the centre, e- per px in the exposure.
    pub centre_e: f64,
    /// Change per px along the Sun's azimuth on the image, e- per px per px.
    pub gradient_e_per_px: [f64; 2],
    /// The active area's centre, px.
    pub centre_px: [f64; 2],
}

impl StrayLight {
    /// Light in active pixel (`x`, `y`), e- (never negative).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (x - self.centre_px[0], y - self.centre_px[1]);
        (self.centre_e + self.gradient_e_per_px[0] * dx + self.gradient_e_per_px[1] * dy).max(0.0)
    }
}

/// A frame's bright scene on the pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BrightFrame {
    /// The Moon.
    pub moon: Option<MoonDisc>,
    /// The Earth.
    pub earth: Option<EarthDisc>,
    /// The Sun's stray light.
    pub stray: Option<StrayLight>,
    /// Proton hits.
    pub protons: Option<ProtonHits>,
    /// Saturated columns bloom (on whenever a bright scene is rendered; off only to compare).
    pub bloom: bool,
}

impl BrightFrame {
    /// Light of the Moon, the Earth and the stray light in active pixel (`x`, `y`), e-.
    pub fn light_e(&self, x: usize, y: usize) -> f64 {
        let (xf, yf) = (x as f64, y as f64);
        self.moon.map_or(0.0, |m| m.at(xf, yf))
            + self.earth.map_or(0.0, |e| e.at(xf, yf))
            + self.stray.map_or(0.0, |s| s.at(xf, yf))
    }

    /// Proton charge in active pixel (`x`, `y`), e-.
    pub fn proton_e(&self, x: usize, y: usize) -> f64 {
        self.protons.as_ref().map_or(0.0, |p| p.at(x, y))
    }
}

/// One column after blooming.
#[derive(Clone, Debug, PartialEq)]
pub enum BloomedColumn {
    /// Every pixel full.
    Full,
    /// Per row: `None` a full pixel, else the charge spilled into it, e-.
    Rows(Vec<Option<f64>>),
}

impl BloomedColumn {
    /// Row `y`: `None` full, else the spill it received.
    pub fn at(&self, y: usize) -> Option<f64> {
        match self {
            Self::Full => None,
            Self::Rows(r) => r.get(y).copied().unwrap_or(Some(0.0)),
        }
    }
}

/// Blooms one column of expected charge `q_e` (per row) at `full_well_e`: returns `None`
/// when no pixel passes it, else the column after the spill. Half of each pixel's excess
/// goes up (towards row 0), half down, each filling the pixels it passes; what passes the
/// ends is lost.
pub fn bloom_column(q_e: &[f64], full_well_e: f64) -> Option<BloomedColumn> {
    if !q_e.iter().any(|q| *q > full_well_e) {
        return None;
    }
    let n = q_e.len();
    let mut held: Vec<f64> = q_e.iter().map(|q| q.min(full_well_e)).collect();
    let excess: Vec<f64> = q_e.iter().map(|q| (q - full_well_e).max(0.0)).collect();
    // Upwards: from the bottom row to row 0.
    let mut carry = 0.0;
    for y in (0..n).rev() {
        carry += excess[y] / 2.0;
        let take = (full_well_e - held[y]).min(carry).max(0.0);
        held[y] += take;
        carry -= take;
    }
    // Downwards: from row 0 to the bottom.
    carry = 0.0;
    for y in 0..n {
        carry += excess[y] / 2.0;
        let take = (full_well_e - held[y]).min(carry).max(0.0);
        held[y] += take;
        carry -= take;
    }
    let rows: Vec<Option<f64>> = held
        .iter()
        .zip(q_e)
        .map(|(h, q)| (*h < full_well_e).then(|| (h - q.min(full_well_e)).max(0.0)))
        .collect();
    if rows.iter().all(Option::is_none) {
        return Some(BloomedColumn::Full);
    }
    Some(BloomedColumn::Rows(rows))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn excess_spills_both_ways_and_is_kept_until_the_ends() {
        let mut q = vec![10.0; 21];
        q[10] = 100.0 + 2.0 * 90.0 + 2.0 * 90.0 + 20.0;
        let b = bloom_column(&q, 100.0).unwrap();
        // 380 e- of excess: 190 each way, filling two pixels each side and 10 e- more.
        for y in 8..=12 {
            assert_eq!(b.at(y), None, "{y}");
        }
        assert_eq!(b.at(7), Some(10.0));
        assert_eq!(b.at(13), Some(10.0));
        assert_eq!(b.at(6), Some(0.0));
        assert!(bloom_column(&[10.0; 5], 100.0).is_none());
        assert_eq!(
            bloom_column(&[1e6, 0.0, 0.0], 100.0),
            Some(BloomedColumn::Full)
        );
    }

    #[test]
    fn a_half_moon_is_half_lit() {
        let m = MoonDisc {
            centre_px: [50.0, 50.0],
            radius_px: 17.6,
            phase_deg: 90.0,
            sun_direction_rad: 0.0,
            surface_e: 1.0,
        };
        let lit: f64 = (0..100)
            .flat_map(|y| (0..100).map(move |x| (x, y)))
            .map(|(x, y)| m.at(f64::from(x), f64::from(y)))
            .sum();
        let area = std::f64::consts::PI * 17.6 * 17.6;
        assert!((lit / area - 0.5).abs() < 0.02, "{}", lit / area);
        // The lit half faces the Sun (+x).
        assert!(m.at(60.0, 50.0) > 0.0 && m.at(40.0, 50.0) == 0.0);
    }
}
