//! The calibration table's camera-model section (kind 10): written and read back within the
//! format's resolution, every corrupted byte rejected, and the parser's own checks (length,
//! reserved field, a distortion with no inverse over the active area) each with its typed
//! error.

use startrack_core::attitude::{Camera, CameraError};
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::camera::{CAMERA_SECTION_LEN, decode, encode};
use startrack_core::table::{
    CalibTable, SectionKind, TableError, TableSpec, WriteError, write_table,
};
use startrack_core::units::{GainEPerAdu, Kelvin};

const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

fn fitted() -> Camera {
    Camera {
        k1: -0.0712,
        k2: 0.1534,
        p1: 2.1e-4,
        p2: -1.3e-4,
        colour_scale_per_mag: 2.4e-4,
        colour_ref_bv_mag: 0.65,
        ..Camera::pinhole(3862.271, [517.318, 504.776])
    }
}

fn table(cam: Option<Camera>) -> Result<Vec<u8>, WriteError> {
    let gains = [GainEPerAdu::ONE, GainEPerAdu::ONE];
    let spec = TableSpec {
        geometry: ReadoutGeometry::CCD47_20_DUAL,
        saturation_adu: 65_000,
        gains: &gains,
        column_bias: None,
        dark_rel: None,
        flat_inv: None,
        hot_ref_k: Kelvin::ZERO,
        hot: &[],
        telegraph: &[],
        cti: None,
        psf_model: None,
        camera_model: cam,
        dark_law: None,
    };
    let mut out = vec![0u8; spec.encoded_len()];
    write_table(&spec, &mut out).map(|n| {
        out.truncate(n);
        out
    })
}

/// Replaces the camera section's bytes and reseals its CRC and the header's.
fn with_section(bytes: &[u8], section: &[u8; CAMERA_SECTION_LEN]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let n = usize::from(u16::from_le_bytes([b[6], b[7]]));
    let i = (0..n)
        .find(|i| u16::from_le_bytes([b[32 + 16 * i], b[33 + 16 * i]]) == 10)
        .expect("camera section listed");
    let e = 32 + 16 * i;
    let off = u32::from_le_bytes(b[e + 4..e + 8].try_into().unwrap()) as usize;
    b[off..off + CAMERA_SECTION_LEN].copy_from_slice(section);
    let crc = CRC.checksum(&b[off..off + CAMERA_SECTION_LEN]);
    b[e + 12..e + 16].copy_from_slice(&crc.to_le_bytes());
    let mut d = CRC.digest();
    d.update(&b[..28]);
    d.update(&b[32..32 + 16 * n]);
    let h = d.finalize();
    b[28..32].copy_from_slice(&h.to_le_bytes());
    b
}

#[test]
fn a_written_model_reads_back_within_its_resolution() {
    let cam = fitted();
    let bytes = table(Some(cam)).unwrap();
    assert_eq!(
        bytes.len(),
        table(None).unwrap().len() + 16 + CAMERA_SECTION_LEN
    );
    let t = CalibTable::parse(&bytes).unwrap();
    let back = t.camera_model().expect("camera model present");
    assert!((back.focal_length_px - cam.focal_length_px).abs() <= 0.5 / 65536.0);
    for i in 0..2 {
        assert!((back.principal_point_px[i] - cam.principal_point_px[i]).abs() <= 0.5 / 65536.0);
    }
    for (a, b) in [
        (back.k1, cam.k1),
        (back.k2, cam.k2),
        (back.p1, cam.p1),
        (back.p2, cam.p2),
    ] {
        assert!((a - b).abs() <= 0.5 / f64::from(1u32 << 28), "{a} {b}");
    }
    assert!((back.colour_scale_per_mag - cam.colour_scale_per_mag).abs() <= 0.5 / 2f64.powi(31));
    assert_eq!(back.colour_ref_bv_mag, 0.65);
    // The stored model images every point within 1e-4 px of the fitted one.
    for (x, y) in [(0.0, 0.0), (1023.0, 0.0), (511.5, 511.5), (1023.0, 1023.0)] {
        let d = cam.direction_of(x, y, 1.5).unwrap();
        let p = back.project_of(d, 1.5).unwrap();
        assert!((p[0] - x).abs() < 1e-4 && (p[1] - y).abs() < 1e-4, "{p:?}");
    }
    assert_eq!(
        CalibTable::parse(&table(None).unwrap())
            .unwrap()
            .camera_model(),
        None
    );
}

#[test]
fn every_changed_byte_of_the_section_is_rejected() {
    let bytes = table(Some(fitted())).unwrap();
    let start = bytes.len() - CAMERA_SECTION_LEN; // the last section, in kind order
    for i in start..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 0x5a;
        assert_eq!(
            CalibTable::parse(&b).err(),
            Some(TableError::SectionCrc(SectionKind::CameraModel)),
            "byte {i}"
        );
    }
}

#[test]
fn the_parser_checks_the_model_itself() {
    let bytes = table(Some(fitted())).unwrap();
    let good = encode(&fitted()).unwrap();

    let mut reserved = good;
    reserved[35] = 1;
    assert_eq!(
        CalibTable::parse(&with_section(&bytes, &reserved)).err(),
        Some(TableError::Reserved)
    );

    let mut zero_f = good;
    zero_f[..4].fill(0);
    assert_eq!(
        CalibTable::parse(&with_section(&bytes, &zero_f)).err(),
        Some(TableError::CameraModel(CameraError::BadParameter))
    );

    // k1 = k2 = -7.5 folds the image before the frame's corner (the radial map peaks at
    // r_d = 0.138, the corner with its margin is at 0.146): no inverse over the active area.
    let folded = encode(&Camera {
        k1: -7.5,
        k2: -7.5,
        ..fitted()
    })
    .unwrap();
    assert_eq!(
        CalibTable::parse(&with_section(&bytes, &folded)).err(),
        Some(TableError::CameraModel(CameraError::NoInverse))
    );
    // The writer refuses the same model rather than write a table the parser rejects.
    assert_eq!(
        table(Some(Camera {
            k1: -7.5,
            k2: -7.5,
            ..fitted()
        }))
        .err(),
        Some(WriteError::Invalid(TableError::CameraModel(
            CameraError::NoInverse
        )))
    );
    // Values outside their format are refused at writing.
    for cam in [
        Camera {
            k1: 9.0,
            ..fitted()
        },
        Camera {
            colour_scale_per_mag: 1.5,
            ..fitted()
        },
        Camera {
            focal_length_px: f64::NAN,
            ..fitted()
        },
    ] {
        assert_eq!(encode(&cam), Err(CameraError::BadParameter));
        assert_eq!(
            table(Some(cam)).err(),
            Some(WriteError::Invalid(TableError::CameraModel(
                CameraError::BadParameter
            )))
        );
    }
    assert_eq!(
        decode(&good[..35]).err(),
        Some(TableError::SectionLength(SectionKind::CameraModel))
    );
}
