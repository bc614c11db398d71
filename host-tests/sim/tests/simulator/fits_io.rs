//! FITS round trips and every typed error of `startrack_sim::fits`.

use startrack_core::geometry::ReadoutGeometry;
use startrack_sim::fits::{
    FitsError, MapF32, RawFrame, read_map, read_map_shaped, read_raw_frame, write_map,
    write_raw_frame,
};
use std::path::PathBuf;

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("startrack-fits-io-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A frame whose every sample differs from its neighbours and spans the full u16 range.
fn ramp(g: &ReadoutGeometry) -> RawFrame {
    let (lines, cols) = (usize::from(g.lines), g.line_len());
    let data_adu = (0..lines * cols)
        .map(|i| (i.wrapping_mul(40_503) % 65_536) as u16)
        .collect();
    RawFrame {
        lines,
        cols,
        data_adu,
    }
}

#[test]
fn raw_frame_round_trips_bit_for_bit_including_0_and_65535() {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let mut f = ramp(&g);
    f.data_adu[0] = 0;
    f.data_adu[1] = 65535;
    let p = tmp("raw.fits");
    write_raw_frame(&p, &f, &[("EXPTIME", 1.5)]).unwrap();
    let back = read_raw_frame(&p, &g).unwrap();
    assert_eq!(back, f);
    // Stored the FITS way for unsigned 16-bit: BITPIX 16, BZERO 32768.
    let m = read_map(&p, &["BITPIX", "BZERO", "EXPTIME"]).unwrap();
    assert_eq!(m.key("BITPIX"), Some(16.0));
    assert_eq!(m.key("BZERO"), Some(32768.0));
    assert_eq!(m.key("EXPTIME"), Some(1.5));
}

#[test]
fn map_round_trips_with_keywords() {
    let m = MapF32 {
        rows: 3,
        cols: 5,
        data: (0..15).map(|i| i as f32 * 0.25 - 1.0).collect(),
        keys: vec![("GAIN1".into(), 1.5), ("GAIN2".into(), 1.625)],
    };
    let p = tmp("map.fits");
    write_map(&p, &m).unwrap();
    let back = read_map(&p, &["GAIN1", "GAIN2", "ABSENT"]).unwrap();
    assert_eq!(back, m);
    assert_eq!(back.key("absent"), None);
}

#[test]
fn missing_file_is_an_io_error() {
    let e = read_raw_frame(&tmp("nope.fits"), &ReadoutGeometry::CCD47_20_DUAL).unwrap_err();
    assert!(matches!(e, FitsError::Io { .. }), "{e}");
}

#[test]
fn text_file_is_not_fits() {
    let p = tmp("text.fits");
    std::fs::write(&p, "x_px,y_px\n1,2\n".repeat(400)).unwrap();
    let e = read_raw_frame(&p, &ReadoutGeometry::CCD47_20_DUAL).unwrap_err();
    assert!(matches!(e, FitsError::NotFits { .. }), "{e}");
    assert!(e.to_string().contains("not a FITS file"));
}

#[test]
fn float_frame_is_the_wrong_type() {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let p = tmp("float.fits");
    let (rows, cols) = (usize::from(g.lines), g.line_len());
    let m = MapF32 {
        rows,
        cols,
        data: vec![1000.0; rows * cols],
        keys: vec![],
    };
    write_map(&p, &m).unwrap();
    let e = read_raw_frame(&p, &g).unwrap_err();
    assert!(matches!(e, FitsError::WrongType { .. }), "{e}");
}

#[test]
fn active_area_only_frame_is_the_wrong_shape() {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let p = tmp("shape.fits");
    let f = RawFrame {
        lines: 1024,
        cols: 1024,
        data_adu: vec![1000; 1024 * 1024],
    };
    write_raw_frame(&p, &f, &[]).unwrap();
    let e = read_raw_frame(&p, &g).unwrap_err();
    assert_eq!(
        e,
        FitsError::WrongShape {
            path: p.clone(),
            found: (1024, 1024),
            expected: (1033, 1072)
        }
    );
    let e = read_map_shaped(&p, 1033, 1072, &[]).unwrap_err();
    assert!(matches!(e, FitsError::WrongShape { .. }), "{e}");
}

#[test]
fn nan_in_a_map_is_rejected() {
    let p = tmp("nan.fits");
    let mut m = MapF32 {
        rows: 2,
        cols: 3,
        data: vec![1.0; 6],
        keys: vec![],
    };
    m.data[4] = f32::NAN;
    write_map(&p, &m).unwrap();
    let e = read_map(&p, &[]).unwrap_err();
    assert_eq!(
        e,
        FitsError::NotFinite {
            path: p.clone(),
            row: 1,
            col: 1
        }
    );
}
