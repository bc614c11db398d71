//! The bench's deterministic synthetic inputs: the calibration table it calibrates with, raw
//! lines of a CCD47-20 readout with stars and noise, and the pixel-phase curves the
//! corrected CoGs apply. Every draw comes from one [`Lcg`], so the inputs are the same in
//! every run. None of it is timed; it costs one LCG step a raw sample ([`raw_line`]) or four
//! ([`raw_line_noisy`]).

use fixed::types::{U0F16, U8F8, U16F16};
use startrack_core::calib::LineLevels;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::{CurveHeader, PixCorrBackground};
use startrack_core::table::{HotPixel, HotPolicy, MapHeader, MapSpec, TableSpec, write_table};
use startrack_core::units::{ColumnBiasAdu, DarkRel, FlatInv, GainEPerAdu};

pub const G: ReadoutGeometry = ReadoutGeometry::CCD47_20_DUAL;
pub const RAW_COLS: usize = 1072;
pub const ACTIVE: usize = 1024;
const TILE_LOG2: u8 = 3;
const TILES: usize = MapHeader::for_area(ACTIVE as u16, ACTIVE as u16, TILE_LOG2).tiles();
const BIAS_ADU: u32 = 1000;

/// A 32-bit LCG (Numerical Recipes constants): deterministic noise.
pub struct Lcg(pub u32);

impl Lcg {
    pub fn next(&mut self) -> u32 {
        self.0 = self.0.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        self.0 >> 8
    }
}

/// Writes the bench's calibration table into `buf` and returns its length: CCD47-20, both
/// outputs, per-column bias, 8x8-tiled dark and flat maps (the README's flashed table), hot
/// and telegraph pixels. The map tiles draw from `rng`.
pub fn write_bench_table(rng: &mut Lcg, buf: &mut [u8]) -> Result<usize, &'static str> {
    let gains = [GainEPerAdu::from_num(1.5), GainEPerAdu::from_num(1.625)];
    let mut column_bias = [ColumnBiasAdu::ZERO; RAW_COLS];
    for (i, c) in column_bias.iter_mut().enumerate() {
        *c = ColumnBiasAdu::from_bits((i as i16 % 37) - 18);
    }
    let mut dark = [DarkRel::ONE; TILES];
    let mut flat = [FlatInv::ONE; TILES];
    for (d, f) in dark.iter_mut().zip(flat.iter_mut()) {
        *d = DarkRel::from_bits(56 + (rng.next() % 17) as u8);
        *f = FlatInv::from_bits(15_800 + (rng.next() % 1_200) as u16);
    }
    let hot_at = |x: u16, y: u16, policy| HotPixel {
        x,
        y,
        rate_e_per_s: U16F16::from_num(40),
        doubling_k: U8F8::from_num(6.5),
        policy,
    };
    let hot = [
        hot_at(300, 100, HotPolicy::Correct),
        hot_at(513, 101, HotPolicy::Correct),
        hot_at(514, 300, HotPolicy::Exclude),
        hot_at(100, 700, HotPolicy::Correct),
    ];
    let telegraph = [(40u16, 200u16), (900, 640)];
    let spec = TableSpec {
        geometry: G,
        saturation_adu: 65_000,
        gains: &gains,
        column_bias: Some(&column_bias),
        dark_rel: Some(MapSpec {
            tile_log2: TILE_LOG2,
            tiles: &dark,
        }),
        flat_inv: Some(MapSpec {
            tile_log2: TILE_LOG2,
            tiles: &flat,
        }),
        hot_ref_k: U16F16::from_num(263),
        hot: &hot,
        telegraph: &telegraph,
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    };
    write_table(&spec, buf).map_err(|_| "write_table failed")
}

/// exp(-k^2 / 2) x 1000 for k = -3..=3: a Gaussian PSF of sigma 1 px, separable.
const PSF_1000: [u32; 7] = [11, 135, 607, 1000, 607, 135, 11];
/// Peak of a star, ADU above bias.
const STAR_PEAK_ADU: u32 = 20_000;
/// The PSF's sigma of the synthetic stars, px.
pub const PSF_SIGMA_PX: f32 = 1.0;

/// Raw line of active row `y`: bias, noise of +-8 ADU, and a star centred on active (sx, sy).
pub fn raw_line(y: usize, star: (usize, usize), rng: &mut Lcg, out: &mut [u16; RAW_COLS]) {
    let first_active = usize::from(G.overscan_px + G.covered_px);
    for (col, v) in out.iter_mut().enumerate() {
        let mut s = BIAS_ADU + rng.next() % 17;
        if col >= first_active && col < first_active + ACTIVE {
            let x = col - first_active;
            let (dx, dy) = (x.abs_diff(star.0), y.abs_diff(star.1));
            if dx <= 3 && dy <= 3 {
                let wx = PSF_1000[3 + dx];
                let wy = PSF_1000[3 + dy];
                s += STAR_PEAK_ADU * wx / 1000 * wy / 1000;
            }
        }
        *v = s as u16;
    }
}

/// Raw line of active row `y` for the scan: bias, near-Gaussian noise (sum of four uniform
/// 0..=15 ADU draws: sigma 9.2 ADU, a tail like a Gaussian's to 3.5 sigma, so the 2.5-sigma
/// join threshold passes ~0.6 % of the samples as real noise does) and the stars of `stars`.
pub fn raw_line_noisy(
    y: usize,
    stars: &[(usize, usize)],
    rng: &mut Lcg,
    out: &mut [u16; RAW_COLS],
) {
    raw_line_trailed(y, stars, 1, rng, out);
}

/// [`raw_line_noisy`] with each star trailed along the row: `steps` copies of it at 1 px
/// intervals centred on its position (`steps` odd), each `1 / steps` of its signal (a trail
/// of `steps - 1` px over the exposure).
pub fn raw_line_trailed(
    y: usize,
    stars: &[(usize, usize)],
    steps: usize,
    rng: &mut Lcg,
    out: &mut [u16; RAW_COLS],
) {
    let first_active = usize::from(G.overscan_px + G.covered_px);
    let steps = steps.max(1);
    let half = steps / 2;
    let peak = STAR_PEAK_ADU / steps as u32;
    for (col, v) in out.iter_mut().enumerate() {
        // The LCG's top bits: its low bits have short periods (bits 8..11 repeat every 4096
        // draws, about one line), which made correlated noise peaks.
        let mut s = BIAS_ADU + (0..4).map(|_| rng.next() >> 20).sum::<u32>();
        if col >= first_active && col < first_active + ACTIVE {
            let x = col - first_active;
            for star in stars {
                let dy = y.abs_diff(star.1);
                for k in 0..steps {
                    let dx = (x + half).abs_diff(star.0 + k);
                    if dx <= 3 && dy <= 3 {
                        s += peak * PSF_1000[3 + dx] / 1000 * PSF_1000[3 + dy] / 1000;
                    }
                }
            }
        }
        *v = s.min(65_535) as u16;
    }
}

/// The levels of a line of bias alone: the initial value of arrays of levels that are
/// overwritten before use.
pub fn placeholder_levels() -> Result<LineLevels, &'static str> {
    LineLevels::measure(&G, &[BIAS_ADU as u16; RAW_COLS]).map_err(|_| "levels")
}

/// A pixel-phase curve's bytes (power 1, `box_side`, `background`, a = 1.2 px): 33 knots of
/// an S-shaped correction; the values do not change the cost.
pub fn s_curve_bytes(box_side: u8, background: PixCorrBackground) -> [u8; 8 + 2 * 33] {
    let mut bytes = [0u8; 8 + 2 * 33];
    let header = CurveHeader {
        power: CogPower::One,
        box_side,
        background,
        knots: 33,
        a_px: U8F8::from_num(1.2),
        phase_max_px: U0F16::from_num(0.45),
    };
    bytes[..8].copy_from_slice(&header.to_bytes());
    for k in 1..33usize {
        let v = (k as i32 * (32 - k as i32) * 3) as i16;
        bytes[8 + 2 * k..10 + 2 * k].copy_from_slice(&v.to_le_bytes());
    }
    bytes
}
