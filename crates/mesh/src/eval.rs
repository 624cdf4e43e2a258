//! Middlebury multi-view stereo metrics (Seitz, Curless, Diebel, Scharstein and Szeliski, *A
//! comparison and evaluation of multi-view stereo reconstruction algorithms*, CVPR 2006):
//!
//! * **accuracy**: the distance `d` such that a given fraction (90%) of the reconstructed surface
//!   lies within `d` of the ground-truth surface — measured on area-uniform samples of the
//!   reconstruction;
//! * **completeness**: the fraction of ground-truth surface samples within a threshold of the
//!   reconstruction. Only ground truth the input views saw counts: [`visible_surface_samples`]
//!   lifts the ground-truth depth maps of the input views.
//!
//! Distances use the exact point-to-triangle distance through a [`MeshIndex`] hierarchy.

use handheld_core::TriMesh;
use nalgebra::Point3;
use rayon::prelude::*;

use crate::bvh::MeshIndex;
use crate::error::{in_range, positive, MeshError, Result};
use crate::view::{Depth, Projector};
use handheld_core::PosedView;

/// Options of [`evaluate`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct EvalOptions {
    /// Fraction of the reconstruction the accuracy distance covers. Default 0.9 (Middlebury).
    pub accuracy_fraction: f64,
    /// Distance within which a ground-truth sample counts as reconstructed, in world units.
    /// Default 0.01 (set it to 1% of the scene size).
    pub completeness_threshold: f64,
    /// Spacing of the area-uniform samples of the reconstruction, in world units. Default 0.01.
    pub sample_spacing: f64,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            accuracy_fraction: 0.9,
            completeness_threshold: 0.01,
            sample_spacing: 0.01,
        }
    }
}

impl EvalOptions {
    pub fn validate(&self) -> Result<()> {
        in_range("accuracy_fraction", self.accuracy_fraction, 0.0, 1.0)?;
        positive("completeness_threshold", self.completeness_threshold)?;
        positive("sample_spacing", self.sample_spacing)
    }
}

/// Scores of one reconstruction.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MultiViewScores {
    /// Distance covering `accuracy_fraction` of the reconstruction (world units).
    pub accuracy: f64,
    /// Mean distance of the reconstruction samples to the ground truth.
    pub mean_distance: f64,
    /// Fraction of ground-truth samples within `completeness_threshold` of the reconstruction.
    pub completeness: f64,
    /// Reconstruction samples scored.
    pub reconstruction_samples: usize,
    /// Ground-truth samples scored.
    pub ground_truth_samples: usize,
}

/// Area-uniform, deterministic samples of a mesh's surface: `area / spacing²` points per triangle
/// (the fractional parts carried from triangle to triangle) on an R2 low-discrepancy sequence in
/// barycentric coordinates, plus every vertex.
pub fn sample_surface(mesh: &TriMesh, spacing: f64) -> Vec<Point3<f64>> {
    let pos = |i: u32| {
        let q = mesh.vertices.positions[i as usize];
        Point3::new(q[0] as f64, q[1] as f64, q[2] as f64)
    };
    let mut out: Vec<Point3<f64>> = (0..mesh.vertices.len() as u32).map(pos).collect();
    let inv = 1.0 / (spacing * spacing);
    let (g1, g2) = (0.754_877_666_246_692_7, 0.569_840_290_998_053_3); // R2 sequence constants.
    let mut carry = 0.0;
    let mut k = 0u64;
    for f in &mesh.faces {
        if f.iter().any(|&i| i as usize >= mesh.vertices.len()) {
            continue;
        }
        let (a, b, c) = (pos(f[0]), pos(f[1]), pos(f[2]));
        carry += 0.5 * (b - a).cross(&(c - a)).norm() * inv;
        while carry >= 1.0 - 1e-9 {
            carry -= 1.0;
            k += 1;
            let (mut u, mut v) = ((0.5 + g1 * k as f64).fract(), (0.5 + g2 * k as f64).fract());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            out.push(a + (b - a) * u + (c - a) * v);
        }
    }
    out
}

/// World points of every `stride`-th pixel (in x and y) with a valid depth in the given views:
/// the part of a ground-truth surface the input views saw. Only depth maps are read (views may
/// carry an empty image).
pub fn visible_surface_samples(views: &[PosedView], stride: usize) -> Result<Vec<Point3<f64>>> {
    if stride == 0 {
        return Err(MeshError::InvalidOption {
            option: "stride",
            reason: "must be positive".into(),
        });
    }
    let mut out = Vec::new();
    for (i, v) in views.iter().enumerate() {
        let v = Depth::of(v, i)?;
        let proj = Projector::new(v.posed);
        let (w, h) = (v.depth.width, v.depth.height);
        for y in (0..h).step_by(stride) {
            for x in (0..w).step_by(stride) {
                let d = v.depth.data[y * w + x];
                if d.is_finite() && d > 0.0 {
                    out.push(proj.lift(x as f64, y as f64, d as f64));
                }
            }
        }
    }
    Ok(out)
}

/// The value below which `fraction` of `values` lie (nearest rank).
pub fn percentile(values: &mut [f64], fraction: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    let rank = ((fraction * values.len() as f64).ceil() as usize).clamp(1, values.len());
    values[rank - 1]
}

/// Accuracy and completeness of `reconstruction` against the `ground_truth` mesh, with
/// completeness over `ground_truth_samples` (e.g. from [`visible_surface_samples`]).
pub fn evaluate(
    reconstruction: &TriMesh,
    ground_truth: &TriMesh,
    ground_truth_samples: &[Point3<f64>],
    opts: &EvalOptions,
) -> Result<MultiViewScores> {
    opts.validate()?;
    reconstruction.validate().map_err(MeshError::BadMesh)?;
    ground_truth.validate().map_err(MeshError::BadMesh)?;
    if reconstruction.faces.is_empty() || ground_truth.faces.is_empty() {
        return Err(MeshError::EmptyResult {
            stage: "evaluation",
            reason: "the reconstruction or the ground truth has no triangle".into(),
        });
    }
    if ground_truth_samples.is_empty() {
        return Err(MeshError::NoViews {
            what: "ground-truth samples",
        });
    }
    let gt_index = MeshIndex::new(ground_truth);
    let rec_index = MeshIndex::new(reconstruction);
    let samples = sample_surface(reconstruction, opts.sample_spacing);
    let mut dist: Vec<f64> = samples.par_iter().map(|p| gt_index.distance(p)).collect();
    let mean_distance = dist.iter().sum::<f64>() / dist.len() as f64;
    let accuracy = percentile(&mut dist, opts.accuracy_fraction);
    let t = opts.completeness_threshold;
    let covered = ground_truth_samples
        .par_iter()
        .filter(|p| rec_index.distance_within(p, t) <= t)
        .count();
    Ok(MultiViewScores {
        accuracy,
        mean_distance,
        completeness: covered as f64 / ground_truth_samples.len() as f64,
        reconstruction_samples: samples.len(),
        ground_truth_samples: ground_truth_samples.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use handheld_core::PointCloud;

    fn square(z: f32) -> TriMesh {
        TriMesh {
            vertices: PointCloud {
                positions: vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]],
                ..Default::default()
            },
            uvs: Vec::new(),
            faces: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    #[test]
    fn samples_percentiles_and_scores() {
        let s = sample_surface(&square(0.0), 0.1);
        assert_eq!(s.len(), 4 + 100);
        assert!(s
            .iter()
            .all(|p| (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y)));
        let mut v: Vec<f64> = (1..=10).map(f64::from).collect();
        assert_eq!(percentile(&mut v, 0.9), 9.0);
        assert_eq!(percentile(&mut v, 1.0), 10.0);
        let gt = square(0.0);
        let samples = sample_surface(&gt, 0.05);
        let opts = EvalOptions {
            completeness_threshold: 0.02,
            sample_spacing: 0.05,
            ..Default::default()
        };
        // A copy lifted by 1 cm: accuracy 1 cm, complete within 2 cm, not within 5 mm.
        let lifted = evaluate(&square(0.01), &gt, &samples, &opts).unwrap();
        assert!((lifted.accuracy - 0.01).abs() < 1e-6 && lifted.completeness == 1.0);
        let strict = EvalOptions {
            completeness_threshold: 0.005,
            ..opts.clone()
        };
        assert_eq!(
            evaluate(&square(0.01), &gt, &samples, &strict)
                .unwrap()
                .completeness,
            0.0
        );
        assert!(evaluate(&TriMesh::default(), &gt, &samples, &opts).is_err());
    }
}
