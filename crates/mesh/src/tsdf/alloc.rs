//! The allocation pass of the TSDF (see the parent module): every (strided) valid pixel's ray
//! sampled within the truncation band around its depth, and the keys of the blocks it crosses
//! collected, at the level that owns the point ([`crate::levels`]).

use std::collections::HashSet;

use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;

use super::update::{left_out_factor, noise_weight};
use super::{depth_quantile, BlockKey, TsdfVolume, BLOCK};
use crate::error::{MeshError, Result};
use crate::levels::scale;
use crate::view::{Depth, Projector};

impl TsdfVolume {
    pub(super) fn collect_keys(
        &self,
        view: &Depth,
        proj: &Projector,
        view_index: usize,
    ) -> Result<(HashSet<BlockKey>, usize, usize)> {
        let f = view.posed.camera.intrinsics.f;
        let z05 = depth_quantile(view, 0.05).ok_or(MeshError::EmptyDepth { view: view_index })?;
        let z95 = depth_quantile(view, 0.95).ok_or(MeshError::EmptyDepth { view: view_index })?;
        // The level a depth of this view gets from its own footprint (the field's can only be finer).
        let own_level = |z: f64| -> i8 {
            match &self.levels {
                None => 0,
                Some(field) => field.level_of_footprint(z / f) as i8,
            }
        };
        // A quarter of a block side, in pixels, at the depths where a block is smallest in the image.
        let stride = [z05, z95]
            .iter()
            .map(|&z| 0.25 * self.level_voxel_size(own_level(z)) * BLOCK as f64 * f / z)
            .fold(f64::INFINITY, f64::min)
            .floor()
            .clamp(1.0, 16.0) as usize;
        let (w, h) = (view.depth.width, view.depth.height);
        let (base_vs, base_trunc) = (self.voxel_size, self.truncation);
        let min_conf = self.min_confidence;
        let max_std = self.max_depth_std;
        let levels = self.levels.as_ref();
        let rt = proj.rot.transpose();
        type Acc = (HashSet<([i32; 3], i8)>, usize, usize);
        let (keys, samples, uncertain): Acc = (0..h)
            .into_par_iter()
            .step_by(stride)
            .fold(
                || (HashSet::new(), 0, 0),
                |(mut set, mut n, mut bad), y| {
                    let mut last = ([i32::MIN; 3], 0);
                    for x in (0..w).step_by(stride) {
                        if view.weight(y * w + x, min_conf) <= 0.0 {
                            continue;
                        }
                        let z = view.depth.data[y * w + x] as f64;
                        let nrm = view
                            .posed
                            .camera
                            .intrinsics
                            .pixel_to_normalized(Vector2::new(x as f64, y as f64));
                        let dir = rt * Vector3::new(nrm.x, nrm.y, 1.0);
                        let (level, seen) = match levels {
                            None => (0, 0),
                            Some(field) => {
                                let p = proj.center + dir * z;
                                let (fp, seen) = field.footprint_and_views(&p);
                                let fp = fp.unwrap_or(z / f).min(z / f);
                                (field.level_of_footprint(fp) as i8, seen)
                            }
                        };
                        let s = scale(level as i32);
                        let (block_side, trunc) = (base_vs * s * BLOCK as f64, base_trunc * s);
                        n += 1;
                        let left_out = left_out_factor(seen);
                        if noise_weight(view.std(y * w + x), max_std * trunc, left_out) <= 0.0 {
                            bad += 1;
                            continue;
                        }
                        let n_steps = ((3.0 * trunc / (0.5 * block_side)).ceil() as usize).max(1);
                        let inv_block = 1.0 / block_side;
                        let scale_dir = dir.norm();
                        for st in 0..=n_steps {
                            let zz = z + trunc * (2.0 * st as f64 / n_steps as f64 - 1.0)
                                / scale_dir
                                * 1.5;
                            if zz <= 0.0 {
                                continue;
                            }
                            let p = proj.center + dir * zz;
                            let k = [
                                (p.x * inv_block + 0.5 / BLOCK as f64).floor() as i32,
                                (p.y * inv_block + 0.5 / BLOCK as f64).floor() as i32,
                                (p.z * inv_block + 0.5 / BLOCK as f64).floor() as i32,
                            ];
                            if (k, level) != last {
                                set.insert((k, level));
                                last = (k, level);
                            }
                        }
                    }
                    (set, n, bad)
                },
            )
            .reduce(
                || (HashSet::new(), 0, 0),
                |a, b| {
                    let set = if a.0.len() < b.0.len() {
                        merge_sets(b.0, a.0)
                    } else {
                        merge_sets(a.0, b.0)
                    };
                    (set, a.1 + b.1, a.2 + b.2)
                },
            );
        Ok((keys, samples, uncertain))
    }
}

fn merge_sets<T: std::hash::Hash + Eq>(mut a: HashSet<T>, b: HashSet<T>) -> HashSet<T> {
    a.extend(b);
    a
}
