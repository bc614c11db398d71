//! The pixel-phase correction curves of `calib build --psf-a-px` (table section 7): one per
//! width, CoG box and power for the median-perimeter background `startrack process` uses, then,
//! while the section has room, one power-1 curve per width and box up to 9 for a given
//! background (the firmware's tracking path). Each curve built or refused gives one note.
//! Cost: one [`build_curve`] per combination, a bisection per knot on the exact
//! pixel-integrated Gaussian (see [`startrack_sim::pixcorr`]).

use super::args::{CalibBuildArgs, parse_list};
use crate::LabError;
use startrack_core::table::pixcorr::CogPower;
use startrack_core::table::pixcorr::PixCorrBackground;
use startrack_sim::pixcorr::{Curve, CurveSpec, build_curve};

/// Knots per pixel-phase curve (74 bytes each).
pub const PIXCORR_KNOTS: u8 = 33;

/// Most curves the pixel-phase section holds.
pub const MAX_CURVES: usize = 16;

/// The largest correction of a curve, px, for its note.
fn largest_correction_px(c: &Curve) -> f64 {
    c.knots_px.iter().fold(0.0f64, |m, k| m.max(k.abs()))
}

/// The pixel-phase curves of `args` (empty without `--psf-a-px`) and one note per curve
/// built or refused.
pub fn curves_from_args(args: &CalibBuildArgs) -> Result<(Vec<Curve>, Vec<String>), LabError> {
    let Some(list) = &args.psf_a_px else {
        return Ok((
            Vec::new(),
            vec![
                "no --psf-a-px: no pixel-phase correction (cog1/cog2 are flagged uncorrected)"
                    .into(),
            ],
        ));
    };
    let widths: Vec<f64> = parse_list("--psf-a-px", list)?;
    if let Some(a) = widths
        .iter()
        .find(|a| !(a.is_finite() && (0.1..=50.0).contains(*a)))
    {
        return Err(LabError::Invalid(format!(
            "--psf-a-px {a}: must be 0.1 to 50 px"
        )));
    }
    let boxes: Vec<u8> = parse_list("--pixcorr-boxes", &args.pixcorr_boxes)?;
    if let Some(b) = boxes
        .iter()
        .find(|b| !(3..=29).contains(*b) || b.is_multiple_of(2))
    {
        return Err(LabError::Invalid(format!(
            "--pixcorr-boxes: box {b} must be odd, 3 to 29"
        )));
    }
    let powers = parse_list::<u8>("--pixcorr-powers", &args.pixcorr_powers)?
        .into_iter()
        .map(|p| match p {
            1 => Ok(CogPower::One),
            2 => Ok(CogPower::Two),
            _ => Err(LabError::Invalid(format!(
                "--pixcorr-powers: power {p} must be 1 or 2"
            ))),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut curves = Vec::new();
    let mut notes = Vec::new();
    for &a_px in &widths {
        for &box_side in &boxes {
            for &power in &powers {
                let spec = CurveSpec {
                    a_px,
                    box_side,
                    power,
                    background: PixCorrBackground::PerimeterMedian,
                    knots: PIXCORR_KNOTS,
                };
                let p = if power == CogPower::One { 1 } else { 2 };
                match build_curve(&spec) {
                    Ok(c) => {
                        notes.push(format!(
                            "pixel-phase curve: a {a_px} px, box {box_side}, power {p}, median perimeter background (largest correction {:.4} px)",
                            largest_correction_px(&c)
                        ));
                        curves.push(c);
                    }
                    Err(e) => notes.push(format!(
                        "no pixel-phase curve for a {a_px} px, box {box_side}, power {p}: {e}"
                    )),
                }
            }
        }
    }
    // The firmware's tracking path (core `centroid::raw_cog`: power 1, a given background
    // carried from the star's last measurement) needs curves made for a given background:
    // one per width for each box the fused path takes (side <= 9), while the section has
    // room (a note says when it had not).
    for &a_px in &widths {
        for &box_side in boxes.iter().filter(|b| **b <= 9) {
            let spec = CurveSpec {
                a_px,
                box_side,
                power: CogPower::One,
                background: PixCorrBackground::Given,
                knots: PIXCORR_KNOTS,
            };
            if curves.len() >= MAX_CURVES {
                notes.push(format!(
                    "no tracking curve (given background) for a {a_px} px, box {box_side}: the section is full"
                ));
                continue;
            }
            match build_curve(&spec) {
                Ok(c) => {
                    notes.push(format!(
                        "tracking curve (given background): a {a_px} px, box {box_side}, power 1 (largest correction {:.4} px)",
                        largest_correction_px(&c)
                    ));
                    curves.push(c);
                }
                Err(e) => notes.push(format!(
                    "no tracking curve (given background) for a {a_px} px, box {box_side}: {e}"
                )),
            }
        }
    }
    if curves.len() > MAX_CURVES {
        return Err(LabError::Invalid(format!(
            "{} pixel-phase curves: the table holds at most {MAX_CURVES} (fewer widths, boxes or powers)",
            curves.len()
        )));
    }
    Ok((curves, notes))
}
