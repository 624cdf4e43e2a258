//! One calibrated pair, end to end: rectify (§4.1), take the disparity range from the sparse
//! points both views see, match (§4.2), and keep only disparities whose two ends fall inside
//! their images.

use handheld_core::{FloatMap, PosedView};
use image::RgbImage;
use nalgebra::{Point3, Vector2};
use serde::{Deserialize, Serialize};

use crate::disparity::Disparity;
use crate::error::{DenseError, Result};
use crate::options::StereoOptions;
use crate::rectify::{rectify_pair, Rectification, RectifyOptions};
use crate::stereo::StereoMatcher;

/// Options of [`match_pair`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PairOptions {
    /// Rectification of the pair.
    pub rectify: RectifyOptions,
    /// Matcher settings; its disparity range is replaced by the one from the sparse points.
    pub stereo: StereoOptions,
    /// Widening of the sparse disparity range, as a fraction of its span (plus 2 px).
    pub range_margin: f64,
    /// Largest number of disparities a pair may span; wider sparse ranges are an error. 0 (the
    /// default) sets no limit: coarse-to-fine matching ([`StereoOptions::pyramid_disparities`])
    /// searches a fixed number per pixel however wide the range.
    pub max_disparities: usize,
}

impl Default for PairOptions {
    fn default() -> Self {
        Self {
            rectify: RectifyOptions::default(),
            // Four SGM paths: as accurate as eight on Middlebury (teddy bad1 10.8 % vs 11.1 %) and on
            // the synthetic linking curve, at about half the aggregation time.
            // No hole filling: linking follows measured disparities only.
            stereo: StereoOptions {
                sgm_paths: crate::options::SgmPaths::Four,
                hole_fill: crate::options::HoleFill::None,
                ..StereoOptions::default()
            },
            range_margin: 0.15,
            max_disparities: 0,
        }
    }
}

/// A matched pair: the rectification and the disparity in its frame (left = first view).
/// Serialisable for the work units of a distributed run (use an exact binary format: maps hold NaN).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct PairDisparity {
    pub rectification: Rectification,
    pub disparity: Disparity,
    /// The disparity range searched.
    pub range: (i32, i32),
}

/// Rectifies and matches `left` against `right` (their cameras, poses and images; the original
/// distorted pixels). `points` are sparse world points (those both views see fix the disparity
/// range, as §4.2 asks).
pub fn match_pair(
    left: &PosedView,
    right: &PosedView,
    points: &[Point3<f64>],
    opts: &PairOptions,
) -> Result<PairDisparity> {
    let mut matcher = StereoMatcher::new(opts.stereo.clone())?;
    match_pair_with(&mut matcher, left, right, points, opts)
}

/// Every consecutive pair `(i, i + 1)` of an ordered sequence, matched with one reused matcher:
/// the pair disparities [`crate::link_depth`] chains through.
pub fn match_sequence_pairs(
    views: &[PosedView],
    points: &[Point3<f64>],
    opts: &PairOptions,
) -> Result<Vec<Option<PairDisparity>>> {
    let mut matcher = StereoMatcher::new(opts.stereo.clone())?;
    views
        .windows(2)
        .map(|w| match_pair_with(&mut matcher, &w[0], &w[1], points, opts).map(Some))
        .collect()
}

/// [`match_pair`] with a reusable matcher (its options are `opts.stereo` apart from the range).
pub fn match_pair_with(
    matcher: &mut StereoMatcher,
    left: &PosedView,
    right: &PosedView,
    points: &[Point3<f64>],
    opts: &PairOptions,
) -> Result<PairDisparity> {
    for (v, which) in [(left, "left"), (right, "right")] {
        if (v.image.width(), v.image.height()) != (v.posed.camera.width, v.posed.camera.height) {
            return Err(DenseError::InvalidImage {
                which,
                reason: format!(
                    "{}: image is {}x{} but its camera is {}x{}",
                    v.name,
                    v.image.width(),
                    v.image.height(),
                    v.posed.camera.width,
                    v.posed.camera.height
                ),
            });
        }
    }
    let rect = rectify_pair(&left.posed, &right.posed, &opts.rectify)?;
    let range = rect
        .disparity_range(points, opts.range_margin)
        .ok_or_else(|| DenseError::Rectification {
            reason: "fewer than 3 sparse points are seen in both views, so the disparity range \
                     is unknown"
                .into(),
        })?;
    // Both ends of a match lie in rectified images of this width: no disparity reaches it.
    let reach = rect.size().0.saturating_sub(1) as i32;
    let range = (range.0.max(-reach), range.1.min(reach));
    if range.0 >= range.1 {
        return Err(DenseError::Rectification {
            reason: format!(
                "the sparse points' disparities lie beyond the rectified image ({} px)",
                reach + 1
            ),
        });
    }
    if opts.max_disparities > 0 && (range.1 - range.0) as usize + 1 > opts.max_disparities {
        return Err(DenseError::Rectification {
            reason: format!(
                "the sparse points span disparities {}..{}, more than max_disparities = {}",
                range.0, range.1, opts.max_disparities
            ),
        });
    }
    // The matcher works on grey levels: convert first, so resampling touches one channel.
    let (l, lmask) = rect.resample(0, &grey_image(&left.image));
    let (r, rmask) = rect.resample(1, &grey_image(&right.image));
    matcher.set_disparity_range(range.0, range.1.max(range.0 + 1))?;
    let mut d = matcher.match_pair(&l, &r)?;
    restrict_to_images(&mut d, &lmask, &rmask);
    Ok(PairDisparity {
        rectification: rect,
        disparity: d,
        range,
    })
}

/// Rec. 601 luma of an RGB map (the matcher's own conversion); grey maps are returned as is.
pub fn to_grey(map: &FloatMap) -> std::borrow::Cow<'_, FloatMap> {
    if map.channels != 3 {
        return std::borrow::Cow::Borrowed(map);
    }
    std::borrow::Cow::Owned(FloatMap {
        width: map.width,
        height: map.height,
        channels: 1,
        data: map
            .data
            .chunks_exact(3)
            .map(|c| 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2])
            .collect(),
    })
}

/// Rec. 601 luma of an 8-bit RGB image as a one-channel float map (the same values as
/// [`to_grey`] of the image's float copy).
pub fn grey_image(image: &RgbImage) -> FloatMap {
    FloatMap {
        width: image.width() as usize,
        height: image.height() as usize,
        channels: 1,
        data: image
            .as_raw()
            .chunks_exact(3)
            .map(|c| 0.299 * f32::from(c[0]) + 0.587 * f32::from(c[1]) + 0.114 * f32::from(c[2]))
            .collect(),
    }
}

/// Drops disparities whose pixel or whose match lies outside the resampled image.
fn restrict_to_images(d: &mut Disparity, lmask: &[bool], rmask: &[bool]) {
    let w = d.width;
    let inside = |mask: &[bool], y: usize, x: f32| {
        let xi = x.round();
        xi >= 0.0 && (xi as usize) < w && mask[y * w + xi as usize]
    };
    for i in 0..d.data.len() {
        let (x, y) = (i % w, i / w);
        let v = d.data[i];
        if !lmask[i] || !v.is_finite() || !inside(rmask, y, x as f32 - v) {
            d.data[i] = f32::NAN;
            d.valid[i] = false;
        }
        if let Some(r) = d.right.get_mut(i) {
            if !rmask[i] || !r.is_finite() || !inside(lmask, y, x as f32 + *r) {
                *r = f32::NAN;
            }
        }
    }
}

impl PairDisparity {
    /// Follows the pair from an original pixel of view `side` to the matching original pixel of
    /// the other view (eq. 28: `m′ = R′⁻¹(R(m) + D(R(m)))`), using measured disparities only.
    pub fn transfer(&self, side: usize, m: Vector2<f64>) -> Option<Vector2<f64>> {
        self.transfer_scaled(side, m).map(|(q, _)| q)
    }

    /// [`PairDisparity::transfer`] with the pixel size the disparity was measured at
    /// ([`Disparity::scale`]), by which its matching uncertainty grows.
    pub fn transfer_scaled(&self, side: usize, m: Vector2<f64>) -> Option<(Vector2<f64>, f64)> {
        let rect = &self.rectification;
        let r = rect.to_rect(side, m)?;
        let d = &self.disparity;
        let (map, valid): (&[f32], Option<&[bool]>) = if side == 0 {
            (&d.data, Some(&d.valid))
        } else {
            (&d.right, None)
        };
        let disp = sample(map, valid, d.width, d.height, r)?;
        let disp = f64::from(disp);
        let scale = d.scale_at(side, r.y.round() as usize * d.width + r.x.round() as usize);
        let x = if side == 0 { r.x - disp } else { r.x + disp };
        let other = 1 - side;
        let m2 = rect.from_rect(other, Vector2::new(x, r.y))?;
        rect.view(other).contains(&m2).then_some((m2, scale))
    }
}

/// Disparity at a fractional rectified position: bilinear when the four neighbours are measured
/// and agree within one pixel, the nearest measured value otherwise.
fn sample(map: &[f32], valid: Option<&[bool]>, w: usize, h: usize, r: Vector2<f64>) -> Option<f32> {
    if !(r.x >= 0.0 && r.y >= 0.0 && r.x <= (w - 1) as f64 && r.y <= (h - 1) as f64) {
        return None;
    }
    let ok = |i: usize| map[i].is_finite() && valid.is_none_or(|v| v[i]);
    let (x0, y0) = (r.x.floor() as usize, r.y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let idx = [y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1];
    if idx.iter().all(|&i| ok(i)) {
        let v = idx.map(|i| map[i]);
        let (lo, hi) = v
            .iter()
            .fold((f32::MAX, f32::MIN), |a, &x| (a.0.min(x), a.1.max(x)));
        if hi - lo <= 1.0 {
            let (fx, fy) = ((r.x - x0 as f64) as f32, (r.y - y0 as f64) as f32);
            let top = v[0] * (1.0 - fx) + v[1] * fx;
            let bot = v[2] * (1.0 - fx) + v[3] * fx;
            return Some(top * (1.0 - fy) + bot * fy);
        }
    }
    let i = r.y.round() as usize * w + r.x.round() as usize;
    ok(i).then(|| map[i])
}
