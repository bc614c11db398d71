//! The simulated sensor's true calibration, encoded as a core calibration table: what a
//! perfect ground calibration would measure (quantised to the table's formats).

use super::render::Simulator;
use fixed::types::U8F8;
use startrack_core::geometry::{ReadoutGeometry, Segment};
use startrack_core::table::{
    HotPixel, HotPolicy, MapHeader, MapSpec, TableSpec, WriteError, write_table,
};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, FlatInv, GainEPerAdu, Kelvin};

/// Which of the sensor's corrections the table carries; the others are left out ("no
/// correction"), which is how the demo shows what each one is worth.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TruthSections {
    /// Per-column bias.
    pub column_bias: bool,
    /// Relative dark map.
    pub dark: bool,
    /// Inverse flat map.
    pub flat: bool,
}

impl TruthSections {
    /// Every correction.
    pub const ALL: Self = Self {
        column_bias: true,
        dark: true,
        flat: true,
    };
    /// Only the gains (bias from the over-scan and a uniform dark still apply).
    pub const NONE: Self = Self {
        column_bias: false,
        dark: false,
        flat: false,
    };
}

/// The mean of `f(x, y)` over each `2^tile_log2` square tile of `g`'s active area, row-major
/// (the tiles of [`MapHeader::for_area`]), the last row and column of tiles clipped at the
/// area's edges; a tile with no pixel (an empty area) gives 0. `tile_log2 = 0` gives `f` per
/// pixel; above 16 it is taken as 16, as the table's header does. Cost: one call of `f` per
/// active pixel.
pub fn tile_means(g: &ReadoutGeometry, tile_log2: u8, f: &dyn Fn(usize, usize) -> f64) -> Vec<f64> {
    let header = MapHeader::for_area(g.active_cols, g.active_rows, tile_log2);
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    let t = 1usize << header.tile_log2;
    let (tx, ty) = (usize::from(header.tiles_x), usize::from(header.tiles_y));
    (0..ty * tx)
        .map(|i| {
            let (x0, y0) = ((i % tx) * t, (i / tx) * t);
            let (x1, y1) = ((x0 + t).min(cols), (y0 + t).min(rows));
            let sum: f64 = (y0..y1)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .sum();
            sum / ((x1 - x0) * (y1 - y0)).max(1) as f64
        })
        .collect()
}

/// Writes `spec` into a buffer of exactly its encoded length.
fn encode(spec: &TableSpec<'_>) -> Result<Vec<u8>, WriteError> {
    let mut buf = vec![0u8; spec.encoded_len()];
    let n = write_table(spec, &mut buf)?;
    buf.truncate(n);
    Ok(buf)
}

impl Simulator {
    /// Each output's true gain, in the table's format (saturating).
    fn true_gains(&self) -> Vec<GainEPerAdu> {
        let p = &self.params;
        (0..p.geometry.outputs)
            .map(|o| GainEPerAdu::saturating_from_num(p.gain_e_per_adu[usize::from(o)]))
            .collect()
    }

    /// The true per-column bias of a whole raw line, in the table's format (saturating); 0 on
    /// the over-scan, which is the bias reference.
    fn true_column_bias(&self) -> Vec<ColumnBiasAdu> {
        let g = self.params.geometry;
        (0..g.line_len())
            .map(|c| match g.segment(c) {
                Some(Segment::OverScan) => ColumnBiasAdu::ZERO,
                _ => ColumnBiasAdu::saturating_from_num(self.column_bias_adu(c)),
            })
            .collect()
    }

    /// The mean relative dark of the covered pixels: the dark map is normalised to it.
    pub fn covered_dark_mean(&self) -> f64 {
        let g = &self.params.geometry;
        let (mut sum, mut n) = (0.0, 0usize);
        for line in 0..usize::from(g.lines) {
            for (s, e) in g.covered_cols() {
                for col in s..e {
                    sum += self.dark_rel(col, line);
                    n += 1;
                }
            }
        }
        if n == 0 { 1.0 } else { sum / n as f64 }
    }

    /// Encodes the sensor's true maps as a calibration table with per-pixel maps.
    pub fn truth_table(&self, sections: TruthSections) -> Result<Vec<u8>, WriteError> {
        self.truth_table_tiled(sections, 0)
    }

    /// Encodes the sensor's true maps as a calibration table, each map averaged over square
    /// tiles of `2^tile_log2` pixels (0: per pixel). Tiles lose the pixel-to-pixel part of
    /// DSNU and PRNU: they are the reduced form for internal flash, not a full correction.
    pub fn truth_table_tiled(
        &self,
        sections: TruthSections,
        tile_log2: u8,
    ) -> Result<Vec<u8>, WriteError> {
        self.truth_table_with_curves(sections, tile_log2, &[])
    }

    /// [`Self::truth_table_tiled`] with a pixel-phase section holding `curves` (none: no
    /// section).
    pub fn truth_table_with_curves(
        &self,
        sections: TruthSections,
        tile_log2: u8,
        curves: &[crate::pixcorr::Curve],
    ) -> Result<Vec<u8>, WriteError> {
        let g = self.params.geometry;
        let (gains, column_bias) = (self.true_gains(), self.true_column_bias());
        let norm = self.covered_dark_mean();
        let dark: Vec<DarkRel> = if sections.dark {
            tile_means(&g, tile_log2, &|x, y| {
                self.dark_rel(g.raw_col_of_x(x), y) / norm
            })
            .into_iter()
            .map(DarkRel::saturating_from_num)
            .collect()
        } else {
            Vec::new()
        };
        let flat: Vec<FlatInv> = if sections.flat {
            tile_means(&g, tile_log2, &|x, y| 1.0 / self.flat(x, y))
                .into_iter()
                .map(|v| FlatInv::saturating_from_num(v).max(FlatInv::DELTA))
                .collect()
        } else {
            Vec::new()
        };
        let (hot, telegraph) = (self.hot_pixels_truth(), self.telegraph_truth());
        let spec = TableSpec {
            geometry: g,
            saturation_adu: self.saturation_level_adu(),
            gains: &gains,
            column_bias: sections.column_bias.then_some(&column_bias[..]),
            dark_rel: sections.dark.then_some(MapSpec {
                tile_log2,
                tiles: &dark,
            }),
            flat_inv: sections.flat.then_some(MapSpec {
                tile_log2,
                tiles: &flat,
            }),
            hot_ref_k: self.hot_reference_k(),
            hot: &hot,
            telegraph: &telegraph,
            cti: None,
            psf_model: None,
            camera_model: None,
            dark_law: None,
        };
        if curves.is_empty() {
            encode(&spec)
        } else {
            crate::pixcorr::write_table_with_curves(&spec, curves)
        }
    }

    /// Reference temperature of the hot-pixel rates (293 K when hot pixels are off).
    pub fn hot_reference_k(&self) -> Kelvin {
        self.params.effects.hot.map_or(Kelvin::from_num(293), |h| {
            Kelvin::saturating_from_num(h.reference_k)
        })
    }

    /// `f(x, y, raw column)` over the active area row by row, its `Some`s in that order
    /// (sorted by (y, x)). Cost: one call of `f` per active pixel.
    fn scan_active<T>(&self, f: impl Fn(u16, u16, usize) -> Option<T>) -> Vec<T> {
        let g = self.params.geometry;
        (0..g.active_rows)
            .flat_map(|y| (0..g.active_cols).map(move |x| (x, y)))
            .filter_map(|(x, y)| f(x, y, g.raw_col_of_x(usize::from(x))))
            .collect()
    }

    /// The true hot pixels of the active area, sorted by (y, x), with the `Correct` policy
    /// (empty when hot pixels are off). Scans every active pixel once.
    pub fn hot_pixels_truth(&self) -> Vec<HotPixel> {
        let Some(h) = self.params.effects.hot else {
            return Vec::new();
        };
        self.scan_active(|x, y, col| {
            self.hot_rate_e_per_s(col, usize::from(y))
                .map(|rate| HotPixel {
                    x,
                    y,
                    rate_e_per_s: ERatePerS::saturating_from_num(rate),
                    doubling_k: U8F8::saturating_from_num(h.doubling_k),
                    policy: HotPolicy::Correct,
                })
        })
    }

    /// The true telegraph pixels of the active area (x, y), sorted by (y, x) (empty when
    /// telegraph pixels are off).
    pub fn telegraph_truth(&self) -> Vec<(u16, u16)> {
        if self.params.effects.telegraph.is_none() {
            return Vec::new();
        }
        self.scan_active(|x, y, col| self.telegraph_step_e(col, usize::from(y)).map(|_| (x, y)))
    }
}

impl Simulator {
    /// A per-pixel calibration table with the given maps (active area, row-major) instead of
    /// the truth: e.g. the maps of [`super::measured`]. `None` leaves a map out ("no
    /// correction"); gains and, when `column_bias`, the true column bias are included.
    pub fn table_from_maps(
        &self,
        column_bias: bool,
        dark_rel: Option<&[f64]>,
        flat_inv: Option<&[f64]>,
    ) -> Result<Vec<u8>, WriteError> {
        let g = self.params.geometry;
        let (gains, bias) = (self.true_gains(), self.true_column_bias());
        let dark: Option<Vec<DarkRel>> =
            dark_rel.map(|m| m.iter().map(|v| DarkRel::saturating_from_num(*v)).collect());
        let flat: Option<Vec<FlatInv>> = flat_inv.map(|m| {
            m.iter()
                .map(|v| FlatInv::saturating_from_num(*v).max(FlatInv::DELTA))
                .collect()
        });
        let spec = TableSpec {
            geometry: g,
            saturation_adu: self.saturation_level_adu(),
            gains: &gains,
            column_bias: column_bias.then_some(&bias[..]),
            dark_rel: dark.as_deref().map(|tiles| MapSpec {
                tile_log2: 0,
                tiles,
            }),
            flat_inv: flat.as_deref().map(|tiles| MapSpec {
                tile_log2: 0,
                tiles,
            }),
            hot_ref_k: Kelvin::from_num(293),
            hot: &[],
            telegraph: &[],
            cti: None,
            psf_model: None,
            camera_model: None,
            dark_law: None,
        };
        encode(&spec)
    }
}
