//! Points whose depth the views do not determine, taken out of the finished model.
//!
//! A point's depth comes from the parallax between its rays: the widest angle θ between two of
//! them, measured with the angular noise `σ_θ = σ̂ √(σ_a²/f_a² + σ_b²/f_b²)` of that pair (σ̂ the
//! model's observation noise, [`noise_sigma`]; σ_a, σ_b the keypoints' relative localisation
//! σ). Depth goes as 1/θ (H&Z §12.6, the uncertainty of two-view triangulation), so where
//! θ < 3 σ_θ a parallax of zero, a point at infinity, is within three standard deviations: the
//! point has a direction but no depth. Such points come from views taken from (almost) one spot,
//! a near-duplicate shot or a camera that only turned between frames; an adjustment keeps them
//! where they started and a viewer or a depth range would take that place for a measurement.
//! A point seen only from a shot and its repeats (`crate::duplicates`) is taken out whatever its
//! parallax in the model: there the two centres' distance is fitted noise (templeSparseRing's
//! views 1 and 11, one ground-truth pose, left 832 such points at 0.02° of parallax, 7 % of them
//! beyond the object's extent).
//!
//! They are taken out after the last adjustment, where their observations have done their one
//! job (they tie the rotations of the views that share them): the cameras are as the adjustment
//! left them. COLMAP filters points by a fixed triangulation angle (1.5° by default); the bound
//! here follows the measured noise and focal length, so a far point with a small but measured
//! parallax (a street's far façade seen from a moving car) stays.

use handheld_bundle::observation_sigma;
use std::collections::BTreeMap;

use handheld_core::{ImageId, MetricReconstruction, PointId};

use crate::context::Context;
use crate::metric::ba::remove_points;
use crate::metric::noise::noise_sigma;

/// Standard deviations of parallax a point needs for its depth to count as measured.
pub(crate) const MIN_PARALLAX_SIGMAS: f64 = 3.0;

/// Observation noise assumed when the model has no redundant observations to measure it on.
const FALLBACK_NOISE_PX: f64 = 1.0;

/// The shot each view repeats (`ctx.duplicates`, identical copies and near-duplicates alike;
/// itself when none), by image id.
fn shots(ctx: &Context) -> BTreeMap<ImageId, ImageId> {
    let images = &ctx.input.images;
    let mut of: Vec<usize> = (0..images.len()).collect();
    for d in &ctx.duplicates {
        of[d.image] = d.of;
    }
    (0..images.len())
        .map(|i| {
            // Follow a chain of repeats (a burst) to its first shot.
            let mut r = i;
            for _ in 0..images.len() {
                if of[r] == r {
                    break;
                }
                r = of[r];
            }
            (images[i].id, images[r].id)
        })
        .collect()
}

/// The points of `rec` whose widest pair of rays is within [`MIN_PARALLAX_SIGMAS`] of parallel,
/// and those seen only from one shot and its repeats (whose baseline in the model is fitted
/// noise: the photos were taken from one spot, `crate::duplicates`).
pub(crate) fn depthless_points(ctx: &Context, rec: &MetricReconstruction) -> Vec<PointId> {
    let noise = noise_sigma(ctx, rec).map_or(FALLBACK_NOISE_PX, |n| n.observation);
    let shot = shots(ctx);
    let mut out = Vec::new();
    let mut rays: Vec<(nalgebra::Vector3<f64>, f64)> = Vec::new();
    for (id, p) in &rec.points {
        let first = p.track.elements.first().map(|e| shot.get(&e.image_id));
        if first.is_some()
            && p.track
                .elements
                .iter()
                .all(|e| Some(shot.get(&e.image_id)) == first)
        {
            out.push(*id);
            continue;
        }
        rays.clear();
        for el in &p.track.elements {
            let Some(view) = rec.views.get(&el.image_id) else {
                continue;
            };
            let Some(f) = rec.cameras.get(&view.camera_id).map(|c| c.intrinsics.f) else {
                continue;
            };
            let d = p.xyz - view.center();
            let norm = d.norm();
            if !norm.is_finite() || norm <= 0.0 || !f.is_finite() || f <= 0.0 {
                continue;
            }
            // The ray's angular σ (radians).
            let s = noise * observation_sigma(&ctx.keypoint_sigma, el.image_id, el.point2d_idx) / f;
            rays.push((d / norm, s));
        }
        let determined = rays.iter().enumerate().any(|(i, (a, sa))| {
            rays[i + 1..].iter().any(|(b, sb)| {
                let theta = a.cross(b).norm().atan2(a.dot(b));
                theta >= MIN_PARALLAX_SIGMAS * (sa * sa + sb * sb).sqrt()
            })
        });
        if !determined {
            out.push(*id);
        }
    }
    out
}

/// Takes the [`depthless_points`] out of `rec`; returns how many.
pub(crate) fn take_out_depthless(ctx: &Context, rec: &mut MetricReconstruction) -> usize {
    let ids = depthless_points(ctx, rec);
    let n = ids.len();
    if n > 0 {
        tracing::info!(
            "{n} of {} points have no measured depth (their rays are parallel within {MIN_PARALLAX_SIGMAS} σ, or only one spot saw them): taken out of the model",
            rec.points.len()
        );
    }
    remove_points(rec, ids);
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::CorrespondenceGraph;
    use crate::test_scene::scene;
    use crate::SfmOptions;

    #[test]
    fn a_point_at_infinity_is_taken_out_and_the_measured_ones_stay() {
        let (input, mut rec) = scene();
        let graph = CorrespondenceGraph::build(&input, 8);
        let opts = SfmOptions::default();
        let ctx = Context::new(&input, &graph, &opts);
        assert!(
            depthless_points(&ctx, &rec).is_empty(),
            "every true point has parallax"
        );
        // Three points pushed a million scene sizes out along their first view's ray: what an
        // adjustment leaves of a point whose rays coincide.
        let far: Vec<PointId> = rec.points.keys().copied().step_by(97).take(3).collect();
        for id in &far {
            let p = &rec.points[id];
            let c = rec.views[&p.track.elements[0].image_id].center();
            let xyz = c + (p.xyz - c) * 1e6;
            rec.points.get_mut(id).expect("point").xyz = xyz;
        }
        let mut out = depthless_points(&ctx, &rec);
        out.sort();
        assert_eq!(out, far);
        let before = rec.points.len();
        assert_eq!(take_out_depthless(&ctx, &mut rec), 3);
        assert_eq!(rec.points.len(), before - 3);
        assert!(rec
            .views
            .values()
            .flat_map(|v| &v.observations)
            .all(|o| o.point_id.is_none_or(|p| !far.contains(&p))));
    }
}
