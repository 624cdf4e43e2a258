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

use crate::input::SfmImage;
use crate::projective::Context;

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
    let rec_ref = &*rec;
    let proposals: Vec<(ImageId, Vec<Proposal>)> = views
        .par_iter()
        .filter_map(|vid| {
            let im = &images[*index.get(vid)?];
            if im.descriptor_dim == 0 {
                return None;
            }
            Some((*vid, propose(rec_ref, images, &index, im)))
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
    images: &[SfmImage],
    index: &HashMap<ImageId, usize>,
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
        // The point's descriptors, from its observations.
        let descs: Vec<&[u8]> = pt
            .track
            .elements
            .iter()
            .filter_map(|e| descriptor(&images[*index.get(&e.image_id)?], e.point2d_idx as usize))
            .collect();
        if descs.is_empty() {
            continue;
        }
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
