//! The recorded views of a scene prepared for rendering, its fixed plane L (§5.2) and its extent.

use handheld_core::PosedView;
use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;

use super::source::Source;
use super::support::{self, Virtual};
use super::{IbrError, Plane};

/// The recorded views of a scene, prepared for rendering, and its fixed plane L.
pub struct IbrScene {
    pub sources: Vec<Source>,
    pub plane: Plane,
    /// A box around the scene (2nd to 98th percentiles of its points, widened by a quarter).
    pub bounds: (Point3<f64>, Point3<f64>),
    /// Whether any view has a depth map (without, only [`IbrMethod::Plane`] is meaningful).
    pub has_depth: bool,
}

impl IbrScene {
    /// Prepares `views` (depth maps optional) for rendering. The fixed plane L is least-squares
    /// fitted to `points` (the sparse points), or to the depth maps' points when fewer than 3 are
    /// given.
    pub fn new(views: &[PosedView], points: &[Point3<f64>]) -> Result<Self, IbrError> {
        if views.is_empty() {
            return Err(IbrError::NoViews);
        }
        for v in views {
            v.validate()?;
        }
        let sources: Vec<Source> = views.par_iter().map(Source::new).collect();
        let has_depth = sources.iter().any(Source::has_depth);
        let samples = if points.len() >= 3 {
            points.to_vec()
        } else {
            depth_samples(views)
        };
        let bounds = robust_bounds(&samples);
        // The least-squares plane of the points inside the percentile box (far outliers of a
        // sparse model would tilt it).
        let inner: Vec<Point3<f64>> = {
            let (lo, hi) = (bounds.0, bounds.1);
            let m = (hi - lo) / 6.0; // undo the widening by a quarter on each side
            samples
                .iter()
                .filter(|p| (0..3).all(|k| p[k] >= lo[k] + m[k] && p[k] <= hi[k] - m[k]))
                .copied()
                .collect()
        };
        let plane = support::fit_plane(if inner.len() >= 3 { &inner } else { &samples })
            .ok_or(IbrError::NoPlane)?;
        Ok(Self {
            sources,
            plane,
            bounds,
            has_depth,
        })
    }

    /// The centroid of the scene points used for paths: the median of the depth maps' points
    /// when there are some, else the point of the plane nearest the cameras' centroid.
    pub fn focus(&self, points: &[Point3<f64>]) -> Point3<f64> {
        if points.is_empty() {
            let c = self
                .sources
                .iter()
                .fold(Vector3::zeros(), |a, s| a + s.center.coords)
                / self.sources.len() as f64;
            let off = self.plane.n.dot(&c) + self.plane.d;
            return Point3::from(c - self.plane.n * off);
        }
        let med = |k: usize| {
            let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        Point3::new(med(0), med(1), med(2))
    }
}

/// The 2nd and 98th percentiles of the points along each axis, widened by a quarter of the
/// extent on each side.
pub(crate) fn robust_bounds(points: &[Point3<f64>]) -> (Point3<f64>, Point3<f64>) {
    let mut lo = Point3::origin();
    let mut hi = Point3::origin();
    for k in 0..3 {
        let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
        v.sort_by(f64::total_cmp);
        let a = v[v.len() * 2 / 100];
        let b = v[(v.len() * 98 / 100).min(v.len() - 1)];
        let m = 0.25 * (b - a);
        lo[k] = a - m;
        hi[k] = b + m;
    }
    (lo, hi)
}

/// The range of virtual-camera depths of the scene box: (near, far).
pub(crate) fn depth_range(virt: &Virtual, bounds: &(Point3<f64>, Point3<f64>)) -> (f64, f64) {
    let (lo, hi) = bounds;
    let mut zmin = f64::INFINITY;
    let mut zmax = f64::NEG_INFINITY;
    for i in 0..8 {
        let c = Vector3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        );
        let z = (virt.r * c + virt.t).z;
        zmin = zmin.min(z);
        zmax = zmax.max(z);
    }
    let diag = (hi - lo).norm();
    let far = zmax.max(1e-3 * diag);
    (zmin.max(1e-2 * far), far)
}

/// Points of the views' depth maps on a coarse grid.
fn depth_samples(views: &[PosedView]) -> Vec<Point3<f64>> {
    let mut out = Vec::new();
    for v in views {
        let Some(d) = &v.depth else { continue };
        let step = (d.width.max(d.height) / 32).max(1);
        let world_from_cam = v.posed.cam_from_world.inverse();
        for y in (0..d.height).step_by(step) {
            for x in (0..d.width).step_by(step) {
                let z = f64::from(d.get(x, y, 0));
                if z.is_finite() && z > 0.0 {
                    let ray = v.posed.camera.ray_in_cam(Vector2::new(x as f64, y as f64));
                    let p = Point3::from(ray / ray.z * z);
                    out.push(world_from_cam.transform_point(&p));
                }
            }
        }
    }
    out
}
