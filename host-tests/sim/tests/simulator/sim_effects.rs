//! The simulator's optional physics (`sim::effects`) and measured maps (`sim::measured`):
//! each effect does what it says, and a window rendered alone equals the same pixels of
//! full-frame lines, bit for bit, with no effect and with every effect on.
//!
//! Statistical checks state their tolerance from the number of draws: a proportion q over n
//! draws within 5 binomial standard errors `sqrt(q (1 - q) / n)`; a noise RMS over n pixels
//! within 5 relative standard errors `1 / sqrt(2 n)`.

use startrack_core::window::Rect;
use startrack_sim::sim::effects::{
    CosmicRays, Cti, DarkLaw, Effects, HotPixels, PsfShape, TelegraphPixels,
};
use startrack_sim::sim::measured::MeasuredMap;
use startrack_sim::sim::{SensorParams, Simulator, Star};

fn all_effects() -> Effects {
    Effects {
        psf: PsfShape::Coma {
            length_px: 2.0,
            angle_rad: 0.7,
        },
        temperature_k: 300.0,
        dark_law: Some(DarkLaw {
            reference_k: 293.0,
            doubling_k: 6.5,
        }),
        hot: Some(HotPixels {
            fraction: 0.02,
            rate_min_e_per_s: 100.0,
            rate_max_e_per_s: 5000.0,
            reference_k: 293.0,
            doubling_k: 9.0,
            exposure_s: 0.5,
        }),
        telegraph: Some(TelegraphPixels {
            fraction: 0.02,
            amplitude_e: 300.0,
            p_high: 0.4,
        }),
        cosmics: Some(CosmicRays {
            rate_per_px: 0.01,
            mean_e: 5000.0,
        }),
        cti: Some(Cti {
            fraction: 0.05,
            trail_lines: 4,
            decay: 0.5,
        }),
        traps: None,
    }
}

fn star(x: f64, y: f64) -> Star {
    star_e(x, y, 80_000.0)
}

fn star_e(x: f64, y: f64, signal_e: f64) -> Star {
    Star {
        x_px: x,
        y_px: y,
        signal_e,
        a_px: 1.5,
    }
}

/// `rect` rendered alone equals the same pixels of whole rendered lines, bit for bit, and a
/// rerun gives the same samples; `what` names the case in a failure.
fn assert_window_equals_lines(sim: &Simulator, rect: Rect, what: &str) {
    let g = sim.params.geometry;
    let win = sim.render_window(rect);
    let mut line = vec![0u16; g.line_len()];
    for r in 0..rect.height {
        sim.render_line(usize::from(rect.y0 + r), &mut line);
        for c in 0..rect.width {
            let x = usize::from(rect.x0 + c);
            assert_eq!(
                win[usize::from(r * rect.width + c)],
                line[g.raw_col_of_x(x)],
                "{what} ({x}, {})",
                rect.y0 + r
            );
        }
    }
    assert_eq!(win, sim.render_window(rect), "{what}: rerun");
}

/// RMS of `m`'s values minus `truth(x, y)` over its region (row by row), and the number of
/// pixels.
fn rms_against_truth(
    m: &MeasuredMap,
    active_cols: usize,
    truth: impl Fn(usize, usize) -> f64,
) -> (f64, usize) {
    let r = m.region;
    let (mut sq, mut n) = (0.0, 0usize);
    for y in r.y0..r.y0 + r.height {
        for x in r.x0..r.x0 + r.width {
            let (x, y) = (usize::from(x), usize::from(y));
            sq += (m.values[y * active_cols + x] - truth(x, y)).powi(2);
            n += 1;
        }
    }
    ((sq / n as f64).sqrt(), n)
}

/// A noise RMS measured over `n` pixels is within 5 relative standard errors
/// `1 / sqrt(2 n)` of `expect`.
fn assert_rms_near(rms: f64, expect: f64, n: usize) {
    let tol = 5.0 / (2.0 * n as f64).sqrt();
    assert!(
        (rms / expect - 1.0).abs() < tol,
        "rms {rms} expected {expect}"
    );
}

#[test]
fn window_equals_full_frame_with_every_effect_on() {
    for psf in [
        PsfShape::Defocus {
            ring_radius_px: 2.5,
        },
        PsfShape::Coma {
            length_px: 2.0,
            angle_rad: 0.7,
        },
    ] {
        let params = SensorParams {
            effects: Effects {
                psf,
                ..all_effects()
            },
            ..SensorParams::default()
        };
        // Stars inside, on the edge and just outside the window; the window touches the
        // left edge of the active area (cosmic-ray neighbours in the covered columns).
        let sim = Simulator {
            frame: 7,
            ..Simulator::new(
                params,
                vec![star(6.3, 20.2), star(12.0, 14.5), star(3.0, 31.0)],
            )
        };
        let rect = Rect {
            x0: 0,
            y0: 12,
            width: 17,
            height: 16,
        };
        assert_window_equals_lines(&sim, rect, &format!("{psf:?}"));
    }
}

/// Moved here from a unit test of `sim/render.rs`, which repeated the check of
/// [`assert_window_equals_lines`].
#[test]
fn window_equals_full_lines() {
    let sim = Simulator::new(SensorParams::default(), vec![star_e(510.3, 20.7, 50_000.0)]);
    let rect = Rect {
        x0: 505,
        y0: 16,
        width: 11,
        height: 9,
    };
    assert_window_equals_lines(&sim, rect, "no effects");
    // Another frame gives other noise.
    let next = Simulator {
        frame: 1,
        ..sim.clone()
    };
    assert_ne!(sim.render_window(rect), next.render_window(rect));
}

#[test]
fn psf_shapes_keep_flux_and_photocentre() {
    for psf in [
        PsfShape::Gaussian,
        PsfShape::Defocus {
            ring_radius_px: 2.0,
        },
        PsfShape::Coma {
            length_px: 3.0,
            angle_rad: 0.4,
        },
    ] {
        let params = SensorParams {
            effects: Effects {
                psf,
                ..Effects::default()
            },
            ..SensorParams::default()
        };
        let s = star(100.3, 200.6);
        let sim = Simulator::new(params, vec![s]);
        let (mut sum, mut sx, mut sy, mut m3) = (0.0, 0.0, 0.0, 0.0);
        for y in 180..222 {
            for x in 80..122 {
                let e = sim.star_e(x, y);
                sum += e;
                sx += e * x as f64;
                sy += e * y as f64;
            }
        }
        let (cx, cy) = (sx / sum, sy / sum);
        for y in 180..222 {
            for x in 80..122 {
                m3 += sim.star_e(x, y) * (x as f64 - cx).powi(3);
            }
        }
        assert!((sum / s.signal_e - 1.0).abs() < 1e-9, "{psf:?} flux {sum}");
        assert!(
            (cx - s.x_px).abs() < 1e-6 && (cy - s.y_px).abs() < 1e-6,
            "{psf:?} ({cx}, {cy})"
        );
        let skew = m3 / sum;
        match psf {
            // The tail runs towards +x: the image is skewed that way.
            PsfShape::Coma { .. } => assert!(skew > 0.05, "{psf:?} skew {skew}"),
            // Symmetric images: only the pixel grid skews the sampled moments (~1e-5 px^3).
            _ => assert!(skew.abs() < 1e-3, "{psf:?} skew {skew}"),
        }
        if let PsfShape::Defocus { .. } = psf {
            // A donut: the centre pixel holds less than a pixel on the ring.
            assert!(sim.star_e(100, 201) < sim.star_e(102, 201));
        }
    }
}

#[test]
fn dark_and_hot_pixels_follow_their_own_temperature_laws() {
    let effects = |t: f64| Effects {
        temperature_k: t,
        ..all_effects()
    };
    let at = |t: f64| {
        Simulator::new(
            SensorParams {
                effects: effects(t),
                ..SensorParams::default()
            },
            Vec::new(),
        )
    };
    let (cold, warm) = (at(293.0), at(293.0 + 6.5));
    let (mut hot, mut normal, mut n) = (0usize, 0usize, 0usize);
    for line in 0..100 {
        for col in [10usize, 20, 500, 900] {
            n += 1;
            let rate = cold.hot_rate_e_per_s(col, line);
            let tele = cold.telegraph_e(col, line);
            let tele_w = warm.telegraph_e(col, line);
            // Regular dark doubles over its doubling temperature (6.5 K).
            let reg_c = cold.expected_dark_e(col, line) - cold.hot_dark_e(col, line) - tele;
            let reg_w = warm.expected_dark_e(col, line) - warm.hot_dark_e(col, line) - tele_w;
            assert!((reg_w / reg_c - 2.0).abs() < 1e-9 || reg_c == 0.0);
            match rate {
                Some(r) => {
                    hot += 1;
                    assert!((100.0..=5000.0).contains(&r));
                    // Hot pixels double over 9 K, not 6.5 K.
                    let ratio = warm.hot_dark_e(col, line) / cold.hot_dark_e(col, line);
                    assert!((ratio - 2f64.powf(6.5 / 9.0)).abs() < 1e-9, "{ratio}");
                    assert!((cold.hot_dark_e(col, line) - r * 0.5).abs() < 1e-9);
                }
                None => {
                    normal += 1;
                    assert_eq!(cold.hot_dark_e(col, line), 0.0);
                }
            }
        }
    }
    assert_eq!(hot + normal, n);
    let q = 0.02;
    let se = (q * (1.0 - q) / n as f64).sqrt();
    assert!((hot as f64 / n as f64 - q).abs() < 5.0 * se, "{hot} of {n}");
}

#[test]
fn telegraph_pixels_switch_between_two_levels() {
    let params = SensorParams {
        noise: false,
        dsnu: 0.0,
        column_bias_sigma_adu: 0.0,
        effects: Effects {
            telegraph: Some(TelegraphPixels {
                fraction: 0.05,
                amplitude_e: 300.0,
                p_high: 0.4,
            }),
            ..Effects::default()
        },
        ..SensorParams::default()
    };
    let sim = Simulator::new(params, Vec::new());
    let g = sim.params.geometry;
    // Find a telegraph pixel; its frames take exactly two values.
    let (col, line) = (0..200usize)
        .flat_map(|l| (0..64usize).map(move |x| (g.raw_col_of_x(x), l)))
        .find(|&(c, l)| sim.telegraph_step_e(c, l).is_some())
        .unwrap();
    let step = sim.telegraph_step_e(col, line).unwrap();
    assert!((150.0..=450.0).contains(&step));
    let frames = 2000;
    let mut levels = std::collections::BTreeSet::new();
    let mut high = 0;
    for f in 0..frames {
        let s = Simulator {
            frame: f,
            ..sim.clone()
        };
        levels.insert(s.raw_sample(col, line));
        if s.telegraph_e(col, line) > 0.0 {
            high += 1;
        }
    }
    assert_eq!(levels.len(), 2, "{levels:?}");
    let se = (0.4f64 * 0.6 / f64::from(frames)).sqrt();
    assert!((f64::from(high) / f64::from(frames) - 0.4).abs() < 5.0 * se);
}

#[test]
fn cosmic_rays_hit_at_their_rate_and_spread_to_neighbours() {
    let params = SensorParams {
        effects: Effects {
            cosmics: Some(CosmicRays {
                rate_per_px: 0.002,
                mean_e: 5000.0,
            }),
            ..Effects::default()
        },
        ..SensorParams::default()
    };
    let sim = Simulator::new(params, Vec::new());
    let g = sim.params.geometry;
    let (mut hits, mut n) = (0usize, 0usize);
    for line in 1..300 {
        for x in 1..300 {
            let col = g.raw_col_of_x(x);
            n += 1;
            let h = sim.cosmic_hit_e(col, line);
            if h > 0.0 {
                hits += 1;
                assert!((2500.0..=7500.0).contains(&h));
                assert!(sim.cosmic_e(col, line) >= 0.6 * h);
                assert!(sim.cosmic_e(col + 1, line) >= 0.1 * h);
                assert!(sim.cosmic_e(col, line + 1) >= 0.1 * h);
            }
        }
    }
    let q = 0.002;
    let se = (q * (1.0 - q) / n as f64).sqrt();
    assert!(
        (hits as f64 / n as f64 - q).abs() < 5.0 * se,
        "{hits} of {n}"
    );
    // Another frame, other hits.
    let next = Simulator {
        frame: 1,
        ..sim.clone()
    };
    let differ = (1..300).any(|l| sim.cosmic_hit_e(100, l) != next.cosmic_hit_e(100, l));
    assert!(differ);
}

#[test]
fn cti_trails_follow_the_readout_and_conserve_charge() {
    let base = SensorParams {
        noise: false,
        dark_mean_e: 0.0,
        prnu: 0.0,
        ..SensorParams::default()
    };
    let cti = Cti {
        fraction: 0.1,
        trail_lines: 5,
        decay: 0.6,
    };
    let s = star(300.0, 300.0);
    let plain = Simulator::new(base.clone(), vec![s]);
    let trailed = Simulator::new(
        SensorParams {
            effects: Effects {
                cti: Some(cti),
                ..Effects::default()
            },
            ..base
        },
        vec![s],
    );
    let g = base.geometry;
    let col = g.raw_col_of_x(300);
    let column =
        |sim: &Simulator| -> Vec<f64> { (280..330).map(|l| sim.expected_e(col, l).0).collect() };
    let (a, b) = (column(&plain), column(&trailed));
    let (sa, sb): (f64, f64) = (a.iter().sum(), b.iter().sum());
    assert!((sa - sb).abs() < 1e-9 * sa, "{sa} {sb}");
    let centroid = |v: &[f64]| {
        v.iter().enumerate().map(|(i, e)| i as f64 * e).sum::<f64>() / v.iter().sum::<f64>()
    };
    // The trail is behind the star in readout order (higher lines): the photocentre moves
    // by f x mean release delay.
    let w = cti.weights();
    let delay: f64 = w.iter().enumerate().map(|(k, w)| (k + 1) as f64 * w).sum();
    let shift = centroid(&b) - centroid(&a);
    assert!((shift - cti.fraction * delay).abs() < 1e-9, "{shift}");
    // Lines before the star lose nothing to later ones.
    assert!((a[0] - b[0] / (1.0 - cti.fraction)).abs() < 1e-12 * a[0].max(1.0) || a[0] < 1e-30);
}

#[test]
fn measured_dark_map_has_the_noise_of_its_frames() {
    let params = SensorParams {
        column_bias_sigma_adu: 0.0,
        ..SensorParams::default()
    };
    let sim = Simulator::new(params, Vec::new());
    let g = sim.params.geometry;
    let region = Rect {
        x0: 200,
        y0: 300,
        width: 48,
        height: 48,
    };
    let frames = 16;
    let m = sim
        .measure_dark_map(frames, 1000, region, 0..usize::from(g.lines))
        .unwrap();
    let norm = sim.covered_dark_mean();
    let (rms, n) = rms_against_truth(&m, usize::from(g.active_cols), |x, y| {
        sim.dark_rel(g.raw_col_of_x(x), y) / norm
    });
    // Dark shot noise + read noise per frame, and ADC rounding (gain^2 / 12), over N frames,
    // relative to the mean dark.
    let d = sim.params.dark_mean_e;
    let gain = 1.5f64;
    let expect = ((d + 25.0 + gain * gain / 12.0) / f64::from(frames)).sqrt() / d;
    assert_rms_near(rms, expect, n);
    // Outside the region: no correction.
    assert_eq!(m.values[0], 1.0);
}

#[test]
fn measured_flat_map_recovers_the_prnu() {
    let params = SensorParams {
        prnu: 0.02,
        ..SensorParams::default()
    };
    let sim = Simulator::new(params, Vec::new());
    let g = sim.params.geometry;
    let region = Rect {
        x0: 600,
        y0: 100,
        width: 40,
        height: 40,
    };
    let (frames, level) = (8, 20_000.0);
    let m = sim.measure_flat_inv_map(frames, 50, level, region).unwrap();
    let mut mean_flat = 0.0;
    for y in 100..140 {
        for x in 600..640 {
            mean_flat += sim.flat(x, y);
        }
    }
    mean_flat /= 1600.0;
    let (rms, n) = rms_against_truth(&m, usize::from(g.active_cols), |x, y| {
        mean_flat / sim.flat(x, y)
    });
    // Photon + read noise over N frames at the level; far below the 2 % PRNU.
    let expect = ((level + 25.0 + 250.0) / f64::from(frames)).sqrt() / level;
    eprintln!("flat map rms {rms} expected {expect}");
    assert_rms_near(rms, expect, n);
    assert!(rms < 0.02 / 5.0);
}

#[test]
fn truth_table_hot_pixels_are_corrected_by_the_core() {
    use startrack_core::calib::{
        DarkScaleEstimator, FrameCalibration, FrameConditions, LineLevels, PixelFlags,
    };
    use startrack_core::table::CalibTable;
    use startrack_core::units::{Electrons, Kelvin};
    use startrack_sim::sim::truth::TruthSections;
    let params = SensorParams {
        noise: false,
        prnu: 0.0,
        column_bias_sigma_adu: 0.0,
        effects: Effects {
            temperature_k: 301.0,
            hot: Some(HotPixels {
                fraction: 0.01,
                rate_min_e_per_s: 200.0,
                rate_max_e_per_s: 20_000.0,
                reference_k: 293.0,
                doubling_k: 9.0,
                exposure_s: 0.5,
            }),
            ..Effects::default()
        },
        ..SensorParams::default()
    };
    let sim = Simulator::new(params, Vec::new());
    let g = sim.params.geometry;
    let bytes = sim.truth_table(TruthSections::ALL).unwrap();
    let table = CalibTable::parse(&bytes).unwrap();
    assert_eq!(table.hot_pixels().len(), sim.hot_pixels_truth().len());
    let mut line = vec![0u16; g.line_len()];
    let mut est = DarkScaleEstimator::new();
    for y in 0..usize::from(g.lines) {
        sim.render_reference_line(y, &mut line);
        let lv = LineLevels::measure(&g, &line).unwrap();
        est.add_line(&table, &line, &lv).unwrap();
    }
    let cal = FrameCalibration::new(
        table,
        FrameConditions {
            dark_scale_e: est.estimate().unwrap(),
            exposure_ms: 500,
            temperature_k: Kelvin::from_num(301),
        },
    );
    let rect = Rect {
        x0: 300,
        y0: 300,
        width: 64,
        height: 64,
    };
    let raw = sim.render_window(rect);
    let levels: Vec<LineLevels> = (300..364)
        .map(|y| {
            sim.render_reference_line(y, &mut line);
            LineLevels::measure(&g, &line).unwrap()
        })
        .collect();
    let mut e = vec![Electrons::ZERO; rect.len()];
    let mut f = vec![PixelFlags::empty(); rect.len()];
    cal.calibrate_window(rect, &raw, &levels, &mut e, &mut f)
        .unwrap();
    let hot_in_window = sim
        .hot_pixels_truth()
        .iter()
        .filter(|h| rect.contains(h.x, h.y))
        .count();
    assert!(hot_in_window > 10, "{hot_in_window}");
    // Noise-free: every pixel, hot or not, calibrates to ~0 e-. The bound: ADC rounding
    // (gain / 2 = 0.8 e-), the dark map's 1/64 step x 250 e- / 2 (2 e-), the rate's U16F16
    // and the doubling's U8F8 rounding (1/512 K over 9 K: 0.05 % of up to 15 ke-, 8 e-).
    for v in &e {
        assert!(v.to_num::<f64>().abs() < 11.0, "{v}");
    }
}
