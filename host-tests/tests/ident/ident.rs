//! Lost-in-space and tracking identification on fields rendered from the repo's catalog at
//! random attitudes (seeded), with centroid noise, false stars and dropouts. Fast enough for
//! CI; the long run is `IDENT_FIELDS=100000 cargo test --release -p startrack-host --test
//! ident -- --ignored --nocapture`.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use startrack_core::attitude::Quat;
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig, IdentError, Solution};
use startrack_sim::sky::build::default_catalog;
use startrack_sim::sky::field::{self, FLUX_E_AT_MAG0, FieldSpec, FieldStar};
use std::sync::OnceLock;

fn catalog_bytes() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| default_catalog().map(|b| b.bytes).unwrap_or_default())
}

/// The repo's catalog, built once for every module of this binary.
pub(crate) fn catalog() -> Catalog<'static> {
    Catalog::parse(catalog_bytes()).unwrap_or_else(|e| panic!("catalog: {e}"))
}

/// A long run's size: the environment variable `name` when it parses, else `default`.
pub(crate) fn count_from_env(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// A solution is right when its attitude is within 1 mrad (4 px) of the truth: a wrong
/// identification is off by degrees.
pub(crate) fn is_right(sol: &Solution, truth: Quat) -> bool {
    let e = sol.attitude.q.error_vector(truth);
    (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt() < 1e-3
}

/// Matches that are not the true star nor, for a double closer than 2 px that the sensor
/// cannot split, its companion: a false star that fell on a catalog star (one that dropped
/// out) is indistinguishable from it.
fn mismatched_stars(sol: &Solution, stars: &[FieldStar]) -> usize {
    let cat = catalog();
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

struct Tally {
    fields: usize,
    solved: usize,
    wrong: usize,
    worst_bound: f64,
    max_hyps: u32,
    mismatched: usize,
    matched: usize,
}

fn run_lis(fields: usize, seed: u64, spec: &FieldSpec) -> Tally {
    let cat = catalog();
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut t = Tally {
        fields,
        solved: 0,
        wrong: 0,
        worst_bound: 0.0,
        max_hyps: 0,
        mismatched: 0,
        matched: 0,
    };
    for f in 0..fields {
        let q = field::random_attitude(&mut rng);
        let stars = field::render(&cat, q, spec, &mut rng);
        let meas = field::measured(&stars, &spec.camera, spec.sigma_px);
        match ident::lost_in_space(&cat, &meas, &cfg) {
            Ok(sol) => {
                t.solved += 1;
                t.max_hyps = t.max_hyps.max(sol.hypotheses);
                t.worst_bound = t.worst_bound.max(sol.false_probability);
                if !is_right(&sol, q) {
                    t.wrong += 1;
                    let e = sol.attitude.q.error_vector(q);
                    println!(
                        "wrong: field {f}, error {e:?} rad, sigmas ({:e}, {:e}) rad, {} matched, {} not the true star, bound {:e}, {} stars",
                        sol.attitude.boresight_sigma_rad(),
                        sol.attitude.roll_sigma_rad(),
                        sol.matches.len(),
                        mismatched_stars(&sol, &stars),
                        sol.false_probability,
                        stars.len()
                    );
                }
                t.matched += sol.matches.len();
                t.mismatched += mismatched_stars(&sol, &stars);
            }
            Err(IdentError::NoMatch { hypotheses }) => t.max_hyps = t.max_hyps.max(hypotheses),
            Err(_) => {}
        }
    }
    t
}

fn noisy_spec() -> FieldSpec {
    let mut spec = FieldSpec::ccd47_15deg(0.3);
    spec.dropout = 0.1;
    spec.false_stars = 3;
    spec
}

#[test]
fn catalog_sized_for_internal_flash() {
    let b = default_catalog().unwrap_or_else(|e| panic!("{e}"));
    println!(
        "catalog: {} bytes, {} stars, {} pattern stars, {} pairs, at most {} stars in a field cone",
        b.bytes.len(),
        b.stars,
        b.pattern_stars,
        b.pairs,
        b.max_field_stars
    );
    assert!(b.bytes.len() < 768 * 1024, "{} bytes", b.bytes.len());
}

#[test]
fn lost_in_space_solves_noisy_fields_and_is_never_wrong() {
    let spec = noisy_spec();
    let t = run_lis(1000, 14, &spec);
    println!(
        "lost in space: {}/{} solved, {} wrong, worst false-match bound {:.1e}, at most {} hypotheses, {} of {} matched stars not the true one",
        t.solved, t.fields, t.wrong, t.worst_bound, t.max_hyps, t.mismatched, t.matched
    );
    assert!(
        t.mismatched * 1000 < t.matched,
        "{} of {}",
        t.mismatched,
        t.matched
    );
    assert_eq!(t.wrong, 0);
    assert!(
        t.solved * 1000 >= t.fields * 999,
        "{} of {}",
        t.solved,
        t.fields
    );
}

#[test]
fn random_point_sets_never_solve() {
    let (solved, max_hyps) = random_point_sets(&catalog(), 7, 100, 10, 30, false);
    println!("random point sets: {solved} of 100 solved, at most {max_hyps} hypotheses tried");
    assert_eq!(solved, 0);
}

/// Lost in space on `sets` sets of uniformly random points (`min_n` to `min_n + span - 1` of
/// them, seeded by `seed`) over the 15 degree field, all of one flux or, with `random_flux`,
/// each of a magnitude uniform over Hp 1 to 6.5 (so the photometric test sees brightnesses
/// unrelated to the sky): how many solved, and the most hypotheses one set cost. Any other
/// error than no match fails the test.
pub(crate) fn random_point_sets(
    cat: &Catalog<'_>,
    seed: u64,
    sets: usize,
    min_n: usize,
    span: u32,
    random_flux: bool,
) -> (usize, u32) {
    let spec = FieldSpec::ccd47_15deg(0.3);
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut solved, mut max_hyps) = (0, 0);
    for _ in 0..sets {
        let n = min_n + (rng.random::<u32>() % span) as usize;
        let pts: Vec<FieldStar> = (0..n)
            .map(|_| FieldStar {
                x_px: rng.random::<f64>() * 1023.0,
                y_px: rng.random::<f64>() * 1023.0,
                flux_e: if random_flux {
                    FLUX_E_AT_MAG0 * 10f64.powf(-0.4 * (1.0 + 5.5 * rng.random::<f64>()))
                } else {
                    1.0
                },
                truth: None,
            })
            .collect();
        let meas = field::measured(&pts, &spec.camera, spec.sigma_px);
        match ident::lost_in_space(cat, &meas, &cfg) {
            Ok(_) => solved += 1,
            Err(IdentError::NoMatch { hypotheses }) => max_hyps = max_hyps.max(hypotheses),
            Err(e) => panic!("{e}"),
        }
    }
    (solved, max_hyps)
}

#[test]
fn tracking_solves_with_a_prior_2_degrees_off() {
    let cat = catalog();
    let spec = noisy_spec();
    let cfg = IdentConfig::for_camera(spec.camera.focal_length_px, spec.sigma_px);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let prior_error = 2f64.to_radians();
    let (fields, mut solved, mut wrong, mut max_hyps) = (500, 0, 0, 0);
    for _ in 0..fields {
        let q = field::random_attitude(&mut rng);
        let stars = field::render(&cat, q, &spec, &mut rng);
        let meas = field::measured(&stars, &spec.camera, spec.sigma_px);
        // The prior: the truth turned by exactly 2 degrees about a random axis.
        let axis = field::random_attitude(&mut rng).rotate([0.0, 0.0, 1.0]);
        let prior = Quat::from_axis_angle(axis, prior_error) * q;
        match ident::track(&cat, &meas, prior, prior_error, &cfg) {
            Ok(sol) => {
                solved += 1;
                max_hyps = max_hyps.max(sol.hypotheses);
                if !is_right(&sol, q) {
                    println!(
                        "wrong: {:?} {} matches {} bad bound {:e}",
                        sol.attitude.q.error_vector(q),
                        sol.matches.len(),
                        mismatched_stars(&sol, &stars),
                        sol.false_probability
                    );
                    wrong += 1;
                }
            }
            Err(IdentError::NoMatch { hypotheses }) => max_hyps = max_hyps.max(hypotheses),
            Err(e) => panic!("{e}"),
        }
    }
    println!(
        "tracking, prior 2 deg off: {solved}/{fields} solved, {wrong} wrong, at most {max_hyps} hypotheses"
    );
    assert_eq!(wrong, 0);
    assert!(solved * 1000 >= fields * 999, "{solved} of {fields}");
}

/// The long run: `IDENT_FIELDS=100000 cargo test --release -p startrack-host --test ident ident:: --
/// --ignored --nocapture`.
#[test]
#[ignore]
fn lost_in_space_long_run() {
    let fields = count_from_env("IDENT_FIELDS", 100_000);
    let t = run_lis(fields, 1914, &noisy_spec());
    println!(
        "lost in space: {}/{} solved, {} wrong, worst false-match bound {:.1e}, at most {} hypotheses, {} of {} matched stars not the true one",
        t.solved, t.fields, t.wrong, t.worst_bound, t.max_hyps, t.mismatched, t.matched
    );
    assert_eq!(t.wrong, 0);
}
