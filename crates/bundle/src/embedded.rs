//! Embedded point iterations (Jeong, Nistér, Steedly, Szeliski & Kweon 2012, *Pushing the envelope
//! of modern methods for bundle adjustment*, PAMI 34(8), §4.2): after a joint step has moved the
//! cameras, every point is re-solved alone, with the cameras held, by a few Gauss–Newton steps on
//! its own 3×3 normal equations. The joint step's point update is only the linearised response to
//! the camera update; where a point's depth is poorly conditioned (little parallax, a long chain of
//! views) that response is far from the point's best position under the new cameras, the joint
//! model overstates the decrease, and Levenberg–Marquardt crawls with gain ratios near ½ and a trust
//! region that hardly grows. Each point's problem is independent and costs a few observations'
//! Jacobians, so the iterations are cheap beside the reduced system.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::loss::{Corrector, RobustLoss};
use crate::problem::{CameraModel, Problem};
use crate::residual::{metric_jacobian, metric_residual, NUM_INTRINSICS};
use crate::structure::Structure;

/// Relative damping of a point's 3×3 system (`V + ε·diag(V)`): keeps a point seen along nearly
/// parallel rays from a step along its undetermined depth.
const POINT_DAMPING: f64 = 1e-6;

/// One point's robust cost `½ Σ ρ(‖r/σ‖²)` over its observations, at `x`.
fn point_cost(p: &Problem, obs: &[u32], x: &[f64; 4], loss: &RobustLoss) -> f64 {
    let mut c = 0.0;
    for &o in obs {
        let o = o as usize;
        let cam = p.obs_camera[o] as usize;
        let r = metric_residual(
            &p.cameras[cam],
            &p.groups[p.camera_group[cam]],
            x,
            p.obs_xy[o],
            &p.motion(o),
        );
        let w = p.obs_weight(o);
        let s = (r[0] * r[0] + r[1] * r[1]) * w * w;
        c += loss.evaluate(s)[0];
    }
    0.5 * c
}

/// Re-solves every point of a metric problem with the cameras held: at most `iterations`
/// Gauss–Newton steps each, a step kept only where it lowers the point's cost. Returns the data
/// cost `½ Σ ρ` of the points where they end (summed point by point, in order), or `None` for a
/// projective problem, which is left alone (its points live on the sphere).
pub(crate) fn refine_points(
    p: &mut Problem,
    st: &Structure,
    loss: &RobustLoss,
    iterations: usize,
) -> Option<f64> {
    if iterations == 0 || p.model != CameraModel::Metric {
        return None;
    }
    let q: &Problem = p;
    let updated: Vec<(f64, [f64; 4])> = (0..q.points.len())
        .into_par_iter()
        .with_min_len(256)
        .map(|pt| refine_point(q, st.point_obs.row(pt), q.points[pt], loss, iterations))
        .collect();
    let mut cost = 0.0;
    for (pt, (c, x)) in updated.into_iter().enumerate() {
        cost += c;
        p.points[pt] = x;
    }
    Some(cost)
}

/// One point's Gauss–Newton steps (see [`refine_points`]): its cost and position where they end.
fn refine_point(
    q: &Problem,
    obs: &[u32],
    mut x: [f64; 4],
    loss: &RobustLoss,
    iterations: usize,
) -> (f64, [f64; 4]) {
    let mut cost = None;
    for _ in 0..iterations {
        let mut v = Matrix3::<f64>::zeros();
        let mut b = Vector3::<f64>::zeros();
        let mut here = 0.0;
        for &o in obs {
            let o = o as usize;
            let cam = q.obs_camera[o] as usize;
            let mut jpose = [[0.0; 2]; 6];
            let mut jintr = [[0.0; 2]; NUM_INTRINSICS];
            let mut jp = [[0.0; 2]; 3];
            let r = metric_jacobian(
                &q.cameras[cam],
                &q.groups[q.camera_group[cam]],
                &x,
                q.obs_xy[o],
                &q.motion(o),
                &mut jpose,
                &mut jintr,
                &mut jp,
            );
            let w = q.obs_weight(o);
            let r = [r[0] * w, r[1] * w];
            for col in jp.iter_mut() {
                col[0] *= w;
                col[1] *= w;
            }
            let s = r[0] * r[0] + r[1] * r[1];
            here += loss.evaluate(s)[0];
            let corr = Corrector::new(loss, s);
            corr.correct_jacobian(r, &mut jp);
            let r = corr.correct_residual(r);
            for a in 0..3 {
                b[a] -= jp[a][0] * r[0] + jp[a][1] * r[1];
                for c in a..3 {
                    v[(a, c)] += jp[a][0] * jp[c][0] + jp[a][1] * jp[c][1];
                }
            }
        }
        let here = 0.5 * here;
        cost.get_or_insert(here);
        for a in 0..3 {
            v[(a, a)] *= 1.0 + POINT_DAMPING;
            for c in 0..a {
                v[(a, c)] = v[(c, a)];
            }
        }
        let Some(chol) = v.cholesky() else { break };
        let d = chol.solve(&b);
        let trial = [x[0] + d[0], x[1] + d[1], x[2] + d[2], x[3]];
        let c = point_cost(q, obs, &trial, loss);
        if c.is_nan() || c >= here {
            break;
        }
        x = trial;
        cost = Some(c);
    }
    (cost.unwrap_or_else(|| point_cost(q, obs, &x, loss)), x)
}
