//! Reading a plain image (not a CCD47-20 raw frame) into one channel of `f32` values.
//!
//! - FITS: the primary HDU's 2-D image, any BITPIX, BZERO and BSCALE applied by CFITSIO
//!   ([`startrack_sim::fits::read_map`]); row 0 is the first FITS row.
//! - TIFF (8 and 16 bit), PNG and JPEG: the `image` crate; colour becomes luminance with
//!   the Rec. 709 weights (0.2126 R + 0.7152 G + 0.0722 B, the `image` crate's own), at the
//!   file's bit depth (0..255 or 0..65535). A 16-bit colour image keeps 16 bits.
//!
//! Pixel convention: x = column, y = row, 0-based, first pixel centre at (0, 0), row 0 the
//! top row on screen. The saturation level is the sample type's full scale (255, 65535,
//! 32767 for signed 16-bit FITS...; for floating-point FITS the `SATURATE` keyword when
//! present, else none): a pixel at or above it is flagged, never fitted.
//!
//! Cost: the decode, then one pass over the pixels; the image is held in memory (4 bytes a
//! pixel).

use crate::LabError;
use std::path::Path;

/// Smallest side accepted, px: a star's fitting window (9 px) and two background tiles.
pub const MIN_SIDE_PX: usize = 32;
/// Largest side accepted, px (the line detector's blocks cover 4096 columns; u16 rows).
pub const MAX_SIDE_PX: usize = 4096;

/// One channel of an image.
#[derive(Clone, Debug, PartialEq)]
pub struct Picture {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values in the file's units (ADU), row-major.
    pub data_adu: Vec<f32>,
    /// Pixels at or above this are saturated (none known: `None`).
    pub saturation_adu: Option<f32>,
}

impl Picture {
    /// Value at (`x`, `y`), 0 outside.
    pub fn at(&self, x: usize, y: usize) -> f32 {
        if x >= self.width {
            return 0.0;
        }
        self.data_adu
            .get(y * self.width + x)
            .copied()
            .unwrap_or(0.0)
    }

    fn checked(self, path: &Path) -> Result<Self, LabError> {
        let bad = |msg: String| Err(LabError::Invalid(format!("{}: {msg}", path.display())));
        if self.width < MIN_SIDE_PX || self.height < MIN_SIDE_PX {
            return bad(format!(
                "image of {} x {} px is too small (at least {MIN_SIDE_PX} x {MIN_SIDE_PX})",
                self.width, self.height
            ));
        }
        if self.width > MAX_SIDE_PX || self.height > MAX_SIDE_PX {
            return bad(format!(
                "image of {} x {} px is too large (at most {MAX_SIDE_PX} a side)",
                self.width, self.height
            ));
        }
        if self.data_adu.len() != self.width * self.height {
            return bad("pixel count does not match the image size".into());
        }
        if let Some(i) = self.data_adu.iter().position(|v| !v.is_finite()) {
            return bad(format!(
                "value at row {}, column {} is NaN or infinite",
                i / self.width,
                i % self.width
            ));
        }
        Ok(self)
    }
}

fn is_fits(path: &Path) -> bool {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if matches!(ext.as_str(), "fits" | "fit" | "fts") {
        return true;
    }
    // A FITS file starts with "SIMPLE  =" whatever its name.
    std::fs::File::open(path)
        .ok()
        .and_then(|mut f| {
            let mut head = [0u8; 9];
            std::io::Read::read_exact(&mut f, &mut head).ok()?;
            Some(&head == b"SIMPLE  =")
        })
        .unwrap_or(false)
}

/// Reads `path` (see the module docs).
pub fn load(path: &Path) -> Result<Picture, LabError> {
    let pic = if is_fits(path) {
        load_fits(path)?
    } else {
        load_raster(path)?
    };
    pic.checked(path)
}

fn load_fits(path: &Path) -> Result<Picture, LabError> {
    let map = startrack_sim::fits::read_map(path, &["SATURATE"])?;
    let full_scale = startrack_sim::fits::full_scale(path)?;
    Ok(Picture {
        width: map.cols,
        height: map.rows,
        saturation_adu: full_scale.or(map.key("SATURATE")).map(|v| v as f32),
        data_adu: map.data,
    })
}

fn load_raster(path: &Path) -> Result<Picture, LabError> {
    let bytes = crate::read_file(path)?;
    let img = image::load_from_memory(&bytes)
        .map_err(|e| LabError::Invalid(format!("{}: not a readable image: {e}", path.display())))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    use image::DynamicImage as D;
    let (data_adu, full): (Vec<f32>, f32) = match img {
        D::ImageLuma8(_) | D::ImageLumaA8(_) | D::ImageRgb8(_) | D::ImageRgba8(_) => (
            img.into_luma8()
                .into_raw()
                .into_iter()
                .map(f32::from)
                .collect(),
            255.0,
        ),
        D::ImageLuma16(_) | D::ImageLumaA16(_) | D::ImageRgb16(_) | D::ImageRgba16(_) => (
            img.into_luma16()
                .into_raw()
                .into_iter()
                .map(f32::from)
                .collect(),
            65535.0,
        ),
        other => {
            return Err(LabError::Invalid(format!(
                "{}: unsupported sample type {:?} (8 or 16-bit integer images only)",
                path.display(),
                other.color()
            )));
        }
    };
    Ok(Picture {
        width,
        height,
        data_adu,
        saturation_adu: Some(full),
    })
}
