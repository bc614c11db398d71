//! The camera model from real night-sky images (`startrack optics fit --images`): each
//! image's stars found and identified as `solve-image` does ([`crate::realsky`]), then the
//! camera fitted over all images together by [`super::fit`].
//!
//! - Start: the pinhole `solve-image` identified every image with (the focal length the
//!   median of the images' refit ones, the principal point at the image centre), or a given
//!   model; each image's attitude and matched stars from its solution.
//! - Rounds: the model and the attitudes are fitted to the matches (weighted by the stars'
//!   inverse variances, [`star_sigma_px`]); then every measured star of each image is
//!   matched again to the nearest catalog star through the fitted model and that image's
//!   fitted attitude (`solve-image`'s matching, radius `5 sigma_floor + 1` px, then a cut
//!   at 5 of the star's own sigmas), and fitted again, until the matches stop changing (at most
//!   [`MAX_ROUNDS`] fits). The first fit is to `solve-image`'s own matches at its own
//!   attitudes, which agree with the camera it solved with whatever the start's principal
//!   point: a principal point moved by `d` px looks like the attitude turned by `d / f`, so
//!   matching through a new model at an old attitude would miss every star.
//! - Before and after: the pinhole with only its focal length fitted to the same matches
//!   (and the same attitudes fitted) is the model `solve-image` had; its residual RMS
//!   against the fitted model's says what the model removes.
//! - Holdout ([`holdout`]): the model fitted on some images, then on the others, with the
//!   model held and only their attitudes fitted (matches through the held model, rounds as
//!   above), the residual RMS through it and through the pinhole fitted on the same
//!   training images, over the same stars. A model that fits noise does better on its own
//!   images than on others.
//!
//! Cost: the images' identification (`solve-image`'s), then per round one match per star
//! (a cone search) and one fit (a few iterations of an `8 + 3 N`-square Cholesky solve);
//! milliseconds for 8 images beyond the identification.

use super::{FitError, FitOptions, Frame, IdStar, fit};
use crate::realsky::solve::{CUT_SIGMAS, match_all, star_sigma_px};
use crate::realsky::stars::ImageStar;
use startrack_core::attitude::{Camera, Quat};
use startrack_core::catalog::Catalog;

/// Most match-and-fit rounds.
pub const MAX_ROUNDS: usize = 6;

/// One solved image, as the fit takes it.
#[derive(Clone, Debug, PartialEq)]
pub struct SkyImage {
    /// Its name (the file's stem).
    pub name: String,
    /// Columns and rows.
    pub size_px: [usize; 2],
    /// Its measured stars, brightest first.
    pub stars: Vec<ImageStar>,
    /// Its attitude from `solve-image` (ICRS to camera).
    pub attitude: Quat,
    /// Its refit focal length from `solve-image`, px.
    pub focal_length_px: f64,
    /// `solve-image`'s matches: (index in [`Self::stars`], catalog index).
    pub matches: Vec<(usize, usize)>,
}

/// A fit over images.
#[derive(Clone, Debug, PartialEq)]
pub struct SkyFit {
    /// Each image's matched stars ([`Frame::field`]: the image's index), at the last round.
    pub frames: Vec<Frame>,
    /// The model's fit to them.
    pub fit: super::Fit,
    /// The pinhole's fit to the same matches (focal length and attitudes only).
    pub pinhole: super::Fit,
    /// Rounds taken.
    pub rounds: usize,
}

/// The identified star of measured star `star` matched to catalog star `catalog`.
fn id_star(
    cat: &Catalog<'_>,
    img: &SkyImage,
    star: usize,
    catalog: usize,
    sigma_floor_px: f64,
) -> Option<IdStar> {
    let s = img.stars.get(star)?;
    let c = cat.star(catalog)?;
    Some(IdStar {
        x_px: s.x_px,
        y_px: s.y_px,
        icrs: c.dir,
        bv_mag: f64::from(c.bv_mmag) / 1000.0,
        catalog: u16::try_from(catalog).ok()?,
        sigma_px: star_sigma_px(s, sigma_floor_px),
    })
}

/// `solve-image`'s own matches of `img`, at its attitude.
fn solved_frame(cat: &Catalog<'_>, index: usize, img: &SkyImage, sigma_floor_px: f64) -> Frame {
    Frame {
        field: index,
        attitude: img.attitude,
        stars: img
            .matches
            .iter()
            .filter_map(|&(s, c)| id_star(cat, img, s, c, sigma_floor_px))
            .collect(),
    }
}

/// Matches `img`'s stars through `camera` at `q` (see the module docs).
pub fn frame_of(
    cat: &Catalog<'_>,
    index: usize,
    img: &SkyImage,
    camera: &Camera,
    q: Quat,
    sigma_floor_px: f64,
) -> Frame {
    let radius_px = CUT_SIGMAS * sigma_floor_px + 1.0;
    let stars = match_all(cat, &img.stars, q, camera, radius_px)
        .into_iter()
        .filter_map(|m| {
            let s = id_star(cat, img, m.star, m.catalog, sigma_floor_px)?;
            (m.residual_rad <= CUT_SIGMAS * s.sigma_px / camera.focal_length_px).then_some(s)
        })
        .collect();
    Frame {
        field: index,
        attitude: q,
        stars,
    }
}

fn same_matches(a: &[Frame], b: &[Frame]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            x.stars.len() == y.stars.len()
                && x.stars
                    .iter()
                    .zip(&y.stars)
                    .all(|(s, t)| s.catalog == t.catalog && s.x_px == t.x_px && s.y_px == t.y_px)
        })
}

/// Fits and matches in rounds (see the module docs): the first fit to `solve-image`'s own
/// matches at its attitudes (which agree with the camera it solved with, whatever `start`'s
/// principal point), then every star matched again through the fit, until the matches
/// stop changing. `opts` says what is fitted. Returns the last fit, the frames it was
/// fitted to and the rounds taken.
fn rounds(
    cat: &Catalog<'_>,
    images: &[SkyImage],
    start: &Camera,
    sigma_floor_px: f64,
    opts: FitOptions,
) -> Result<(Vec<Frame>, super::Fit, usize), FitError> {
    let mut frames: Vec<Frame> = images
        .iter()
        .enumerate()
        .map(|(i, img)| solved_frame(cat, i, img, sigma_floor_px))
        .collect();
    let mut cam = *start;
    let mut round = 0;
    loop {
        round += 1;
        let f = fit(&frames, &cam, opts)?;
        cam = f.camera;
        let next: Vec<Frame> = images
            .iter()
            .enumerate()
            .map(|(i, img)| frame_of(cat, i, img, &cam, f.attitudes[i], sigma_floor_px))
            .collect();
        if round >= MAX_ROUNDS || same_matches(&frames, &next) {
            return Ok((frames, f, round));
        }
        frames = next;
    }
}

/// The pinhole `solve-image` starts from: the images' median refit focal length, the
/// principal point at the first image's centre.
pub fn pinhole_start(images: &[SkyImage]) -> Camera {
    let mut f: Vec<f64> = images.iter().map(|i| i.focal_length_px).collect();
    f.sort_by(f64::total_cmp);
    let f_med = f.get(f.len() / 2).copied().unwrap_or(1.0);
    let size = images.first().map_or([1, 1], |i| i.size_px);
    Camera::pinhole(f_med, crate::realsky::solve::centre(size))
}

/// The focal length alone fitted, the rest held (the pinhole of `solve-image`).
fn focal_only() -> FitOptions {
    FitOptions {
        focal_length: true,
        ..FitOptions::attitudes_only()
    }
}

/// Fits the camera model over `images` (see the module docs).
pub fn fit_images(
    cat: &Catalog<'_>,
    images: &[SkyImage],
    start: &Camera,
    sigma_floor_px: f64,
    opts: FitOptions,
) -> Result<SkyFit, FitError> {
    let (frames, f, rounds_taken) = rounds(cat, images, start, sigma_floor_px, opts)?;
    let pinhole = fit(&frames, &pinhole_start(images), focal_only())?;
    Ok(SkyFit {
        frames,
        fit: f,
        pinhole,
        rounds: rounds_taken,
    })
}

/// The model fitted on some images, tested on the others (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Holdout {
    /// Images fitted on (indices into the images given).
    pub train: Vec<usize>,
    /// Images tested on.
    pub test: Vec<usize>,
    /// The fit on the training images.
    pub trained: SkyFit,
    /// Stars matched in the test images.
    pub test_stars: usize,
    /// Residual RMS per axis over the test images' stars through the training pinhole, px.
    pub pinhole_rms_px: f64,
    /// The same through the training model, px.
    pub model_rms_px: f64,
}

/// Fits on `train` and tests on `test` (indices into `images`).
pub fn holdout(
    cat: &Catalog<'_>,
    images: &[SkyImage],
    train: &[usize],
    test: &[usize],
    start: &Camera,
    sigma_floor_px: f64,
    opts: FitOptions,
) -> Result<Holdout, FitError> {
    let pick = |idx: &[usize]| -> Vec<SkyImage> {
        idx.iter().filter_map(|&i| images.get(i).cloned()).collect()
    };
    let (train_imgs, test_imgs) = (pick(train), pick(test));
    let trained = fit_images(cat, &train_imgs, start, sigma_floor_px, opts)?;
    let (frames, model, _) = rounds(
        cat,
        &test_imgs,
        &trained.fit.camera,
        sigma_floor_px,
        FitOptions::attitudes_only(),
    )?;
    let pinhole = fit(
        &frames,
        &trained.pinhole.camera,
        FitOptions::attitudes_only(),
    )?;
    Ok(Holdout {
        train: train.to_vec(),
        test: test.to_vec(),
        trained,
        test_stars: model.stars,
        pinhole_rms_px: pinhole.residual_rms_px,
        model_rms_px: model.residual_rms_px,
    })
}
