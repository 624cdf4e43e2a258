//! Sequential plane segmentation of the points a registered view observes (see `register_pair.rs`),
//! with the workspace's one RANSAC loop ([`handheld_robust::run`]): [`PlaneEstimator`] is the
//! model-specific part (three-point plane, Fischler & Bolles 1981; total-least-squares refit) and
//! [`ReplacementSampler`] draws its minimal samples.
//!
//! The estimator lives here rather than in `handheld-robust` because its inlier test is this
//! module's: a point is on a plane within a fraction of its depth *and* of the points' extent.

use handheld_robust::{run, Estimator, InlierCount, RansacOptions, Sampler};
use nalgebra::{Matrix3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Plane inliers lie within this fraction of their depth,
const PLANE_TOLERANCE: f64 = 0.01;
/// and within this fraction of the points' extent (median distance from their centroid): far
/// from a long lens, a whole curved object is thinner than 1 % of its depth and would pass as a
/// plane (dinoSparseRing).
const EXTENT_TOLERANCE: f64 = 0.02;
/// Planes found per partner, and the fewest points a plane must hold.
const MAX_PLANES: usize = 6;
const MIN_PLANE_POINTS: usize = 30;
/// RANSAC trials per plane, all of them drawn (no adaptive stopping).
const PLANE_TRIALS: usize = 2000;

/// A plane `nᵀX = d` with unit normal `n`.
pub(crate) type Plane = (Vector3<f64>, f64);

/// Planes `nᵀX = d` (unit `n`) through 3D points in a camera frame (`z` is the depth).
///
/// - `fit`: the plane through three points, `n ∝ (b − a) × (c − a)`, `d = nᵀa`; nothing for
///   (nearly) collinear points.
/// - `residual`: the distance `|nᵀX − d|` as a fraction of the point's tolerance
///   `min(PLANE_TOLERANCE · z, EXTENT_TOLERANCE · extent)`, `∞` beyond it, so that the RANSAC
///   threshold is 1 and `residual ≤ 1` exactly when the distance is within the tolerance.
/// - `refit`: total least squares, the normal being the eigenvector of the smallest eigenvalue of
///   the points' scatter matrix, oriented like the current model's.
pub(crate) struct PlaneEstimator {
    /// Median distance of all the points from their centroid.
    pub extent: f64,
}

impl PlaneEstimator {
    /// The inlier test of the segmentation.
    fn is_near(&self, (n, d): &Plane, p: &Vector3<f64>) -> bool {
        (n.dot(p) - d).abs() <= self.tolerance(p)
    }

    fn tolerance(&self, p: &Vector3<f64>) -> f64 {
        (PLANE_TOLERANCE * p.z).min(EXTENT_TOLERANCE * self.extent)
    }
}

impl Estimator for PlaneEstimator {
    type Model = Plane;
    type Sample = Vector3<f64>;
    const SAMPLE_SIZE: usize = 3;

    fn fit(&self, s: &[Vector3<f64>], out: &mut Vec<Plane>) {
        let (a, b, c) = (s[0], s[1], s[2]);
        let n = (b - a).cross(&(c - a));
        let len = n.norm();
        if len < 1e-12 {
            return;
        }
        let n = n / len;
        out.push((n, n.dot(&a)));
    }

    fn residual(&self, plane: &Plane, p: &Vector3<f64>) -> f64 {
        if self.is_near(plane, p) {
            // ≤ 1 whenever the distance is within the tolerance (0/0 and ∞/∞ count as 1).
            ((plane.0.dot(p) - plane.1).abs() / self.tolerance(p)).min(1.0)
        } else {
            f64::INFINITY
        }
    }

    fn refit(&self, s: &[Vector3<f64>], (n, _): &Plane) -> Option<Plane> {
        if s.len() < 3 {
            return None;
        }
        let centroid = s.iter().fold(Vector3::zeros(), |acc, p| acc + p) / s.len() as f64;
        let cov = s.iter().fold(Matrix3::zeros(), |acc, p| {
            let q = p - centroid;
            acc + q * q.transpose()
        });
        let eig = cov.symmetric_eigen();
        let mut n2: Vector3<f64> = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        if n2.dot(n) < 0.0 {
            n2 = -n2;
        }
        Some((n2, n2.dot(&centroid)))
    }
}

/// Uniform sampling *with* replacement: `k` independent draws `random_range(0..n)`. A draw that
/// repeats an index gives collinear points, which [`PlaneEstimator::fit`] rejects. This is how the
/// segmentation always drew its triples, kept so that its planes stay the same for a seed.
pub(crate) struct ReplacementSampler {
    rng: ChaCha8Rng,
}

impl ReplacementSampler {
    pub fn new(seed: u64) -> Self {
        Self {
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }
}

impl Sampler for ReplacementSampler {
    fn sample(&mut self, n: usize, k: usize, out: &mut Vec<usize>) {
        out.clear();
        out.extend((0..k).map(|_| self.rng.random_range(0..n)));
    }

    fn rng(&mut self) -> &mut ChaCha8Rng {
        &mut self.rng
    }
}

/// RANSAC options of one plane: every one of [`PLANE_TRIALS`] trials drawn, plain inlier count,
/// no local optimisation or T(d,d) (the refit comes once, after the loop).
fn plane_ransac(seed: u64) -> RansacOptions {
    RansacOptions {
        max_error: 1.0,
        min_iterations: PLANE_TRIALS,
        max_iterations: PLANE_TRIALS,
        min_inlier_ratio: 0.0,
        local_optimization: false,
        tdd: None,
        seed,
        ..Default::default()
    }
}

/// Sequential RANSAC: the plane with the most points within the tolerance of [`PlaneEstimator`],
/// refitted to them by least squares, then the same among the rest, up to [`MAX_PLANES`] planes of
/// at least [`MIN_PLANE_POINTS`]. One generator, seeded by `seed`, draws for all planes. Returns
/// each point's plane.
pub(crate) fn segment_planes(pts: &[Vector3<f64>], seed: u64) -> (Vec<Option<usize>>, Vec<Plane>) {
    let mut label = vec![None; pts.len()];
    let mut planes = Vec::new();
    let centroid = pts.iter().fold(Vector3::zeros(), |s, p| s + p) / pts.len().max(1) as f64;
    let mut spread: Vec<f64> = pts.iter().map(|p| (p - centroid).norm()).collect();
    let mid = spread.len() / 2;
    let extent = if spread.is_empty() {
        0.0
    } else {
        *spread.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let estimator = PlaneEstimator { extent };
    let mut sampler = ReplacementSampler::new(seed);
    let opts = plane_ransac(seed);
    for _ in 0..MAX_PLANES {
        let rest: Vec<usize> = (0..pts.len()).filter(|&i| label[i].is_none()).collect();
        if rest.len() < MIN_PLANE_POINTS {
            break;
        }
        let points: Vec<Vector3<f64>> = rest.iter().map(|&i| pts[i]).collect();
        let Ok(report) = run(&estimator, &InlierCount, &mut sampler, &points, &opts) else {
            break;
        };
        let Some(plane) = report.model else { break };
        if report.support < MIN_PLANE_POINTS {
            break;
        }
        let inliers: Vec<usize> = rest
            .iter()
            .zip(&report.inlier_mask)
            .filter_map(|(&i, &inlier)| inlier.then_some(i))
            .collect();
        let inlier_points: Vec<Vector3<f64>> = inliers.iter().map(|&i| pts[i]).collect();
        let Some(refined) = estimator.refit(&inlier_points, &plane) else {
            break;
        };
        for &i in &inliers {
            label[i] = Some(planes.len());
        }
        planes.push(refined);
    }
    (label, planes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The segmentation as it was written before it moved onto [`handheld_robust::run`]: its own
    /// loop over `PLANE_TRIALS` triples drawn with replacement. Kept to check that the move left
    /// every plane and label bit-identical.
    fn segment_planes_reference(
        pts: &[Vector3<f64>],
        seed: u64,
    ) -> (Vec<Option<usize>>, Vec<Plane>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut label = vec![None; pts.len()];
        let mut planes = Vec::new();
        let centroid = pts.iter().fold(Vector3::zeros(), |s, p| s + p) / pts.len().max(1) as f64;
        let mut spread: Vec<f64> = pts.iter().map(|p| (p - centroid).norm()).collect();
        let mid = spread.len() / 2;
        let extent = if spread.is_empty() {
            0.0
        } else {
            *spread.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        let near = |n: &Vector3<f64>, d: f64, p: &Vector3<f64>| {
            (n.dot(p) - d).abs() <= (PLANE_TOLERANCE * p.z).min(EXTENT_TOLERANCE * extent)
        };
        for _ in 0..MAX_PLANES {
            let rest: Vec<usize> = (0..pts.len()).filter(|&i| label[i].is_none()).collect();
            if rest.len() < MIN_PLANE_POINTS {
                break;
            }
            let mut best: Option<(usize, Vector3<f64>, f64)> = None;
            for _ in 0..PLANE_TRIALS {
                let (a, b, c) = (
                    pts[rest[rng.random_range(0..rest.len())]],
                    pts[rest[rng.random_range(0..rest.len())]],
                    pts[rest[rng.random_range(0..rest.len())]],
                );
                let n = (b - a).cross(&(c - a));
                let len = n.norm();
                if len < 1e-12 {
                    continue;
                }
                let n = n / len;
                let d = n.dot(&a);
                let count = rest.iter().filter(|&&i| near(&n, d, &pts[i])).count();
                if best.as_ref().is_none_or(|b| count > b.0) {
                    best = Some((count, n, d));
                }
            }
            let Some((count, n, d)) = best else { break };
            if count < MIN_PLANE_POINTS {
                break;
            }
            let inl: Vec<usize> = rest
                .iter()
                .copied()
                .filter(|&i| near(&n, d, &pts[i]))
                .collect();
            let centroid = inl.iter().fold(Vector3::zeros(), |s, &i| s + pts[i]) / inl.len() as f64;
            let cov = inl.iter().fold(Matrix3::zeros(), |s, &i| {
                let q = pts[i] - centroid;
                s + q * q.transpose()
            });
            let eig = cov.symmetric_eigen();
            let mut n2: Vector3<f64> = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
            if n2.dot(&n) < 0.0 {
                n2 = -n2;
            }
            let d2 = n2.dot(&centroid);
            for &i in &inl {
                label[i] = Some(planes.len());
            }
            planes.push((n2, d2));
        }
        (label, planes)
    }

    /// A room seen from inside: three walls with noise, clutter, a ball, and a few duplicate
    /// points (which make some triples degenerate).
    fn room(seed: u64) -> Vec<Vector3<f64>> {
        let mut r = ChaCha8Rng::seed_from_u64(seed);
        let mut pts = Vec::new();
        for _ in 0..300 {
            let (u, v) = (r.random_range(-1.5..1.5), r.random_range(-1.0..1.0));
            let noise = r.random_range(-0.01..0.01);
            match r.random_range(0..5) {
                0 | 1 => pts.push(Vector3::new(u, v, 5.0 - 0.1 * u + noise)),
                2 => pts.push(Vector3::new(-2.0 + noise, v, 3.5 + u)),
                3 => pts.push(Vector3::new(u, 1.2 + noise, 3.5 + v)),
                _ => pts.push(Vector3::new(u, v, r.random_range(2.0..6.0))),
            }
        }
        for k in 0..20 {
            pts.push(pts[k * 7]);
        }
        pts
    }

    #[test]
    fn the_shared_loop_reproduces_the_former_segmentation_bit_for_bit() {
        for seed in 0..8 {
            let pts = room(seed);
            let (label, planes) = segment_planes(&pts, seed ^ 0x51);
            let (label_ref, planes_ref) = segment_planes_reference(&pts, seed ^ 0x51);
            assert!(planes.len() >= 2, "seed {seed}: {} planes", planes.len());
            assert_eq!(label, label_ref, "seed {seed}");
            assert_eq!(planes.len(), planes_ref.len(), "seed {seed}");
            for (a, b) in planes.iter().zip(&planes_ref) {
                assert_eq!(a.1.to_bits(), b.1.to_bits(), "seed {seed}");
                for k in 0..3 {
                    assert_eq!(a.0[k].to_bits(), b.0[k].to_bits(), "seed {seed}");
                }
            }
        }
        // Fewer points than a plane needs, and none at all.
        let few = room(1)[..20].to_vec();
        assert_eq!(segment_planes(&few, 3), segment_planes_reference(&few, 3));
        assert_eq!(segment_planes(&[], 3), segment_planes_reference(&[], 3));
    }

    #[test]
    fn a_small_curved_object_far_away_is_not_a_plane() {
        // A ball of radius 0.05 at depth 1 (a long lens around a small object): thinner than 1 %
        // of its depth near its silhouette, but curved at the scale of its extent.
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..10 {
                let (a, b) = (i as f64 * 0.314, 0.2 + j as f64 * 0.12);
                let dir = Vector3::new(b.sin() * a.cos(), b.sin() * a.sin(), -b.cos());
                pts.push(Vector3::new(0.0, 0.0, 1.0) + 0.05 * dir);
            }
        }
        let (label, planes) = segment_planes(&pts, 5);
        assert_eq!(
            (label.clone(), planes.clone()),
            segment_planes_reference(&pts, 5)
        );
        let labelled = label.iter().filter(|l| l.is_some()).count();
        assert!(
            labelled < pts.len() / 2,
            "{} planes label {labelled} points",
            planes.len()
        );
    }
}
