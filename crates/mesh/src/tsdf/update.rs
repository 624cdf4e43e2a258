//! The update pass of the TSDF (see the parent module): every voxel of a block projected into one
//! view, its distance along the line of sight turned into a distance to the surface, truncated, and
//! averaged with the running weight (Curless & Levoy 1996, eq. 4–5).

use nalgebra::Vector3;

use super::{Block, BLOCK};
use crate::levels::scale;
use crate::view::{sample_depth, Depth, Projector};

/// What the update pass needs of one view.
pub(super) struct UpdateContext<'a> {
    pub view: &'a Depth<'a>,
    pub proj: &'a Projector,
    /// Per-pixel incidence cosine ([`crate::view::incidence_map`]), in units of `1 / u16::MAX`.
    pub cos: &'a [u16],
    pub vs: f64,
    pub trunc: f64,
    pub max_w: f32,
    pub min_conf: f64,
    /// `max_depth_std` (0: off).
    pub max_std: f64,
}

/// Samples noisier than `max_depth_std` bands still count, with the weight of their variance
/// relative to it, up to this many times `max_depth_std` at least; beyond, they are left out
/// (see [`left_out_factor`]).
pub(super) const LEFT_OUT_FACTOR: f64 = 2.0;

/// How many times `max_depth_std` a sample's standard deviation may reach before it is left out,
/// where `views` depth maps can have measured the place: `max(2, √views)`. The average of `n`
/// samples of standard deviation `σ` has `σ/√n`, so a sample up to `√n · K·t` can still average
/// into the `K·t` that counts fully when every view that sees the place measured it; beyond, even
/// all of them together could not place the surface within the band (far background, too
/// little parallax). At least 2: four samples, the fewest a surface is fused from in practice.
/// `views` 0 (not known: one voxel size everywhere) gives 2.
pub(super) fn left_out_factor(views: usize) -> f64 {
    (views as f64).sqrt().max(LEFT_OUT_FACTOR)
}

/// The factor on a sample's weight for its standard deviation `std`, with `max_std` the band
/// multiple (in world units) up to which samples count fully: 1 up to it, the ratio of the
/// variances `(max_std / std)²` beyond (inverse-variance weighting: the weighted average is then
/// the maximum-likelihood depth of Gaussian samples), and 0 (left out) beyond
/// `left_out · max_std` ([`left_out_factor`]). `max_std` 0 counts every sample fully.
pub(super) fn noise_weight(std: f64, max_std: f64, left_out: f64) -> f64 {
    if max_std <= 0.0 || std <= max_std {
        1.0
    } else if std > left_out * max_std {
        0.0
    } else {
        (max_std / std).powi(2)
    }
}

/// Smallest incidence cosine used (about 78°): beyond it the normal estimate is unreliable.
const MIN_COS: f64 = 0.2;

/// The update pass of one block for one view (see the module documentation). The distance along
/// the line of sight is multiplied by the incidence cosine, which turns it into the distance to the
/// (locally planar) surface, so the band has the same thickness at grazing angles; the sample's
/// weight is its confidence times that cosine (Curless & Levoy 1996, §4), times
/// [`noise_weight`] where its depth is noisier than the band can hold.
pub(super) fn update_block(b: &mut Block, ctx: &UpdateContext) {
    let s = scale(b.level as i32);
    let (view, proj, vs, trunc) = (ctx.view, ctx.proj, ctx.vs * s, ctx.trunc * s);
    let max_std = ctx.max_std * trunc;
    let left_out = left_out_factor(b.views as usize);
    let n = BLOCK as f64;
    let origin = Vector3::new(b.key[0] as f64, b.key[1] as f64, b.key[2] as f64) * n * vs;
    let base = proj.rot * origin + proj.trans;
    let (ex, ey, ez) = (
        proj.rot.column(0) * vs,
        proj.rot.column(1) * vs,
        proj.rot.column(2) * vs,
    );
    // Cheap rejection: the block's eight corner voxels all outside the frustum (or behind).
    let m = n - 1.0;
    let corners: [Vector3<f64>; 8] = std::array::from_fn(|c| {
        base + ex * (m * (c & 1) as f64)
            + ey * (m * (c >> 1 & 1) as f64)
            + ez * (m * (c >> 2 & 1) as f64)
    });
    if proj.outside_frustum(&corners) {
        return;
    }
    let w = view.depth.width;
    let (wi, hi) = (view.depth.width as i64, view.depth.height as i64);
    for z in 0..BLOCK {
        for y in 0..BLOCK {
            let row = base + ez * z as f64 + ey * y as f64;
            for x in 0..BLOCK {
                let pc = row + ex * x as f64;
                let Some(px) = proj.cam_to_pixel(&pc) else {
                    continue;
                };
                let (rx, ry) = (px.x.round() as i64, px.y.round() as i64);
                if rx < 0 || ry < 0 || rx >= wi || ry >= hi {
                    continue;
                }
                let pix = ry as usize * w + rx as usize;
                let conf = view.weight(pix, ctx.min_conf);
                let noise = noise_weight(view.std(pix), max_std, left_out);
                if conf <= 0.0 || noise <= 0.0 {
                    continue;
                }
                let Some(d) = sample_depth(view.depth, &px, 0.5 * trunc / pc.z) else {
                    continue;
                };
                let cos = (f64::from(ctx.cos[pix]) / f64::from(u16::MAX)).max(MIN_COS);
                let sdf = (d - pc.z) * pc.norm() / pc.z * cos;
                if sdf < -trunc {
                    continue;
                }
                let i = x + BLOCK * (y + BLOCK * z);
                let v = (sdf / trunc).min(1.0) as f32;
                let (old_w, new_w) = (b.weight[i], (conf * cos * noise) as f32);
                b.tsdf[i] = (b.tsdf[i] * old_w + v * new_w) / (old_w + new_w);
                b.weight[i] = (old_w + new_w).min(ctx.max_w);
                if sdf < trunc {
                    b.observations[i] = b.observations[i].saturating_add(1);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_weight_is_the_variance_ratio_between_one_and_two_limits() {
        let two = left_out_factor(0);
        assert_eq!(noise_weight(0.5, 1.0, two), 1.0);
        assert_eq!(noise_weight(1.0, 1.0, two), 1.0);
        assert!((noise_weight(1.5, 1.0, two) - 1.0 / 2.25).abs() < 1e-12);
        assert!((noise_weight(2.0, 1.0, two) - 0.25).abs() < 1e-12);
        assert_eq!(noise_weight(2.01, 1.0, two), 0.0);
        // Off: every sample counts fully.
        assert_eq!(noise_weight(100.0, 0.0, two), 1.0);
        // Sixteen views can average a sample of four bands into one.
        assert_eq!(left_out_factor(16), 4.0);
        assert!((noise_weight(4.0, 1.0, left_out_factor(16)) - 1.0 / 16.0).abs() < 1e-12);
        assert_eq!(noise_weight(4.01, 1.0, left_out_factor(16)), 0.0);
        // Fewer than four views keep the floor of two.
        assert_eq!(left_out_factor(3), 2.0);
    }
}
