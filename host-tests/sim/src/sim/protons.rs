//! Proton hits: straight tracks through the CCD47-20's silicon at random angles, their
//! charge from the proton's energy loss, at the rates of a quiet orbit, the South Atlantic
//! Anomaly and a solar flare ([`ProtonEnv`]).
//!
//! A frame's hits ([`ProtonHits::draw`]) are a pure function of (seed, frame): their number
//! is Poisson with mean `rate x area x exposure`; each track starts uniformly over the active
//! area (and a margin of the longest track around it), its azimuth uniform and its polar
//! angle that of an isotropic flux crossing a plane (`cos theta = sqrt(u)`), its energy from
//! the environment's spectrum (a power law `dN/dE ~ E^-gamma` between two energies). The
//! track crosses [`COLLECTION_DEPTH_UM`] of silicon: `depth / cos theta` of path (at most 20
//! times the depth), `depth tan theta` projected on the pixels. Its charge is the mean energy
//! loss over the path ([`let_mev_cm2_g`], no straggling) at 3.6 eV an electron-hole pair,
//! laid evenly along the projected segment and spread by charge diffusion (a Gaussian of
//! [`DIFFUSION_SIGMA_PX`]), each pixel's share integrated exactly (erf differences).
//!
//! Sources of the constants:
//! - rates, tracks per cm^2 of the sensor per s: quiet 1.2 (HST's WF/PC-1: 1.7 events s^-1
//!   on its 1.44 cm^2 CCDs outside the SAA, HST Data Handbook, "Cosmic Rays"); SAA 1,100
//!   (the peak STIS/CCD saw crossing the SAA at ~540 km: Miles et al. 2021,
//!   arXiv:2006.00909); solar flare 10,000 (the 14 July 2000 event's >10 MeV flux peaked at
//!   24,000 pfu on GOES; this model takes a tenth of its 2 pi-steradian flux to pass the
//!   camera's shielding, an assumption);
//! - spectra: quiet, galactic protons 300 MeV-10 GeV with `gamma` 2.7 (the typical cosmic
//!   ray at HST carries 534 +- 117 MeV, Miles et al.); SAA, trapped protons 30-400 MeV behind
//!   the shielding, `gamma` 1.5 (AP8's inner-belt protons stop near 400 MeV); flare,
//!   30 MeV-1 GeV, `gamma` 2.4 (the slope of GOES's >10 to >100 MeV channels in that event);
//! - the energy loss of protons in silicon ([`LET_TABLE`]): NIST PSTAR's electronic stopping
//!   power, rounded; 2.33 g/cm^3; 3.6 eV a pair;
//! - the collection depth and the diffusion are this model's assumptions for a
//!   back-illuminated CCD47-20 (its datasheet gives neither): 16 um and 0.3 px (4 um).
//!
//! Cost: per hit, `10 x length` Gaussian spreads of 7 x 7 erf products; an SAA frame of
//! 100 ms holds ~190 hits, a flare's ~1,800, a few ms to draw.

use super::psf::pixel_fraction;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, Poisson};
use std::collections::HashMap;

/// Silicon that collects a track's charge, um.
pub const COLLECTION_DEPTH_UM: f64 = 16.0;
/// Pixel pitch of the CCD47-20, um.
pub const PITCH_UM: f64 = 13.0;
/// Sigma of the charge's diffusion from the track to the pixels, px.
pub const DIFFUSION_SIGMA_PX: f64 = 0.3;
/// Electrons a micrometre of silicon per MeV cm^2/g of energy loss (2.33 g/cm^3, 3.6 eV a
/// pair): `2.33e-4 g/cm^2 x 1e6 eV/MeV / 3.6 eV`.
pub const E_PER_UM_PER_LET: f64 = 2.33e-4 * 1.0e6 / 3.6;

/// The electronic stopping power of silicon for protons (NIST PSTAR, rounded): energy in
/// MeV, MeV cm^2/g.
pub const LET_TABLE: [(f64, f64); 11] = [
    (10.0, 34.6),
    (20.0, 19.7),
    (30.0, 14.0),
    (50.0, 9.2),
    (100.0, 5.4),
    (200.0, 3.4),
    (300.0, 2.7),
    (500.0, 2.1),
    (1000.0, 1.7),
    (3000.0, 1.6),
    (10000.0, 1.7),
];

/// Energy loss of a proton of `energy_mev` in silicon, MeV cm^2/g: [`LET_TABLE`]
/// interpolated log-log, held at its ends.
pub fn let_mev_cm2_g(energy_mev: f64) -> f64 {
    let first = LET_TABLE[0];
    let last = LET_TABLE[LET_TABLE.len() - 1];
    if energy_mev <= first.0 {
        return first.1;
    }
    if energy_mev >= last.0 {
        return last.1;
    }
    for w in LET_TABLE.windows(2) {
        let ((e0, l0), (e1, l1)) = (w[0], w[1]);
        if energy_mev <= e1 {
            let t = (energy_mev / e0).ln() / (e1 / e0).ln();
            return (l0.ln() + t * (l1 / l0).ln()).exp();
        }
    }
    last.1
}

/// The proton environment of an orbit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProtonEnv {
    /// Outside the belts: galactic cosmic rays.
    Quiet,
    /// The South Atlantic Anomaly's peak: trapped protons.
    Saa,
    /// A large solar flare's proton event.
    Flare,
}

impl ProtonEnv {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Quiet => "quiet",
            Self::Saa => "saa",
            Self::Flare => "flare",
        }
    }

    /// Tracks per cm^2 of the sensor per s (sources in the module doc).
    pub fn rate_per_cm2_s(self) -> f64 {
        match self {
            Self::Quiet => 1.2,
            Self::Saa => 1100.0,
            Self::Flare => 10_000.0,
        }
    }

    /// The spectrum: (lowest, highest energy, MeV; power-law index gamma).
    pub fn spectrum(self) -> (f64, f64, f64) {
        match self {
            Self::Quiet => (300.0, 10_000.0, 2.7),
            Self::Saa => (30.0, 400.0, 1.5),
            Self::Flare => (30.0, 1000.0, 2.4),
        }
    }

    /// An energy from the spectrum, MeV, for a uniform `u` in 0..1 (the inverse of its
    /// cumulative distribution).
    pub fn energy_mev(self, u: f64) -> f64 {
        let (lo, hi, g) = self.spectrum();
        let k = 1.0 - g;
        if k.abs() < 1e-12 {
            return lo * (hi / lo).powf(u);
        }
        (lo.powf(k) + u * (hi.powf(k) - lo.powf(k))).powf(1.0 / k)
    }
}

/// One proton's track on the pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProtonTrack {
    /// Start, active-area px (column, row).
    pub from_px: [f64; 2],
    /// End, px.
    pub to_px: [f64; 2],
    /// Charge collected, e-.
    pub charge_e: f64,
    /// The proton's energy, MeV.
    pub energy_mev: f64,
}

/// A frame's proton hits and the charge they leave in each pixel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProtonHits {
    /// The tracks.
    pub tracks: Vec<ProtonTrack>,
    /// Charge per active pixel hit (column, row), e-.
    deposit: HashMap<(u16, u16), f64>,
}

/// Longest projected track, px (`20 x depth` at grazing incidence).
pub fn max_track_px() -> f64 {
    20.0 * COLLECTION_DEPTH_UM / PITCH_UM
}

impl ProtonHits {
    /// The hits of frame `frame` in `env` over an active area of `cols` x `rows` for an
    /// exposure of `exposure_s`, from `seed`.
    pub fn draw(
        env: ProtonEnv,
        seed: u64,
        frame: u32,
        cols: u16,
        rows: u16,
        exposure_s: f64,
    ) -> Self {
        let key =
            seed ^ 0x5052_4f54_4f4e_0000 ^ u64::from(frame).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(key);
        let margin = max_track_px();
        let (w, h) = (
            f64::from(cols) + 2.0 * margin,
            f64::from(rows) + 2.0 * margin,
        );
        let area_cm2 = w * h * (PITCH_UM * 1e-4).powi(2);
        let mean = env.rate_per_cm2_s() * area_cm2 * exposure_s.max(0.0);
        let n = if mean > 0.0 {
            Poisson::new(mean).map_or(0.0, |p| p.sample(&mut r)) as usize
        } else {
            0
        };
        let mut hits = Self::default();
        for _ in 0..n {
            let x0 = r.random::<f64>() * w - margin;
            let y0 = r.random::<f64>() * h - margin;
            let phi = r.random::<f64>() * std::f64::consts::TAU;
            let cos_t = r.random::<f64>().sqrt().max(0.05);
            let tan_t = (1.0 - cos_t * cos_t).sqrt() / cos_t;
            let energy_mev = env.energy_mev(r.random::<f64>());
            let path_um = COLLECTION_DEPTH_UM / cos_t;
            let len_px = COLLECTION_DEPTH_UM * tan_t / PITCH_UM;
            let track = ProtonTrack {
                from_px: [x0, y0],
                to_px: [x0 + len_px * phi.cos(), y0 + len_px * phi.sin()],
                charge_e: let_mev_cm2_g(energy_mev) * E_PER_UM_PER_LET * path_um,
                energy_mev,
            };
            hits.lay(&track, cols, rows);
            hits.tracks.push(track);
        }
        hits
    }

    /// Lays a track's charge on the pixels.
    fn lay(&mut self, t: &ProtonTrack, cols: u16, rows: u16) {
        let (dx, dy) = (t.to_px[0] - t.from_px[0], t.to_px[1] - t.from_px[1]);
        let steps = ((dx.hypot(dy) / 0.1).ceil() as usize).max(1);
        let q = t.charge_e / steps as f64;
        let s = DIFFUSION_SIGMA_PX;
        for k in 0..steps {
            let f = (k as f64 + 0.5) / steps as f64;
            let (cx, cy) = (t.from_px[0] + f * dx, t.from_px[1] + f * dy);
            let (ix, iy) = (cx.round() as i64, cy.round() as i64);
            for y in iy - 3..=iy + 3 {
                if y < 0 || y >= i64::from(rows) {
                    continue;
                }
                let fy = pixel_fraction(y as f64, cy, s);
                for x in ix - 3..=ix + 3 {
                    if x < 0 || x >= i64::from(cols) {
                        continue;
                    }
                    let e = q * fy * pixel_fraction(x as f64, cx, s);
                    if e > 1e-3 {
                        *self.deposit.entry((x as u16, y as u16)).or_insert(0.0) += e;
                    }
                }
            }
        }
    }

    /// Charge the hits left in active pixel (`x`, `y`), e-.
    pub fn at(&self, x: usize, y: usize) -> f64 {
        match (u16::try_from(x), u16::try_from(y)) {
            (Ok(x), Ok(y)) => self.deposit.get(&(x, y)).copied().unwrap_or(0.0),
            _ => 0.0,
        }
    }

    /// Tracks whose charge reaches the active area.
    pub fn in_area(&self, cols: u16, rows: u16) -> usize {
        let inside = |p: [f64; 2]| {
            p[0] >= -0.5
                && p[1] >= -0.5
                && p[0] < f64::from(cols) - 0.5
                && p[1] < f64::from(rows) - 0.5
        };
        self.tracks
            .iter()
            .filter(|t| inside(t.from_px) || inside(t.to_px))
            .count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rates_spectra_and_charge_are_as_stated() {
        // A minimum-ionising proton crossing 16 um at normal incidence leaves ~1,700 e-.
        let q = let_mev_cm2_g(3000.0) * E_PER_UM_PER_LET * COLLECTION_DEPTH_UM;
        assert!((1500.0..1900.0).contains(&q), "{q}");
        for env in [ProtonEnv::Quiet, ProtonEnv::Saa, ProtonEnv::Flare] {
            let (lo, hi, _) = env.spectrum();
            assert!((env.energy_mev(0.0) - lo).abs() < 1e-6 * lo);
            assert!((env.energy_mev(1.0) - hi).abs() < 1e-6 * hi);
        }
        // An SAA frame of 100 ms on the 1024 x 1024 area: ~1.77 cm^2 x 1100 x 0.1 = 195.
        let hits = ProtonHits::draw(ProtonEnv::Saa, 3, 7, 1024, 1024, 0.1);
        let n = hits.in_area(1024, 1024);
        assert!((150..250).contains(&n), "{n}");
        // Same seed and frame, same hits; charge is conserved within the area.
        assert_eq!(
            hits,
            ProtonHits::draw(ProtonEnv::Saa, 3, 7, 1024, 1024, 0.1)
        );
    }
}
