//! `startrack simulate --out DIR`: a simulated CCD47-20 frame and everything needed to run
//! and judge the pipeline on it, as user files:
//!
//! | file | contents |
//! |---|---|
//! | `frame.fits` | raw readout, BITPIX 16 + BZERO 32768, 1033 x 1072, `EXPTIME` s, `CCDTEMP` K, and `PSFA` px with `--psf-a-px` |
//! | `truth.csv` | `x_px,y_px,signal_e,a_px`: the simulated stars, active-area px |
//! | `bias.fits` | true bias, ADU, full readout (`GAIN1`, `GAIN2` keywords, e-/ADU) |
//! | `dark.fits` | true relative dark, full readout, covered columns' mean = 1 |
//! | `flat.fits` | true flat (relative response), active area |
//! | `hot.csv` | `col,row,dark_e`: the hot pixels of `--hot-fraction` (header only without) |
//!
//! The maps are the sensor's truth (noise-free), the inputs of `startrack calib build`.
//! With `--psf-a-px A` every star has the 80 %-energy radius `A` (else each its own, 0.8 to
//! 2 px) and the frame's `PSFA` keyword says so: `startrack calib build --psf-a-px A` then
//! builds the pixel-phase curves that `startrack process --method cog1` picks for it.
//!
//! The scene options ([`SceneMix`]) make the frames of the accuracy Monte Carlo on whole
//! frames ([`crate::cli::accuracy_frames::monte_carlo`]): `--psf-a-list 0.6,1,2` draws each star's width from a
//! list (no `PSFA` keyword: the width is for the pipeline to find), `--psf-a-field 0.6,2` as
//! a smooth function of the star's place (field curvature), `--snr-range 10,200` each
//! star's eq. 8 SNR (5 x 5 box, the mean dark and read noise as the noise) log-uniformly in
//! a range instead of its signal in 5e3-2e5 e-, and `--hot-fraction F` turns on the
//! simulator's hot pixels ([`HotPixels`], [`HOT_RATES_E_PER_S`] at 293 K, 1 s) and lists
//! every one with its true dark in `hot.csv`, as a ground calibration would.

use super::{CliError, LabError, write_file};
use rand::{RngExt as _, SeedableRng as _};
use startrack_analysis::accuracy::flux_for_snr;
use startrack_core::geometry::Segment;
use startrack_core::window::Rect;
use startrack_homes::demo::{render_frame, star_field};
use startrack_sim::fits::{MapF32, RawFrame, write_map, write_raw_frame};
use startrack_sim::sim::effects::HotPixels;
use startrack_sim::sim::{SensorParams, Simulator};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Options of `startrack simulate`.
#[derive(Clone, Debug, clap::Args)]
pub struct SimulateArgs {
    /// Output directory (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the sensor's fixed patterns, the star field and the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of stars (signal 5e3 to 2e5 e-, 80 % radius 0.8 to 2 px, 20 px from the edges).
    #[arg(long, default_value_t = 12)]
    pub stars: usize,
    /// Mean dark charge of a covered pixel in the exposure, e-.
    #[arg(long, default_value_t = 250.0)]
    pub dark_e: f64,
    /// Read noise, e- rms.
    #[arg(long, default_value_t = 5.0)]
    pub read_noise_e: f64,
    /// Dark signal non-uniformity (relative sigma).
    #[arg(long, default_value_t = 0.1)]
    pub dsnu: f64,
    /// Photo-response non-uniformity (relative sigma).
    #[arg(long, default_value_t = 0.02)]
    pub prnu: f64,
    /// One PSF 80 %-energy radius for every star, px (0.3 to 10; written as `PSFA`).
    #[arg(long)]
    pub psf_a_px: Option<f64>,
    /// Write the dark and flat maps as a ground calibration would measure them, from this many
    /// simulated dark frames and as many flat frames (with their calibration noise), instead
    /// of the simulator's truth; 0 writes the truth. The bias map is always the truth.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=1000))]
    pub measured_frames: u32,
    /// Mixed widths, SNR range, hot pixels.
    #[command(flatten)]
    pub mix: SceneMix,
}

/// The options of `simulate` that shape the scene beyond the basic field (all off by
/// default: the frame is then the basic one, bit for bit).
#[derive(Clone, Debug, Default, PartialEq, clap::Args)]
pub struct SceneMix {
    /// PSF 80 %-energy radii, px, "A,B,...": each star's drawn uniformly from the list
    /// (0.3 to 10 px each; no `PSFA` keyword is written).
    #[arg(long, value_delimiter = ',', conflicts_with = "psf_a_px")]
    pub psf_a_list: Vec<f64>,
    /// "CENTRE,CORNER": each star's width a smooth function of its place, px (0.3 to 10):
    /// `CENTRE + (CORNER - CENTRE) (u^2 + v^2) / 2` with `u`, `v` the field coordinates in
    /// -1..1 (what a field PSF model of degree 2 describes exactly; no `PSFA` keyword).
    #[arg(long, value_delimiter = ',', conflicts_with_all = ["psf_a_px", "psf_a_list"])]
    pub psf_a_field: Vec<f64>,
    /// "LO,HI": each star's signal set for an eq. 8 SNR (5 x 5 box, the mean dark and the
    /// read noise as the noise) drawn log-uniformly from LO to HI (1 to 10000).
    #[arg(long, value_delimiter = ',')]
    pub snr_range: Vec<f64>,
    /// Share of hot pixels (0 to 0.01), each with its own dark rate (`HOT_RATES_E_PER_S`
    /// at 293 K), listed in hot.csv.
    #[arg(long, default_value_t = 0.0)]
    pub hot_fraction: f64,
}

/// The range of the hot pixels' dark rates at 293 K, e-/s (log-uniform): with `calib
/// build`'s default exclusion above 10 000 e- in 1 s, about 30 % of them are excluded and
/// the rest corrected by their own law.
pub const HOT_RATES_E_PER_S: [f64; 2] = [200.0, 50_000.0];

/// Seed offset of the scene mix's draws (widths, SNRs), apart from the star field's.
const MIX_SEED: u64 = 0x4d49_5845;

/// First frame number of the simulated calibration frames of `--measured-frames` (the scene
/// is frame 0; these never share noise with it).
pub const CALIBRATION_FRAME0: u32 = 1_000_000;

/// Mean level of the simulated flat-field frames, e- per pixel (a fifth of full well).
pub const FLAT_LEVEL_E: f64 = 20_000.0;

/// The files `simulate` writes, in `dir`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SimFiles {
    /// Raw frame.
    pub frame: PathBuf,
    /// Star truth.
    pub truth: PathBuf,
    /// Bias map.
    pub bias: PathBuf,
    /// Relative dark map.
    pub dark: PathBuf,
    /// Flat.
    pub flat: PathBuf,
    /// Hot pixel list.
    pub hot: PathBuf,
}

impl SimFiles {
    /// The file names in `dir`.
    pub fn in_dir(dir: &Path) -> Self {
        Self {
            frame: dir.join("frame.fits"),
            truth: dir.join("truth.csv"),
            bias: dir.join("bias.fits"),
            dark: dir.join("dark.fits"),
            flat: dir.join("flat.fits"),
            hot: dir.join("hot.csv"),
        }
    }
}

/// The sensor parameters of `args`.
pub fn params(args: &SimulateArgs) -> Result<SensorParams, CliError> {
    let checks = [
        ("--dark-e", args.dark_e),
        ("--read-noise-e", args.read_noise_e),
        ("--dsnu", args.dsnu),
        ("--prnu", args.prnu),
    ];
    if let Some((name, v)) = checks.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
        return Err(CliError::Usage(format!("{name} {v}: must be 0 or more")));
    }
    let f = args.mix.hot_fraction;
    if !(f.is_finite() && (0.0..=0.01).contains(&f)) {
        return Err(CliError::Usage(format!(
            "--hot-fraction {f}: must be 0 to 0.01"
        )));
    }
    let mut p = SensorParams {
        seed: args.seed,
        dark_mean_e: args.dark_e,
        read_noise_e: args.read_noise_e,
        dsnu: args.dsnu,
        prnu: args.prnu,
        ..SensorParams::default()
    };
    if f > 0.0 {
        p.effects.temperature_k = HOT_REF_K;
        p.effects.hot = Some(HotPixels {
            fraction: f,
            rate_min_e_per_s: HOT_RATES_E_PER_S[0],
            rate_max_e_per_s: HOT_RATES_E_PER_S[1],
            reference_k: HOT_REF_K,
            doubling_k: 6.0,
            exposure_s: 1.0,
        });
    }
    Ok(p)
}

/// The frame's temperature (`CCDTEMP`) and the hot pixels' reference, K.
const HOT_REF_K: f64 = 293.0;

/// Applies `mix`'s widths and SNRs to `stars` (positions kept), from its own seeded stream.
fn mix_stars(
    mix: &SceneMix,
    seed: u64,
    p: &SensorParams,
    stars: &mut [startrack_sim::sim::Star],
) -> Result<(), CliError> {
    if let Some(a) = mix
        .psf_a_list
        .iter()
        .find(|a| !(a.is_finite() && (0.3..=10.0).contains(*a)))
    {
        return Err(CliError::Usage(format!(
            "--psf-a-list {a}: each must be 0.3 to 10 px"
        )));
    }
    let field = match mix.psf_a_field.as_slice() {
        [] => None,
        &[c, k]
            if [c, k]
                .iter()
                .all(|a| a.is_finite() && (0.3..=10.0).contains(a)) =>
        {
            if !mix.psf_a_list.is_empty() {
                return Err(CliError::Usage(
                    "--psf-a-list and --psf-a-field: give one of them".into(),
                ));
            }
            Some((c, k))
        }
        v => {
            return Err(CliError::Usage(format!(
                "--psf-a-field {v:?}: need CENTRE,CORNER, each 0.3 to 10 px"
            )));
        }
    };
    let g = p.geometry;
    let snr = match mix.snr_range.as_slice() {
        [] => None,
        &[lo, hi] if lo.is_finite() && hi.is_finite() && 1.0 <= lo && lo <= hi && hi <= 1e4 => {
            Some((lo, hi))
        }
        v => {
            return Err(CliError::Usage(format!(
                "--snr-range {v:?}: need LO,HI with 1 <= LO <= HI <= 10000"
            )));
        }
    };
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ MIX_SEED);
    let var_bg = p.dark_mean_e + p.sky_e + p.read_noise_e * p.read_noise_e;
    for s in stars {
        if !mix.psf_a_list.is_empty() {
            let i = r.random_range(0..mix.psf_a_list.len());
            s.a_px = mix.psf_a_list.get(i).copied().unwrap_or(s.a_px);
        }
        if let Some((c, k)) = field {
            let u = startrack_lab::psf_model::norm(s.x_px, g.active_cols);
            let v = startrack_lab::psf_model::norm(s.y_px, g.active_rows);
            s.a_px = c + (k - c) * (u * u + v * v) / 2.0;
        }
        if let Some((lo, hi)) = snr {
            let snr = (lo.ln() + r.random::<f64>() * (hi.ln() - lo.ln())).exp();
            s.signal_e = flux_for_snr(snr, 5.0, var_bg);
        }
    }
    Ok(())
}

/// `hot.csv` of the simulator's hot pixels: full-readout `col,row` and the dark in the
/// 1 s reference exposure at the reference temperature, e-.
fn hot_csv(sim: &Simulator) -> String {
    let g = sim.params.geometry;
    let mut s = String::from("col,row,dark_e\n");
    if sim.params.effects.hot.is_some() {
        for l in 0..usize::from(g.lines) {
            for c in 0..g.line_len() {
                if sim.hot_rate_e_per_s(c, l).is_some() {
                    let _ = writeln!(s, "{c},{l},{:.3}", sim.hot_dark_e(c, l));
                }
            }
        }
    }
    s
}

/// Runs `startrack simulate`.
pub fn run(args: &SimulateArgs) -> Result<SimFiles, CliError> {
    let p = params(args)?;
    let g = p.geometry;
    std::fs::create_dir_all(&args.out).map_err(|e| LabError::Io {
        path: args.out.clone(),
        msg: e.to_string(),
    })?;
    let files = SimFiles::in_dir(&args.out);
    if let Some(a) = args.psf_a_px
        && !(a.is_finite() && (0.3..=10.0).contains(&a))
    {
        return Err(CliError::Usage(format!(
            "--psf-a-px {a}: must be 0.3 to 10 px"
        )));
    }
    let mut stars = star_field(args.seed, args.stars, &p);
    if let Some(a) = args.psf_a_px {
        if !(args.mix.psf_a_list.is_empty() && args.mix.psf_a_field.is_empty()) {
            return Err(CliError::Usage(
                "--psf-a-px and --psf-a-list or --psf-a-field: give one of them".into(),
            ));
        }
        for s in &mut stars {
            s.a_px = a;
        }
    }
    mix_stars(&args.mix, args.seed, &p, &mut stars)?;
    let sim = Simulator::new(p.clone(), stars.clone());
    let (lines, len) = (usize::from(g.lines), g.line_len());
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    let gains = vec![
        ("GAIN1".to_string(), p.gain_e_per_adu[0]),
        ("GAIN2".to_string(), p.gain_e_per_adu[1]),
    ];

    let frame = RawFrame {
        lines,
        cols: len,
        data_adu: render_frame(&sim),
    };
    let mut keys = vec![("EXPTIME", 1.0), ("CCDTEMP", HOT_REF_K)];
    if let Some(a) = args.psf_a_px {
        keys.push(("PSFA", a));
    }
    write_raw_frame(&files.frame, &frame, &keys)?;

    let mut truth = String::from("x_px,y_px,signal_e,a_px\n");
    for s in &stars {
        let _ = writeln!(
            truth,
            "{:.6},{:.6},{:.3},{:.6}",
            s.x_px, s.y_px, s.signal_e, s.a_px
        );
    }
    write_file(&files.truth, truth.as_bytes())?;

    let full = |f: &dyn Fn(usize, usize) -> f64| -> Vec<f32> {
        (0..lines)
            .flat_map(|l| (0..len).map(move |c| (c, l)))
            .map(|(c, l)| f(c, l) as f32)
            .collect()
    };
    let bias = MapF32 {
        rows: lines,
        cols: len,
        data: full(&|c, _| p.bias_adu[usize::from(g.output_of_col(c).0)] + sim.column_bias_adu(c)),
        keys: gains.clone(),
    };
    write_map(&files.bias, &bias)?;
    let (dark_data, flat_data) = if args.measured_frames == 0 {
        let norm = sim.covered_dark_mean();
        let flat = (0..rows)
            .flat_map(|y| (0..cols).map(move |x| (x, y)))
            .map(|(x, y)| sim.flat(x, y) as f32)
            .collect();
        (full(&|c, l| sim.dark_rel(c, l) / norm), flat)
    } else {
        measured_maps(&sim, args.measured_frames)?
    };
    let dark = MapF32 {
        rows: lines,
        cols: len,
        data: dark_data,
        keys: gains.clone(),
    };
    write_map(&files.dark, &dark)?;
    let flat = MapF32 {
        rows,
        cols,
        data: flat_data,
        keys: gains,
    };
    write_map(&files.flat, &flat)?;
    write_file(&files.hot, hot_csv(&sim).as_bytes())?;
    Ok(files)
}

/// The relative dark map (full readout) and the flat (active area) measured from `frames` dark
/// and `frames` flat simulated frames ([`Simulator::measure_dark_map`],
/// [`Simulator::measure_flat_inv_map`]). The dark map is measured on the active area and
/// normalised to the covered pixels of every line, so its covered columns are written as 1 (their
/// mean, what `calib build` divides by) and the over-scan columns as 0 (no dark).
fn measured_maps(sim: &Simulator, frames: u32) -> Result<(Vec<f32>, Vec<f32>), CliError> {
    let g = sim.params.geometry;
    let (lines, len) = (usize::from(g.lines), g.line_len());
    let (cols, rows) = (usize::from(g.active_cols), usize::from(g.active_rows));
    let region = Rect {
        x0: 0,
        y0: 0,
        width: g.active_cols,
        height: g.active_rows,
    };
    let measure_err = |e: startrack_core::calib::LineError| {
        CliError::Usage(format!("measuring the calibration maps: {e:?}"))
    };
    let dark = sim
        .measure_dark_map(frames, CALIBRATION_FRAME0, region, 0..lines)
        .map_err(measure_err)?;
    let flat_inv = sim
        .measure_flat_inv_map(frames, CALIBRATION_FRAME0 + frames, FLAT_LEVEL_E, region)
        .map_err(measure_err)?;
    let mut dark_full = vec![0.0f32; lines * len];
    for (l, line) in dark_full.chunks_exact_mut(len).enumerate() {
        for (c, v) in line.iter_mut().enumerate() {
            *v = match g.segment(c) {
                Some(Segment::Active) if l < rows => {
                    dark.values[l * cols + (c - g.first_active_col())] as f32
                }
                Some(Segment::Covered) => 1.0,
                _ => 0.0,
            };
        }
    }
    let flat = flat_inv
        .values
        .iter()
        .take(cols * rows)
        .map(|&inv| if inv > 0.0 { (1.0 / inv) as f32 } else { 1.0 })
        .collect();
    Ok((dark_full, flat))
}
