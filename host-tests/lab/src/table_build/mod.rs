//! The calibration table (core/src/table) from maps a ground calibration measured, given as
//! FITS images, and a hot-pixel CSV: what `startrack calib build` runs.
//!
//! # Inputs and how each becomes a table section
//! - Gains, e-/ADU per output: `--gains G1,G2`, else the `GAIN1`/`GAIN2` keywords of the
//!   first map given (bias, dark, flat). Required: without gains there is no table.
//! - Bias (`--bias`, ADU, full readout: lines x line length, e.g. a mean of bias frames) ->
//!   **column bias** (I12F4 ADU per raw column). The core subtracts, on every line, the
//!   level it measures on that line's over-scan (median of the output's over-scan elements),
//!   then the table's column bias. So the column bias must be each column's offset *above the
//!   over-scan level of its own line*, not the bias map itself: for each line of the bias map
//!   take the same over-scan median per output as the core, subtract it from the line, and
//!   average the differences over lines. Bias drift (per line or per frame) moves over-scan
//!   and columns together and cancels; over-scan columns get 0 (the core never applies
//!   column bias to them). Values beyond ±2048 ADU are clamped and counted.
//! - Dark (`--dark`, relative, full readout) -> **relative dark map** (U2F6) of the active
//!   area. The core scales it by the frame's covered-column mean, so the map is divided by
//!   the mean of its own covered columns (a map already relative to them is unchanged; a
//!   dark frame in e- or ADU above bias works too). Values are averaged over the table's
//!   tiles and clamped to 0..4.
//! - Flat (`--flat`, relative response, active area rows x columns) -> **inverse flat**
//!   (U2F14): 1/flat averaged over each tile, clamped to (0, 4); a flat at or below 0.25
//!   (dead pixel) is clamped and counted.
//! - Hot pixels (`--hot`, CSV `col,row,dark_e` in full-readout coordinates, an optional
//!   header line) -> **hot pixel** entries: `dark_e` is the pixel's dark signal in
//!   `--hot-exposure-s` at `--hot-ref-k` (the rate is their ratio), doubling every
//!   `--hot-doubling-k`; pixels with more than `--hot-exclude-above-e` are excluded rather
//!   than corrected (their shot noise outweighs the correction). Pixels outside the active
//!   area are skipped and counted (the table lists active pixels only).
//!
//! - Pixel-phase correction (`--psf-a-px A[,A2..]`, the PSF's 80 %-energy radius) ->
//!   **pixel-phase curves** (section 7, [`startrack_sim::pixcorr`]): one 33-knot curve per width,
//!   per CoG box in `--pixcorr-boxes` (default 5 and 7: `startrack process`'s default 7 px
//!   window and the firmware's 9 px one) and per power in `--pixcorr-powers` (default 1,2),
//!   all for the median-perimeter background both use. A combination the builder refuses
//!   (CoG not invertible, or the wings reach the perimeter) is reported and skipped; at
//!   most 16 curves fit the section. Then, while the section has room, one power-1 curve
//!   per width and box up to 9 for a *given* background: the firmware's tracking path
//!   (`centroid::raw_cog`, background carried from the star's last measurement) uses it.
//!
//! - CTI coefficients (`--cti FILE`, JSON from `startrack calib cti` or `calib frames`) ->
//!   **CTI** section 8; field PSF model (`--psf-model FILE`, JSON from `startrack calib
//!   psf-model`) -> **field PSF model** section 9 ([`models`]).
//!
//! A missing map gives no section and is reported ("no dark map: no dark correction").
//! Geometry: the CCD47-20 read through both outputs.
//!
//! # Where each job lives
//! - [`args`]: the options and their validation;
//! - [`maps`]: loading the FITS maps and the gains, and each map's conversion ([`hot`]: the
//!   hot-pixel CSV);
//! - [`curves`]: the pixel-phase curves;
//! - here: [`build`] assembles the sections and encodes the table ([`encode`], also the
//!   writer of [`crate::calib_frames`]); `startrack calib build` writes it and prints the notes.
//!
//! Cost: without `--psf-a-px`, reading the FITS maps (two full readouts and one active area)
//! and one pass over each; with it, building the curves ([`curves`]) takes most of the run.
//! The encoding is one pass over the sections.

pub mod args;
pub mod curves;
pub mod hot;
pub mod maps;
pub mod models;

pub use args::CalibBuildArgs;
pub use curves::{MAX_CURVES, PIXCORR_KNOTS, curves_from_args};
pub use hot::hot_from_csv;
pub use maps::{column_bias_from_map, dark_from_map, flat_from_map};

use crate::LabError;
use startrack_core::geometry::ReadoutGeometry;
use startrack_core::table::{MapSpec, TableSpec, write_table};
use startrack_core::units::Kelvin;
use startrack_sim::pixcorr::write_table_with_curves;

/// What `calib build` did, for the report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildReport {
    /// Bytes written.
    pub bytes: usize,
    /// One line per input: what became of it.
    pub notes: Vec<String>,
}

/// Builds the table bytes and the report (nothing written).
pub fn build(args: &CalibBuildArgs) -> Result<(Vec<u8>, BuildReport), LabError> {
    let g = ReadoutGeometry::CCD47_20_DUAL;
    let mut notes = Vec::new();
    let maps::Sections {
        gains,
        column_bias,
        dark_rel,
        flat_inv,
        hot,
    } = maps::load_sections(&g, args, &mut notes)?;
    let hot_ref_k = Kelvin::checked_from_num(args.hot_ref_k).ok_or_else(|| {
        LabError::Invalid(format!(
            "--hot-ref-k {}: must be 0 to 65535",
            args.hot_ref_k
        ))
    })?;
    let spec = TableSpec {
        geometry: g,
        saturation_adu: args.saturation_adu,
        gains: &gains,
        column_bias: column_bias.as_ref().map(|(c, _)| &c[..]),
        dark_rel: dark_rel.as_deref().map(|tiles| MapSpec {
            tile_log2: args.tile_log2,
            tiles,
        }),
        flat_inv: flat_inv.as_deref().map(|tiles| MapSpec {
            tile_log2: args.tile_log2,
            tiles,
        }),
        hot_ref_k,
        hot: &hot,
        telegraph: &[],
        camera_model: args
            .camera_model
            .as_deref()
            .map(crate::optics::read_camera_model)
            .transpose()?,
        cti: None,
        psf_model: None,
        dark_law: args
            .dark_law
            .as_deref()
            .map(args::parse_dark_law)
            .transpose()?,
    };
    let spec = TableSpec {
        cti: args
            .cti
            .as_deref()
            .map(|p| models::cti_from_json(&g, p))
            .transpose()?
            .map(|(c, note)| {
                notes.push(note);
                c
            }),
        psf_model: args
            .psf_model
            .as_deref()
            .map(|p| models::psf_model_from_json(&g, p))
            .transpose()?
            .map(|(m, note)| {
                notes.push(note);
                m
            }),
        ..spec
    };
    if let Some(p) = &args.camera_model {
        notes.push(format!("camera model from {}", p.display()));
    }
    if let Some(l) = spec.dark_law {
        notes.push(format!(
            "dark law {:.4} e-/px/s at {:.2} K, doubling {:.2} K, band {:.3} to {:.3}",
            l.rate_e_per_s, l.reference_k, l.doubling_k, l.band_low, l.band_high
        ));
    }
    let (curves, curve_notes) = curves_from_args(args)?;
    notes.extend(curve_notes);
    let buf = encode(&spec, &curves)?;
    let n = buf.len();
    Ok((buf, BuildReport { bytes: n, notes }))
}

/// Encodes `spec` (and the pixel-phase `curves`, none: no section) into the table's bytes:
/// the one table writer of `calib build` and `calib frames`.
pub fn encode(
    spec: &TableSpec<'_>,
    curves: &[startrack_sim::pixcorr::Curve],
) -> Result<Vec<u8>, LabError> {
    if curves.is_empty() {
        let mut buf = vec![0u8; spec.encoded_len()];
        let n = write_table(spec, &mut buf).map_err(LabError::TableWrite)?;
        buf.truncate(n);
        Ok(buf)
    } else {
        write_table_with_curves(spec, curves).map_err(LabError::TableWrite)
    }
}
