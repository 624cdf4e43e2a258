//! Ground-truth helpers shared by the feature tests: exact back-projection and visibility-checked
//! projection on testkit sequences.

#![allow(dead_code)]

use handheld_testkit::{
    pixel_ray, render_sequence, PathOptions, SequenceOptions, SyntheticSequence,
};
use nalgebra::{Point3, Vector2};

/// World point seen at pixel `(x, y)` of `frame` (exact ray cast), unless the pixel is within 3 px of a
/// depth discontinuity.
pub fn back_project(seq: &SyntheticSequence, frame: usize, x: f64, y: f64) -> Option<Point3<f64>> {
    let depth = &seq.depths[frame];
    let (cx, cy) = (x.round() as isize, y.round() as isize);
    let (mut lo, mut hi) = (f32::INFINITY, 0f32);
    for yy in cy - 3..=cy + 3 {
        for xx in cx - 3..=cx + 3 {
            if xx < 0 || yy < 0 || xx >= depth.width as isize || yy >= depth.height as isize {
                return None;
            }
            let d = depth.get(xx as usize, yy as usize, 0);
            (lo, hi) = (lo.min(d), hi.max(d));
        }
    }
    if !(lo > 0.0 && hi < 1.05 * lo) {
        return None;
    }
    let view = seq.frame(frame)?;
    let (o, dir) = pixel_ray(&view, Vector2::new(x, y));
    Some(o + dir * seq.scene.intersect(&o, &dir)?.t)
}

/// Projection of `p` into `frame` when it is visible there (not occluded).
pub fn project_visible(
    seq: &SyntheticSequence,
    frame: usize,
    p: &Point3<f64>,
) -> Option<Vector2<f64>> {
    let view = seq.frame(frame)?;
    let px = view.project(p)?;
    let (o, dir) = pixel_ray(&view, px);
    let hit = seq.scene.intersect(&o, &dir)?;
    ((o + dir * hit.t - p).norm() < 1e-3 * (p - o).norm()).then_some(px)
}

/// Two 640×480 frames of the default scene (seed 5) on an orbit that sweeps `sweep` degrees.
pub fn orbit_pair(sweep: f64) -> SyntheticSequence {
    let opts = SequenceOptions {
        seed: 5,
        width: 640,
        height: 480,
        num_frames: 2,
        samples_per_axis: 2,
        path: PathOptions {
            sweep,
            ..PathOptions::orbit(2)
        },
        ..SequenceOptions::default()
    };
    render_sequence(&opts).expect("valid options")
}
