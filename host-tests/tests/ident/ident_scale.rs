//! Identification with a focal length the camera model has wrong (up to +-2 %) and in
//! sparse fields (stars to Hp 5.5): lost in space solves and estimates the scale, tracking
//! follows a drift of it, and no field is ever solved wrong. Fields rendered from the repo's
//! catalog at random attitudes (seeded) through the true camera and measured through a
//! model whose focal length is off. The long runs are `#[ignore]`d, with their command on
//! each.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use startrack_core::attitude::{Camera, Quat};
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig, IdentError, Measured};
use startrack_sim::sky::field::{self, FLUX_E_AT_MAG0, FieldSpec, FieldStar};

use super::ident::{catalog, count_from_env, is_right};

/// The camera model identification is told: a pinhole at the true camera's principal point,
/// its focal length `1 + focal_error` times the true camera's, none of its distortion.
fn told(camera: &Camera, focal_error: f64) -> Camera {
    Camera::pinhole(
        camera.focal_length_px * (1.0 + focal_error),
        camera.principal_point_px,
    )
}

/// Only the stars (and false stars) at least as bright as `mag_limit` in observed flux.
fn brighter_than(stars: Vec<FieldStar>, mag_limit: f64) -> Vec<FieldStar> {
    let min_flux_e = FLUX_E_AT_MAG0 * 10f64.powf(-0.4 * mag_limit);
    stars
        .into_iter()
        .filter(|s| s.flux_e >= min_flux_e)
        .collect()
}

/// What a lost-in-space run did.
#[derive(Debug, Default)]
pub struct Tally {
    pub fields: usize,
    pub solved: usize,
    pub wrong: usize,
    /// Fields with fewer stars than the fewest a solution can have (4).
    pub too_few: usize,
    pub worst_bound: f64,
    pub max_hyps: u32,
    /// Sum over solved fields of ((scale - truth) / sigma)^2.
    pub scale_chi2: f64,
    /// Largest |scale - truth| / sigma.
    pub worst_scale_sigmas: f64,
    /// Fewest matched stars in a solution.
    pub min_matched: usize,
    /// Unsolved fields by their count of true (catalog) stars, 0 to 15 and more.
    pub unsolved_by_stars: [usize; 16],
    /// Unsolved fields that no identification can solve at all: fewer true stars than
    /// false ones plus 3, so that a hypothesis matching every true star still leaves more
    /// stars unmatched than it matched beyond its triangle (the gated count's rule,
    /// `2 m >= n + 3`).
    pub unsolved_by_rule: usize,
    /// Solved fields by their count of true (catalog) stars, 0 to 15 and more.
    pub solved_by_stars: [usize; 16],
    /// The place of the accepted hypothesis in the search, one per solved field.
    pub accepted_at: Vec<u32>,
    /// Solutions with a matched star that is not its true star (nor a companion within
    /// 2 px the sensor cannot split).
    pub misidentified: usize,
    /// Solutions whose attitude error is beyond their own covariance: normalised error
    /// squared above [`NEES_WRONG`].
    pub beyond_covariance: usize,
    /// Mean normalised error squared of the solutions (3 expected).
    pub mean_nees: f64,
    /// Solutions more than 1 mrad off (counted in `wrong`) and, of them, the largest
    /// normalised error squared.
    pub worst_wrong_nees: f64,
    /// Solutions more than a degree off: a wrong identification, not a loose roll.
    pub off_by_degrees: usize,
}

/// A normalised attitude error squared (3 degrees of freedom) beyond this is an attitude its
/// covariance does not cover: a chi-square with 3 degrees of freedom exceeds 30 with
/// probability 1.4e-6.
const NEES_WRONG: f64 = 30.0;

/// `e^T P^-1 e`: the error rotation vector `e` normalised by the covariance `p`.
pub(crate) fn nees(p: [[f64; 3]; 3], e: [f64; 3]) -> f64 {
    let det = p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1])
        - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0])
        + p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
    let mut s = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            let (a, b, c, d) = ((j + 1) % 3, (j + 2) % 3, (i + 1) % 3, (i + 2) % 3);
            let inv_ij = (p[a][c] * p[b][d] - p[a][d] * p[b][c]) / det;
            s += e[i] * inv_ij * e[j];
        }
    }
    s
}

/// Matched stars that are not the star they were rendered from nor within 2 px of it.
fn misidentified(cat: &Catalog<'_>, sol: &ident::Solution, stars: &[FieldStar]) -> usize {
    let two_px = 2.0 / FieldSpec::ccd47_15deg(0.0).camera.focal_length_px;
    sol.matches
        .iter()
        .filter(|m| {
            let t = stars.get(usize::from(m.star)).and_then(|s| s.truth);
            !t.and_then(|t| Some((cat.dir(t.into())?, cat.dir(m.catalog.into())?)))
                .is_some_and(|(a, b)| startrack_core::attitude::angle_between(a, b) < two_px)
        })
        .count()
}

/// `fields` fields, each with a focal error drawn uniformly in `+-max_focal_error`, the
/// stars cut at `mag_limit`, identified at the acceptance level `alpha` (`None`: the
/// configuration's, 10^-9).
fn run_lis(
    fields: usize,
    seed: u64,
    spec: &FieldSpec,
    max_focal_error: f64,
    mag_limit: f64,
    band: Option<&Band>,
    alpha: Option<f64>,
) -> Tally {
    let mut cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    if let Some(a) = alpha {
        cfg.max_false_probability = a;
    }
    let cat = catalog();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut t = Tally {
        fields,
        min_matched: usize::MAX,
        ..Tally::default()
    };
    for f in 0..fields {
        // Where the field starts in the generator's stream: `replay` draws it again.
        let word_pos = rng.get_word_pos();
        let q = field::random_attitude(&mut rng);
        let focal_error = max_focal_error * (2.0 * rng.random::<f64>() - 1.0);
        let stars = brighter_than(field::render(&cat, q, spec, &mut rng), mag_limit);
        let model = told(&spec.camera, focal_error);
        let mut meas: Vec<Measured> = field::measured(&stars, &model, spec.sigma_px);
        if let Some(b) = band {
            into_band(&cat, &mut meas, &stars, b, seed ^ (f as u64) << 20);
        }
        let r = ident::lost_in_space(&cat, &meas, &cfg);
        match r {
            Ok(sol) => {
                t.solved += 1;
                let real = stars.iter().filter(|s| s.truth.is_some()).count();
                t.solved_by_stars[real.min(15)] += 1;
                t.accepted_at.push(sol.hypotheses);
                t.max_hyps = t.max_hyps.max(sol.hypotheses);
                t.worst_bound = t.worst_bound.max(sol.false_probability);
                t.min_matched = t.min_matched.min(sol.matches.len());
                let z2 = nees(sol.attitude.cov_rad2, sol.attitude.q.error_vector(q));
                t.mean_nees += z2;
                t.beyond_covariance += usize::from(z2 > NEES_WRONG);
                t.misidentified += usize::from(misidentified(&cat, &sol, &stars) > 0);
                if !is_right(&sol, q) {
                    t.wrong += 1;
                    t.worst_wrong_nees = t.worst_wrong_nees.max(z2);
                    let e = sol.attitude.q.error_vector(q);
                    let off_rad = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
                    t.off_by_degrees += usize::from(off_rad > 1f64.to_radians());
                    println!(
                        "beyond 1 mrad: field {f} (word {word_pos}), focal error {focal_error:+.4}, error {:?} rad, roll sigma {:.2e} rad, NEES {z2:.1}, {} matched, bound {:e}",
                        sol.attitude.q.error_vector(q),
                        sol.attitude.cov_rad2[2][2].sqrt(),
                        sol.matches.len(),
                        sol.false_probability
                    );
                    continue;
                }
                // Measured separations are (true focal / model focal) times the true ones.
                let truth = 1.0 / (1.0 + focal_error);
                let z = (sol.scale.value - truth) / sol.scale.sigma;
                t.scale_chi2 += z * z;
                t.worst_scale_sigmas = t.worst_scale_sigmas.max(z.abs());
            }
            Err(IdentError::NoMatch { hypotheses }) => {
                t.max_hyps = t.max_hyps.max(hypotheses);
                let real = stars.iter().filter(|s| s.truth.is_some()).count();
                t.unsolved_by_stars[real.min(15)] += 1;
                let n = meas.len().min(ident::MAX_STARS);
                t.unsolved_by_rule += usize::from(2 * real.min(n) < n + 3);
            }
            Err(IdentError::TooFewStars) => t.too_few += 1,
            Err(e) => panic!("{e}"),
        }
    }
    t.mean_nees /= t.solved.max(1) as f64;
    t
}

fn print(name: &str, t: &Tally) {
    println!(
        "{name}: {}/{} solved, {} wrong, {} with fewer than 4 stars, worst false-match bound {:.1e}, at most {} hypotheses, fewest matched {}, scale: mean squared error/sigma {:.3}, worst {:.2} sigma",
        t.solved,
        t.fields,
        t.wrong,
        t.too_few,
        t.worst_bound,
        t.max_hyps,
        t.min_matched,
        t.scale_chi2 / t.solved.max(1) as f64,
        t.worst_scale_sigmas
    );
    println!(
        "  unsolved fields by their true stars (0..15+): {:?}",
        t.unsolved_by_stars
    );
    println!(
        "  misidentified {}, beyond their covariance (NEES > {NEES_WRONG}) {}, mean NEES {:.3}, worst NEES of those beyond 1 mrad {:.1}",
        t.misidentified, t.beyond_covariance, t.mean_nees, t.worst_wrong_nees
    );
}

/// The floors docs/attitude.md states, for fields of 30, 60, 100, 150 and the densest
/// field's catalog stars (0.3 px, 10^-9, at most 5,000 hypotheses), for the true triangle
/// found 1st, 10th (the median of sparse fields, `sparse_acceptance_levels`) and 36th
/// (their 90th percentile).
const FLOORS: [(u32, [usize; 5]); 3] = [
    (1, [6, 6, 6, 6, 6]),
    (10, [6, 6, 6, 6, 7]),
    (36, [6, 6, 6, 7, 7]),
];

/// 0.3 px, 10 % of the stars dropped, 3 false stars.
fn nominal_spec() -> FieldSpec {
    let mut spec = FieldSpec::ccd47_15deg(0.3);
    spec.dropout = 0.1;
    spec.false_stars = 3;
    spec
}
/// The nominal fields through optics with radial and decentring distortion the model does not
/// hold (an uncalibrated camera): k1 0.1, k2 -0.3, p1 1.5e-4, p2 -1e-4, the camera the optics
/// fit's simulated test recovers (docs/attitude.md, "The fit"). A star at the sensor's corner
/// is 2.2 px from where the pinhole puts it.
fn distorted_spec() -> FieldSpec {
    let mut spec = nominal_spec();
    spec.camera.k1 = 0.1;
    spec.camera.k2 = -0.3;
    spec.camera.p1 = 1.5e-4;
    spec.camera.p2 = -1e-4;
    spec
}

/// The nominal fields with 15 false stars rather than 3, as a radiation storm's particle hits
/// or a bright object's glints would add where the tracker's rejection lets them through.
/// Drawn uniformly over Hp 1 to 6.5, they are brighter than most true stars: 6 to 12 of a
/// field's 12 brightest points are false, the triangles are tried from those, and most fields
/// go unsolved (17 % solved in a 1,000-field trial), but none may be solved wrong.
fn storm_spec() -> FieldSpec {
    let mut spec = nominal_spec();
    spec.false_stars = 15;
    spec
}

/// Stars to Hp 5.5 (the cut applied to the rendered list), 0.3 px, 3 false stars over
/// Hp 1..6.5 before the cut (so about 2 a field survive it), nothing dropped.
fn sparse_spec() -> FieldSpec {
    let mut spec = FieldSpec::ccd47_15deg(0.3);
    spec.false_stars = 3;
    spec
}

/// A camera whose photometry is not Hp's, as identification is told the stars'
/// brightness: a flux scale 0.5 mag off, a colour term of 0.2 mag per mag of B-V (a silicon
/// sensor's band against Hp) and 0.1 mag of noise more than the generator's 0.1.
const CAMERA_BAND: Band = Band {
    zero_point_mag: 0.5,
    colour_mag_per_bv: 0.2,
    noise_mag: 0.1,
};

/// How the camera's band differs from Hp (see [`CAMERA_BAND`]).
#[derive(Clone, Copy, Debug)]
pub struct Band {
    pub zero_point_mag: f64,
    pub colour_mag_per_bv: f64,
    pub noise_mag: f64,
}

/// The instrumental magnitudes of `meas` moved from the generator's Hp to the camera's
/// `band` (false stars keep theirs, noise added), from a stream of their own (`seed`) so the
/// fields drawn stay the same.
fn into_band(
    cat: &Catalog<'_>,
    meas: &mut [Measured],
    stars: &[FieldStar],
    band: &Band,
    seed: u64,
) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for (m, s) in meas.iter_mut().zip(stars) {
        let bv = s
            .truth
            .and_then(|t| cat.star(t.into()))
            .map_or(0.0, |x| f64::from(x.bv_mmag) / 1000.0);
        let noise: f64 = (0..12).map(|_| rng.random::<f64>()).sum::<f64>() - 6.0;
        m.inst_mag = m.inst_mag.map(|v| {
            (f64::from(v)
                + band.zero_point_mag
                + band.colour_mag_per_bv * bv
                + band.noise_mag * noise) as f32
        });
    }
}

/// Distortion the model does not hold moves stars at the field's edge by up to 2.2 px, near
/// the 2.5 px match radius, and adds to the scale a field fits: the 28 of 1,000 fields left
/// unsolved are those told a focal length 1.86 to 2 % short, whose fitted scale the
/// distortion takes outside the searched +-2 % (no solution, by rule). None is solved wrong. The attitude's covariance does not cover the unmodelled distortion
/// (nor does the scale's: it absorbs part of it), so the attitudes are judged by the 1 mrad
/// limit.
#[test]
fn lost_in_space_with_distortion_not_in_the_model() {
    let spec = distorted_spec();
    let corner = told(&spec.camera, 0.0)
        .project(spec.camera.direction(0.0, 0.0))
        .expect("the corner is in front of the camera");
    println!("the corner (0, 0) through the pinhole: {corner:.3?}");
    let t = run_lis(1000, 37, &spec, 0.02, 99.0, None, None);
    print(
        "lost in space, distortion not in the model, focal length off by up to 2 %",
        &t,
    );
    assert_eq!(t.wrong, 0);
    assert!(
        t.solved * 100 >= t.fields * 95,
        "{} of {}",
        t.solved,
        t.fields
    );
}

#[test]
fn lost_in_space_with_the_focal_length_off_by_2_percent() {
    let t = run_lis(1000, 31, &nominal_spec(), 0.02, 99.0, None, None);
    print("lost in space, focal length off by up to 2 %", &t);
    assert_eq!(t.wrong, 0);
    assert!(
        t.solved * 1000 >= t.fields * 999,
        "{} of {}",
        t.solved,
        t.fields
    );
    // The scale's sigma is right: the mean squared normalised error is near 1 (its
    // spread over 1,000 fields is about 0.05) and no field is off by 5 sigma.
    let chi2 = t.scale_chi2 / t.solved as f64;
    assert!((0.8..1.25).contains(&chi2), "{chi2}");
    assert!(t.worst_scale_sigmas < 5.0, "{}", t.worst_scale_sigmas);
}

#[test]
fn lost_in_space_at_each_end_of_the_scale_range() {
    for focal_error in [-0.02, 0.02] {
        let cat = catalog();
        let spec = nominal_spec();
        let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
        let mut rng = ChaCha8Rng::seed_from_u64(41);
        let (mut solved, fields) = (0, 200);
        for _ in 0..fields {
            let q = field::random_attitude(&mut rng);
            let stars = field::render(&cat, q, &spec, &mut rng);
            let meas = field::measured(&stars, &told(&spec.camera, focal_error), spec.sigma_px);
            if let Ok(sol) = ident::lost_in_space(&cat, &meas, &cfg) {
                assert!(
                    is_right(&sol, q),
                    "focal error {focal_error}: wrong attitude"
                );
                solved += 1;
            }
        }
        println!("focal length off by {focal_error:+}: {solved}/{fields} solved");
        assert!(
            solved * 100 >= fields * 99,
            "{focal_error}: {solved} of {fields}"
        );
    }
}

#[test]
fn sparse_fields_solve_or_say_no_and_are_never_wrong() {
    let t = run_lis(
        1000,
        51,
        &sparse_spec(),
        0.02,
        5.5,
        Some(&CAMERA_BAND),
        None,
    );
    print("sparse (Hp <= 5.5), focal length off by up to 2 %", &t);
    assert_eq!(t.wrong, 0);
    assert!(t.worst_bound <= 1e-9, "{}", t.worst_bound);
    // The solved fraction is measured (docs/attitude.md); this floor catches a regression.
    assert!(
        t.solved * 100 >= t.fields * 92,
        "{} of {}",
        t.solved,
        t.fields
    );
}

/// The floor: the fewest stars, all matched, whose false-match bound passes 10^-9, for a
/// field holding `field_stars` catalog stars, the true triangle the `j`-th hypothesis.
fn floor(cat: &Catalog<'_>, cfg: &IdentConfig, field_stars: f64, sigma_rad: f64, j: u32) -> usize {
    (4..=ident::MAX_STARS)
        .find(|&m| {
            ident::bound_with_field_stars(cat, cfg, m, field_stars, sigma_rad, j)
                <= cfg.max_false_probability
        })
        .unwrap_or(usize::MAX)
}

#[test]
fn the_floor_of_a_sparse_field() {
    let cat = catalog();
    let spec = FieldSpec::ccd47_15deg(0.3);
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    let sigma_rad = spec.sigma_px / spec.camera.focal_length_px;
    let densest = f64::from(cat.max_field_stars());
    let fields = [30.0, 60.0, 100.0, 150.0, densest];
    let rows: Vec<(u32, Vec<usize>)> = FLOORS
        .iter()
        .map(|&(j, _)| {
            let row = fields
                .iter()
                .map(|&n| floor(&cat, &cfg, n, sigma_rad, j))
                .collect();
            (j, row)
        })
        .collect();
    for (j, row) in &rows {
        println!(
            "true triangle the hypothesis {j}: fewest stars to solve in fields of {fields:?} catalog stars: {row:?}"
        );
    }
    // The sky's own fields: the catalog stars in the field cone at random boresights.
    let mut rng = ChaCha8Rng::seed_from_u64(81);
    let mut counts: Vec<usize> = (0..2000)
        .map(|_| {
            let b = field::random_attitude(&mut rng).rotate_inv([0.0, 0.0, 1.0]);
            cat.cone(b, cat.field_radius_rad() + cfg.match_radius_rad)
                .count()
        })
        .collect();
    counts.sort_unstable();
    println!(
        "catalog stars in a field cone: 5 % {}, median {}, 95 % {}, max {}",
        counts[100], counts[1000], counts[1900], counts[1999]
    );
    for ((j, row), (fj, want)) in rows.iter().zip(FLOORS) {
        assert_eq!((*j, row.as_slice()), (fj, want.as_slice()));
    }
}

#[test]
fn random_point_sets_never_solve_with_the_scale_searched() {
    // 4 to 39 points: sparse sets as well as dense ones.
    let sets = 200;
    let (solved, max_hyps) = super::ident::random_point_sets(&catalog(), 61, sets, 4, 36, false);
    println!("random point sets: {solved} of {sets} solved, at most {max_hyps} hypotheses");
    assert_eq!(solved, 0);
}

/// `IDENT_SETS=10000 cargo test --release -p startrack-host --test ident
/// ident_scale::random_point_sets_long_run -- --ignored --nocapture`: sets of 4 to 39
/// random points of random brightness, the focal length searched over +-2 %: none solved.
#[test]
#[ignore]
fn random_point_sets_long_run() {
    let sets = count_from_env("IDENT_SETS", 10_000);
    let (solved, max_hyps) = super::ident::random_point_sets(&catalog(), 67, sets, 4, 36, true);
    println!(
        "random point sets of random brightness: {solved} of {sets} solved, at most {max_hyps} hypotheses"
    );
    assert_eq!(solved, 0);
}

#[test]
fn tracking_follows_a_scale_drift() {
    // The focal length drifts from right to 2 % long over 200 frames (0.01 % a frame, a
    // thermal drift far faster than a flight unit's); the attitude turns 0.1 degree a frame.
    let cat = catalog();
    let spec = nominal_spec();
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    let mut rng = ChaCha8Rng::seed_from_u64(71);
    let mut q = field::random_attitude(&mut rng);
    let axis = field::random_attitude(&mut rng).rotate([0.0, 0.0, 1.0]);
    let step = Quat::from_axis_angle(axis, 0.1f64.to_radians());
    let (mut prior, mut prior_scale) = (None::<Quat>, 1.0);
    let (frames, mut tracked, mut worst_sigmas) = (200, 0, 0.0f64);
    for frame in 0..frames {
        let focal_error = 0.02 * frame as f64 / (frames - 1) as f64;
        let stars = field::render(&cat, q, &spec, &mut rng);
        let meas = field::measured(&stars, &told(&spec.camera, focal_error), spec.sigma_px);
        let sol = match prior {
            Some(p) => {
                let s = ident::track_scaled(&cat, &meas, p, prior_scale, 0.5f64.to_radians(), &cfg)
                    .unwrap_or_else(|e| panic!("frame {frame}: tracking: {e}"));
                tracked += 1;
                s
            }
            None => ident::lost_in_space(&cat, &meas, &cfg).unwrap_or_else(|e| panic!("{e}")),
        };
        assert!(is_right(&sol, q), "frame {frame}: wrong attitude");
        let z = (sol.scale.value - 1.0 / (1.0 + focal_error)) / sol.scale.sigma;
        worst_sigmas = worst_sigmas.max(z.abs());
        prior = Some(sol.attitude.q);
        prior_scale = sol.scale.value;
        q = (step * q).normalized().unwrap_or(q);
    }
    println!(
        "tracking with a 2 % focal drift: {tracked} of {} frames tracked, scale within {worst_sigmas:.2} sigma of the truth",
        frames - 1
    );
    assert_eq!(tracked, frames - 1);
    assert!(worst_sigmas < 5.0, "{worst_sigmas}");
}

/// The sparse fields of the 20,000-field run (`long_runs`, seed 3051) that came out more
/// than 1 mrad off, each from where it starts in the generator's stream, with what was
/// wrong: one where a false star 2.7 px from a true star took its catalog star and pulled
/// the roll 1.05 mrad (4.4 of its sigmas), one solved from a cluster of 9 stars at the
/// field's edge whose roll (6.7 mrad, sigma 3 mrad) left the other 9 true stars beyond the
/// match radius; and three roll errors of 1.01 to 1.08 mrad that all their true stars and
/// only those made, 2.3 to 3.5 of their own roll sigmas (0.29 to 0.47 mrad).
const SPARSE_REPLAYS: [(u128, bool); 5] = [
    (59_220, true),
    (219_082, true),
    (3_900_832, false),
    (6_260_388, false),
    (6_447_678, false),
];

/// The field that starts at word `word_pos` of seed `seed`'s stream, as `run_lis` draws it.
fn replay(
    seed: u64,
    word_pos: u128,
    spec: &FieldSpec,
    mag_limit: f64,
) -> (Quat, Vec<FieldStar>, Vec<Measured>) {
    let cat = catalog();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_word_pos(word_pos);
    let q = field::random_attitude(&mut rng);
    let focal_error = 0.02 * (2.0 * rng.random::<f64>() - 1.0);
    let stars = brighter_than(field::render(&cat, q, spec, &mut rng), mag_limit);
    let meas = field::measured(&stars, &told(&spec.camera, focal_error), spec.sigma_px);
    (q, stars, meas)
}

#[test]
fn sparse_fields_once_beyond_1_mrad_are_right_or_within_their_covariance() {
    let cat = catalog();
    let spec = sparse_spec();
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    for (word_pos, was_a_defect) in SPARSE_REPLAYS {
        let (q, stars, meas) = replay(3051, word_pos, &spec, 5.5);
        let sol = ident::lost_in_space(&cat, &meas, &cfg)
            .unwrap_or_else(|e| panic!("word {word_pos}: {e}"));
        let e = sol.attitude.q.error_vector(q);
        let z2 = nees(sol.attitude.cov_rad2, e);
        let roll_sigmas = e[2].abs() / sol.attitude.cov_rad2[2][2].sqrt();
        println!(
            "word {word_pos}: {} of {} matched, error {:.3?} mrad, roll {roll_sigmas:.2} sigma, NEES {z2:.1}",
            sol.matches.len(),
            meas.len(),
            e.map(|x| x * 1e3)
        );
        assert_eq!(misidentified(&cat, &sol, &stars), 0, "word {word_pos}");
        // The chi-square (3 degrees of freedom) 0.999 quantile.
        assert!(z2 < 16.27, "word {word_pos}: NEES {z2}");
        if was_a_defect {
            assert!(is_right(&sol, q), "word {word_pos}: {e:?}");
        } else {
            assert!(roll_sigmas < 4.0, "word {word_pos}: {roll_sigmas}");
        }
    }
}

/// `IDENT_FIELDS=100000 cargo test --release -p startrack-host --test ident ident_scale::
/// -- --ignored --nocapture`. Nominal fields: none more than 1 mrad off nor beyond its
/// covariance. Distortion not in the model: none more than 1 mrad off. Fifteen false stars
/// (a tenth as many fields: each is slow, most triangles holding a false star): none more
/// than 1 mrad off nor beyond its covariance. Sparse fields: no attitude beyond its own covariance (NEES above
/// [`NEES_WRONG`]); the attitudes more than 1 mrad off are printed and counted (a roll sigma
/// of a few tenths of a mrad in a field of 7 to 10 stars makes some).
#[test]
#[ignore]
fn long_runs() {
    let fields = count_from_env("IDENT_FIELDS", 100_000);
    let t = run_lis(fields, 3031, &nominal_spec(), 0.02, 99.0, None, None);
    print("lost in space, focal length off by up to 2 %", &t);
    assert_eq!(t.wrong, 0);
    // A false star can fall on a catalog star that dropped out, indistinguishable from it
    // (10 % dropped): counted, not failed.
    assert_eq!(t.beyond_covariance, 0);
    let d = run_lis(fields, 3041, &distorted_spec(), 0.02, 99.0, None, None);
    print(
        "distortion not in the model, focal length off by up to 2 %",
        &d,
    );
    assert_eq!(d.wrong, 0);
    storm_case(fields / 10, 3061);
    let s = run_lis(
        fields,
        3051,
        &sparse_spec(),
        0.02,
        5.5,
        Some(&CAMERA_BAND),
        None,
    );
    print("sparse (Hp <= 5.5), focal length off by up to 2 %", &s);
    // The cut at Hp 5.5 hides the catalog's fainter stars as dropouts do: a false star on one
    // is counted, not failed.
    assert_eq!(s.beyond_covariance, 0);
    assert!(s.worst_wrong_nees < NEES_WRONG, "{}", s.worst_wrong_nees);
}

/// The fifteen-false-star case alone at its own size (`IDENT_STORM_FIELDS`, 100,000 by
/// default; [`long_runs`] runs a tenth of its fields):
/// `cargo test --release -p startrack-host --test ident ident_scale::storm_long_run --
/// --ignored --nocapture`. None more than 1 mrad off nor beyond its covariance.
#[test]
#[ignore]
fn storm_long_run() {
    storm_case(count_from_env("IDENT_STORM_FIELDS", 100_000), 3071);
}

/// Lost in space on `fields` fields of fifteen false stars (seed `seed`): printed, none more
/// than 1 mrad off nor beyond its covariance.
fn storm_case(fields: usize, seed: u64) {
    let f = run_lis(fields, seed, &storm_spec(), 0.02, 99.0, None, None);
    print("15 false stars, focal length off by up to 2 %", &f);
    assert_eq!(f.wrong, 0);
    assert_eq!(f.beyond_covariance, 0);
}

/// `IDENT_FIELDS=100000 cargo test --release -p startrack-host --test ident
/// ident_scale::sparse_acceptance_levels -- --ignored --nocapture`: the sparse fields of
/// `long_runs` (seed 3051) solved at acceptance levels 10^-9 (the configuration's) to
/// 10^-6: how many more each looser level solves, by their true stars, and how many of
/// those it solves wrong (more than a degree off: a wrong identification). The trade of
/// docs/attitude.md, "Sparse fields: the floor".
#[test]
#[ignore]
fn sparse_acceptance_levels() {
    let fields = count_from_env("IDENT_FIELDS", 100_000);
    let spec = sparse_spec();
    for alpha in [1e-9, 1e-8, 1e-7, 1e-6] {
        let mut t = run_lis(
            fields,
            3051,
            &spec,
            0.02,
            5.5,
            Some(&CAMERA_BAND),
            Some(alpha),
        );
        t.accepted_at.sort_unstable();
        let at = |f: usize| t.accepted_at.get(t.accepted_at.len() * f / 100).copied();
        println!(
            "alpha {alpha:.0e}: {} of {} solved, {} more than 1 mrad off, {} more than a degree off, {} beyond their covariance; solved by true stars (0..15+) {:?}; unsolved {:?}, {} of them too few true stars for the rule 2 m >= n + 3; accepted hypothesis median {:?}, 90 % {:?}",
            t.solved,
            t.fields,
            t.wrong,
            t.off_by_degrees,
            t.beyond_covariance,
            t.solved_by_stars,
            t.unsolved_by_stars,
            t.unsolved_by_rule,
            at(50),
            at(90)
        );
    }
}

/// The nominal field of the 100,000-field run (`long_runs`, seed 3031) that came out wrong:
/// field 98736, from word 34,905,592 of the stream. Its triangle's two close stars and one
/// far false star (12 px from a true star, and brighter) fixed the tilt, roll and scale;
/// a cluster of 8 true stars around the close pair agreed, and the far false star, the only
/// one fixing roll and scale, was followed by the fit rather than checked: 2.3 mrad off,
/// NEES 1645, 11 matched.
#[test]
fn the_nominal_field_once_wrong_is_right() {
    let z2 = replayed_field_is_right(3031, 34_905_592, &nominal_spec());
    assert!(z2 < 16.27, "NEES {z2}");
}

/// Replays the field at `word_pos` of the stream of `seed`, solves it lost in space and
/// asserts it right with every star matched to its own catalog star: its NEES.
fn replayed_field_is_right(seed: u64, word_pos: u128, spec: &FieldSpec) -> f64 {
    let cat = catalog();
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    let (q, stars, meas) = replay(seed, word_pos, spec, 99.0);
    let sol = ident::lost_in_space(&cat, &meas, &cfg).expect("the field solves");
    let e = sol.attitude.q.error_vector(q);
    let z2 = nees(sol.attitude.cov_rad2, e);
    println!(
        "{} of {} matched, error {:.3?} mrad, NEES {z2:.1}",
        sol.matches.len(),
        meas.len(),
        e.map(|x| x * 1e3)
    );
    assert_eq!(misidentified(&cat, &sol, &stars), 0);
    assert!(is_right(&sol, q), "{e:?}");
    z2
}

/// The field of the 100,000-field run with distortion not in the model (`long_runs`, seed
/// 3041) once solved wrong: field 97516, from word 34,318,952 of the stream. A cluster of 7
/// true stars and one wrong neighbour, its roll bent 6.5 mrad, matched 8 of 32 stars and
/// passed the gated count at 1.8e-10; the gated count is made only for a hypothesis that
/// explains the field, and the field solves right.
#[test]
fn the_distorted_field_once_wrong_is_right() {
    // Its covariance does not hold the distortion: judged by the 1 mrad limit only.
    replayed_field_is_right(3041, 34_318_952, &distorted_spec());
}
