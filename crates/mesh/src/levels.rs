//! Voxel sizes that follow the depth (issue #35): the fusion's resolution levels.
//!
//! A depth map's sample at camera depth `z` covers a pixel footprint of `z/f` in the world. One voxel
//! size for a street whose depths run from 2 m to 100 m is either too coarse near or far too many
//! voxels far away. The volume therefore holds blocks at several *levels*: level `l` has voxels of
//! `2^l` times the base size (the base is [`crate::tsdf::VoxelSize::PixelFootprint`] at the median
//! footprint). Which level holds a point of space is a function of space and the cameras only, so
//! the blocks allocated do not depend on the order of the views:
//!
//! `l(p) = round(log2(φ(p) / φ_ref))`, clamped to `[finest, coarsest]`,
//!
//! where `φ(p) = min_i z_i(p)/f_i` over the views `i` whose frustum holds `p` (the finest footprint any
//! view has there) and `φ_ref` the median footprint. Each level then spans a factor of two in
//! footprint, so a voxel covers between 0.7 and 1.4 times the base's number of pixels wherever it is.
//! This is the scale-space idea of Fuhrmann and Goesele, *Fusion of depth maps with multiple scales*
//! (SIGGRAPH Asia 2011), on the octave grid of the multi-resolution volumes of Steinbrücker, Sturm
//! and Cremers, *Volumetric 3D mapping in real-time on a CPU* (ICRA 2014): a sample is stored at the
//! octave of its footprint, so memory follows the pixels the images hold, not the scene's extent.
//!
//! Each level is meshed on its own, and a marching cube is kept only where its own level owns space
//! ([`LevelField::level`] at the cube's centre), so the levels do not overlap. Where two levels meet,
//! the surfaces leave a crack of at most one coarse voxel (no transition cells).

use nalgebra::{Matrix3, Point3, Vector3};

use crate::view::Projector;

/// One view's frustum test and focal length.
#[derive(Clone, Debug)]
struct Frustum {
    rot: Matrix3<f64>,
    trans: Vector3<f64>,
    /// Normalised image bounds `[x_min, x_max, y_min, y_max]`.
    bounds: [f64; 4],
    inv_f: f64,
}

/// The level of every point of space (see the module documentation).
#[derive(Clone, Debug)]
pub struct LevelField {
    views: Vec<Frustum>,
    inv_ref: f64,
    pub finest: i32,
    pub coarsest: i32,
}

impl LevelField {
    /// The field of these views, with `reference` the footprint (world units per pixel) of level 0.
    pub(crate) fn new(
        projectors: &[Projector],
        reference: f64,
        finest: i32,
        coarsest: i32,
    ) -> Self {
        let views = projectors
            .iter()
            .map(|p| Frustum {
                rot: p.rot,
                trans: p.trans,
                bounds: p.bounds,
                inv_f: 1.0 / p.posed.camera.intrinsics.f,
            })
            .collect();
        Self {
            views,
            inv_ref: 1.0 / reference,
            finest,
            coarsest,
        }
    }

    /// The finest footprint `φ(p)` any view has at `p`, `None` where no frustum holds it.
    pub fn footprint(&self, p: &Point3<f64>) -> Option<f64> {
        self.footprint_and_views(p).0
    }

    /// [`Self::footprint`] and the number of views whose frustum holds `p`: how many depth maps
    /// can at most have measured the surface there (occlusion aside).
    pub fn footprint_and_views(&self, p: &Point3<f64>) -> (Option<f64>, usize) {
        let mut best = f64::INFINITY;
        let mut seen = 0;
        for v in &self.views {
            let pc = v.rot * p.coords + v.trans;
            if pc.z <= 0.0 {
                continue;
            }
            let b = &v.bounds;
            let (x, y) = (pc.x, pc.y);
            if x < b[0] * pc.z || x > b[1] * pc.z || y < b[2] * pc.z || y > b[3] * pc.z {
                continue;
            }
            seen += 1;
            best = best.min(pc.z * v.inv_f);
        }
        (best.is_finite().then_some(best), seen)
    }

    /// The level of a footprint.
    pub fn level_of_footprint(&self, footprint: f64) -> i32 {
        let l = (footprint * self.inv_ref).log2().round();
        if l.is_nan() {
            return self.finest;
        }
        (l as i32).clamp(self.finest, self.coarsest)
    }

    /// The level that owns `p`, `None` where no view sees it.
    pub fn level(&self, p: &Point3<f64>) -> Option<i32> {
        self.footprint(p).map(|f| self.level_of_footprint(f))
    }
}

/// `2^level` as a factor.
pub fn scale(level: i32) -> f64 {
    2f64.powi(level)
}
