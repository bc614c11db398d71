//! A solved image's FITS WCS (gnomonic, `TAN`) and its annotated PNG.
//!
//! # WCS
//! The pinhole camera is exactly a gnomonic projection about the principal point, so the
//! solution is a TAN WCS: `CRPIX` the principal point in FITS's 1-based pixels (`x + 1`,
//! `y + 1`; FITS row 1 is row 0 here, the first row of the file and the top row of a TIFF),
//! `CRVAL` its RA and Dec, and the `CD` matrix the camera's axes projected on the local east
//! and north at `CRVAL` over the focal length: with `R` the rotation ICRS to camera, `e`,
//! `n` east and north at the boresight, `CD1_j = (R e)_j / f`, `CD2_j = (R n)_j / f` (deg
//! per px). Written as a header-only FITS file (`NAXIS 0`, as astrometry.net's `.wcs` files)
//! that astropy and DS9 read with the image.
//!
//! A camera with distortion gets SIP terms (Shupe et al. 2005, `CTYPE` `RA---TAN-SIP`):
//! with `(u, v)` the pixel less `CRPIX`, the undistorted pixel is `(u + A(u, v), v + B(u, v))`
//! and `CD` takes that to the tangent plane; `AP`, `BP` map back. The camera's distortion is
//! a polynomial of the undistorted point, so `AP`, `BP` are it exactly (order 2 for `p1`,
//! `p2`, 3 for `k1`, 5 for `k2`): with `f` the focal length,
//! `AP_3_0 = AP_1_2 = k1 / f^2`, `AP_5_0 = AP_1_4 = k2 / f^4`, `AP_3_2 = 2 k2 / f^4`,
//! `AP_2_0 = 3 p2 / f`, `AP_0_2 = p2 / f`, `AP_1_1 = 2 p1 / f`, and `BP` the same with the
//! axes and `p1`, `p2` swapped. `A`, `B` (order [`SIP_ORDER`]) are fitted by least squares
//! to the model's inverse on a 33 x 25 grid over the image and a 5 % margin; the largest
//! misfit on the grid is kept ([`Sip::fit_error_px`]). Cost: the grid's inversions and
//! a 33-term least-squares solve, a millisecond.
//!
//! # Annotated PNG
//! The background-subtracted image, stretched for the eye (square root between +2 and +60
//! background sigmas: the sky black, so the PNG compresses), every detection circled in yellow, each identified star circled in
//! green and labelled with its HIP number and Hp magnitude, and the catalog stars the
//! solution predicts in the image (to the catalog's faintest) marked with a red cross.
//! Labels need a TrueType font ([`startrack_analysis::figures::plot::ensure_font`]); without one the PNG
//! is drawn unlabelled.

use super::picture::Picture;
use super::solve::{ImageSolution, ra_dec_deg};
use super::stars::StarField;
use crate::LabError;
use nalgebra::{DMatrix, DVector};
use startrack_core::attitude::Camera;
use startrack_core::catalog::Catalog;
use std::path::Path;

/// Order of the fitted forward SIP polynomials `A`, `B`.
pub const SIP_ORDER: usize = 7;

/// SIP distortion terms: each polynomial as `(p, q, coefficient)`, the coefficient of
/// `u^p v^q` (px, `u`, `v` in px from `CRPIX`).
#[derive(Clone, Debug, PartialEq)]
pub struct Sip {
    /// Order of `A` and `B`.
    pub order: usize,
    /// Pixel to undistorted, column.
    pub a: Vec<(usize, usize, f64)>,
    /// Pixel to undistorted, row.
    pub b: Vec<(usize, usize, f64)>,
    /// Order of `AP` and `BP`.
    pub inv_order: usize,
    /// Undistorted to pixel, column.
    pub ap: Vec<(usize, usize, f64)>,
    /// Undistorted to pixel, row.
    pub bp: Vec<(usize, usize, f64)>,
    /// Largest misfit of `A`, `B` to the model's inverse on the fitting grid, px.
    pub fit_error_px: f64,
}

/// Whether `c` has any distortion (then its WCS needs SIP terms).
pub fn has_distortion(c: &Camera) -> bool {
    [c.k1, c.k2, c.p1, c.p2].iter().any(|v| *v != 0.0)
}

/// An image axis.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Axis {
    X,
    Y,
}

/// The forward SIP terms of `c` on one axis, `(p, q, coefficient)` of `u^p v^q`, zero terms
/// left out: `A` for [`Axis::X`]; `B` for [`Axis::Y`], the same polynomial with `u` and `v`
/// and the two tangential coefficients swapped.
fn sip_forward(c: &Camera, axis: Axis) -> Vec<(usize, usize, f64)> {
    let f = c.focal_length_px;
    let (f2, f4) = (f * f, f * f * f * f);
    let (pa, pb) = match axis {
        Axis::X => (c.p2, c.p1),
        Axis::Y => (c.p1, c.p2),
    };
    [
        (2, 0, 3.0 * pa / f),
        (0, 2, pa / f),
        (1, 1, 2.0 * pb / f),
        (3, 0, c.k1 / f2),
        (1, 2, c.k1 / f2),
        (5, 0, c.k2 / f4),
        (3, 2, 2.0 * c.k2 / f4),
        (1, 4, c.k2 / f4),
    ]
    .into_iter()
    .map(|(p, q, v)| {
        if axis == Axis::X {
            (p, q, v)
        } else {
            (q, p, v)
        }
    })
    .filter(|t| t.2 != 0.0)
    .collect()
}

/// The SIP terms of `c` over an image of `size_px`, or `None` without distortion or where the
/// model has no inverse on the grid.
pub fn sip_of(c: &Camera, size_px: [usize; 2]) -> Option<Sip> {
    if !has_distortion(c) {
        return None;
    }
    let f = c.focal_length_px;
    let (ap, bp) = (sip_forward(c, Axis::X), sip_forward(c, Axis::Y));
    let inv_order = if c.k2 != 0.0 {
        5
    } else if c.k1 != 0.0 {
        3
    } else {
        2
    };
    // A, B: least squares on the grid, in units of the half-diagonal for conditioning.
    let [w, h] = size_px.map(|v| v as f64);
    let [cx, cy] = c.principal_point_px;
    let s = 0.5 * w.hypot(h);
    let terms: Vec<(usize, usize)> = (2..=SIP_ORDER)
        .flat_map(|n| (0..=n).map(move |p| (p, n - p)))
        .collect();
    let (nx, ny) = (33usize, 25usize);
    let mut rows = Vec::with_capacity(nx * ny);
    let mut du = Vec::with_capacity(nx * ny);
    let mut dv = Vec::with_capacity(nx * ny);
    for i in 0..nx {
        for j in 0..ny {
            let x = -0.05 * w + 1.1 * w * i as f64 / (nx - 1) as f64 - 0.5;
            let y = -0.05 * h + 1.1 * h * j as f64 / (ny - 1) as f64 - 0.5;
            let d = c.direction_of(x, y, c.colour_ref_bv_mag).ok()?;
            let (u, v) = (x - cx, y - cy);
            let (uu, vu) = (f * d[0] / d[2], f * d[1] / d[2]);
            rows.push(
                terms
                    .iter()
                    .map(|&(p, q)| (u / s).powi(p as i32) * (v / s).powi(q as i32))
                    .collect::<Vec<f64>>(),
            );
            du.push(uu - u);
            dv.push(vu - v);
        }
    }
    let m = DMatrix::from_fn(rows.len(), terms.len(), |r, k| rows[r][k]);
    let svd = m.clone().svd(true, true);
    let ca = svd.solve(&DVector::from_vec(du.clone()), 1e-15).ok()?;
    let cb = svd.solve(&DVector::from_vec(dv.clone()), 1e-15).ok()?;
    let (ra, rb) = (&m * &ca, &m * &cb);
    let fit_error_px = (0..rows.len())
        .map(|r| (ra[r] - du[r]).hypot(rb[r] - dv[r]))
        .fold(0.0, f64::max);
    let scaled = |cv: &DVector<f64>| -> Vec<(usize, usize, f64)> {
        terms
            .iter()
            .zip(cv.iter())
            .map(|(&(p, q), k)| (p, q, k / s.powi((p + q) as i32)))
            .collect()
    };
    Some(Sip {
        order: SIP_ORDER,
        a: scaled(&ca),
        b: scaled(&cb),
        inv_order,
        ap,
        bp,
        fit_error_px,
    })
}

/// The TAN WCS of a solution.
#[derive(Clone, Debug, PartialEq)]
pub struct TanWcs {
    /// Reference pixel, FITS 1-based (column, row).
    pub crpix: [f64; 2],
    /// Reference point RA, Dec, deg.
    pub crval_deg: [f64; 2],
    /// `CD` matrix, deg per px: `[[CD1_1, CD1_2], [CD2_1, CD2_2]]`.
    pub cd_deg: [[f64; 2]; 2],
    /// Image size, px.
    pub size_px: [usize; 2],
    /// Distortion terms, when the camera has distortion.
    pub sip: Option<Sip>,
}

/// The WCS of `sol` for an image of `size_px`.
pub fn tan_wcs(sol: &ImageSolution, size_px: [usize; 2]) -> TanWcs {
    let q = sol.attitude.q;
    let b = q.rotate_inv([0.0, 0.0, 1.0]);
    let (ra, dec) = ra_dec_deg(b);
    let (a, d) = (ra.to_radians(), dec.to_radians());
    let east = [-a.sin(), a.cos(), 0.0];
    let north = [-d.sin() * a.cos(), -d.sin() * a.sin(), d.cos()];
    let (re, rn) = (q.rotate(east), q.rotate(north));
    let f = sol.focal_length_px;
    let k = 180.0 / std::f64::consts::PI / f;
    let pp = sol.camera.principal_point_px;
    TanWcs {
        crpix: [pp[0] + 1.0, pp[1] + 1.0],
        crval_deg: [ra, dec],
        cd_deg: [[re[0] * k, re[1] * k], [rn[0] * k, rn[1] * k]],
        size_px,
        sip: sip_of(&sol.camera, size_px),
    }
}

/// Writes `wcs` as a header-only FITS file.
pub fn write_wcs(path: &Path, wcs: &TanWcs) -> Result<(), LabError> {
    let err = |e: fitsio::errors::Error| LabError::Io {
        path: path.to_path_buf(),
        msg: e.to_string(),
    };
    let _ = std::fs::remove_file(path);
    let mut f = fitsio::FitsFile::create(path).open().map_err(err)?;
    let hdu = f.primary_hdu().map_err(err)?;
    hdu.write_key(&mut f, "WCSAXES", 2i64).map_err(err)?;
    let suffix = if wcs.sip.is_some() { "-SIP" } else { "" };
    hdu.write_key(&mut f, "CTYPE1", format!("RA---TAN{suffix}").as_str())
        .map_err(err)?;
    hdu.write_key(&mut f, "CTYPE2", format!("DEC--TAN{suffix}").as_str())
        .map_err(err)?;
    hdu.write_key(&mut f, "CUNIT1", "deg").map_err(err)?;
    hdu.write_key(&mut f, "CUNIT2", "deg").map_err(err)?;
    hdu.write_key(&mut f, "RADESYS", "ICRS").map_err(err)?;
    for (k, v) in [
        ("CRPIX1", wcs.crpix[0]),
        ("CRPIX2", wcs.crpix[1]),
        ("CRVAL1", wcs.crval_deg[0]),
        ("CRVAL2", wcs.crval_deg[1]),
        ("CD1_1", wcs.cd_deg[0][0]),
        ("CD1_2", wcs.cd_deg[0][1]),
        ("CD2_1", wcs.cd_deg[1][0]),
        ("CD2_2", wcs.cd_deg[1][1]),
    ] {
        hdu.write_key(&mut f, k, v).map_err(err)?;
    }
    hdu.write_key(&mut f, "IMAGEW", wcs.size_px[0] as i64)
        .map_err(err)?;
    hdu.write_key(&mut f, "IMAGEH", wcs.size_px[1] as i64)
        .map_err(err)?;
    if let Some(sip) = &wcs.sip {
        for (name, order, terms) in [
            ("A", sip.order, &sip.a),
            ("B", sip.order, &sip.b),
            ("AP", sip.inv_order, &sip.ap),
            ("BP", sip.inv_order, &sip.bp),
        ] {
            hdu.write_key(&mut f, &format!("{name}_ORDER"), order as i64)
                .map_err(err)?;
            for &(p, q, v) in terms {
                hdu.write_key(&mut f, &format!("{name}_{p}_{q}"), v)
                    .map_err(err)?;
            }
        }
    }
    Ok(())
}

/// Writes the annotated PNG (see the module docs).
pub fn write_annotated_png(
    path: &Path,
    pic: &Picture,
    field: &StarField,
    sol: &ImageSolution,
    cat: &Catalog<'_>,
    hip_of: &dyn Fn([f64; 3]) -> u32,
) -> Result<(), LabError> {
    use plotters::prelude::*;
    let (w, h) = (pic.width, pic.height);
    // Stretch: the background-subtracted values over the robust sigma of the residual.
    let mut resid: Vec<f32> = pic
        .data_adu
        .iter()
        .zip(&field.background_adu)
        .map(|(v, b)| v - b)
        .collect();
    let mut abs: Vec<f32> = resid.iter().map(|v| v.abs()).collect();
    let mid = abs.len() / 2;
    let sigma = abs.select_nth_unstable_by(mid, f32::total_cmp).1.max(1e-6) * 1.4826;
    let (lo, hi) = (2.0 * sigma, 60.0 * sigma);
    let mut rgb = vec![0u8; w * h * 3];
    for (px, v) in rgb.chunks_exact_mut(3).zip(resid.iter_mut()) {
        let t = ((*v - lo) / (hi - lo)).clamp(0.0, 1.0).sqrt();
        let g = (t * 255.0).round() as u8;
        px.copy_from_slice(&[g, g, g]);
    }
    let font = startrack_analysis::figures::plot::ensure_font().is_ok();
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w as u32, h as u32)).into_drawing_area();
        let yellow = RGBColor(230, 200, 40);
        let green = RGBColor(60, 220, 90);
        let red = RGBColor(240, 60, 60);
        let pt = |x: f64, y: f64| (x.round() as i32, y.round() as i32);
        let draw = |e: Result<(), DrawingAreaErrorKind<_>>| {
            e.map_err(|e| LabError::Io {
                path: path.to_path_buf(),
                msg: format!("drawing: {e}"),
            })
        };
        for s in &field.stars {
            draw(root.draw(&Circle::new(pt(s.x_px, s.y_px), 7, yellow)))?;
        }
        // Catalog stars the solution predicts in the frame.
        let cone = (((w * w + h * h) as f64).sqrt() / 2.0 / sol.focal_length_px).atan();
        for (_, dir) in cat.cone(sol.attitude.q.rotate_inv([0.0, 0.0, 1.0]), cone) {
            let Some(p) = sol.camera.project(sol.attitude.q.rotate(dir)) else {
                continue;
            };
            if p[0] < 0.0 || p[1] < 0.0 || p[0] > w as f64 || p[1] > h as f64 {
                continue;
            }
            let (x, y) = pt(p[0], p[1]);
            draw(root.draw(&PathElement::new(vec![(x - 12, y), (x - 5, y)], red)))?;
            draw(root.draw(&PathElement::new(vec![(x + 5, y), (x + 12, y)], red)))?;
            draw(root.draw(&PathElement::new(vec![(x, y - 12), (x, y - 5)], red)))?;
            draw(root.draw(&PathElement::new(vec![(x, y + 5), (x, y + 12)], red)))?;
        }
        for m in &sol.matches {
            let (Some(s), Some(c)) = (field.stars.get(m.star), cat.star(m.catalog)) else {
                continue;
            };
            let (x, y) = pt(s.x_px, s.y_px);
            draw(root.draw(&Circle::new((x, y), 10, green.stroke_width(2))))?;
            if font {
                let label = format!("HIP {} {:.1}", hip_of(c.dir), f64::from(c.hp_mmag) / 1000.0);
                let style = ("sans-serif", 13).into_font().color(&green);
                draw(root.draw(&Text::new(label, (x + 12, y - 16), style)))?;
            }
        }
        draw(root.present())?;
    }
    let img = image::RgbImage::from_raw(w as u32, h as u32, rgb).ok_or_else(|| LabError::Io {
        path: path.to_path_buf(),
        msg: "image buffer size".into(),
    })?;
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| LabError::Io {
            path: path.to_path_buf(),
            msg: e.to_string(),
        })
}
