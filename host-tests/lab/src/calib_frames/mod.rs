//! Calibration from raw lab frames: `startrack calib frames` turns bias frames, flat pairs and
//! darks at several exposures and temperatures (raw CCD47-20 readouts in FITS, sorted by
//! `IMAGETYP`, `EXPTIME`, `CCDTEMP`, `DATE-OBS`) into a calibration table and a report.
//!
//! One stage per file, in the order the frames are read:
//! - [`read`]: headers, sorting, flat pairs, and every bad input as one line naming the file;
//! - [`bias`]: master bias and the column bias against each line's over-scan;
//! - [`ptc`]: gain and read noise per output by photon transfer, the full well (where the
//!   mean stops rising) and EMVA 1288's linearity error;
//! - [`dark`]: the relative dark map normalised by the core's covered-pixel estimator, and the
//!   hot pixels with their own rate and doubling temperature;
//! - [`flat`]: the flat field per output;
//! - [`rts`]: telegraph pixels from the longest time-ordered dark series;
//! - [`eper`]: charge-transfer inefficiency by the extended pixel edge response of the flats
//!   (the trap law, and from it the table's CTI coefficients);
//! - [`report`]: `report.json`, `hot.csv`, `rts.csv`, the maps as FITS and the PNG figures;
//! - [`labset`]: a simulated lab set with the simulator's truth, for the tests and the docs.
//!
//! Memory is bounded whatever the number of frames: each file is read once, whole, and
//! folded into running sums (a few maps of the readout, one per dark temperature); one frame
//! (2.2 MB for the CCD47-20) is held at a time. The table is encoded by `calib build`'s
//! writer ([`crate::table_build::encode`]). Cost: reading each file plus a few
//! operations per sample; the darks add one median of the over-scan and one sort of the
//! covered pixels per line (the core's own level and dark-scale code).

pub mod bias;
pub mod dark;
pub mod eper;
pub mod flat;
pub mod labset;
pub mod ptc;
pub mod read;
pub mod report;
pub mod rts;

pub use read::{FrameInfo, FrameKind, FramesError, Grouping, Inventory};

use crate::LabError;
use crate::table_build::{column_bias_from_map, encode, flat_from_map};
use dark::HotFit;
use fixed::types::U8F8;
use ptc::PairPoint;
use startrack_core::geometry::{Output, ReadoutGeometry, Segment};
use startrack_core::table::{CalibTable, DarkLaw, HotPixel, HotPolicy, MapSpec, TableSpec};
use startrack_core::units::{ColumnBiasAdu, DarkRel, ERatePerS, GainEPerAdu, Kelvin};
use startrack_sim::fits::MapF32;
use std::path::PathBuf;

/// Share of a flat's active pixels at the ADC's top above which the flat is saturated: it
/// serves the full well and the linearity error only (not the gain, the flat field or EPER).
pub const SATURATED_SHARE: f64 = 0.001;

/// A saturated flat is refused when a flat of equal or longer exposure has a share of pixels
/// at the ADC's top smaller by more than this: once a pixel saturates it stays saturated at
/// longer exposures. Which pixels saturate is set mostly by their fixed response (PRNU, 2 %
/// of the signal against a shot noise of 0.3 % near full well), so two flats of one exposure
/// share far less than this margin's worth of chance: only a changed lamp or a broken frame
/// passes it.
pub const SATURATED_SHARE_DROP: f64 = 0.01;

/// Hot pixels with a rate above this at 293 K are excluded rather than corrected (`calib
/// build`'s default, 10 000 e- in 1 s).
pub const HOT_EXCLUDE_ABOVE_E_PER_S: f64 = 10_000.0;

/// Everything measured from a lab set.
#[derive(Clone, Debug)]
pub struct Products {
    /// Readout geometry.
    pub geometry: ReadoutGeometry,
    /// Gain per output, e-/ADU.
    pub gain_e_per_adu: Vec<f64>,
    /// Read noise per output, e- rms.
    pub read_noise_e: Vec<f64>,
    /// Bias-pair variance per output (read noise and rounding), ADU^2.
    pub bias_var_adu2: Vec<f64>,
    /// Full well per output, e- through the gain: where the flats' mean stops rising (`None`
    /// when no flat pair reaches the plateau).
    pub full_well_e: Vec<Option<f64>>,
    /// The same, mean signal above bias, ADU.
    pub full_well_adu: Vec<Option<f64>>,
    /// EMVA 1288 linearity error per output, percent, over 5 to 95 % of the full well
    /// (`None` without a full well or with fewer than 3 pairs in that range).
    pub nonlinearity_pct: Vec<Option<f64>>,
    /// EXPTIME of every flat in the flat field and EPER (the pairs of the linear range), s.
    pub flat_field_exposures_s: Vec<f64>,
    /// Photon transfer points (every flat pair on every output).
    pub ptc: Vec<PairPoint>,
    /// Master bias, ADU, full readout.
    pub master_bias: MapF32,
    /// Column bias per raw column, as the table stores it.
    pub column_bias: Vec<ColumnBiasAdu>,
    /// Relative dark, full readout (the core's covered dark scale = 1).
    pub dark_rel: MapF32,
    /// The covered pixels' dark rate per temperature: (K, e-/s).
    pub covered_rates: Vec<(f64, f64)>,
    /// The covered pixels' dark law fitted over [`Self::covered_rates`] (`None`: darks at
    /// fewer than two temperatures, or a rate that does not rise).
    pub covered_dark_law: Option<dark::CoveredLaw>,
    /// Hot pixels with their laws (raw coordinates).
    pub hot: Vec<HotFit>,
    /// Hot candidates without a usable temperature law.
    pub hot_unfitted: usize,
    /// Flat field, active area, each output's mean 1.
    pub flat: MapF32,
    /// Telegraph pixels (raw column, raw line).
    pub rts: Vec<(usize, usize)>,
    /// The series they come from: (EXPTIME s, CCDTEMP K, frames); `None` without one.
    pub rts_series: Option<(f64, f64, u32)>,
    /// Frames read: bias, flats, darks.
    pub frames: (usize, usize, usize),
    /// The trap law measured by EPER on the flats (`None` without enough extra lines or
    /// signal levels).
    pub eper: Option<eper::EperResult>,
    /// What was done with what, one line each.
    pub notes: Vec<String>,
    /// Each group of frames found and what it was used for, one line each.
    pub groups: Vec<String>,
}

/// A table with `gains` and the column bias only, for the core's level and dark-scale code.
fn level_table(
    g: &ReadoutGeometry,
    gains: &[f64],
    column_bias: &[ColumnBiasAdu],
) -> Result<Vec<u8>, FramesError> {
    let gains: Vec<GainEPerAdu> = crate::table_build::args::encode_gains(gains)
        .map_err(|e| FramesError::Missing(e.to_string()))?;
    let spec = TableSpec {
        geometry: *g,
        saturation_adu: u16::MAX,
        gains: &gains,
        column_bias: Some(column_bias),
        dark_rel: None,
        flat_inv: None,
        hot_ref_k: Kelvin::from_num(293),
        hot: &[],
        telegraph: &[],
        cti: None,
        psf_model: None,
        camera_model: None,
        dark_law: None,
    };
    encode(&spec, &[]).map_err(|e| FramesError::Missing(e.to_string()))
}

fn table_err(e: impl std::fmt::Display) -> FramesError {
    FramesError::Missing(format!("internal table: {e}"))
}

/// The dark group with the most frames (the earliest of equals), and its count.
fn longest_series(groups: &[read::DarkGroup]) -> Option<(usize, u32)> {
    groups
        .iter()
        .enumerate()
        .rev()
        .max_by_key(|(_, d)| d.frames)
        .map(|(i, d)| (i, d.frames as u32))
}

/// Reads every frame of `paths` once and measures every product for geometry `g` with the
/// default grouping; `tick` is called after each file (a progress bar).
pub fn calibrate(
    paths: &[PathBuf],
    g: &ReadoutGeometry,
    tick: &dyn Fn(),
) -> Result<Products, FramesError> {
    calibrate_with(paths, g, &Grouping::default(), tick)
}

/// [`calibrate`] with the frames grouped by `grouping`.
pub fn calibrate_with(
    paths: &[PathBuf],
    g: &ReadoutGeometry,
    grouping: &Grouping,
    tick: &dyn Fn(),
) -> Result<Products, FramesError> {
    let inv = read::inventory_with(paths, g, grouping)?;
    let mut notes = Vec::new();
    let mut groups = Vec::new();
    let outputs = usize::from(g.outputs);
    // Bias: master bias and the pairs' variance.
    let mut bias = bias::BiasAccum::new(g);
    let mut prev = None;
    let mut bias_var = vec![(0.0f64, 0usize); outputs];
    for info in &inv.bias {
        let f = read::read_frame(info, g)?;
        bias.add(&f);
        match prev.take() {
            None => prev = Some(f),
            Some(a) => {
                for (o, slot) in bias_var.iter_mut().enumerate() {
                    let p = ptc::pair_point(&a, &f, g, Output(o as u8), &[], 0.0);
                    slot.0 += p.var_adu2;
                    slot.1 += 1;
                }
            }
        }
        tick();
    }
    let master_bias = bias.master();
    let (column_bias, clamped) = column_bias_from_map(g, &master_bias);
    let cb_adu: Vec<f64> = column_bias.iter().map(|c| c.to_num::<f64>()).collect();
    let bias_var_adu2: Vec<f64> = bias_var
        .iter()
        .map(|(s, n)| s / (*n).max(1) as f64)
        .collect();
    notes.push(format!(
        "column bias from {} bias frames ({} pairs for the read noise){}",
        bias.frames(),
        bias_var.first().map_or(0, |b| b.1),
        if clamped > 0 {
            format!(", {clamped} columns clamped")
        } else {
            String::new()
        }
    ));
    // Flats: photon transfer points, then the sums of the flat.
    let gain1 = vec![1.0; outputs];
    let lt = level_table(g, &gain1, &column_bias)?;
    let t1 = CalibTable::parse(&lt).map_err(table_err)?;
    let mut flat = flat::FlatAccum::new(g);
    let mut points = Vec::new();
    let mut edges = Vec::new();
    let range_adu: Vec<f64> = (0..outputs)
        .map(|o| {
            let (s, e) = g.overscan_cols(Output(o as u8));
            let n = (e - s) * master_bias.rows;
            let sum: f64 = master_bias
                .data
                .chunks_exact(master_bias.cols.max(1))
                .flat_map(|l| l.get(s..e).unwrap_or(&[]).iter())
                .map(|v| f64::from(*v))
                .sum();
            65535.0 - sum / n.max(1) as f64
        })
        .collect();
    // Pairs in order of exposure: a saturated flat is accepted as the top of the ladder only.
    let mut most_saturated: Option<(f64, PathBuf)> = None;
    let mut flat_field_exposures_s = Vec::new();
    for (a_info, b_info) in &inv.flat_pairs {
        let a = read::read_frame(a_info, g)?;
        tick();
        let b = read::read_frame(b_info, g)?;
        tick();
        let mut saturated = false;
        for (f, info) in [(&a, a_info), (&b, b_info)] {
            let share = saturated_share(f, g);
            if let Some((top, path)) = &most_saturated
                && share < top - SATURATED_SHARE_DROP
            {
                return Err(FramesError::Saturated {
                    path: path.clone(),
                    fraction: *top,
                    unsaturated: info.path.clone(),
                });
            }
            if share > SATURATED_SHARE && most_saturated.as_ref().is_none_or(|m| share > m.0) {
                most_saturated = Some((share, info.path.clone()));
            }
            saturated |= share > SATURATED_SHARE;
        }
        let pair: Vec<PairPoint> = (0..outputs)
            .map(|o| ptc::pair_point(&a, &b, g, Output(o as u8), &cb_adu, a_info.exptime_s))
            .collect();
        // The flat field and EPER take the pairs of the ADC's linear range on every output.
        let linear = !saturated
            && pair.iter().all(|p| {
                p.mean_adu
                    < ptc::LINEAR_FRACTION
                        * range_adu.get(usize::from(p.output)).copied().unwrap_or(0.0)
            });
        if linear {
            for (f, info) in [(&a, a_info), (&b, b_info)] {
                edges.extend(eper::edge_response(f, g, &cb_adu).unwrap_or_default());
                flat.add(f, &t1, info.exptime_s, info.ccdtemp_k)
                    .ok_or_else(|| {
                        FramesError::Missing(format!(
                            "{}: a line without over-scan levels",
                            info.path.display()
                        ))
                    })?;
                flat_field_exposures_s.push(info.exptime_s);
            }
        }
        points.extend(pair);
    }
    if !inv.unpaired_flats.is_empty() {
        notes.push(format!(
            "{} flats without a partner of equal EXPTIME not used",
            inv.unpaired_flats.len()
        ));
    }
    let mut fits = Vec::new();
    let (mut full_well_e, mut full_well_adu, mut nonlinearity_pct) =
        (Vec::new(), Vec::new(), Vec::new());
    for o in 0..outputs {
        let pts: Vec<PairPoint> = points
            .iter()
            .filter(|p| usize::from(p.output) == o)
            .copied()
            .collect();
        let bv = bias_var_adu2.get(o).copied().unwrap_or(0.0);
        let range = range_adu.get(o).copied().unwrap_or(65535.0);
        let sat = ptc::saturation(&pts);
        let top = sat.map_or(range, |s| s.mean_adu.min(range));
        let fit = ptc::fit_output(&pts, bv, top, read::MIN_FLAT_PAIRS).ok_or_else(|| {
            FramesError::Missing(format!(
                "too few flats: output {o} has fewer than {} pairs in the linear range (below {:.0} % of {})",
                read::MIN_FLAT_PAIRS,
                100.0 * ptc::LINEAR_FRACTION,
                if sat.is_ok() { "the saturation signal" } else { "the ADC's range" }
            ))
        })?;
        // Frame-limited floors (relative standard errors): the gain's from the variance of
        // N pixel differences per pair, the read noise's from the bias pairs (half the
        // variance's relative error) plus the gain's.
        let px = ptc_pixels(&pts);
        let gain_floor = (2.0 / (px * fit.pairs_fitted.max(1) as f64)).sqrt();
        let bias_pairs = bias_var.get(o).map_or(0, |b| b.1).max(1) as f64;
        let read_floor = (1.0 / (2.0 * px * bias_pairs)).sqrt().hypot(gain_floor);
        notes.push(format!(
            "output {o}: gain {:.4} e-/ADU from {} flat pairs of the linear range (floor {:.3} %), read noise {:.3} e- from {} bias pairs (floor {:.3} %)",
            fit.gain_e_per_adu,
            fit.pairs_fitted,
            100.0 * gain_floor,
            fit.read_noise_e,
            bias_pairs,
            100.0 * read_floor
        ));
        match sat {
            Ok(s) => {
                let fw = fit.gain_e_per_adu * s.mean_adu;
                let le = ptc::linearity_error_pct(&pts, s.mean_adu);
                notes.push(format!(
                    "output {o}: full well {fw:.0} e- ({:.1} ADU above bias: the mean stops rising from {} s); {}",
                    s.mean_adu,
                    s.exptime_s,
                    match le {
                        Some((pct, n)) => format!(
                            "linearity error {pct:.3} % over 5 to 95 % of it ({n} pairs)"
                        ),
                        None => "no linearity error: fewer than 3 pairs within 5 to 95 % of it".into(),
                    }
                ));
                let used_above = flat_field_exposures_s
                    .iter()
                    .step_by(2)
                    .filter_map(|t| {
                        pts.iter()
                            .find(|p| p.exptime_s == *t)
                            .filter(|p| p.mean_adu >= ptc::LINEAR_FRACTION * s.mean_adu)
                    })
                    .count();
                if used_above > 0 {
                    notes.push(format!(
                        "output {o}: {used_above} flat pairs of the flat field are above {:.0} % of the full well",
                        100.0 * ptc::LINEAR_FRACTION
                    ));
                }
                full_well_e.push(Some(fw));
                full_well_adu.push(Some(s.mean_adu));
                nonlinearity_pct.push(le.map(|l| l.0));
            }
            Err(r) => {
                notes.push(if r.to_s > 0.0 {
                    format!(
                        "output {o}: no flat reaches saturation (the mean still rises {:.2} % from {} s to {} s): no full well or linearity error",
                        100.0 * r.rise,
                        r.from_s,
                        r.to_s
                    )
                } else {
                    format!(
                        "output {o}: no flat reaches saturation: no full well or linearity error"
                    )
                });
                full_well_e.push(None);
                full_well_adu.push(None);
                nonlinearity_pct.push(None);
            }
        }
        fits.push(fit);
    }
    let gains: Vec<f64> = fits.iter().map(|f| f.gain_e_per_adu).collect();
    let read_noise_e: Vec<f64> = fits.iter().map(|f| f.read_noise_e).collect();
    // Darks: relative map, hot pixels, and the series for telegraph pixels.
    let gt = level_table(g, &gains, &column_bias)?;
    let tg = CalibTable::parse(&gt).map_err(table_err)?;
    let mut darks = dark::DarkAccum::new(g);
    let series = longest_series(&inv.dark_groups).filter(|(_, n)| *n >= rts::MIN_SERIES_FRAMES);
    let mut series_acc = series.map(|_| rts::SeriesAccum::new(g));
    for (info, &setting) in inv.darks.iter().zip(&inv.dark_setting) {
        let f = read::read_frame(info, g)?;
        let group_temp_k = inv
            .dark_groups
            .get(setting)
            .map_or(info.ccdtemp_k, |d| d.temperature_k);
        darks
            .add(&f, &tg, info.exptime_s, group_temp_k)
            .ok_or_else(|| {
                FramesError::Missing(format!(
                    "{}: no covered pixels to scale the dark",
                    info.path.display()
                ))
            })?;
        if let (Some((i, _)), Some(acc)) = (series, series_acc.as_mut())
            && setting == i
        {
            acc.add(&f, &cb_adu);
        }
        tick();
    }
    groups.push(format!(
        "bias: {} frames, {} to {}: master bias and column bias; {} consecutive pairs: read noise",
        inv.bias.len(),
        inv.bias.first().map_or("", |b| b.date_obs.as_str()),
        inv.bias.last().map_or("", |b| b.date_obs.as_str()),
        inv.bias.len() / 2
    ));
    for (t, n) in &inv.flat_groups {
        let used = flat_field_exposures_s
            .iter()
            .filter(|u| read::same_exposure(**u, *t))
            .count();
        groups.push(format!(
            "flats {t} s: {n} frames, {} pairs: photon transfer{}",
            n / 2,
            if used > 0 {
                ", flat field and EPER"
            } else {
                " (past the linear range: full well and linearity error only)"
            }
        ));
    }
    for (i, d) in inv.dark_groups.iter().enumerate() {
        groups.push(format!(
            "darks {} s at {:.3} K (CCDTEMP span {:.3} K): {} frames, {} to {}: relative dark and hot-pixel laws{}",
            d.exptime_s,
            d.temperature_k,
            d.temperature_span_k,
            d.frames,
            d.dates.0,
            d.dates.1,
            if series.is_some_and(|(s, _)| s == i) {
                ", telegraph series"
            } else {
                ""
            }
        ));
    }
    if inv.lights > 0 {
        groups.push(format!("{} light frames: not used", inv.lights));
    }
    let dark_rel = darks.relative_map(&read_noise_e).ok_or_else(|| {
        FramesError::Missing(
            "the darks' covered pixels hold no dark signal: no relative dark map".into(),
        )
    })?;
    if darks.covered_rates().len() < 2 {
        notes.push(
            "darks at one temperature: hot pixels have no temperature law (none listed)".into(),
        );
    }
    let (hot, hot_unfitted) = darks.hot_pixels(&read_noise_e);
    let covered_dark_law = dark::fit_covered_law(&darks.covered_rates());
    notes.push(match covered_dark_law {
        Some(l) => format!(
            "covered dark law {:.4} e-/px/s at {} K, doubling {:.3} K (table section 11)",
            l.rate_e_per_s_at_293k,
            dark::HOT_REFERENCE_K,
            l.doubling_k
        ),
        None => "no covered dark law (darks at fewer than two temperatures, or no rise): the tracker's dark drift is not measured".into(),
    });
    notes.push(format!(
        "relative dark from {} darks at {} temperatures (floor {:.4} RMS: the darks' shot and read noise); {} hot pixels ({} candidates without a law; doubling standard error {:.3} K RMS, in hot.csv)",
        darks.frames(),
        darks.groups.len(),
        darks.floor_rms(&read_noise_e),
        hot.len(),
        hot_unfitted,
        (hot.iter().map(|h| h.doubling_sigma_k.powi(2)).sum::<f64>() / hot.len().max(1) as f64)
            .sqrt()
    ));
    let (rts, rts_series) = match (
        series.and_then(|(i, n)| Some((inv.dark_groups.get(i)?, n))),
        series_acc,
    ) {
        (Some((d, n)), Some(acc)) => {
            let (t, temp) = (d.exptime_s, d.temperature_k);
            let found = acc.telegraph(&gains, &bias_var_adu2);
            let searched = g.lines as usize
                * (0..g.line_len())
                    .filter(|&c| matches!(g.segment(c), Some(Segment::Active | Segment::Covered)))
                    .count();
            notes.push(format!(
                "{} telegraph pixels from a {n}-frame series ({t} s, {temp:.3} K); floor: {:.1} false expected among the {searched} pixels searched ({:.0e} per pixel per test on Gaussian noise)",
                found.len(),
                2.0 * rts::FALSE_ALARM_PER_TEST * searched as f64,
                rts::FALSE_ALARM_PER_TEST
            ));
            (found, Some((t, temp, n)))
        }
        _ => {
            notes.push(format!(
                "no dark series of at least {} frames at one setting: no telegraph pixels",
                rts::MIN_SERIES_FRAMES
            ));
            (Vec::new(), None)
        }
    };
    let flat_map = flat.flat(&gains, &dark_rel, &hot);
    notes.push(format!(
        "flat field from {} flats of the linear range (floor {:.5} RMS: their shot and read noise)",
        flat.frames(),
        flat.floor_rms(&gains, &read_noise_e)
    ));
    let eper = eper::fit(&edges, &gains, &read_noise_e, g);
    notes.push(match &eper {
        Some(e) => format!(
            "CTI by EPER from {} flats: parallel {:.3e} per transfer at {} e- (alpha {:.2}, trail {} px, mean delay {:.2} px); {}",
            e.points.len(),
            e.traps.parallel_per_transfer,
            e.traps.reference_e,
            e.traps.alpha,
            e.traps.trail_px,
            e.mean_delay,
            if e.serial_measured {
                format!("serial {:.3e} per transfer", e.traps.serial_per_transfer)
            } else {
                "serial not measurable with two outputs (no element after the far edge): read a flat set through one output".to_string()
            }
        ),
        None => format!(
            "no CTI: EPER found no edge response above 3 standard errors in flats at signal levels a factor 2 apart (or the readout has fewer than {} extra lines)",
            eper::TAIL
        ),
    });
    Ok(Products {
        geometry: *g,
        full_well_e,
        full_well_adu,
        nonlinearity_pct,
        flat_field_exposures_s,
        gain_e_per_adu: gains,
        read_noise_e,
        bias_var_adu2,
        ptc: points,
        master_bias,
        column_bias,
        dark_rel,
        covered_rates: darks.covered_rates(),
        covered_dark_law,
        hot,
        hot_unfitted,
        flat: flat_map,
        rts,
        rts_series,
        frames: (inv.bias.len(), 2 * inv.flat_pairs.len(), inv.darks.len()),
        eper,
        notes,
        groups,
    })
}

/// Pixels per photon transfer point of an output (the most any of its pairs used).
fn ptc_pixels(pts: &[PairPoint]) -> f64 {
    pts.iter().map(|p| p.pixels).max().unwrap_or(1).max(1) as f64
}

/// Share of a frame's active pixels at 65535 ADU.
fn saturated_share(f: &startrack_sim::fits::RawFrame, g: &ReadoutGeometry) -> f64 {
    let (mut top, mut n) = (0usize, 0usize);
    for line in f.lines().take(usize::from(g.active_rows)) {
        for (c, v) in line.iter().enumerate() {
            if g.segment(c) == Some(Segment::Active) {
                n += 1;
                top += usize::from(*v == u16::MAX);
            }
        }
    }
    top as f64 / n.max(1) as f64
}

impl Products {
    /// The hot pixels of the active area as table entries, sorted by (y, x).
    pub fn hot_entries(&self) -> Vec<HotPixel> {
        let g = self.geometry;
        let mut v: Vec<HotPixel> = self
            .hot
            .iter()
            .filter(|h| {
                g.segment(h.col) == Some(Segment::Active) && h.row < usize::from(g.active_rows)
            })
            .filter_map(|h| {
                let doubling = U8F8::checked_from_num(h.doubling_k).filter(|d| *d > U8F8::ZERO)?;
                Some(HotPixel {
                    x: (h.col - g.first_active_col()) as u16,
                    y: h.row as u16,
                    rate_e_per_s: ERatePerS::saturating_from_num(h.rate_e_per_s_at_293k),
                    doubling_k: doubling,
                    policy: if h.rate_e_per_s_at_293k > HOT_EXCLUDE_ABOVE_E_PER_S {
                        HotPolicy::Exclude
                    } else {
                        HotPolicy::Correct
                    },
                })
            })
            .collect();
        v.sort_by_key(|h| (h.y, h.x));
        v
    }

    /// The telegraph pixels of the active area (x, y), sorted by (y, x).
    pub fn telegraph_entries(&self) -> Vec<(u16, u16)> {
        let g = self.geometry;
        let mut v: Vec<(u16, u16)> = self
            .rts
            .iter()
            .filter(|(c, r)| {
                g.segment(*c) == Some(Segment::Active) && *r < usize::from(g.active_rows)
            })
            .map(|(c, r)| ((c - g.first_active_col()) as u16, *r as u16))
            .collect();
        v.sort_by_key(|&(x, y)| (y, x));
        v
    }

    /// The table's CTI coefficients from the EPER trap law: the flight method's bias fitted
    /// on the simulator with that law ([`crate::cti::CtiExperiment::fit`]); `None` without
    /// EPER.
    pub fn cti_coeffs(&self) -> Option<startrack_core::table::CtiCoeffs> {
        let e = self.eper.as_ref()?;
        let x = crate::cti::CtiExperiment {
            geometry: self.geometry,
            ..crate::cti::CtiExperiment::flight(e.traps)
        };
        x.fit(&x.bias_grid(&crate::cti::CTI_FIT_FLUXES_E, &x.positions(4)))
    }

    /// The calibration table (maps in tiles of 2^`tile_log2` pixels, 0: per pixel).
    pub fn table(&self, tile_log2: u8) -> Result<Vec<u8>, LabError> {
        let g = self.geometry;
        let gains = crate::table_build::args::encode_gains(&self.gain_e_per_adu)?;
        // A hot pixel's map value is its own dark over the regular one (up to hundreds):
        // the core uses its law instead, so the map holds the regular 1 there, as it would
        // for a pixel without a defect, and a tile is not pulled by its hot pixels.
        let hot_at: std::collections::HashSet<(usize, usize)> =
            self.hot.iter().map(|h| (h.col, h.row)).collect();
        let dark: Vec<DarkRel> = startrack_sim::sim::truth::tile_means(&g, tile_log2, &|x, y| {
            let (col, line) = (g.raw_col_of_x(x), g.raw_line_of_y(y));
            if hot_at.contains(&(col, line)) {
                return 1.0;
            }
            f64::from(self.dark_rel.get(line, col).unwrap_or(1.0))
        })
        .into_iter()
        .map(DarkRel::saturating_from_num)
        .collect();
        let (flat_inv, _) = flat_from_map(&g, &self.flat, tile_log2);
        let (hot, telegraph) = (self.hot_entries(), self.telegraph_entries());
        let spec = TableSpec {
            geometry: g,
            saturation_adu: u16::MAX,
            gains: &gains,
            column_bias: Some(&self.column_bias),
            dark_rel: Some(MapSpec {
                tile_log2,
                tiles: &dark,
            }),
            flat_inv: Some(MapSpec {
                tile_log2,
                tiles: &flat_inv,
            }),
            hot_ref_k: Kelvin::from_num(293),
            hot: &hot,
            telegraph: &telegraph,
            cti: self.cti_coeffs(),
            psf_model: None,
            camera_model: None,
            dark_law: self.dark_law(),
        };
        encode(&spec, &[])
    }

    /// The covered dark law as the table stores it (reference 293 K, the default band 0.8
    /// to 1.25), or `None` without a fit or when the fit is outside the section's ranges
    /// (doubling 2 to 20 K, a rate that rounds to a positive U16F16).
    pub fn dark_law(&self) -> Option<DarkLaw> {
        let l = self.covered_dark_law?;
        let [band_low, band_high] = DarkLaw::DEFAULT_BAND;
        let law = DarkLaw {
            rate_e_per_s: ERatePerS::checked_from_num(l.rate_e_per_s_at_293k)?,
            reference_k: Kelvin::from_num(dark::HOT_REFERENCE_K),
            doubling_k: U8F8::checked_from_num(l.doubling_k)?,
            band_low,
            band_high,
        };
        law.out_of_range_field().is_none().then_some(law)
    }
}
