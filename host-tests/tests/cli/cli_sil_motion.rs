//! `startrack sil --sky` turning during the exposure: `--rate-deg-s`, `--exposure-ms` and
//! `--slew-accel-deg-s2`, their one-line usage errors, and the attitude CSV's truth at
//! mid-exposure (time, quaternion in `solve`'s convention, rate).

use crate::common_cli::startrack;

/// A bad motion option is one line on standard error, prefixed with the command, no panic,
/// before any frame runs.
#[test]
fn bad_motion_options_are_one_line_usage_errors() {
    let cases: [(&[&str], &str); 7] = [
        (&["--rate-deg-s", "11,0,0"], "--rate-deg-s"),
        (&["--rate-deg-s", "1,0"], "--rate-deg-s"),
        (&["--rate-deg-s", "1,0,0,0"], "--rate-deg-s"),
        (&["--rate-deg-s", "nan,0,0"], "--rate-deg-s"),
        (&["--exposure-ms", "0"], "--exposure-ms"),
        (&["--exposure-ms", "20000"], "--exposure-ms"),
        (
            &["--rate-deg-s", "0,1,0", "--slew-accel-deg-s2", "0"],
            "--slew-accel-deg-s2",
        ),
    ];
    for (extra, names) in cases {
        let mut args = vec!["sil", "--sky", "--frames", "1"];
        args.extend_from_slice(extra);
        let (ok, stdout, stderr) = startrack(&args);
        assert!(!ok, "{args:?} succeeded");
        assert!(stdout.is_empty(), "{args:?} printed {stdout}");
        assert_eq!(stderr.lines().count(), 1, "{args:?}: {stderr}");
        assert!(stderr.starts_with("startrack sil: "), "{args:?}: {stderr}");
        assert!(stderr.contains(names), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    // The rate is a turn of the sky: refused without it, and with --drift-px's steps.
    for extra in [
        &["--rate-deg-s", "0,1,0"][..],
        &["--sky", "--rate-deg-s", "0,1,0", "--drift-px", "1,0"][..],
    ] {
        let mut args = vec!["sil", "--frames", "1"];
        args.extend_from_slice(extra);
        let (ok, _, stderr) = startrack(&args);
        assert!(!ok && stderr.starts_with("error: "), "{args:?}: {stderr}");
    }
}

/// Angle between two attitudes given as quaternions (scalar first), arcsec: of `a* b`,
/// `2 atan2(|vector|, |scalar|)` (no `acos` near 1, which the CSV's 9 decimals would
/// swamp).
fn angle_arcsec(a: [f64; 4], b: [f64; 4]) -> f64 {
    let [a0, a1, a2, a3] = a;
    let [b0, b1, b2, b3] = b;
    let w = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3;
    let v = [
        a0 * b1 - a1 * b0 - a2 * b3 + a3 * b2,
        a0 * b2 + a1 * b3 - a2 * b0 - a3 * b1,
        a0 * b3 - a1 * b2 + a2 * b1 - a3 * b0,
    ];
    let s = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    2.0 * s.atan2(w.abs()).to_degrees() * 3600.0
}

/// A slew from rest at 2 deg/s^2 to 0.5 deg/s about x, 50 ms exposures every 100 ms: the
/// truth columns hold each frame's mid-exposure (0.025 s, 0.125 s), the rate the ramp gives
/// then (0.05, 0.25 deg/s), a true attitude that turned by the ramp's angle between them
/// (54 arcsec), and the fix's error columns are its angle from that true attitude.
#[test]
fn the_attitude_csv_carries_the_truth_at_mid_exposure() {
    let dir = tempfile::tempdir().unwrap();
    let att = dir.path().join("att.csv");
    let att_s = att.to_str().unwrap();
    let (ok, _, stderr) = startrack(&[
        "sil",
        "--sky",
        "--frames",
        "2",
        "--rate-deg-s",
        "0.5,0,0",
        "--slew-accel-deg-s2",
        "2",
        "--exposure-ms",
        "50",
        "--attitude",
        att_s,
    ]);
    assert!(ok, "{stderr}");
    let text = std::fs::read_to_string(&att).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    assert_eq!(header.len(), 31, "{header:?}");
    let rows: Vec<Vec<f64>> = lines
        .map(|l| {
            l.split(',')
                .map(|v| v.parse::<f64>().unwrap_or(f64::NAN))
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), 2);
    let q = |r: &Vec<f64>, p: &str| {
        [
            r[col(&format!("{p}qw"))],
            r[col(&format!("{p}qx"))],
            r[col(&format!("{p}qy"))],
            r[col(&format!("{p}qz"))],
        ]
    };
    for (r, (t, w)) in rows.iter().zip([(0.025, 0.05), (0.125, 0.25)]) {
        assert!((r[col("t_mid_s")] - t).abs() < 1e-9, "{r:?}");
        assert!((r[col("true_wx_deg_s")] - w).abs() < 1e-6, "{r:?}");
        assert_eq!(
            (r[col("true_wy_deg_s")], r[col("true_wz_deg_s")]),
            (0.0, 0.0)
        );
        if r[col("solved")] == 1.0 {
            let error = r[col("error_boresight_arcsec")].hypot(r[col("error_roll_arcsec")]);
            let angle = angle_arcsec(q(r, ""), q(r, "true_"));
            assert!((angle - error).abs() < 0.01, "{angle} {error}: {r:?}");
        }
    }
    let turned = angle_arcsec(q(&rows[0], "true_"), q(&rows[1], "true_"));
    assert!((turned - 54.0).abs() < 0.01, "{turned}");
}
