//! A seeded scene with exact two-view geometry as the SfM input, for the unit tests of the steps
//! that read the verified pairs (`metric/consistency.rs`, `merge/`).

use handheld_core::{ImageId, MetricReconstruction, PointId};
use handheld_geometry::skew;
use handheld_robust::TwoViewConfiguration;
use handheld_testkit::multiview::{multi_view_set, MultiViewOptions};

use crate::input::{SfmImage, SfmInput, SfmPair};

/// Eight views of a seeded scene (0.5 px noise, no outliers) as the SfM input: keypoints are
/// the observations, every pair gets its common points as inliers and the exact fundamental
/// matrix of the true cameras (`x_bᵀ F x_a = 0`, F = K⁻ᵀ [t]× R K⁻¹ with R, t from a to b).
pub(crate) fn scene() -> (SfmInput, MetricReconstruction) {
    let mv = multi_view_set(&MultiViewOptions {
        num_views: 8,
        num_points: 800,
        seed: 7,
        ..Default::default()
    })
    .expect("synthetic set");
    let rec = mv.reconstruction;
    let ids: Vec<ImageId> = rec.views.keys().copied().collect();
    let images: Vec<SfmImage> = ids
        .iter()
        .map(|id| {
            let v = &rec.views[id];
            let cam = &rec.cameras[&v.camera_id];
            SfmImage {
                id: *id,
                name: v.name.clone(),
                width: cam.width,
                height: cam.height,
                keypoints: v.observations.iter().map(|o| o.xy).collect(),
                keypoint_scales: Vec::new(),
                camera_key: "cam".into(),
                focal_prior_px: None,
                frame: None,
                track_ids: Vec::new(),
                descriptors: Vec::new(),
                descriptor_dim: 0,
            }
        })
        .collect();
    let index = |id: ImageId, p: PointId| {
        rec.views[&id]
            .observations
            .iter()
            .position(|o| o.point_id == Some(p))
    };
    let mut pairs = Vec::new();
    for a in 0..ids.len() {
        for b in a + 1..ids.len() {
            let matches: Vec<(u32, u32)> = rec
                .points
                .keys()
                .filter_map(|&p| Some((index(ids[a], p)? as u32, index(ids[b], p)? as u32)))
                .collect();
            let (va, vb) = (&rec.views[&ids[a]], &rec.views[&ids[b]]);
            let rel = vb.cam_from_world * va.cam_from_world.inverse();
            let k = rec.cameras[&va.camera_id].intrinsics.k_matrix();
            let ki = k.try_inverse().expect("K");
            let e = skew(&rel.translation.vector) * rel.rotation.to_rotation_matrix().matrix();
            pairs.push(SfmPair {
                a,
                b,
                matches,
                f: Some(ki.transpose() * e * ki),
                configuration: TwoViewConfiguration::General,
                view_distance_px: None,
            });
        }
    }
    let input = SfmInput {
        images,
        pairs,
        video: false,
    };
    (input, rec)
}
