//! Owned table specs and their contents: the small test sensors and the CCD47-20, distinct
//! non-trivial values for every section (tiles, column bias, gains, hot and telegraph lists,
//! two hand-encoded pixel-phase curves), and the full and gains-only specs built from them.
//! Cost: one value per tile, column or list entry.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::{PixCorr, PixCorrBackground};
use startrack_core::table::{
    CtiCoeffs, CtiOutput, HotPixel, HotPolicy, MapSpec, PsfModel, TableSpec, write_table,
    write_table_with_pixcorr,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu, Kelvin};

use fixed::types::{I16F16, U0F16, U0F32, U8F8};

// ---------------------------------------------------------------------------------------------
// Geometries.

/// A small sensor that keeps tests fast: 4 over-scan, 2 covered, 16 x 12 active, 14 lines,
/// one output (line length 28).
pub const SMALL: ReadoutGeometry = ReadoutGeometry {
    overscan_px: 4,
    covered_px: 2,
    active_cols: 16,
    active_rows: 12,
    lines: 14,
    outputs: 1,
};

/// The same small sensor read through two outputs.
pub const SMALL_DUAL: ReadoutGeometry = ReadoutGeometry {
    outputs: 2,
    ..SMALL
};

/// The CCD47-20 read through both outputs.
pub const CCD: ReadoutGeometry = ReadoutGeometry::CCD47_20_DUAL;

// ---------------------------------------------------------------------------------------------
// Owned specs.

/// Everything a `TableSpec` borrows, owned.
#[derive(Clone, Debug)]
pub struct OwnedSpec {
    pub geometry: ReadoutGeometry,
    pub saturation_adu: u16,
    pub gains: Vec<GainEPerAdu>,
    pub column_bias: Option<Vec<ColumnBiasAdu>>,
    pub dark: Option<(u8, Vec<DarkRel>)>,
    pub flat: Option<(u8, Vec<FlatInv>)>,
    pub hot_ref_k: Kelvin,
    pub hot: Vec<HotPixel>,
    pub telegraph: Vec<(u16, u16)>,
    /// Pixel-phase correction curves, each encoded by [`enc_curve`] (none: no section).
    pub pixcorr: Vec<Vec<u8>>,
    /// CTI coefficients (none: no section).
    pub cti: Option<CtiCoeffs>,
    /// Field PSF model (none: no section).
    pub psf_model: Option<PsfModel>,
    /// The camera model (none: no section).
    pub camera_model: Option<startrack_core::attitude::Camera>,
    /// The covered pixels' dark law (none: no section).
    pub dark_law: Option<startrack_core::table::DarkLaw>,
}

impl OwnedSpec {
    /// The curves, parsed by the core (panics on a malformed fixture).
    pub fn curves(&self) -> Vec<PixCorr<'_>> {
        self.pixcorr
            .iter()
            .map(|b| PixCorr::parse(b).expect("fixture curve").0)
            .collect()
    }

    /// Bytes of the whole table, pixel-phase section included.
    pub fn encoded_len(&self) -> usize {
        self.spec().encoded_len_with_pixcorr(&self.curves())
    }

    pub fn spec(&self) -> TableSpec<'_> {
        TableSpec {
            geometry: self.geometry,
            saturation_adu: self.saturation_adu,
            gains: &self.gains,
            column_bias: self.column_bias.as_deref(),
            dark_rel: self.dark.as_ref().map(|(t, v)| MapSpec {
                tile_log2: *t,
                tiles: v,
            }),
            flat_inv: self.flat.as_ref().map(|(t, v)| MapSpec {
                tile_log2: *t,
                tiles: v,
            }),
            hot_ref_k: self.hot_ref_k,
            hot: &self.hot,
            telegraph: &self.telegraph,
            cti: self.cti,
            psf_model: self.psf_model,
            camera_model: self.camera_model,
            dark_law: self.dark_law,
        }
    }

    /// Encodes with `write_table_with_pixcorr`, panicking (in the test) on failure.
    pub fn write(&self) -> Vec<u8> {
        let curves = self.curves();
        let mut buf = vec![0u8; self.encoded_len()];
        let n = write_table_with_pixcorr(&self.spec(), &curves, &mut buf)
            .unwrap_or_else(|e| panic!("write_table failed: {e}"));
        assert_eq!(n, buf.len(), "write_table length differs from encoded_len");
        buf
    }
}

/// Encodes `spec` into a buffer of exactly `encoded_len` bytes.
pub fn write_spec(spec: &TableSpec<'_>) -> Result<Vec<u8>, startrack_core::table::WriteError> {
    let mut buf = vec![0u8; spec.encoded_len()];
    let n = write_table(spec, &mut buf)?;
    assert_eq!(n, buf.len(), "write_table length differs from encoded_len");
    Ok(buf)
}

/// Tiles across and down an area of `cols` x `rows` with tiles of `2^log2` pixels, computed
/// independently of `MapHeader::for_area`.
pub fn tiles_of(cols: u16, rows: u16, log2: u8) -> (usize, usize) {
    let t = 1usize << log2;
    (usize::from(cols).div_ceil(t), usize::from(rows).div_ceil(t))
}

/// Index of the tile holding active pixel (x, y).
pub fn tile_index(g: &ReadoutGeometry, log2: u8, x: u16, y: u16) -> usize {
    let (tx, _) = tiles_of(g.active_cols, g.active_rows, log2);
    (usize::from(y) >> log2) * tx + (usize::from(x) >> log2)
}

/// Distinct, non-trivial dark tiles (every u8 value appears for large maps).
pub fn dark_tiles(g: &ReadoutGeometry, log2: u8) -> Vec<DarkRel> {
    let (tx, ty) = tiles_of(g.active_cols, g.active_rows, log2);
    (0..tx * ty)
        .map(|i| DarkRel::from_bits(((i * 31 + 7) % 256) as u8))
        .collect()
}

/// Non-zero inverse-flat tiles that differ between neighbours.
pub fn flat_tiles(g: &ReadoutGeometry, log2: u8) -> Vec<FlatInv> {
    let (tx, ty) = tiles_of(g.active_cols, g.active_rows, log2);
    (0..tx * ty)
        .map(|i| FlatInv::from_bits(1 + ((i * 7919 + 13) % 65535) as u16))
        .collect()
}

/// Column offsets of both signs over the whole range of I12F4.
pub fn column_bias(g: &ReadoutGeometry) -> Vec<ColumnBiasAdu> {
    (0..g.line_len())
        .map(|c| ColumnBiasAdu::from_bits(((c * 4099 + 5) % 65536) as u16 as i16))
        .collect()
}

/// Distinct gains per output (1.5 and 1.75 e-/ADU plus a low-order bit pattern).
pub fn gains(g: &ReadoutGeometry) -> Vec<GainEPerAdu> {
    (0..g.outputs)
        .map(|o| {
            GainEPerAdu::from_num(1.5 + 0.25 * f64::from(o))
                + GainEPerAdu::from_bits(0x123 + u32::from(o))
        })
        .collect()
}

/// A sorted hot list over the active area: both corners, the middle and a few more, both
/// policies, distinct rates and doubling temperatures.
pub fn hot_pixels(g: &ReadoutGeometry) -> Vec<HotPixel> {
    let (c, r) = (g.active_cols, g.active_rows);
    let mut pos = vec![
        (0, 0),
        (c - 1, 0),
        (c / 2, r / 2),
        (c / 3, r / 2),
        (0, r - 1),
        (c - 1, r - 1),
    ];
    pos.extend((1..r.min(40)).step_by(3).map(|y| ((y * 7) % c, y)));
    pos.sort_by_key(|&(x, y)| (y, x));
    pos.dedup();
    pos.iter()
        .enumerate()
        .map(|(i, &(x, y))| HotPixel {
            x,
            y,
            rate_e_per_s: ERatePerS::from_bits(0x0001_8000 + 0x0101 * i as u32),
            doubling_k: U8F8::from_bits(0x0600 + 3 * i as u16),
            policy: if i % 2 == 0 {
                HotPolicy::Correct
            } else {
                HotPolicy::Exclude
            },
        })
        .collect()
}

/// A sorted telegraph list over the active area, disjoint from `hot_pixels`' positions in
/// general (not required by the format).
pub fn telegraph(g: &ReadoutGeometry) -> Vec<(u16, u16)> {
    let (c, r) = (g.active_cols, g.active_rows);
    let mut pos = vec![(1, 0), (c - 2, r - 1), (c / 2 + 1, r / 2)];
    pos.extend((0..r.min(30)).step_by(5).map(|y| ((y * 3 + 2) % c, y)));
    pos.sort_by_key(|&(x, y)| (y, x));
    pos.dedup();
    pos
}

/// A spec with every section filled.
pub fn full_spec(g: ReadoutGeometry, dark_log2: u8, flat_log2: u8) -> OwnedSpec {
    OwnedSpec {
        geometry: g,
        saturation_adu: 0xFFF0 - u16::from(dark_log2) - 16 * u16::from(flat_log2),
        gains: gains(&g),
        column_bias: Some(column_bias(&g)),
        dark: Some((dark_log2, dark_tiles(&g, dark_log2))),
        flat: Some((flat_log2, flat_tiles(&g, flat_log2))),
        hot_ref_k: Kelvin::from_num(233.25),
        hot: hot_pixels(&g),
        telegraph: telegraph(&g),
        pixcorr: pixcorr_curves(),
        cti: Some(cti_coeffs(&g)),
        psf_model: Some(psf_model()),
        camera_model: Some(camera_model(&g)),
        dark_law: Some(dark_law()),
    }
}

/// CTI coefficients with distinct bit patterns per output (outputs past the geometry's 0).
pub fn cti_coeffs(g: &ReadoutGeometry) -> CtiCoeffs {
    let mut outputs = [CtiOutput::default(); 2];
    for (i, o) in outputs.iter_mut().enumerate().take(usize::from(g.outputs)) {
        *o = CtiOutput {
            parallel_px: U0F32::from_bits(0x0001_2345 + 0x1111 * i as u32),
            serial_px: U0F32::from_bits(0x0000_6789 + 0x2222 * i as u32),
        };
    }
    CtiCoeffs {
        reference_flux_e: 10_000,
        flux_offset_e: 345,
        alpha: U0F16::from_bits(0x8123),
        outputs,
    }
}

/// A degree-2 PSF model, a = 1.2 + 0.1 u - 0.05 v + 0.2 u^2 + 0.03 u v + 0.15 v^2 px
/// (positive over the field).
pub fn psf_model() -> PsfModel {
    let mut coeffs = [I16F16::ZERO; 10];
    for (c, v) in coeffs.iter_mut().zip([1.2, 0.1, -0.05, 0.2, 0.03, 0.15]) {
        *c = I16F16::from_num(v);
    }
    PsfModel {
        degree: 2,
        scatter_px: U8F8::from_bits(0x0013),
        stars: 321,
        coeffs,
    }
}

/// A distorted camera with lateral colour whose field is the active area (focal length four
/// times the width, principal point off centre).
pub fn camera_model(g: &ReadoutGeometry) -> startrack_core::attitude::Camera {
    let w = f64::from(g.active_cols);
    startrack_core::attitude::Camera {
        k1: -0.0625,
        k2: 0.25,
        p1: 1.5e-4,
        p2: -2.5e-4,
        colour_scale_per_mag: 3e-4,
        colour_ref_bv_mag: 0.625,
        ..startrack_core::attitude::Camera::pinhole(
            4.0 * w,
            [0.5 * w + 0.25, 0.5 * f64::from(g.active_rows) - 0.75],
        )
    }
}

/// A dark law with a distinct bit pattern in every field: 12.3456 e-/px/s at 253.75 K,
/// doubling 6.5 K, band 0.75 to 1.5.
pub fn dark_law() -> startrack_core::table::DarkLaw {
    startrack_core::table::DarkLaw {
        rate_e_per_s: ERatePerS::from_bits(0x000C_5876),
        reference_k: Kelvin::from_num(253.75),
        doubling_k: U8F8::from_bits(0x0680),
        band_low: U8F8::from_bits(0x00C0),
        band_high: U8F8::from_bits(0x0180),
    }
}

/// Two small curves (5 and 7 knots), encoded from the documented layout by hand.
pub fn pixcorr_curves() -> Vec<Vec<u8>> {
    vec![
        enc_curve(
            CogPower::One,
            5,
            PixCorrBackground::Given,
            0x0180,
            0x7000,
            &[0, -300, -520, -610, -400],
        ),
        enc_curve(
            CogPower::Two,
            7,
            PixCorrBackground::PerimeterMedian,
            0x0240,
            0x6800,
            &[0, 100, 250, 380, 420, 400, 330],
        ),
    ]
}

/// One curve: the 8-byte header (power, box, background, knot count, a U8F8 bits, m_max
/// U0F16 bits) and its I1F15 knot bits.
pub fn enc_curve(
    power: CogPower,
    box_side: u8,
    bg: PixCorrBackground,
    a_bits: u16,
    m_max_bits: u16,
    knots: &[i16],
) -> Vec<u8> {
    let p = if power == CogPower::One { 1 } else { 2 };
    let mut v = vec![p, box_side, bg as u8, knots.len() as u8];
    v.extend_from_slice(&a_bits.to_le_bytes());
    v.extend_from_slice(&m_max_bits.to_le_bytes());
    v.extend(knots.iter().flat_map(|k| k.to_le_bytes()));
    v
}

/// A spec with only the required gains.
pub fn gains_only(g: ReadoutGeometry) -> OwnedSpec {
    OwnedSpec {
        geometry: g,
        saturation_adu: 60_000,
        gains: gains(&g),
        column_bias: None,
        dark: None,
        flat: None,
        hot_ref_k: Kelvin::from_num(240),
        hot: Vec::new(),
        telegraph: Vec::new(),
        pixcorr: Vec::new(),
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    }
}
