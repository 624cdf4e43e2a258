//! Automatic placement: the dominant supporting plane of the sparse points by RANSAC on
//! [`handheld_robust::run`], the object standing upright on it.

use handheld_core::{Rigid3, TriMesh};
use handheld_robust::{run, Estimator, InlierCount, RansacOptions, UniformSampler};
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use super::{bounds, AugmentError, Placement};

/// A plane `n · X = d` (unit `n`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SupportPlane {
    pub normal: [f64; 3],
    pub d: f64,
    pub inliers: usize,
    /// Angle between the plane's normal and the cameras' mean up direction (degrees).
    pub tilt_deg: f64,
}

/// How [`auto_place`] decided.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PlacementReport {
    pub plane: SupportPlane,
    /// The point of the plane the object stands on.
    pub anchor: [f64; 3],
    /// The object's height in model units.
    pub height: f64,
    /// The plane was not close to horizontal for the cameras (a warning).
    pub warnings: Vec<String>,
}

/// Options of [`auto_place`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct PlaceOptions {
    /// The object's height as a fraction of the median camera distance to the anchor.
    pub height_fraction: f64,
    /// RANSAC inlier distance as a fraction of the median camera-to-point distance.
    pub plane_tolerance: f64,
    /// Planes tilted more than this from the cameras' up direction are not "supporting".
    pub max_tilt_deg: f64,
    pub seed: u64,
}

impl Default for PlaceOptions {
    fn default() -> Self {
        Self {
            height_fraction: 0.12,
            plane_tolerance: 0.004,
            max_tilt_deg: 30.0,
            seed: 7,
        }
    }
}

/// A plane through three points that is close to horizontal (within `max_tilt` of `up`); the
/// residual is the distance in units of `tolerance`. Three-point fit (Fischler & Bolles 1981),
/// total-least-squares refit.
struct GroundEstimator {
    up: Vector3<f64>,
    cos_max_tilt: f64,
    tolerance: f64,
}

impl Estimator for GroundEstimator {
    type Model = (Vector3<f64>, f64);
    type Sample = Vector3<f64>;
    const SAMPLE_SIZE: usize = 3;

    fn fit(&self, s: &[Vector3<f64>], out: &mut Vec<Self::Model>) {
        let n = (s[1] - s[0]).cross(&(s[2] - s[0]));
        let len = n.norm();
        if len < 1e-12 {
            return;
        }
        let n = n / len;
        if n.dot(&self.up).abs() >= self.cos_max_tilt {
            out.push((n, n.dot(&s[0])));
        }
    }

    fn residual(&self, (n, d): &Self::Model, p: &Vector3<f64>) -> f64 {
        (n.dot(p) - d).abs() / self.tolerance
    }

    fn refit(&self, s: &[Vector3<f64>], (n, _): &Self::Model) -> Option<Self::Model> {
        if s.len() < 3 {
            return None;
        }
        let c = s.iter().sum::<Vector3<f64>>() / s.len() as f64;
        let cov = s
            .iter()
            .fold(Matrix3::zeros(), |a, p| a + (p - c) * (p - c).transpose());
        let eig = cov.symmetric_eigen();
        let mut m: Vector3<f64> = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        if m.dot(n) < 0.0 {
            m = -m;
        }
        (m.dot(&self.up).abs() >= self.cos_max_tilt).then(|| (m, m.dot(&c)))
    }
}

/// Places `object` automatically: the dominant supporting plane among `points` (model frame,
/// with the number of frames that see each), found by RANSAC among the planes within
/// `max_tilt_deg` of the cameras' mean up direction; the object stands upright on it (its +Y
/// along the plane's normal, towards the cameras; its +Z facing the cameras), at the point of
/// the plane under the centroid of the inliers most frames see, and its height is a fraction of
/// the cameras' median distance to that point. `cameras`: world → camera of every frame.
pub fn auto_place(
    object: &TriMesh,
    points: &[(Point3<f64>, usize)],
    cameras: &[Rigid3],
    opts: &PlaceOptions,
) -> Result<(Placement, PlacementReport), AugmentError> {
    if object.faces.is_empty() || object.vertices.positions.is_empty() {
        return Err(AugmentError::EmptyObject);
    }
    if points.len() < 3 || cameras.is_empty() {
        return Err(AugmentError::NoPlane(format!(
            "{} points and {} cameras; a supporting plane needs at least 3 points",
            points.len(),
            cameras.len()
        )));
    }
    let centres: Vec<Vector3<f64>> = cameras
        .iter()
        .map(|c| c.inverse().translation.vector)
        .collect();
    let up = cameras
        .iter()
        .map(|c| c.rotation.inverse() * Vector3::new(0.0, -1.0, 0.0))
        .sum::<Vector3<f64>>()
        .try_normalize(1e-9)
        .ok_or_else(|| AugmentError::NoPlane("the cameras have no common up direction".into()))?;
    let mut dists: Vec<f64> = points
        .iter()
        .map(|(p, _)| {
            centres
                .iter()
                .map(|c| (p.coords - c).norm())
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    dists.sort_by(f64::total_cmp);
    let scale = dists[dists.len() / 2];
    let samples: Vec<Vector3<f64>> = points.iter().map(|(p, _)| p.coords).collect();
    let est = GroundEstimator {
        up,
        cos_max_tilt: opts.max_tilt_deg.to_radians().cos(),
        tolerance: opts.plane_tolerance * scale,
    };
    let ransac = RansacOptions {
        max_error: 1.0,
        max_iterations: 2000,
        min_inlier_ratio: 0.0,
        ..RansacOptions::default()
    };
    let mut sampler = UniformSampler::new(opts.seed);
    let report = run(&est, &InlierCount, &mut sampler, &samples, &ransac).map_err(|e| {
        AugmentError::NoPlane(format!(
            "no near-horizontal plane among the sparse points ({e})"
        ))
    })?;
    let (mut n, mut d) = report.model.ok_or_else(|| {
        AugmentError::NoPlane(format!(
            "no plane within {}° of the cameras' up direction among the sparse points",
            opts.max_tilt_deg
        ))
    })?;
    let inliers: Vec<usize> = (0..samples.len())
        .filter(|&i| est.residual(&(n, d), &samples[i]) <= 1.0)
        .collect();
    if inliers.len() < 3 {
        return Err(AugmentError::NoPlane(
            "fewer than 3 points on the best plane".into(),
        ));
    }
    let cmean = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
    if n.dot(&cmean) - d < 0.0 {
        n = -n;
        d = -d;
    }
    // The inliers most frames see: track length at least the 75th percentile.
    let mut lens: Vec<usize> = inliers.iter().map(|&i| points[i].1).collect();
    lens.sort_unstable();
    let cut = lens[lens.len() * 3 / 4];
    let best: Vec<Vector3<f64>> = inliers
        .iter()
        .filter(|&&i| points[i].1 >= cut)
        .map(|&i| samples[i])
        .collect();
    let centroid = best.iter().sum::<Vector3<f64>>() / best.len().max(1) as f64;
    let anchor = centroid - n * (n.dot(&centroid) - d);
    let mut to_anchor: Vec<f64> = centres.iter().map(|c| (anchor - c).norm()).collect();
    to_anchor.sort_by(f64::total_cmp);
    let height = opts.height_fraction * to_anchor[to_anchor.len() / 2];
    // The object's frame: +Y up, +Z its front.
    let (lo, hi) = bounds(object);
    let obj_height = (hi.y - lo.y).max(1e-12);
    let s = height / obj_height;
    let front = {
        let v = cmean - anchor;
        let v = v - n * v.dot(&n);
        v.try_normalize(1e-12)
            .unwrap_or_else(|| n.cross(&Vector3::x()).normalize())
    };
    let x = n.cross(&front);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, n, front]));
    let base = Vector3::new((lo.x + hi.x) / 2.0, lo.y, (lo.z + hi.z) / 2.0);
    let t = anchor - r * base * s;
    let tilt = n.dot(&up).clamp(-1.0, 1.0).acos().to_degrees();
    Ok((
        Placement::new(s, &r, &t),
        PlacementReport {
            plane: SupportPlane {
                normal: [n.x, n.y, n.z],
                d,
                inliers: inliers.len(),
                tilt_deg: tilt,
            },
            anchor: [anchor.x, anchor.y, anchor.z],
            height,
            warnings: Vec::new(),
        },
    ))
}
