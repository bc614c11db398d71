//! Stages `ident_lost_in_space_p50`, `ident_lost_in_space_p99`, `ident_lost_in_space_max`,
//! `ident_track_p99`, `predict_catalog_windows_p99` and `ident_confirm_p99`, per field, and
//! `rate_filter_push` (below): star identification with the attitude from all matched
//! stars (`core/src/ident`, `core/src/attitude`) against the repo's 15 degree catalog
//! (`host-tests/data/catalog-15deg.bin`, `startrack catalog build`), on [`FIELDS`] fields
//! rendered here at pseudo-random attitudes: each catalog star in the 1024 x 1024 frame
//! (f = 3889 px), centroid noise about 0.3 px, 10 % dropped, 3 false stars, brightest first.
//! Tracking starts from the true attitude turned by 2 degrees.
//!
//! Tracking from the attitude, as the frame cycle runs it each tracking frame: the catalog's
//! stars predicted at the next frame (`core/src/predict.rs`: the field's attitude turning at
//! 1 deg/s across the boresight, 0.1 s ahead, 100 ms exposures, the flight choice of 32
//! stars), then `ident::confirm` on those stars measured with 0.3 px noise and their
//! identities, from the propagated attitude, and its attitude refined with each star's 2x2
//! covariance (`attitude::refine`, as the attitude stage does; the trailed stars'
//! anisotropy costs the same as these round ones).
//!
//! Timed: `ident::lost_in_space` (or `ident::track`) on the measured directions; not timed:
//! rendering the field. Also printed, as a `#` line: the stack each uses (high-water mark of
//! a painted stack, one field each). Every field must solve, else the bench fails. Cost of the bench
//! itself: a cone search and a projection per field.

use crate::harness::{Bench, Out};
use crate::inputs::Lcg;
use core::fmt::Write as _;
use core::hint::black_box;
use startrack_core::attitude::{self, Attitude, Camera, ImageObservation, Quat, Rate};
use startrack_core::catalog::Catalog;
use startrack_core::ident::{self, IdentConfig, MAX_STARS, Measured};
use startrack_core::predict::{self, PredictConfig, PredictFrom, PredictedStars};

/// The catalog the tracker flies for a 15 degree field.
static CATALOG: &[u8] = include_bytes!("../../../../host-tests/data/catalog-15deg.bin");

/// Fields identified.
pub const FIELDS: usize = 200;

const SIGMA_PX: f64 = 0.3;
const FOCAL_PX: f64 = 3889.0;

/// Uniform in [0, 1).
fn uniform(rng: &mut Lcg) -> f64 {
    f64::from(rng.next()) / 16_777_216.0
}

/// About N(0, 1): a sum of 12 uniforms less 6.
fn normal(rng: &mut Lcg) -> f64 {
    (0..12).map(|_| uniform(rng)).sum::<f64>() - 6.0
}

/// The measured field at attitude `q`, brightest first; returns the count.
fn render(
    cat: &Catalog<'_>,
    cam: &Camera,
    q: Quat,
    rng: &mut Lcg,
    out: &mut [Measured; MAX_STARS],
) -> usize {
    let mut found: [(i16, [f64; 2]); 64] = [(0, [0.0; 2]); 64];
    let mut n = 0;
    let boresight = q.rotate_inv([0.0, 0.0, 1.0]);
    for (i, dir) in cat.cone(boresight, cat.field_radius_rad()) {
        let Some(p) = cam.project(q.rotate(dir)) else {
            continue;
        };
        if p[0] < -0.5 || p[1] < -0.5 || p[0] >= 1023.5 || p[1] >= 1023.5 || uniform(rng) < 0.1 {
            continue;
        }
        let hp = cat.star(i).map_or(i16::MAX, |s| s.hp_mmag);
        if let Some(slot) = found.get_mut(n) {
            *slot = (
                hp,
                [p[0] + SIGMA_PX * normal(rng), p[1] + SIGMA_PX * normal(rng)],
            );
            n += 1;
        }
    }
    for _ in 0..3 {
        let hp = 1000 + (uniform(rng) * 5500.0) as i16;
        if let Some(slot) = found.get_mut(n) {
            *slot = (hp, [uniform(rng) * 1023.0, uniform(rng) * 1023.0]);
            n += 1;
        }
    }
    let found = found.get_mut(..n).unwrap_or(&mut []);
    found.sort_unstable_by_key(|s| s.0);
    let mut m = 0;
    for (o, s) in out.iter_mut().zip(found.iter()) {
        let dir = cam.direction(s.1[0], s.1[1]);
        *o = Measured {
            dir,
            sigma_rad: SIGMA_PX / FOCAL_PX * dir[2],
            inst_mag: Some(f32::from(s.0) / 1000.0),
        };
        m += 1;
    }
    m
}

fn random_quat(rng: &mut Lcg) -> Quat {
    loop {
        let q = Quat([normal(rng), normal(rng), normal(rng), normal(rng)]);
        if let Some(q) = q.normalized() {
            return q;
        }
    }
}

/// Bytes of stack painted below the caller's frame for the high-water mark.
const PAINT_BYTES: usize = 48 * 1024;
const PAINT: u32 = 0x5A5A_A5A5;

fn stack_pointer() -> usize {
    let sp: usize;
    // SAFETY: reads the stack pointer register, nothing else.
    unsafe { core::arch::asm!("mov {}, sp", out(reg) sp, options(nomem, nostack)) };
    sp
}

/// Paints `PAINT_BYTES` below the current stack pointer (less a margin for this frame).
#[inline(never)]
fn paint_stack() {
    let top = (stack_pointer() - 256) & !3;
    let mut p = top - PAINT_BYTES;
    while p < top {
        // SAFETY: the bench's RAM is 4 MB with the stack at its top and nothing else in
        // these 48 KB below the live frames; the words are written, then only read.
        unsafe { (p as *mut u32).write_volatile(PAINT) };
        p += 4;
    }
}

/// Bytes of stack used below `base` since [`paint_stack`]: from the lowest word that no
/// longer holds the paint.
fn stack_used(base: usize) -> usize {
    let bottom = ((base - 256) & !3) - PAINT_BYTES;
    let mut p = bottom;
    // SAFETY: the same painted words, read back.
    while p < base && unsafe { (p as *const u32).read_volatile() } == PAINT {
        p += 4;
    }
    base - p
}

/// Measures the stack `f` uses, in bytes.
fn stack_of(mut f: impl FnMut()) -> usize {
    let base = stack_pointer();
    paint_stack();
    f();
    stack_used(base)
}

/// Measures and prints the stages.
pub fn run(out: &mut Out, bench: &Bench, rng: &mut Lcg) -> Result<(), &'static str> {
    let cat = Catalog::parse(CATALOG).map_err(|_| "catalog does not parse")?;
    let cam = Camera::pinhole(FOCAL_PX, [511.5, 511.5]);
    let cfg = IdentConfig::for_camera(FOCAL_PX, SIGMA_PX);
    let mut lis = [0u64; FIELDS];
    let mut trk = [0u64; FIELDS];
    let mut prd = [0u64; FIELDS];
    let mut cnf = [0u64; FIELDS];
    let mut known = [Measured {
        dir: [0.0, 0.0, 1.0],
        sigma_rad: 1.0,
        inst_mag: None,
    }; MAX_STARS];
    let mut ids = [0u16; MAX_STARS];
    let w_rad_s = [0.0, 1f64.to_radians(), 0.0];
    // The predicted stars' noise from a generator of its own: the fields stay those the
    // identification stages have always been measured on.
    let mut noise = Lcg(0x7072_6564);
    let small = |s: f64| {
        [
            [s * s, 0.0, 0.0],
            [0.0, s * s, 0.0],
            [0.0, 0.0, 9.0 * s * s],
        ]
    };
    let mut meas = [Measured {
        dir: [0.0, 0.0, 1.0],
        sigma_rad: 1.0,
        inst_mag: None,
    }; MAX_STARS];
    for (((l, t), p), c) in lis
        .iter_mut()
        .zip(trk.iter_mut())
        .zip(prd.iter_mut())
        .zip(cnf.iter_mut())
    {
        let q = random_quat(rng);
        let n = render(&cat, &cam, q, rng, &mut meas);
        let stars = meas.get(..n).ok_or("field")?;
        let mut ok = false;
        *l = bench
            .measure(|| ok = black_box(ident::lost_in_space(&cat, black_box(stars), &cfg)).is_ok());
        if !ok {
            return Err("a lost-in-space field did not solve");
        }
        let axis = random_quat(rng).rotate([0.0, 0.0, 1.0]);
        let prior = Quat::from_axis_angle(axis, 2f64.to_radians()) * q;
        let err = 2.1f64.to_radians();
        *t = bench.measure(|| {
            ok = black_box(ident::track(&cat, black_box(stars), prior, err, &cfg)).is_ok()
        });
        if !ok {
            return Err("a tracking field did not solve");
        }
        let from = PredictFrom {
            attitude: Attitude {
                q,
                cov_rad2: small(0.5e-6),
            },
            rate: Rate {
                w_rad_s,
                cov_rad2_s2: small(0.2e-6),
            },
            accel_rad_s2: [0.0; 3],
            scale: 1.0,
            interval_s: 0.1,
            exposure_s: 0.1,
            period_s: 0.1,
            velocity_m_s: None,
        };
        let mut next = PredictedStars::new();
        let pcfg = PredictConfig::flight(7);
        *p = bench.measure(|| {
            ok = black_box(predict::predict(
                &cat,
                &cam,
                black_box(&from),
                [1024, 1024],
                &pcfg,
                &mut next,
            ))
            .is_ok()
        });
        if !ok || next.len() < 8 {
            return Err("a field predicted too few stars");
        }
        let mut m = 0;
        for ((k, i), s) in known.iter_mut().zip(ids.iter_mut()).zip(next.iter()) {
            let dir = cam.direction(
                f64::from(s.x_px) + SIGMA_PX * normal(&mut noise),
                f64::from(s.y_px) + SIGMA_PX * normal(&mut noise),
            );
            *k = Measured {
                dir,
                sigma_rad: SIGMA_PX / FOCAL_PX * dir[2],
                inst_mag: None,
            };
            *i = s.catalog;
            m += 1;
        }
        let (stars, ids) = (known.get(..m).ok_or("field")?, ids.get(..m).ok_or("ids")?);
        let q_next = Quat::from_rotation_vector(w_rad_s.map(|c| c * 0.1)) * q;
        *c = bench.measure(|| {
            ok = black_box(ident::confirm(
                &cat,
                black_box(stars),
                ids,
                q_next,
                1.0,
                &cfg,
            ))
            .ok()
            .and_then(|sol| refined(&cat, stars, &sol))
            .is_some()
        });
        if !ok {
            return Err("a field's predicted identities did not confirm");
        }
    }
    // Stack high-water mark of one field each way (a comment line: the CSV is instructions).
    let q = random_quat(rng);
    let n = render(&cat, &cam, q, rng, &mut meas);
    let stars = meas.get(..n).ok_or("field")?;
    let lis_stack = stack_of(|| {
        let _ = black_box(ident::lost_in_space(&cat, black_box(stars), &cfg));
    });
    let prior = Quat::from_axis_angle([1.0, 0.0, 0.0], 2f64.to_radians()) * q;
    let trk_stack = stack_of(|| {
        let _ = black_box(ident::track(
            &cat,
            black_box(stars),
            prior,
            2.1f64.to_radians(),
            &cfg,
        ));
    });
    let _ = writeln!(
        out,
        "# ident stack high-water: lost in space {lis_stack} bytes, tracking {trk_stack} bytes"
    );
    lis.sort_unstable();
    trk.sort_unstable();
    prd.sort_unstable();
    cnf.sort_unstable();
    let at = |v: &[u64; FIELDS], p: usize| v.get((FIELDS - 1) * p / 100).copied().unwrap_or(0);
    bench.row(out, "ident_lost_in_space_p50", "field", at(&lis, 50), 1);
    bench.row(out, "ident_lost_in_space_p99", "field", at(&lis, 99), 1);
    bench.row(out, "ident_lost_in_space_max", "field", at(&lis, 100), 1);
    bench.row(out, "ident_track_p99", "field", at(&trk, 99), 1);
    bench.row(out, "predict_catalog_windows_p99", "frame", at(&prd, 99), 1);
    bench.row(out, "ident_confirm_p99", "frame", at(&cnf, 99), 1);
    rate_filter(out, bench, rng)
}

/// Stage `rate_filter_push`, per attitude: the largest cost of a push into the frame
/// cycle's rate filter (`core/src/attitude/rate.rs`) over 40 attitudes of a slew at
/// 2 deg/s^2 across the boresight, 49.4 ms apart, 0.1" and 1" of noise: the window full
/// from the twelfth, both fits each push, the acceleration's fit chosen.
fn rate_filter(out: &mut Out, bench: &Bench, rng: &mut Lcg) -> Result<(), &'static str> {
    const ARCSEC: f64 = 4.848_136_811e-6;
    let q0 = random_quat(rng);
    let alpha = [2f64.to_radians(), 0.0, 0.0];
    let cov = [
        [0.01 * ARCSEC * ARCSEC, 0.0, 0.0],
        [0.0, 0.01 * ARCSEC * ARCSEC, 0.0],
        [0.0, 0.0, ARCSEC * ARCSEC],
    ];
    let mut f = startrack_core::attitude::RateFilter::new(1f64.to_radians());
    let mut worst = 0u64;
    let mut rated = 0;
    for k in 0..40u64 {
        let t = k as f64 * 0.0494;
        let e = [
            0.1 * ARCSEC * normal(rng),
            0.1 * ARCSEC * normal(rng),
            ARCSEC * normal(rng),
        ];
        let truth = Quat::from_rotation_vector(alpha.map(|a| 0.5 * a * t * t)) * q0;
        let a = Attitude {
            q: Quat::from_rotation_vector(e) * truth,
            cov_rad2: cov,
        };
        let mut rate = None;
        let c = bench.measure(|| rate = black_box(f.push(black_box(k * 49_400), &a)));
        worst = worst.max(c);
        rated += usize::from(rate.is_some());
    }
    if rated < 39 || f.len() != startrack_core::attitude::RATE_WINDOW {
        return Err("the rate filter restarted during the slew");
    }
    bench.row(out, "rate_filter_push", "attitude", worst, 1);
    Ok(())
}

/// `sol`'s attitude refined with its matches' covariances (the attitude stage's last step,
/// `Solver::refined`: isotropic here, the cost is the same).
fn refined(cat: &Catalog<'_>, stars: &[Measured], sol: &ident::Solution) -> Option<Attitude> {
    let mut obs: heapless::Vec<ImageObservation, MAX_STARS> = heapless::Vec::new();
    for m in &sol.matches {
        let s = stars.get(usize::from(m.star))?;
        let v = s.sigma_rad * s.sigma_rad;
        obs.push(ImageObservation {
            camera: s.dir,
            icrs: cat.dir(usize::from(m.catalog))?,
            cov_rad2: [v, v, 0.0],
        })
        .ok()?;
    }
    attitude::refine(sol.attitude.q, &obs).ok()
}
