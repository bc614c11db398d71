//! The tracker's availability with bright objects, stray light and radiation: the SIL over
//! the sky ([`startrack_homes::sil`]) with the Moon, the Earth's limb, the Sun's stray light,
//! a planet or proton hits ([`startrack_sim::sky::bright`]), per scene the frames with an
//! attitude, the wrong ones, the frames with at least [`MIN_UNAFFECTED`] unaffected stars
//! and how many of those have an attitude, the frames from the object leaving the field to
//! the next attitude, and the frames each cause flags.
//!
//! A solved frame is wrong as [`crate::sil_rates::is_wrong`] says (60 arcsec, or 10 of its
//! own sigmas). A true star is unaffected when no object and no proton charge is within
//! 6 px of it ([`sil::unaffected`]). The recovery is counted from the first frame whose
//! image holds neither the Moon nor the Earth ([`sil::object_in_field`]) after one that
//! did, to the first frame from it with an attitude (0: that frame has one). Each frame's
//! [`Obstructions`] are checked against its truth ([`sil::causes`], [`flag_errors`]).
//!
//! The scenes: the SIL's still sky (seeded attitude), the flight tracker, 100 ms exposures
//! every 100 ms; each bright object fixed in the sky as the field drifts by `drift_px` a
//! frame. Cost: what its frames cost in the SIL (~1 s an acquisition frame in release,
//! ~0.02 s a tracking frame) plus the bright scene: a frame's bloomed columns (up to
//! ~0.1 s with the Earth) and its proton hits (a few ms), twice a frame (the tracker's
//! frame and the truth's).

use crate::sil_rates::is_wrong;
use startrack_core::tracker::{MOON_MIN_COLUMNS, Obstructions, STRAY_LIGHT_LIMIT_E};
use startrack_homes::sil::{self, SilConfig, SilReport};
use startrack_sim::sim::protons::ProtonEnv;
use startrack_sim::sky::bright::{BrightSky, EarthSpec, MoonSpec, PlanetSpec, SunSpec};

/// The fewest unaffected stars a frame must hold for the target "an attitude in every
/// frame with at least this many" to apply.
pub const MIN_UNAFFECTED: usize = 3;

/// A scene to run.
#[derive(Clone, Debug, PartialEq)]
pub struct BrightCase {
    /// Its name in the table.
    pub name: &'static str,
    /// What the sky holds beyond its stars.
    pub bright: BrightSky,
    /// The field's drift per frame, px (x, y).
    pub drift_px: (f64, f64),
    /// Frames.
    pub frames: u32,
}

fn moon(x: f64, y: f64, phase_deg: f64) -> BrightSky {
    BrightSky {
        moon: Some(MoonSpec {
            at_px: [x, y],
            phase_deg,
        }),
        ..BrightSky::default()
    }
}

fn protons(env: ProtonEnv) -> BrightSky {
    BrightSky {
        protons: Some(env),
        ..BrightSky::default()
    }
}

/// The short scenes the CI test asserts on and the table shows: the full Moon leaving the
/// field at its edge, the Earth's limb 150 px into a corner, the Sun at 32 deg, Venus,
/// the SAA's and a solar flare's protons; `frames` frames each (the Moon's scene runs
/// until 5 frames after it leaves).
pub fn short_cases(frames: u32) -> Vec<BrightCase> {
    vec![
        BrightCase {
            name: "moon leaving",
            bright: moon(1020.0, 480.0, 0.0),
            drift_px: (0.9, 0.0),
            frames: frames.max(30),
        },
        BrightCase {
            name: "earth limb",
            bright: BrightSky {
                earth: Some(EarthSpec {
                    corner: 3,
                    depth_px: 150.0,
                }),
                ..BrightSky::default()
            },
            drift_px: (0.3, 0.0),
            frames,
        },
        BrightCase {
            name: "sun 32 deg",
            bright: BrightSky {
                sun: Some(SunSpec {
                    angle_deg: 32.0,
                    azimuth_deg: 0.0,
                }),
                ..BrightSky::default()
            },
            drift_px: (0.3, 0.0),
            frames,
        },
        BrightCase {
            name: "venus",
            bright: BrightSky {
                planets: vec![PlanetSpec {
                    at_px: [400.0, 300.0],
                    mag: -4.5,
                }],
                ..BrightSky::default()
            },
            drift_px: (0.3, 0.0),
            frames,
        },
        BrightCase {
            name: "saa",
            bright: protons(ProtonEnv::Saa),
            drift_px: (0.3, 0.0),
            frames,
        },
        BrightCase {
            name: "flare",
            bright: protons(ProtonEnv::Flare),
            drift_px: (0.3, 0.0),
            frames,
        },
    ]
}

/// The long scene behind `#[ignore]`: the full Moon crossing the whole field, from beyond
/// its left edge to beyond its right, at 0.9 px a frame (1,230 frames).
pub fn moon_crossing() -> BrightCase {
    BrightCase {
        name: "moon crossing",
        bright: moon(-40.0, 480.0, 0.0),
        drift_px: (0.9, 0.0),
        frames: 1230,
    }
}

/// A scene's result.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BrightRow {
    /// The scene's name.
    pub scene: String,
    /// Frames run.
    pub frames: usize,
    /// Frames with an attitude.
    pub solved: usize,
    /// Solved frames that are wrong.
    pub wrong: usize,
    /// Frames with at least [`MIN_UNAFFECTED`] unaffected stars.
    pub eligible: usize,
    /// ... of them with an attitude.
    pub eligible_solved: usize,
    /// Frames from the object leaving to the next attitude (the worst, if it left more than
    /// once); `None` when nothing left the field.
    pub recovery_frames: Option<usize>,
    /// Frames whose report flags the Moon.
    pub flagged_moon: usize,
    /// ... the Earth.
    pub flagged_earth: usize,
    /// ... the Sun's stray light.
    pub flagged_sun: usize,
    /// ... radiation.
    pub flagged_radiation: usize,
    /// Windows counted as particle hits over the run.
    pub hits: usize,
    /// Detections and windows masked over the run.
    pub masked: usize,
    /// Frames whose truth holds a cause the flags should name: the Moon or the Earth in the
    /// field, the Sun's stray light above the limit, an SAA or flare proton rate.
    pub cause_frames: usize,
    /// Frames whose flags say what the truth does not ([`flag_errors`]): a stale flag.
    pub wrong_flags: usize,
    /// The first such frame, its flags, truth and errors (not in the CSV).
    pub first_wrong_flags: Option<String>,
}

/// What a frame's flags say wrongly against its truth: each bit set without its cause in the
/// frame, and each of the Moon, the Earth and the Sun missing where the frame holds it (the
/// Moon spanning at least [`MOON_SURE_COLS`] columns: a thinner sliver at the edge is
/// narrower than the tracker's Moon and may go either way). Radiation is a rate over the
/// last second's frames, and a tracking frame reads ~0.5 % of the area: a frame of an SAA
/// or flare run without the bit is not counted, one of a run without protons (or at the
/// quiet rate) with it is.
pub fn flag_errors(flags: Obstructions, truth: &sil::Causes) -> Vec<&'static str> {
    let mut e = Vec::new();
    let moon = truth.moon_cols > 0.0;
    let moon_sure = truth.moon_cols >= MOON_SURE_COLS;
    if flags.contains(Obstructions::MOON) && !moon && !truth.earth {
        e.push("Moon flagged, not in the field");
    }
    if !flags.intersects(Obstructions::MOON | Obstructions::EARTH) && moon_sure {
        e.push("Moon in the field, not flagged");
    }
    if flags.contains(Obstructions::EARTH) && !truth.earth {
        e.push("Earth flagged, not in the field");
    }
    if !flags.contains(Obstructions::EARTH) && truth.earth {
        e.push("Earth in the field, not flagged");
    }
    let sun = truth.stray_e > f64::from(STRAY_LIGHT_LIMIT_E);
    if flags.contains(Obstructions::SUN) != sun {
        e.push(if sun {
            "stray light, not flagged"
        } else {
            "Sun flagged, no stray light"
        });
    }
    let radiation = matches!(truth.protons, Some(ProtonEnv::Saa | ProtonEnv::Flare));
    if flags.contains(Obstructions::RADIATION) && !radiation {
        e.push("radiation flagged, no protons");
    }
    e
}

/// A Moon spanning at least this many columns of the active area must be flagged (the
/// tracker's [`MOON_MIN_COLUMNS`] and two for its limb's unsaturated edge).
pub const MOON_SURE_COLS: f64 = MOON_MIN_COLUMNS as f64 + 2.0;

/// Whether the truth holds a cause the flags should name.
fn cause_present(truth: &sil::Causes) -> bool {
    truth.moon_cols > 0.0
        || truth.earth
        || truth.stray_e > f64::from(STRAY_LIGHT_LIMIT_E)
        || matches!(truth.protons, Some(ProtonEnv::Saa | ProtonEnv::Flare))
}

/// The SIL configuration of `case` with `seed`.
pub fn config(case: &BrightCase, seed: u64) -> SilConfig {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x534b_5900);
    let q0 = startrack_sim::sky::field::random_attitude(&mut rng);
    let f = startrack_sim::sky::field::FieldSpec::ccd47_15deg(0.0)
        .camera
        .focal_length_px;
    let (dx, dy) = case.drift_px;
    SilConfig {
        frames: case.frames,
        seed,
        sky: Some(startrack_sim::sky::scene::SkyScene::ccd47_15deg(
            q0,
            [-dy / f, dx / f, 0.0],
        )),
        bright: case.bright.clone(),
        ..SilConfig::default()
    }
}

/// The row of a run.
pub fn row(name: &str, report: &SilReport) -> BrightRow {
    use startrack_core::link::telemetry::Validity;
    let mut r = BrightRow {
        scene: name.to_string(),
        frames: report.frames.len(),
        ..BrightRow::default()
    };
    let mut left_at: Option<usize> = None;
    let mut was_in = false;
    let mut worst_recovery: Option<usize> = None;
    for (k, f) in report.frames.iter().enumerate() {
        let solved = f
            .attitude
            .as_ref()
            .and_then(|c| c.fix.as_ref().ok().map(|fix| (c, fix)));
        if let Some((c, fix)) = solved {
            r.solved += 1;
            let a = &fix.attitude;
            if let Some(e) = c.error_rad()
                && is_wrong(e, a.boresight_sigma_rad(), a.roll_sigma_rad())
            {
                r.wrong += 1;
            }
        }
        if f.unaffected.is_some_and(|n| n >= MIN_UNAFFECTED) {
            r.eligible += 1;
            r.eligible_solved += usize::from(solved.is_some());
        }
        // Every frame's summary carries its flags (the attitude report only a solved
        // frame's, the same bits).
        let flags = f.summary.obstructions;
        let report_differs = f
            .attitude
            .as_ref()
            .and_then(|c| c.report)
            .is_some_and(|rep| {
                rep.flags & Validity::of_obstructions(Obstructions::all())
                    != Validity::of_obstructions(flags)
            });
        r.flagged_moon += usize::from(flags.contains(Obstructions::MOON));
        r.flagged_earth += usize::from(flags.contains(Obstructions::EARTH));
        r.flagged_sun += usize::from(flags.contains(Obstructions::SUN));
        r.flagged_radiation += usize::from(flags.contains(Obstructions::RADIATION));
        if let Some(truth) = f.causes.as_ref() {
            r.cause_frames += usize::from(cause_present(truth));
            let mut errors = flag_errors(flags, truth);
            if report_differs {
                errors.push("the report's bits are not the summary's");
            }
            if !errors.is_empty() {
                r.wrong_flags += 1;
                if r.first_wrong_flags.is_none() {
                    r.first_wrong_flags =
                        Some(format!("frame {k}: {flags:?} {truth:?}: {errors:?}"));
                }
            }
        }
        r.hits += usize::from(f.summary.hits);
        r.masked += usize::from(f.summary.masked);
        let inside = f.object_in_field.unwrap_or(false);
        if was_in && !inside {
            left_at = Some(k);
        }
        was_in = inside;
        if let Some(at) = left_at
            && solved.is_some()
        {
            let wait = k - at;
            worst_recovery = Some(worst_recovery.map_or(wait, |w| w.max(wait)));
            left_at = None;
        }
    }
    if let Some(at) = left_at {
        // Never recovered before the run ended.
        worst_recovery = Some(report.frames.len() - at);
    }
    r.recovery_frames = worst_recovery;
    r
}

/// Runs `case` with `seed`.
pub fn run_case(case: &BrightCase, seed: u64) -> Result<BrightRow, String> {
    Ok(row(case.name, &sil::run(&config(case, seed))?))
}

/// The CSV header of [`csv`].
pub const CSV_HEADER: &str = "scene,frames,solved,wrong,eligible,eligible_solved,recovery_frames,cause_frames,flagged_moon,flagged_earth,flagged_sun,flagged_radiation,wrong_flags,hits,masked";

/// The rows as CSV, after `comment` lines (each prefixed `# `).
pub fn csv(rows: &[BrightRow], comment: &[&str]) -> String {
    let mut out = crate::figures::csv::csv_head(comment, CSV_HEADER);
    for r in rows {
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            r.scene,
            r.frames,
            r.solved,
            r.wrong,
            r.eligible,
            r.eligible_solved,
            r.recovery_frames.map_or(String::new(), |v| v.to_string()),
            r.cause_frames,
            r.flagged_moon,
            r.flagged_earth,
            r.flagged_sun,
            r.flagged_radiation,
            r.wrong_flags,
            r.hits,
            r.masked
        ));
    }
    out
}

/// The flight cycle the turning scenes run: a frame every 50 ms (20 Hz), 39 ms exposures
/// (`TrackerConfig::FLIGHT`), us.
pub const TURNING_PERIOD_US: u64 = 50_000;

/// The SIL over the sky turning at `rate_deg_s` across the boresight (about the camera's x
/// axis: the stars trail along the columns) during each 39 ms exposure, a frame every
/// [`TURNING_PERIOD_US`], from power-on, with `env`'s proton hits; seed `seed`.
pub fn turning_config(env: ProtonEnv, rate_deg_s: f64, frames: u32, seed: u64) -> SilConfig {
    use rand::SeedableRng;
    use startrack_sim::sky::motion::{ExposureMotion, RateProfile};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5455_524e);
    let q0 = startrack_sim::sky::field::random_attitude(&mut rng);
    let tracker = startrack_core::tracker::TrackerConfig::FLIGHT;
    let period_s = TURNING_PERIOD_US as f64 * 1e-6;
    let exposure_s = f64::from(tracker.exposure_ms) * 1e-3;
    let profile = RateProfile::constant([rate_deg_s.to_radians(), 0.0, 0.0]);
    // Valid by construction: a finite rate, the exposure inside the period.
    let motion =
        ExposureMotion::new(profile, period_s, exposure_s).unwrap_or_else(|e| unreachable!("{e}"));
    SilConfig {
        frames,
        seed,
        tracker,
        period_us: TURNING_PERIOD_US,
        sky: Some(startrack_sim::sky::scene::SkyScene::ccd47_15deg_moving(
            q0, motion,
        )),
        bright: protons(env),
        ..SilConfig::default()
    }
}

/// A turning run's result: its row (as [`row`]) and the first frame with an attitude
/// (`None`: none), lost in space's from power-on.
pub fn run_turning(
    env: ProtonEnv,
    rate_deg_s: f64,
    frames: u32,
    seed: u64,
) -> Result<(BrightRow, Option<usize>), String> {
    let report = sil::run(&turning_config(env, rate_deg_s, frames, seed))?;
    let first = report
        .frames
        .iter()
        .position(|f| f.attitude.as_ref().is_some_and(|c| c.fix.as_ref().is_ok()));
    Ok((row(env.name(), &report), first))
}
