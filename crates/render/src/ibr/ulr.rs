//! Unstructured-lumigraph weights (Buehler, Bosse, McMillan, Gortler & Cohen, SIGGRAPH 2001).

use nalgebra::Vector3;

use super::source::Source;
use super::support::{self, Blend, Virtual};
use super::IbrOptions;

/// Buehler et al. (2001), §4: the penalty of each view at a scene point is its angle to the
/// virtual ray plus α times its resolution penalty (how much farther it is than the virtual
/// camera, relative); views that do not see the point are out. The k best keep weights
/// `1 − p / p_k+1`, normalised.
pub(crate) fn ulr_blend(
    virt: &Virtual,
    x: &Vector3<f64>,
    sources: &[Source],
    opts: &IbrOptions,
) -> Blend {
    let dv = x - virt.center;
    let lv = dv.norm();
    let mut best: [(f64, usize); support::MAX_BLEND + 1] =
        [(f64::INFINITY, usize::MAX); support::MAX_BLEND + 1];
    let k = opts.ulr_k;
    for (i, s) in sources.iter().enumerate() {
        let y = s.to_cam(x);
        let Some(px) = s.pixel_of_cam(&y) else {
            continue;
        };
        if let Some(d) = s.depth_at(&px) {
            if y.z > d * (1.0 + opts.occlusion_tolerance) {
                continue;
            }
        }
        let ds = x - s.center.coords;
        let ls = ds.norm();
        let angle = (dv.dot(&ds) / (lv * ls)).clamp(-1.0, 1.0).acos();
        let res = ((ls - lv) / lv).max(0.0);
        let p = (1.0 - opts.ulr_resolution_weight) * angle + opts.ulr_resolution_weight * res;
        // Insert into the sorted k+1 best.
        let mut j = k;
        if p >= best[j].0 {
            continue;
        }
        best[j] = (p, i);
        while j > 0 && best[j].0 < best[j - 1].0 {
            best.swap(j, j - 1);
            j -= 1;
        }
    }
    let mut b = Blend::default();
    let thresh = best[k].0;
    let mut sum = 0.0;
    let mut raw = [0.0f64; support::MAX_BLEND];
    for j in 0..k {
        if best[j].1 == usize::MAX {
            break;
        }
        raw[j] = if thresh.is_finite() {
            (1.0 - best[j].0 / thresh.max(1e-12)).max(0.0)
        } else {
            1.0
        };
        sum += raw[j];
    }
    if sum <= 0.0 {
        if best[0].1 != usize::MAX {
            b.push(best[0].1, 1.0);
        }
        return b;
    }
    for j in 0..k {
        if best[j].1 != usize::MAX && raw[j] > 0.0 {
            b.push(best[j].1, (raw[j] / sum) as f32);
        }
    }
    b
}
