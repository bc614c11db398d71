//! `startrack calib frames DIR... --out TABLE --report-dir DIR`: a calibration table and a
//! report from raw lab frames (see [`startrack_lab::calib_frames`]), and `startrack calib lab-set
//! --out DIR`, which writes a simulated lab set to try it on. Every FITS file of the folders
//! and their sub-folders is read (`.fits`, `.fit`, `.fts`, and each gzipped, `.gz`, or
//! tile-compressed, `.fz`); a bad input stops the run with one line naming the file and the
//! problem, and no table is written. Cost: reading each file once and a few operations per
//! sample (5.1 s and 131 MB for the CCD47-20 lab set of 98 frames, 30 s and 148 MB for the
//! 235 frames of the second lab campaign, on a machine loaded by other jobs, in release;
//! the command prints both); a progress
//! bar on a terminal. Writing that lab set takes about 4 minutes (simulating 108 M samples;
//! 3 minutes and 86 M without the ladder).

use super::{CliError, LabError, write_file};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::MAX_TILE_LOG2;
use startrack_lab::calib_frames::labset::LabSet;
use startrack_lab::calib_frames::{Grouping, Products, calibrate_with, report};
use std::path::{Path, PathBuf};

/// The readouts `calib frames` and `calib lab-set` know.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Sensor {
    /// The CCD47-20 read through both outputs, 1033 x 1072.
    #[value(name = "ccd47-20")]
    Ccd4720,
    /// The small test readout of the lab-set tests: 128 x 128 active, the CCD47-20's
    /// over-scan and covered strips, 130 lines.
    #[value(name = "test-128")]
    Test128,
}

impl Sensor {
    /// Its readout geometry.
    pub fn geometry(self) -> ReadoutGeometry {
        match self {
            Self::Ccd4720 => ReadoutGeometry::CCD47_20_DUAL,
            Self::Test128 => LabSet::small(0).geometry,
        }
    }
}

/// Options of `startrack calib frames`.
#[derive(Clone, Debug, clap::Args)]
pub struct CalibFramesArgs {
    /// Folders of raw FITS frames (IMAGETYP, EXPTIME or EXPOSURE, CCDTEMP in K or CCD-TEMP in
    /// deg C, DATE-OBS in each header), searched with their sub-folders.
    #[arg(required = true)]
    pub dirs: Vec<PathBuf>,
    /// Output table file.
    #[arg(long)]
    pub out: PathBuf,
    /// Folder for report.json, hot.csv, rts.csv, the maps as FITS and the PNGs.
    #[arg(long)]
    pub report_dir: PathBuf,
    /// Map tiles of 2^N pixels: 0 is per pixel; 3 (8x8) fits the firmware's CALIB sector.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u8).range(0..=i64::from(MAX_TILE_LOG2)))]
    pub tile_log2: u8,
    /// The readout of the frames.
    #[arg(long, value_enum, default_value_t = Sensor::Ccd4720)]
    pub sensor: Sensor,
    /// Regulation band: darks whose CCDTEMP lies within this of their group's median are
    /// one temperature, K.
    #[arg(long, default_value_t = startrack_lab::calib_frames::read::DEFAULT_TEMPERATURE_TOLERANCE_K)]
    pub temperature_tolerance_k: f64,
}

/// Options of `startrack calib lab-set`.
#[derive(Clone, Debug, clap::Args)]
pub struct LabSetArgs {
    /// Output folder (created if needed).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the simulated sensor and of the frames' noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The readout to simulate.
    #[arg(long, value_enum, default_value_t = Sensor::Ccd4720)]
    pub sensor: Sensor,
    /// Also write the sensor's truth (flat, relative dark, column bias, defects) as FITS
    /// into this folder, to judge other tools' products against.
    #[arg(long)]
    pub truth_dir: Option<PathBuf>,
    /// Leave out the saturation ladder (the 20 flats past the linear range, recorded last):
    /// the 78 frames that a tool combining every flat into its master flat can use.
    #[arg(long)]
    pub no_saturation_ladder: bool,
}

/// True for a FITS file name: `.fits`, `.fit`, `.fts`, each also gzipped (`.gz`) or
/// tile-compressed (`.fz`), any case.
pub fn is_fits_name(name: &str) -> bool {
    let n = name.to_ascii_lowercase();
    let n = n
        .strip_suffix(".gz")
        .or_else(|| n.strip_suffix(".fz"))
        .unwrap_or(&n);
    [".fits", ".fit", ".fts"].iter().any(|e| n.ends_with(e))
}

fn collect_fits(dir: &Path, out: &mut Vec<PathBuf>) -> Result<(), CliError> {
    let rd = std::fs::read_dir(dir).map_err(|e| LabError::Io {
        path: dir.to_path_buf(),
        msg: e.to_string(),
    })?;
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            collect_fits(&p, out)?;
        } else if p
            .file_name()
            .and_then(|x| x.to_str())
            .is_some_and(is_fits_name)
        {
            out.push(p);
        }
    }
    Ok(())
}

/// The FITS files of `dirs` and their sub-folders, sorted by path.
pub fn fits_files(dirs: &[PathBuf]) -> Result<Vec<PathBuf>, CliError> {
    let mut v = Vec::new();
    for d in dirs {
        collect_fits(d, &mut v)?;
    }
    v.sort();
    v.dedup();
    if v.is_empty() {
        return Err(CliError::Usage(format!(
            "no FITS files in {}",
            dirs.iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    Ok(v)
}

/// Runs `startrack calib frames`: measures, writes the report, then the table.
pub fn run(args: &CalibFramesArgs) -> Result<Products, CliError> {
    let started = std::time::Instant::now();
    let files = fits_files(&args.dirs)?;
    let bar = indicatif::ProgressBar::new(files.len() as u64);
    let tick = || bar.inc(1);
    let grouping = Grouping {
        temperature_tolerance_k: args.temperature_tolerance_k,
    };
    let products = calibrate_with(&files, &args.sensor.geometry(), &grouping, &tick)
        .map_err(|e| CliError::Usage(e.to_string()))?;
    bar.finish_and_clear();
    let table = products.table(args.tile_log2)?;
    let written = report::write(&products, &args.report_dir)?;
    write_file(&args.out, &table)?;
    for n in products.groups.iter().chain(&products.notes) {
        println!("{n}");
    }
    for s in &written.skipped_png {
        println!("skipped {s}");
    }
    println!(
        "wrote {} ({} bytes) and {} files in {}",
        args.out.display(),
        table.len(),
        written.files.len(),
        args.report_dir.display()
    );
    println!(
        "{} files in {:.1} s{}",
        files.len(),
        started.elapsed().as_secs_f64(),
        peak_resident_mb().map_or(String::new(), |mb| format!(
            ", peak resident memory {mb:.0} MB"
        ))
    );
    Ok(products)
}

/// This process's peak resident memory, MB (Linux: `VmHWM` of `/proc/self/status`; `None`
/// elsewhere).
pub fn peak_resident_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Runs `startrack calib lab-set`: writes the frames and prints how many.
pub fn run_lab_set(args: &LabSetArgs) -> Result<Vec<PathBuf>, CliError> {
    let mut set = match args.sensor {
        Sensor::Ccd4720 => LabSet::ccd47_20(args.seed),
        Sensor::Test128 => LabSet::small(args.seed),
    };
    if args.no_saturation_ladder {
        set.saturation_exposures_s.clear();
    }
    let paths = set.write(Path::new(&args.out))?;
    println!("wrote {} frames in {}", paths.len(), args.out.display());
    if let Some(dir) = &args.truth_dir {
        let t = set.write_truth(dir)?;
        println!("wrote {} truth maps in {}", t.len(), dir.display());
    }
    Ok(paths)
}
