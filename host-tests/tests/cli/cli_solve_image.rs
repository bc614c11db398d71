//! `startrack solve-image` on the shared real night-sky frames (ESA tetra3 test data, credit
//! ESA / Gustav Pettersson, CC BY-SA 3.0 IGO; `../shared/realsky` from the repo root, the
//! test skips with a message where it is absent) and on bad input.
//!
//! - Every shared frame solves from its FITS copy, and the first two from their TIFF
//!   originals too with the same attitude (the two readers agree to the bit), with at least 25 matched stars,
//!   a residual RMS under 12 arcsec (0.3 px at 40 arcsec a pixel) and the fitted field of
//!   view within 0.5 % of tetra3rs's 11.42 degrees.
//! - Each frame's solution is the one committed in `host-tests/figures/realsky-tetra3rs.csv`
//!   (RA, Dec and roll as written there, so a change that moves them must regenerate it),
//!   its boresight within 10 arcsec of tetra3rs's and its roll within 60 arcsec.
//! - Each frame's TAN WCS (`<stem>.wcs`, read back with CFITSIO) maps every matched star's
//!   catalog RA and Dec to its measured pixel within 0.3 px RMS (the standard gnomonic
//!   formulas here, independent of the code that wrote it), and the annotated PNG is there
//!   at the frame's size; docs/attitude.md quotes the range of those RMS.
//! - The openstartracker frames of 0.1 s at gain 40 (`../shared/realsky-more`, skipped where
//!   absent) solve or not as committed in `host-tests/figures/realsky-more.csv`, each
//!   solution as written there and within 10 arcsec (roll 60) of tetra3rs's.
//! - Bad input gets one line on stderr and a non-zero exit: a truncated TIFF, a 1 x 1
//!   image, a 16-bit PNG with a colour map (a bit depth PNG forbids for palette images),
//!   an image of nothing but noise, a field of view of 0 or 180 degrees; and of the camera
//!   options: no focal length at all, a principal point outside the image, a `--camera`
//!   file that is neither a table nor a model, a table without a camera section.

use crate::common_cli::startrack;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use startrack_host::cli::solve_image::{ImageCameraArgs, SolveImageArgs, run};
use std::path::{Path, PathBuf};

/// The shared frames, if present.
pub fn realsky_dir() -> Option<PathBuf> {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/realsky");
    d.is_dir().then_some(d)
}

fn args(images: Vec<PathBuf>, out: PathBuf) -> SolveImageArgs {
    SolveImageArgs {
        images,
        camera: ImageCameraArgs::fov(11.4),
        catalog: None,
        list: None,
        out,
    }
}

fn frames(dir: &Path, ext: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|r| r.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    v.retain(|p| p.extension().is_some_and(|x| x == ext));
    v.sort();
    v
}

#[test]
fn every_shared_frame_solves_from_fits_and_tiff() {
    let Some(dir) = realsky_dir() else {
        eprintln!("skipped: ../shared/realsky (the real night-sky frames) is not there");
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let fits = frames(&dir, "fits");
    let tiff = frames(&dir, "tiff");
    assert_eq!((fits.len(), tiff.len()), (8, 8));
    let mut images = fits.clone();
    images.extend(tiff.iter().take(2).cloned());
    let s = run(&args(images, tmp.path().to_path_buf())).unwrap();
    for i in &s.images {
        let sol = i.result.as_ref().unwrap_or_else(|e| panic!("{e}"));
        let rmse_arcsec = sol.rmse_rad.to_degrees() * 3600.0;
        let fov = startrack_lab::realsky::solve::fov_deg(i.size_px[0], sol.focal_length_px);
        eprintln!(
            "{}: {} matched, RMS {rmse_arcsec:.2} arcsec, fov {fov:.4} deg, {:.0} ms",
            i.path.display(),
            sol.matches.len(),
            i.time_ms
        );
        assert!(sol.matches.len() >= 25, "{}", i.path.display());
        assert!(rmse_arcsec < 12.0, "{}", i.path.display());
        assert!((fov / 11.42 - 1.0).abs() < 0.005, "{fov}");
    }
    for (a, b) in s.images.iter().zip(&s.images[8..]) {
        let (qa, qb) = (
            a.result.as_ref().unwrap().attitude.q,
            b.result.as_ref().unwrap().attitude.q,
        );
        assert_eq!(qa, qb, "{} and its TIFF", a.path.display());
    }
    check_against_tetra3rs(&s.images[..8], true);
    let mut rms_all = Vec::new();
    for i in &s.images[..8] {
        let stem = i.path.file_stem().unwrap().to_string_lossy().into_owned();
        let rms_px = wcs_rms_px(tmp.path(), &stem);
        eprintln!("{stem}: WCS maps the matched stars to their pixels within {rms_px:.3} px RMS");
        assert!(rms_px < 0.3, "{stem}: {rms_px} px");
        rms_all.push(rms_px);
        let png = image::open(tmp.path().join(format!("{stem}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (1024, 768));
    }
    // docs/attitude.md quotes the range this measures.
    let (lo, hi) = rms_all
        .iter()
        .fold((f64::MAX, 0.0f64), |(l, h), &v| (l.min(v), h.max(v)));
    let phrase = format!("{lo:.3} to {hi:.3} px RMS");
    let page =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/attitude.md"))
            .unwrap();
    let page = page.split_whitespace().collect::<Vec<_>>().join(" ");
    assert!(
        page.contains(&phrase),
        "docs/attitude.md does not quote {phrase:?}"
    );
    let csv = std::fs::read_to_string(tmp.path().join("solutions.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("image,solved,ra_deg,dec_deg,roll_deg,fov_deg,matched,rmse_arcsec,time_ms")
    );
    assert_eq!(
        lines.filter(|l| l.split(',').nth(1) == Some("1")).count(),
        10
    );
    // A matched-stars file per image, every star with its HIP number.
    let stem = fits[0].file_stem().unwrap().to_string_lossy().into_owned();
    let stars = std::fs::read_to_string(tmp.path().join(format!("{stem}.stars.csv"))).unwrap();
    assert!(stars.starts_with("x_px,y_px,hip,ra_deg,dec_deg,mag,residual_arcsec\n"));
    for l in stars.lines().skip(1) {
        let hip: u32 = l.split(',').nth(2).unwrap().parse().unwrap();
        assert!(hip > 0, "{l}");
    }
}

/// RMS over the matched stars of `<stem>.stars.csv` of the distance between the measured
/// pixel and the catalog position through `<stem>.wcs`, px.
fn wcs_rms_px(dir: &Path, stem: &str) -> f64 {
    let path = dir.join(format!("{stem}.wcs"));
    let mut f = fitsio::FitsFile::open(&path).unwrap();
    let hdu = f.primary_hdu().unwrap();
    let mut key = |k: &str| -> f64 { hdu.read_key::<f64>(&mut f, k).unwrap() };
    let (crpix1, crpix2) = (key("CRPIX1"), key("CRPIX2"));
    let (a0, d0) = (key("CRVAL1").to_radians(), key("CRVAL2").to_radians());
    let cd = [[key("CD1_1"), key("CD1_2")], [key("CD2_1"), key("CD2_2")]];
    let ctype: String = hdu.read_key(&mut f, "CTYPE1").unwrap();
    assert_eq!(ctype.trim(), "RA---TAN");
    let det = cd[0][0] * cd[1][1] - cd[0][1] * cd[1][0];
    let text = std::fs::read_to_string(dir.join(format!("{stem}.stars.csv"))).unwrap();
    let (mut sum2, mut n) = (0.0, 0usize);
    for l in text.lines().skip(1) {
        let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
        let (x, y, a, d) = (v[0], v[1], v[3].to_radians(), v[4].to_radians());
        let cosc = d0.sin() * d.sin() + d0.cos() * d.cos() * (a - a0).cos();
        let xi = (d.cos() * (a - a0).sin() / cosc).to_degrees();
        let eta = ((d0.cos() * d.sin() - d0.sin() * d.cos() * (a - a0).cos()) / cosc).to_degrees();
        let u = (cd[1][1] * xi - cd[0][1] * eta) / det;
        let w = (-cd[1][0] * xi + cd[0][0] * eta) / det;
        let (px, py) = (u + crpix1 - 1.0, w + crpix2 - 1.0);
        sum2 += (px - x).powi(2) + (py - y).powi(2);
        n += 1;
    }
    assert!(n >= 25, "{stem}: {n} matched stars");
    (sum2 / n as f64).sqrt()
}

fn unit(ra_deg: f64, dec_deg: f64) -> [f64; 3] {
    let (ra, dec) = (ra_deg.to_radians(), dec_deg.to_radians());
    [dec.cos() * ra.cos(), dec.cos() * ra.sin(), dec.sin()]
}

/// RA and Dec of the image centre and roll (tetra3's), deg, of a solution of an image of
/// `size_px`.
fn centre_ra_dec_roll(
    sol: &startrack_lab::realsky::solve::ImageSolution,
    size_px: [usize; 2],
) -> [f64; 3] {
    use startrack_lab::realsky::solve::{centre_attitude, ra_dec_deg, roll_tetra3_deg};
    let q = centre_attitude(sol.attitude.q, &sol.camera, size_px);
    let (ra, dec) = ra_dec_deg(q.rotate_inv([0.0, 0.0, 1.0]));
    [ra, dec, roll_tetra3_deg(q)]
}

/// The boresight separation and the roll difference (wrapped to +-180 degrees) of two
/// `[ra, dec, roll]` in degrees, arcsec.
fn differences_arcsec(a: [f64; 3], b: [f64; 3]) -> (f64, f64) {
    let sep = startrack_core::attitude::angle_between(unit(a[0], a[1]), unit(b[0], b[1]));
    let droll = (a[2] - b[2] + 180.0).rem_euclid(360.0) - 180.0;
    (sep.to_degrees() * 3600.0, droll * 3600.0)
}

/// The fresh solutions against the committed comparison (see the module docs).
/// With `as_committed`, also RA, Dec and roll as the CSV writes them.
pub fn check_against_tetra3rs(
    images: &[startrack_host::cli::solve_image::ImageOutcome],
    as_committed: bool,
) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("figures/realsky-tetra3rs.csv");
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let cols: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let get = |r: &[&str], name: &str| -> f64 {
        let i = cols.iter().position(|c| *c == name).unwrap();
        r[i].parse().unwrap()
    };
    assert_eq!(rows.len(), images.len());
    for i in images {
        let name = i.path.file_stem().unwrap().to_string_lossy().into_owned();
        let r = rows
            .iter()
            .find(|r| r[0] == name)
            .expect("frame in the CSV");
        let sol = i.result.as_ref().unwrap();
        let [ra, dec, roll] = centre_ra_dec_roll(sol, i.size_px);
        // As committed (written with 6 decimals).
        for (v, c) in [
            (ra, "st_ra_deg"),
            (dec, "st_dec_deg"),
            (roll, "st_roll_deg"),
        ]
        .into_iter()
        .filter(|_| as_committed)
        {
            assert!(
                (v - get(r, c)).abs() <= 5.1e-7,
                "{name}: {c} {v} is not the CSV's"
            );
        }
        let (sep_arcsec, droll_arcsec) = differences_arcsec(
            [ra, dec, roll],
            [
                get(r, "t3_ra_deg"),
                get(r, "t3_dec_deg"),
                get(r, "t3_roll_deg"),
            ],
        );
        assert!(
            sep_arcsec < 10.0,
            "{name}: boresight {sep_arcsec:.2} arcsec from tetra3rs"
        );
        assert!(
            droll_arcsec.abs() < 60.0,
            "{name}: roll {droll_arcsec:.1} arcsec from tetra3rs"
        );
    }
}

/// The field of view given 7 % small (10.6 degrees for 11.42): the focal-length ladder finds
/// the same solutions. Minutes a frame in the dev profile (each failed rung is up to 5,000
/// hypotheses), so not in CI: `cargo test -p startrack-host --test cli
/// cli_solve_image::fov_seven_percent_off -- --ignored --nocapture`.
#[test]
#[ignore]
fn fov_seven_percent_off_gives_the_same_solutions() {
    let Some(dir) = realsky_dir() else {
        eprintln!("skipped: ../shared/realsky (the real night-sky frames) is not there");
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let s = run(&SolveImageArgs {
        camera: ImageCameraArgs::fov(10.6),
        ..args(frames(&dir, "fits"), tmp.path().to_path_buf())
    })
    .unwrap();
    for i in &s.images {
        let sol = i.result.as_ref().unwrap_or_else(|e| panic!("{e}"));
        eprintln!(
            "{}: solved at rung {}, {} matched",
            i.path.display(),
            sol.trials,
            sol.matches.len()
        );
        assert!(sol.trials > 1, "the nominal focal length is 7 % off");
    }
    check_against_tetra3rs(&s.images, false);
}

/// The openstartracker frames of 0.1 s at gain 40 (MIT, UB Nanosatellite Laboratory; the
/// "More skies" set of docs/attitude.md), laid out as `realsky_more.py`'s ROOT under
/// `../shared/realsky-more` (the test skips with a message where it is absent): each frame
/// solved or not as committed in `host-tests/figures/realsky-more.csv` (the five solved and
/// the first unsolved one), a solution's RA, Dec and roll as written there, its boresight
/// within 10 arcsec and its roll within 60 arcsec of tetra3rs's from the same detections; an
/// unsolved frame gives no attitude.
#[test]
fn openstartracker_frames_are_the_committed_comparison() {
    const FOLDER: &str = "tests/science_cam_may8_0.1sec_gain40/samples";
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/realsky-more/openstartracker")
        .join(FOLDER);
    if !dir.is_dir() {
        eprintln!("skipped: ../shared/realsky-more (the openstartracker frames) is not there");
        return;
    }
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("figures/realsky-more.csv"),
    )
    .unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let cols: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let col = |r: &[&str], name: &str| -> String {
        r[cols.iter().position(|c| *c == name).unwrap()].to_string()
    };
    let num = |r: &[&str], name: &str| -> f64 { col(r, name).parse().unwrap() };
    // The solved frames and the first unsolved one (each unsolved frame is a full failed
    // ladder, seconds).
    let mut unsolved = 0;
    let images: Vec<PathBuf> = frames(&dir, "png")
        .into_iter()
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            let solved = rows
                .iter()
                .any(|r| r[1] == format!("{FOLDER}/{name}") && col(r, "st_solved") == "1");
            unsolved += usize::from(!solved);
            solved || unsolved == 1
        })
        .collect();
    assert_eq!(images.len(), 6, "five solved frames and one not");
    let tmp = tempfile::tempdir().unwrap();
    let s = run(&SolveImageArgs {
        camera: ImageCameraArgs::fov(6.1),
        ..args(images, tmp.path().to_path_buf())
    })
    .unwrap();
    for i in &s.images {
        let name = i.path.file_name().unwrap().to_string_lossy().into_owned();
        let r = rows
            .iter()
            .find(|r| r[1] == format!("{FOLDER}/{name}"))
            .expect("frame in the CSV");
        let Ok(sol) = &i.result else {
            assert_eq!(col(r, "st_solved"), "0", "{name}: solved as committed");
            continue;
        };
        assert_eq!(col(r, "st_solved"), "1", "{name}: unsolved as committed");
        let [ra, dec, roll] = centre_ra_dec_roll(sol, i.size_px);
        for (v, c) in [
            (ra, "st_ra_deg"),
            (dec, "st_dec_deg"),
            (roll, "st_roll_deg"),
        ] {
            assert!((v - num(r, c)).abs() <= 5.1e-7, "{name}: {c} {v}");
        }
        let (sep_arcsec, droll_arcsec) = differences_arcsec(
            [ra, dec, roll],
            [
                num(r, "t3st_ra_deg"),
                num(r, "t3st_dec_deg"),
                num(r, "t3st_roll_deg"),
            ],
        );
        eprintln!(
            "{name}: {} matched, {sep_arcsec:.2} arcsec and roll {droll_arcsec:.1} arcsec from tetra3rs",
            sol.matches.len()
        );
        assert!(sep_arcsec < 10.0 && droll_arcsec.abs() < 60.0, "{name}");
    }
}

/// PNG chunk: length, type, data, CRC-32 of type and data.
fn chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    let mut d = crc.digest();
    d.update(kind);
    d.update(data);
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    out.extend_from_slice(kind);
    out.extend_from_slice(data);
    out.extend_from_slice(&d.finalize().to_be_bytes());
}

/// A PNG of colour type 3 (a colour map) at 16 bits a sample, otherwise well formed: a
/// two-entry palette and rows of zeros in a stored (uncompressed) zlib stream.
fn palette_png_16bit(width: u32, height: u32) -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[16, 3, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"PLTE", &[0, 0, 0, 255, 255, 255]);
    let raw = vec![0u8; (height * (1 + 2 * width)) as usize];
    let mut z = vec![0x78, 0x01, 0x01];
    let len = raw.len() as u16;
    z.extend_from_slice(&len.to_le_bytes());
    z.extend_from_slice(&(!len).to_le_bytes());
    z.extend_from_slice(&raw);
    let (mut a, mut b) = (1u32, 0u32);
    for &v in &raw {
        a = (a + u32::from(v)) % 65521;
        b = (b + a) % 65521;
    }
    z.extend_from_slice(&((b << 16) | a).to_be_bytes());
    chunk(&mut png, b"IDAT", &z);
    chunk(&mut png, b"IEND", &[]);
    png
}

#[test]
fn bad_camera_options_are_one_line_and_a_failure() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(64, 48, |x, y| {
        image::Luma([(1000 + x + y) as u16])
    });
    let png = tmp.path().join("flat.png");
    img.save(&png).unwrap();
    let garbage = tmp.path().join("garbage.bin");
    std::fs::write(&garbage, b"not a table").unwrap();
    let bad_json = tmp.path().join("bad.json");
    std::fs::write(&bad_json, "{\"focal_length_px\": \"long\"}").unwrap();
    let table = tmp.path().join("plain.bin");
    let (bytes, _) =
        startrack_lab::table_build::build(&startrack_lab::table_build::CalibBuildArgs {
            gains: Some("1.0,1.0".into()),
            dark_law: None,
            ..startrack_test_support::cli::bare_args(table.clone())
        })
        .unwrap();
    std::fs::write(&table, bytes).unwrap();
    let p = png.to_str().unwrap();
    let o = out.to_str().unwrap();
    let cases: [(&[&str], &str); 6] = [
        (&["solve-image", p, "--out", o], "focal length is needed"),
        (
            &["solve-image", p, "--focal-length-px", "0.5", "--out", o],
            "--focal-length-px",
        ),
        (
            &[
                "solve-image",
                p,
                "--fov-deg",
                "11.4",
                "--principal-point",
                "500,20",
                "--out",
                o,
            ],
            "principal point",
        ),
        (
            &[
                "solve-image",
                p,
                "--camera",
                garbage.to_str().unwrap(),
                "--out",
                o,
            ],
            "garbage.bin",
        ),
        (
            &[
                "solve-image",
                p,
                "--camera",
                bad_json.to_str().unwrap(),
                "--out",
                o,
            ],
            "bad.json",
        ),
        (
            &[
                "solve-image",
                p,
                "--camera",
                table.to_str().unwrap(),
                "--out",
                o,
            ],
            "no camera section",
        ),
    ];
    for (args, what) in cases {
        let (ok, _, err) = startrack(args);
        assert!(!ok, "{args:?}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(what), "{args:?}: {err}");
    }
}

/// Runs the binary on `images` with `fov`: (success, stderr).
fn cli(images: &[&Path], fov: &str, out: &Path) -> (bool, String) {
    let mut a: Vec<&str> = vec!["solve-image"];
    a.extend(images.iter().map(|p| p.to_str().unwrap()));
    a.extend(["--fov-deg", fov, "--out", out.to_str().unwrap()]);
    let (ok, _, err) = startrack(&a);
    (ok, err)
}

#[test]
fn bad_input_is_one_line_and_a_failure() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    // A truncated 16-bit TIFF.
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(200, 150, |x, y| {
        image::Luma([(1000 + x * 3 + y) as u16])
    });
    let tif = tmp.path().join("whole.tiff");
    img.save(&tif).unwrap();
    let bytes = std::fs::read(&tif).unwrap();
    let cut = tmp.path().join("cut.tiff");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    // A 1 x 1 PNG.
    let one = tmp.path().join("one.png");
    image::GrayImage::from_pixel(1, 1, image::Luma([7]))
        .save(&one)
        .unwrap();
    // Nothing but noise (seeded), 16-bit.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let n = Normal::new(3000.0f64, 200.0).unwrap();
    let noise_img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(512, 384, |_, _| {
        image::Luma([n.sample(&mut rng).round().clamp(0.0, 65535.0) as u16])
    });
    let noise = tmp.path().join("noise.png");
    noise_img.save(&noise).unwrap();
    let palette = tmp.path().join("palette16.png");
    std::fs::write(&palette, palette_png_16bit(64, 48)).unwrap();
    for p in [&cut, &one, &palette, &noise] {
        let (ok, err) = cli(&[p], "11.4", &out);
        assert!(!ok, "{}", p.display());
        assert_eq!(err.trim_end().lines().count(), 1, "{}: {err}", p.display());
        assert!(err.contains(&*p.to_string_lossy()), "{err}");
    }
    for fov in ["0", "180"] {
        let (ok, err) = cli(&[&noise], fov, &out);
        assert!(!ok);
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains("--fov-deg"), "{err}");
    }
}
