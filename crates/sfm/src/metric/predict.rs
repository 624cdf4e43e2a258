//! Matching by predicted projection (§3.2: "the projections of the existing 3D points are predicted
//! in the new view, and the matches are searched for close to these predictions").
//!
//! Pairwise matching misses many correspondences: the ratio test rejects repeated texture, and a pair
//! that was never verified contributes nothing. Once the metric cameras are known, every point is
//! projected into each registered view that does not observe it; an unassigned keypoint within
//! [`SEARCH_RADIUS_PX`] of the prediction joins the point's track when its descriptor is close to one
//! of the point's observations (cosine similarity ≥ [`MIN_SIMILARITY`]) and clearly closer than any
//! other candidate there. A keypoint goes to the best of the points that claim it. The caller then
//! adjusts and filters the model, which removes the few wrong additions.

use std::collections::HashMap;

use handheld_core::{ImageId, MetricReconstruction, PointId, TrackElement};
use nalgebra::Vector2;
use rayon::prelude::*;

use crate::context::Context;
use crate::input::SfmImage;

/// Search radius around a predicted projection, pixels.
const SEARCH_RADIUS_PX: f64 = 3.0;
/// Smallest cosine similarity of the descriptors (RootSIFT, quantised to bytes).
const MIN_SIMILARITY: f32 = 0.85;
/// The best candidate must beat the second by this much similarity.
const MIN_MARGIN: f32 = 0.05;
/// Grid cell of the keypoint index, pixels.
const CELL: f64 = 8.0;

/// A proposed observation: keypoint `kp` of the view sees `point`, with this similarity.
struct Proposal {
    kp: u32,
    point: PointId,
    similarity: f32,
}

/// Descriptor row `k` of an image.
fn descriptor(im: &SfmImage, k: usize) -> Option<&[u8]> {
    let d = im.descriptor_dim;
    (d > 0)
        .then(|| im.descriptors.get(k * d..(k + 1) * d))
        .flatten()
}

fn cosine(a: &[u8], b: &[u8]) -> f32 {
    let (mut ab, mut aa, mut bb) = (0u32, 0u32, 0u32);
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (x as u32, y as u32);
        ab += x * y;
        aa += x * x;
        bb += y * y;
    }
    if aa == 0 || bb == 0 {
        return 0.0;
    }
    ab as f32 / ((aa as f32).sqrt() * (bb as f32).sqrt())
}

/// Extends the tracks of `rec` by predicted projection; returns the number of observations added.
/// Does nothing when the images carry no descriptors.
pub(crate) fn extend_tracks(ctx: &Context, rec: &mut MetricReconstruction) -> usize {
    let images = &ctx.input.images;
    if images.iter().all(|im| im.descriptor_dim == 0) {
        return 0;
    }
    let index: HashMap<ImageId, usize> = images
        .iter()
        .enumerate()
        .map(|(i, im)| (im.id, i))
        .collect();
    let views: Vec<ImageId> = rec.views.keys().copied().collect();
    // Each point's descriptors, from its observations (shared by every view's search).
    let descs: HashMap<PointId, Vec<&[u8]>> = rec
        .points
        .iter()
        .map(|(pid, pt)| {
            let d = pt
                .track
                .elements
                .iter()
                .filter_map(|e| {
                    descriptor(&images[*index.get(&e.image_id)?], e.point2d_idx as usize)
                })
                .collect();
            (*pid, d)
        })
        .collect();
    let rec_ref = &*rec;
    let proposals: Vec<(ImageId, Vec<Proposal>)> = views
        .par_iter()
        .filter_map(|vid| {
            let im = &images[*index.get(vid)?];
            if im.descriptor_dim == 0 {
                return None;
            }
            Some((*vid, propose(rec_ref, &descs, im)))
        })
        .collect();
    let mut added = 0;
    for (vid, mut props) in proposals {
        props.sort_by(|a, b| b.similarity.total_cmp(&a.similarity));
        for p in props {
            let Some(v) = rec.views.get_mut(&vid) else {
                break;
            };
            let Some(obs) = v.observations.get_mut(p.kp as usize) else {
                continue;
            };
            if obs.point_id.is_some() {
                continue;
            }
            let Some(pt) = rec.points.get_mut(&p.point) else {
                continue;
            };
            if pt.track.elements.iter().any(|e| e.image_id == vid) {
                continue;
            }
            obs.point_id = Some(p.point);
            pt.track.elements.push(TrackElement {
                image_id: vid,
                point2d_idx: p.kp,
            });
            added += 1;
        }
    }
    added
}

/// Proposals for one view `im`.
fn propose(
    rec: &MetricReconstruction,
    point_descriptors: &HashMap<PointId, Vec<&[u8]>>,
    im: &SfmImage,
) -> Vec<Proposal> {
    let Some(view) = rec.views.get(&im.id) else {
        return Vec::new();
    };
    let Some(cam) = rec.cameras.get(&view.camera_id) else {
        return Vec::new();
    };
    // Grid of the view's unassigned keypoints.
    let (gw, gh) = (
        (im.width as f64 / CELL).ceil() as usize + 1,
        (im.height as f64 / CELL).ceil() as usize + 1,
    );
    let mut grid: Vec<Vec<u32>> = vec![Vec::new(); gw * gh];
    let cell_of = |p: &Vector2<f64>| -> Option<(usize, usize)> {
        let (cx, cy) = ((p.x / CELL).floor(), (p.y / CELL).floor());
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < gw && (cy as usize) < gh)
            .then_some((cx as usize, cy as usize))
    };
    for (k, o) in view.observations.iter().enumerate() {
        if o.point_id.is_none() {
            if let Some((cx, cy)) = cell_of(&o.xy) {
                grid[cy * gw + cx].push(k as u32);
            }
        }
    }
    let mut out = Vec::new();
    let reach = (SEARCH_RADIUS_PX / CELL).ceil() as isize;
    for (pid, pt) in &rec.points {
        if pt.track.elements.iter().any(|e| e.image_id == im.id) {
            continue;
        }
        let Some(x) = cam.project(&view.cam_from_world, &pt.xyz) else {
            continue;
        };
        let Some((cx, cy)) = cell_of(&x) else {
            continue;
        };
        let Some(descs) = point_descriptors.get(pid).filter(|d| !d.is_empty()) else {
            continue;
        };
        let (mut best, mut second) = ((0.0f32, u32::MAX), 0.0f32);
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let (gx, gy) = (cx as isize + dx, cy as isize + dy);
                if gx < 0 || gy < 0 || gx as usize >= gw || gy as usize >= gh {
                    continue;
                }
                for &k in &grid[gy as usize * gw + gx as usize] {
                    if (view.observations[k as usize].xy - x).norm() > SEARCH_RADIUS_PX {
                        continue;
                    }
                    let Some(dk) = descriptor(im, k as usize) else {
                        continue;
                    };
                    let s = descs.iter().map(|d| cosine(d, dk)).fold(0.0f32, f32::max);
                    if s > best.0 {
                        second = best.0;
                        best = (s, k);
                    } else if s > second {
                        second = s;
                    }
                }
            }
        }
        if best.1 != u32::MAX && best.0 >= MIN_SIMILARITY && best.0 - second >= MIN_MARGIN {
            out.push(Proposal {
                kp: best.1,
                point: *pid,
                similarity: best.0,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::CorrespondenceGraph;
    use crate::input::SfmInput;
    use crate::options::SfmOptions;
    use handheld_core::{Camera, CameraId, Intrinsics, Observation, Point3D, Rigid3, Track, View};
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    fn desc(seed: u8) -> Vec<u8> {
        (0..16u8)
            .map(|k| k.wrapping_mul(seed).wrapping_add(seed) % 97)
            .collect()
    }

    /// Two cameras see three points; view 2 misses one observation that its keypoints hold (at the
    /// exact projection, same descriptor) next to a keypoint with a different descriptor; the
    /// prediction adds exactly the right one, and nothing for a point whose projection has no
    /// similar keypoint.
    #[test]
    fn predicted_projection_adds_the_true_observation_only() {
        let k = Intrinsics {
            f: 500.0,
            aspect: 1.0,
            skew: 0.0,
            pp: Vector2::new(320.0, 240.0),
            k1: 0.0,
            k2: 0.0,
        };
        let cam = Camera {
            id: CameraId(1),
            width: 640,
            height: 480,
            intrinsics: k,
        };
        let poses = [
            Rigid3::identity(),
            Rigid3::from_parts(
                Translation3::new(-0.5, 0.0, 0.0),
                UnitQuaternion::identity(),
            ),
        ];
        let pts = [
            Point3::new(0.0, 0.0, 5.0),
            Point3::new(0.5, 0.3, 6.0),
            Point3::new(-0.4, -0.2, 4.0),
        ];
        let proj = |v: usize, p: usize| cam.project(&poses[v], &pts[p]).unwrap();
        // View 1 observes all three; view 2 observes point 0 only and has keypoints at the
        // projections of points 1 (same descriptor) and 2 (a different descriptor), plus a
        // distractor 2 px from point 1's projection with an unrelated descriptor.
        let kp1: Vec<Vector2<f64>> = (0..3).map(|p| proj(0, p)).collect();
        let kp2 = vec![
            proj(1, 0),
            proj(1, 1),
            proj(1, 2),
            proj(1, 1) + Vector2::new(2.0, 0.0),
        ];
        let d1: Vec<u8> = [desc(3), desc(5), desc(7)].concat();
        let d2: Vec<u8> = [desc(3), desc(5), desc(11), desc(13)].concat();
        let image = |id: u32, kps: Vec<Vector2<f64>>, d: Vec<u8>| SfmImage {
            id: ImageId(id),
            name: format!("{id}.png"),
            width: 640,
            height: 480,
            keypoints: kps,
            keypoint_scales: Vec::new(),
            camera_key: "c".into(),
            focal_prior_px: None,
            frame: None,
            track_ids: Vec::new(),
            descriptors: d,
            descriptor_dim: 16,
        };
        let input = SfmInput {
            images: vec![image(1, kp1.clone(), d1), image(2, kp2.clone(), d2)],
            pairs: Vec::new(),
            video: false,
        };
        let graph = CorrespondenceGraph::build(&input, 8);
        let opts = SfmOptions::default();
        let ctx = Context::new(&input, &graph, &opts);
        let mut rec = MetricReconstruction::default();
        rec.cameras.insert(cam.id, cam.clone());
        for (v, kps) in [kp1, kp2].into_iter().enumerate() {
            let id = ImageId(v as u32 + 1);
            let mut observations: Vec<Observation> = kps
                .into_iter()
                .map(|xy| Observation { xy, point_id: None })
                .collect();
            let seen = if v == 0 { 3 } else { 1 };
            for (p, o) in observations.iter_mut().enumerate().take(seen) {
                o.point_id = Some(PointId(p as u64));
            }
            rec.views.insert(
                id,
                View {
                    id,
                    name: format!("{}.png", v + 1),
                    camera_id: cam.id,
                    cam_from_world: poses[v],
                    observations,
                    frame: None,
                },
            );
        }
        for (p, xyz) in pts.iter().enumerate() {
            let mut elements = vec![TrackElement {
                image_id: ImageId(1),
                point2d_idx: p as u32,
            }];
            if p == 0 {
                elements.push(TrackElement {
                    image_id: ImageId(2),
                    point2d_idx: 0,
                });
            }
            rec.points.insert(
                PointId(p as u64),
                Point3D {
                    xyz: *xyz,
                    color: [0; 3],
                    error: 0.0,
                    track: Track { elements },
                },
            );
        }
        assert_eq!(extend_tracks(&ctx, &mut rec), 1);
        let v2 = &rec.views[&ImageId(2)];
        assert_eq!(v2.observations[1].point_id, Some(PointId(1)));
        assert_eq!(v2.observations[2].point_id, None);
        assert_eq!(v2.observations[3].point_id, None);
        assert_eq!(rec.points[&PointId(1)].track.len(), 2);
    }
}
