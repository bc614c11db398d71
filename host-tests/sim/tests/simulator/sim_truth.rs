//! The simulator's truth tables: per pixel they reproduce the sensor's maps, tiled they are
//! tile means and fit the firmware's 192 KB table limit.

use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::CalibTable;
use startrack_sim::sim::truth::{TruthSections, tile_means};
use startrack_sim::sim::{SensorParams, Simulator};

#[test]
fn tiled_table_fits_calib_sector_and_holds_tile_means() {
    let sim = Simulator::new(SensorParams::default(), Vec::new());
    let bytes = sim.truth_table_tiled(TruthSections::ALL, 3).unwrap();
    assert!(bytes.len() <= 128 * 1024, "{} bytes", bytes.len());
    let t = CalibTable::parse(&bytes).unwrap();
    let g = sim.params.geometry;
    let norm = sim.covered_dark_mean();
    for (tx, ty) in [(0usize, 0usize), (17, 90), (127, 127)] {
        let (x0, y0) = (tx * 8, ty * 8);
        let mut dark = 0.0;
        let mut inv = 0.0;
        for y in y0..y0 + 8 {
            for x in x0..x0 + 8 {
                dark += sim.dark_rel(g.raw_col_of_x(x), y) / norm / 64.0;
                inv += 1.0 / sim.flat(x, y) / 64.0;
            }
        }
        // Every pixel of the tile reads the tile's mean, to the map's resolution.
        for (x, y) in [(x0, y0), (x0 + 7, y0 + 7)] {
            let (x, y) = (x as u16, y as u16);
            assert!((t.dark_rel(x, y).to_num::<f64>() - dark).abs() <= 1.0 / 128.0);
            assert!((t.flat_inv(x, y).to_num::<f64>() - inv).abs() <= 1.0 / 32768.0);
        }
    }
}

#[test]
fn per_pixel_table_reproduces_the_maps() {
    let sim = Simulator::new(SensorParams::default(), Vec::new());
    let bytes = sim.truth_table(TruthSections::ALL).unwrap();
    let t = CalibTable::parse(&bytes).unwrap();
    let g = sim.params.geometry;
    let norm = sim.covered_dark_mean();
    for (x, y) in [(0usize, 0usize), (511, 3), (512, 1000), (1023, 1023)] {
        let want_dark = sim.dark_rel(g.raw_col_of_x(x), y) / norm;
        let (xs, ys) = (x as u16, y as u16);
        assert!((t.dark_rel(xs, ys).to_num::<f64>() - want_dark).abs() <= 1.0 / 128.0);
        assert!((t.flat_inv(xs, ys).to_num::<f64>() - 1.0 / sim.flat(x, y)).abs() <= 1.0 / 32768.0);
        let col = g.raw_col_of_x(x);
        assert!(
            (t.column_bias(col).to_num::<f64>() - sim.column_bias_adu(col)).abs() <= 1.0 / 32.0
        );
    }
}

/// `tile_means` on an area its tiles do not divide: each tile is the mean over its own
/// pixels, the last column and row of tiles clipped at the edges; `tile_log2` 0 is `f` per
/// pixel, and an oversized one is one tile, the area's mean, not a panic. Expected values
/// from the closed form: the mean of `x + 100 y` over `x0..x1` x `y0..y1` is
/// `(x0 + x1 - 1) / 2 + 100 (y0 + y1 - 1) / 2`.
#[test]
fn tile_means_clip_the_last_tiles_at_the_area_edges() {
    let g = ReadoutGeometry {
        active_cols: 20,
        active_rows: 11,
        ..SensorParams::default().geometry
    };
    let f = |x: usize, y: usize| (x + 100 * y) as f64;
    let mean = |x0: usize, x1: usize, y0: usize, y1: usize| {
        (x0 + x1 - 1) as f64 / 2.0 + 100.0 * (y0 + y1 - 1) as f64 / 2.0
    };
    let tiles = tile_means(&g, 3, &f);
    assert_eq!(tiles.len(), 3 * 2);
    for (i, v) in tiles.iter().enumerate() {
        let (x0, y0) = (8 * (i % 3), 8 * (i / 3));
        let expect = mean(x0, (x0 + 8).min(20), y0, (y0 + 8).min(11));
        assert!((v - expect).abs() < 1e-9, "tile {i}: {v} expected {expect}");
    }
    let per_px = tile_means(&g, 0, &f);
    assert_eq!(per_px.len(), 20 * 11);
    assert_eq!(per_px[20 * 7 + 13], f(13, 7));
    let one = tile_means(&g, 200, &f);
    assert_eq!(one.len(), 1);
    assert!((one[0] - mean(0, 20, 0, 11)).abs() < 1e-9, "{one:?}");
}
