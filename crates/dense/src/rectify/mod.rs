//! Rectification of a calibrated pair (paper §4.1): polar ([`polar`]) for any motion, planar
//! ([`planar`]) as the fast path when both epipoles are far outside the images.
//!
//! Both are defined on ideal (undistorted) pixel coordinates and keep exact forward and inverse
//! maps `R(·)` / `R⁻¹(·)` between original (distorted) pixels and rectified `(column, row)`
//! positions, which multi-view linking (eq. 28) chains. [`Rectification::resample`] removes the
//! radial distortion in the same single bilinear resampling step.

pub mod ideal;
pub mod planar;
pub mod polar;

use handheld_core::{FloatMap, PosedCamera};
use nalgebra::{Point3, Vector2};

use crate::error::{DenseError, Result};
use ideal::{bilinear, IdealView};
use planar::PlanarRect;
use polar::PolarRect;

/// Which rectification to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RectifyMethod {
    /// Planar when both epipoles are farther than [`RectifyOptions::planar_epipole_distance`]
    /// image diagonals from the image centres (and the planar images stay small enough), polar
    /// otherwise. Polar rows far from a distant epipole fan out differently in the two images, so
    /// their disparity ranges grow; planar keeps them tight (fountain-P11 pair 2–3: −305..254
    /// planar, −1813..1889 polar).
    #[default]
    Auto,
    Polar,
    Planar,
}

/// Options of [`rectify_pair`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct RectifyOptions {
    pub method: RectifyMethod,
    /// In diagonals; planar rectification is used in `Auto` mode beyond this epipole distance.
    pub planar_epipole_distance: f64,
    /// Planar rectification may produce at most this many times the input's pixels.
    pub planar_max_pixels_ratio: f64,
}

impl Default for RectifyOptions {
    fn default() -> Self {
        Self {
            method: RectifyMethod::Auto,
            planar_epipole_distance: 1.0,
            planar_max_pixels_ratio: 4.0,
        }
    }
}

impl RectifyOptions {
    /// Checks every option; the error names the first offending one.
    pub fn validate(&self) -> Result<()> {
        if !(self.planar_epipole_distance.is_finite() && self.planar_epipole_distance > 0.0) {
            return Err(DenseError::InvalidOption {
                option: "planar_epipole_distance",
                reason: format!("must be positive, got {}", self.planar_epipole_distance),
            });
        }
        if self.planar_max_pixels_ratio.is_nan() || self.planar_max_pixels_ratio < 1.0 {
            return Err(DenseError::InvalidOption {
                option: "planar_max_pixels_ratio",
                reason: format!("must be at least 1, got {}", self.planar_max_pixels_ratio),
            });
        }
        Ok(())
    }
}

#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
enum Kind {
    Planar(PlanarRect),
    Polar(PolarRect),
}

/// A rectified pair: the two views and the rectifying maps. Side 0 is the left (first) view,
/// side 1 the right one; a left rectified `(x, y)` matches the right `(x − d, y)`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Rectification {
    views: [IdealView; 2],
    kind: Kind,
}

/// Rectifies the pair `left`, `right` (side 0 and side 1).
pub fn rectify_pair(
    left: &PosedCamera,
    right: &PosedCamera,
    opts: &RectifyOptions,
) -> Result<Rectification> {
    opts.validate()?;
    let view = |c: &PosedCamera| {
        IdealView::new(c).ok_or_else(|| DenseError::Rectification {
            reason: format!("camera {} has a singular calibration matrix", c.camera.id.0),
        })
    };
    let (v1, v2) = (view(left)?, view(right)?);
    let use_planar = match opts.method {
        RectifyMethod::Planar => true,
        RectifyMethod::Polar => false,
        RectifyMethod::Auto => {
            let far = |v: &IdealView, other: &IdealView| {
                let e = v.projection() * other.center().to_homogeneous();
                let diag = (v.width() as f64).hypot(v.height() as f64);
                let centre = nalgebra::Vector2::new(v.width() as f64, v.height() as f64) * 0.5;
                e.z.abs() * opts.planar_epipole_distance * diag < (e.xy() - centre * e.z).norm()
            };
            far(&v1, &v2) && far(&v2, &v1)
        }
    };
    let kind = if use_planar {
        match PlanarRect::new(&v1, &v2, opts.planar_max_pixels_ratio) {
            Ok(p) => Kind::Planar(p),
            Err(e) if opts.method == RectifyMethod::Auto => {
                tracing::debug!(%e, "planar rectification failed, using polar");
                Kind::Polar(PolarRect::new(&v1, &v2)?)
            }
            Err(e) => return Err(e),
        }
    } else {
        Kind::Polar(PolarRect::new(&v1, &v2)?)
    };
    Ok(Rectification {
        views: [v1, v2],
        kind,
    })
}

impl Rectification {
    /// Width and height of both rectified images.
    pub fn size(&self) -> (usize, usize) {
        match &self.kind {
            Kind::Planar(p) => (p.width, p.height),
            Kind::Polar(p) => (p.width, p.height),
        }
    }

    /// True for polar rectification.
    pub fn is_polar(&self) -> bool {
        matches!(self.kind, Kind::Polar(_))
    }

    /// The calibrated views (ideal coordinates), side 0 and side 1.
    pub fn view(&self, side: usize) -> &IdealView {
        &self.views[side]
    }

    /// `R(m)`: original pixel of view `side` → rectified `(column, row)`.
    pub fn to_rect(&self, side: usize, m: Vector2<f64>) -> Option<Vector2<f64>> {
        let p = self.views[side].to_ideal(m);
        match &self.kind {
            Kind::Planar(k) => k.to_rect(side, p),
            Kind::Polar(k) => k.to_rect(side, p),
        }
    }

    /// `R⁻¹(r)`: rectified `(column, row)` → original pixel of view `side`.
    pub fn from_rect(&self, side: usize, r: Vector2<f64>) -> Option<Vector2<f64>> {
        let p = match &self.kind {
            Kind::Planar(k) => k.from_rect(side, r),
            Kind::Polar(k) => k.from_rect(side, r),
        }?;
        Some(self.views[side].from_ideal(p))
    }

    /// Resamples view `side`'s image into the rectified frame (bilinear, one step from the
    /// original distorted pixels). Returns the image (0 outside the view) and the mask of
    /// rectified pixels that come from inside the view.
    pub fn resample(&self, side: usize, image: &FloatMap) -> (FloatMap, Vec<bool>) {
        use rayon::prelude::*;
        let (w, h) = self.size();
        let ch = image.channels;
        let mut out = FloatMap::filled(w, h, ch, 0.0);
        let mut mask = vec![false; w * h];
        let view = &self.views[side];
        out.data
            .par_chunks_mut(w * ch)
            .zip(mask.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (row, mrow))| {
                // Polar rows are straight half-lines in ideal coordinates: one angle per row.
                let ray = match &self.kind {
                    Kind::Polar(k) => k.row_ray(side, y),
                    Kind::Planar(_) => None,
                };
                for x in 0..w {
                    let m = match ray {
                        Some((e, u, rho0)) => {
                            let rho = x as f64 + rho0;
                            if rho <= 0.0 {
                                continue;
                            }
                            view.from_ideal(e + u * rho)
                        }
                        None => match self.from_rect(side, Vector2::new(x as f64, y as f64)) {
                            Some(m) => m,
                            None => continue,
                        },
                    };
                    if !view.contains(&m) {
                        continue;
                    }
                    for c in 0..ch {
                        if let Some(v) = bilinear(image, m.x, m.y, c) {
                            row[x * ch + c] = v;
                            mrow[x] = true;
                        }
                    }
                }
            });
        (out, mask)
    }

    /// Disparity range `(min, max)` of the world points seen in both views, widened by `margin`
    /// (a fraction of the span, plus 2 px). `None` with fewer than 3 such points.
    pub fn disparity_range(&self, points: &[Point3<f64>], margin: f64) -> Option<(i32, i32)> {
        let ds: Vec<(Vector2<f64>, f64)> = points
            .iter()
            .filter_map(|p| {
                let r0 = self.to_rect(0, self.project(0, p)?)?;
                let r1 = self.to_rect(1, self.project(1, p)?)?;
                ((r0.y - r1.y).abs() < 1.0).then_some((r0, r0.x - r1.x))
            })
            .collect();
        if ds.len() < 3 {
            return None;
        }
        let (lo, hi) = area_weighted_bounds(&ds, RANGE_TRIM);
        let pad = margin * (hi - lo) + 2.0;
        Some(((lo - pad).floor() as i32, (hi + pad).ceil() as i32))
    }

    /// Projects a world point into view `side` (original pixel), `None` behind or outside it.
    pub fn project(&self, side: usize, p: &Point3<f64>) -> Option<Vector2<f64>> {
        let v = &self.views[side];
        v.posed.project(p).filter(|m| v.contains(m))
    }
}

/// The share of the image, at each end of the disparities, left out of the range as stray points.
const RANGE_TRIM: f64 = 0.01;

/// Cells per side of the grid that weighs the points by the image area they stand for.
const AREA_GRID: usize = 32;

/// The disparities at `trim` and `1 − trim` of the image area the points stand for. Each point
/// weighs `1 / (points in its cell)` of a [`AREA_GRID`]² grid over the points' extent, so the
/// range covers most of the *pixels*, not most of the *points*: where most sparse points are far
/// (a street), the few on the near road still stand for a large part of the image (a trim of 1 %
/// of the points cut them off, and the near road got no depth); a few stray points among many
/// good ones in their cell still weigh little. `ds` holds (rectified position, disparity) pairs.
fn area_weighted_bounds(ds: &[(Vector2<f64>, f64)], trim: f64) -> (f64, f64) {
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    for (p, _) in ds {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let size = (hi - lo).map(|v| v.max(1e-9));
    let cell = |p: &Vector2<f64>| -> usize {
        let c = (p - lo).component_div(&size) * AREA_GRID as f64;
        let (x, y) = (
            (c.x as usize).min(AREA_GRID - 1),
            (c.y as usize).min(AREA_GRID - 1),
        );
        y * AREA_GRID + x
    };
    let mut count = vec![0usize; AREA_GRID * AREA_GRID];
    for (p, _) in ds {
        count[cell(p)] += 1;
    }
    let mut weighted: Vec<(f64, f64)> = ds
        .iter()
        .map(|(p, d)| (*d, 1.0 / count[cell(p)] as f64))
        .collect();
    weighted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = weighted.iter().map(|w| w.1).sum();
    let mut acc = 0.0;
    let mut low = weighted[0].0;
    for &(d, w) in &weighted {
        acc += w;
        low = d;
        if acc > trim * total {
            break;
        }
    }
    acc = 0.0;
    let mut high = weighted[weighted.len() - 1].0;
    for &(d, w) in weighted.iter().rev() {
        acc += w;
        high = d;
        if acc > trim * total {
            break;
        }
    }
    (low, high.max(low))
}

#[cfg(test)]
mod tests;
