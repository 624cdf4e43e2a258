//! A verified pair whose parallax is a repeated pattern's copies, not depth.
//!
//! On a wall covered by a repeated motif (printed wallpaper, tiles, a facade's bricks) a wide pair
//! can match part of the wall to the motif's copy one period away: SIFT is not invariant to the
//! perspective change between two wide views, and the copy seen at the same angle as the query
//! looks more like it than the true partner does. The twin test ([`crate::matching::Twins`])
//! keeps such a match, since no look-alike in either image is nearer than it. The pair's inliers
//! are then two homographies, the wall `H₁` and its copy `H₂ = H₁ T` (`T` a translation in the
//! wall by a period), and the fundamental matrix whose epipole is the vanishing point of `T` fits
//! both: a "general" pair whose relative pose is wrong by degrees. On a synthetic wallpaper orbit
//! (`handheld demo --scene wallpaper --width 720 --height 1280 --fov 66 --k1 0.05 --frames 40
//! --seed 7`) 158 of 371 general pairs held more than 20 % of such copies, their relative rotations
//! up to 11° off, and the model had 33 of 40 views, several degrees off.
//!
//! Two views cannot tell a copy from a parallel plane at another depth (Hartley & Zisserman 2004,
//! §13.2: two planes induce a homology `H₁⁻¹ H₂`). The image can: `G = H₁⁻¹ H₂` maps each point
//! of image 1 to where its match would be on the other plane, and for copies that is where image 1
//! repeats itself. So the pair is tested for self-similarity under `G`: of a sample of image 1's
//! keypoints, how many find a keypoint with a near descriptor within [`REACH_PX`] of their image
//! under `G`, against a control map that moves each keypoint half as far (a pattern's lattice, square
//! or not, holds no copy half a period away; a texture that looks alike everywhere hits both).
//! A real second plane (a recess, an object's face) maps image 1 to unrelated texture: as many hits
//! as the control, about none. Copies repeat: 5–44 % of the keypoints on the orbit's pairs, with
//! none under the control. On the ten real sets of `../shared/datasets` no pair was flagged (their
//! match databases are byte-identical with and without the test). On the orbit 135 pairs were
//! flagged and the model held all 40 views within 0.035° (focal length 0.09 % off), in either file
//! order; kitti-seq1's matches stage took 3–4 % longer.
//!
//! A flagged pair is left out of the model (its configuration becomes `TooFewInliers`): which of
//! its two planes is the wall and which the copy cannot be told from the pair, and the views it
//! joined are still joined by their narrower and wider pairs.

use handheld_robust::{
    run, Estimator, HomographyEstimator, Match2d2d, Msac, RansacOptions, TwoViewConfiguration,
    TwoViewGeometry, TwoViewOptions, UniformSampler,
};
use nalgebra::{Matrix3, Vector2, Vector3};

use crate::detector::Features;
use crate::epipolar_grid::Layout;
use crate::guided::{dist, point};

/// Homographies fitted to a pair's inliers, one after the other on what the earlier ones left.
const MAX_PLANES: usize = 3;
/// RANSAC draws for each plane at most: 99 % sure to find a plane holding 26 % of what is left.
/// On the wallpaper orbit, 250 draws (37 %) flagged 104 of the 147 pairs that 1 000 draws with
/// local optimisation flag; 1 000 without it flag 135 and cost kitti-seq1's matches stage 6 %
/// (local optimisation another 14 %).
const PLANE_DRAWS: usize = 1000;
/// Matches a plane's draws are scored on, at most (an even subsample of what is left).
const PLANE_SCORED: usize = 400;
/// The fewest matches a plane needs, and its least share of the pair's inliers.
const MIN_PLANE_MATCHES: usize = 15;
const MIN_PLANE_SHARE: f64 = 0.05;
/// How far from a keypoint's image under `G` a look-alike may lie, pixels.
pub const REACH_PX: f64 = 3.0;
/// Keypoints that `G` moves less than this are not tested (their look-alike would be themselves).
const MIN_SHIFT_PX: f64 = 16.0;
/// Keypoints of image 1 sampled at most.
const SAMPLE: usize = 1024;
/// A look-alike is within this multiple of the pair's median match distance.
const DISTANCE_FACTOR: f32 = 2.0;
/// The verdict: at least this many hits, this share of the keypoints tested, and this multiple of
/// the control's hits.
const MIN_HITS: usize = 32;
const MIN_SHARE: f64 = 0.05;
const CONTROL_FACTOR: usize = 4;

/// What the test found in a flagged pair.
#[derive(Clone, Debug, PartialEq)]
pub struct Copies {
    /// Keypoints of image 1 tested, and how many had a look-alike under `G` and under the control.
    pub tested: usize,
    pub hits: usize,
    pub control_hits: usize,
}

/// Keypoints of one image in square cells of about one keypoint each (at least [`REACH_PX`]): a
/// look-alike query reads 3 × 3 cells.
struct Cells {
    cell: f64,
    cols: usize,
    rows: usize,
    layout: Layout,
}

impl Cells {
    fn new(f: &Features) -> Self {
        let (w, h) = f.keypoints.iter().fold((0f64, 0f64), |(w, h), k| {
            (w.max(k.x as f64), h.max(k.y as f64))
        });
        let cell = (w * h / f.keypoints.len().max(1) as f64)
            .sqrt()
            .clamp(REACH_PX, 64.0);
        let cols = (w / cell) as usize + 1;
        let rows = (h / cell) as usize + 1;
        let layout = Layout::new(f, cols * rows, |k| {
            let (cx, cy) = (
                (k.x.max(0.0) as f64 / cell) as usize,
                (k.y.max(0.0) as f64 / cell) as usize,
            );
            Some(cy.min(rows - 1) * cols + cx.min(cols - 1))
        });
        Self {
            cell,
            cols,
            rows,
            layout,
        }
    }

    /// Whether a keypoint within [`REACH_PX`] of `p`, and more than `MIN_SHIFT_PX / 4` from
    /// keypoint `a`, has a descriptor within `tau` of `a`'s.
    fn look_alike(&self, f: &Features, a: usize, p: Vector2<f64>, tau: f32) -> bool {
        if !(p.x >= 0.0 && p.y >= 0.0) {
            return false;
        }
        let (cx, cy) = ((p.x / self.cell) as usize, (p.y / self.cell) as usize);
        let dim = f.descriptors.dim;
        let da = &f.descriptors.data[a * dim..(a + 1) * dim];
        let xa = point(f, a as u32);
        for y in cy.saturating_sub(1)..(cy + 2).min(self.rows) {
            for x in cx.saturating_sub(1)..(cx + 2).min(self.cols) {
                let c = y * self.cols + x;
                let l = &self.layout;
                for s in l.start[c] as usize..l.start[c + 1] as usize {
                    let xk = Vector2::new(l.xy[s][0], l.xy[s][1]);
                    if (xk - p).norm() > REACH_PX || (xk - xa).norm() <= MIN_SHIFT_PX / 4.0 {
                        continue;
                    }
                    let k = l.index[s] as usize;
                    if dist(da, &f.descriptors.data[k * dim..(k + 1) * dim]) <= tau {
                        return true;
                    }
                }
            }
        }
        false
    }
}

/// The homography through four matches by the projective basis (Hartley & Zisserman 2004, §2.7,
/// ex. 2.7.1(iii)): `H = B₂ B₁⁻¹`, with `Bₖ` taking the canonical basis to image `k`'s four points.
/// Three small solves instead of the DLT's 9 × 9 eigenproblem: the planes' draws are most of this
/// test's cost, and it only has to find them, not refine them. Residuals are the DLT estimator's.
struct BasisHomography;

fn basis(x: [Vector2<f64>; 4]) -> Option<Matrix3<f64>> {
    let h = |v: Vector2<f64>| Vector3::new(v.x, v.y, 1.0);
    let a = Matrix3::from_columns(&[h(x[0]), h(x[1]), h(x[2])]);
    let l = a.try_inverse()? * h(x[3]);
    (l.iter().all(|v| v.abs() > 1e-9))
        .then(|| Matrix3::from_columns(&[h(x[0]) * l.x, h(x[1]) * l.y, h(x[2]) * l.z]))
}

impl Estimator for BasisHomography {
    type Model = Matrix3<f64>;
    type Sample = Match2d2d;
    const SAMPLE_SIZE: usize = 4;

    fn fit(&self, s: &[Match2d2d], out: &mut Vec<Matrix3<f64>>) {
        let b1 = basis([s[0].x1, s[1].x1, s[2].x1, s[3].x1]).and_then(|b| b.try_inverse());
        let b2 = basis([s[0].x2, s[1].x2, s[2].x2, s[3].x2]);
        if let (Some(b1i), Some(b2)) = (b1, b2) {
            let h = b2 * b1i;
            if h.iter().all(|v| v.is_finite()) {
                out.push(h);
            }
        }
    }

    fn residual(&self, model: &Matrix3<f64>, s: &Match2d2d) -> f64 {
        HomographyEstimator.residual(model, s)
    }

    fn residuals<F: FnMut(f64)>(&self, model: &Matrix3<f64>, samples: &[Match2d2d], each: F) {
        HomographyEstimator.residuals(model, samples, each)
    }

    fn refit(&self, samples: &[Match2d2d], model: &Matrix3<f64>) -> Option<Matrix3<f64>> {
        HomographyEstimator.refit(samples, model)
    }
}

/// Up to [`MAX_PLANES`] homographies of the matches, each by RANSAC (MSAC, at most
/// [`PLANE_DRAWS`] draws scored on [`PLANE_SCORED`] matches) on what the earlier ones left. The
/// pair's own dominant homography is not used: model selection fits it to every putative match,
/// and where the copies split them it is often missing (124 of the wallpaper orbit's 371 general
/// pairs).
fn planes(m: &[Match2d2d], threshold_px: f64, ransac: &RansacOptions) -> Vec<Matrix3<f64>> {
    let least = MIN_PLANE_MATCHES.max((MIN_PLANE_SHARE * m.len() as f64).ceil() as usize);
    let opts = RansacOptions {
        max_error: threshold_px,
        max_iterations: PLANE_DRAWS,
        min_iterations: ransac.min_iterations.min(PLANE_DRAWS),
        local_optimization: false,
        ..ransac.clone()
    };
    let mut rest: Vec<Match2d2d> = m.to_vec();
    let mut out = Vec::new();
    while out.len() < MAX_PLANES && rest.len() >= least {
        // The draws are scored on an even subsample: a plane is a share of what is left.
        let step = rest.len().div_ceil(PLANE_SCORED).max(1);
        let scored: Vec<Match2d2d> = rest.iter().step_by(step).copied().collect();
        let sub = RansacOptions {
            min_support: least.div_ceil(step),
            ..opts.clone()
        };
        let mut sampler = UniformSampler::new(opts.seed);
        let Ok(rep) = run(&BasisHomography, &Msac, &mut sampler, &scored, &sub) else {
            break;
        };
        let Some(h) = rep.model.filter(|_| rep.success) else {
            break;
        };
        let mut mask = Vec::with_capacity(rest.len());
        HomographyEstimator.residuals(&h, &rest, |r| mask.push(r <= threshold_px));
        if mask.iter().filter(|&&k| k).count() < least {
            break;
        }
        out.push(h);
        rest = keep_outliers(&rest, &mask);
    }
    out
}

fn keep_outliers(m: &[Match2d2d], inlier: &[bool]) -> Vec<Match2d2d> {
    m.iter()
        .zip(inlier)
        .filter(|(_, &k)| !k)
        .map(|(s, _)| *s)
        .collect()
}

fn apply(g: &Matrix3<f64>, x: Vector2<f64>) -> Option<Vector2<f64>> {
    let p = g * Vector3::new(x.x, x.y, 1.0);
    (p.z.abs() > 1e-12)
        .then(|| Vector2::new(p.x / p.z, p.y / p.z))
        .filter(|p| p.x.is_finite() && p.y.is_finite())
}

/// Whether the inliers of a pair verified as general are a pattern and its copy (module notes):
/// `Some` with the evidence when they are.
pub fn repeated_pattern(
    f1: &Features,
    f2: &Features,
    inliers: &[(u32, u32)],
    threshold_px: f64,
    ransac: &RansacOptions,
) -> Option<Copies> {
    let dim = f1.descriptors.dim;
    if inliers.len() < 2 * MIN_PLANE_MATCHES || dim == 0 || dim != f2.descriptors.dim {
        return None;
    }
    let m: Vec<Match2d2d> = inliers
        .iter()
        .map(|&(a, b)| Match2d2d::new(point(f1, a), point(f2, b)))
        .collect();
    // Most pairs of a real scene have fewer than two planes: nothing else is computed for them.
    let hs = planes(&m, threshold_px, ransac);
    if hs.len() < 2 {
        return None;
    }
    let mut d: Vec<f32> = inliers
        .iter()
        .map(|&(a, b)| {
            let (a, b) = (a as usize, b as usize);
            dist(
                &f1.descriptors.data[a * dim..(a + 1) * dim],
                &f2.descriptors.data[b * dim..(b + 1) * dim],
            )
        })
        .collect();
    let mid = d.len() / 2;
    let tau = DISTANCE_FACTOR * *d.select_nth_unstable_by(mid, f32::total_cmp).1;
    let cells = Cells::new(f1);
    let step = f1.keypoints.len().div_ceil(SAMPLE).max(1);
    let mut best: Option<Copies> = None;
    for p in 0..hs.len() {
        for q in p + 1..hs.len() {
            let Some(g) = hs[p].try_inverse().map(|hp| hp * hs[q]) else {
                continue;
            };
            let (mut tested, mut hits, mut control_hits) = (0, 0, 0);
            for a in (0..f1.keypoints.len()).step_by(step) {
                let x = point(f1, a as u32);
                let Some(y) = apply(&g, x) else { continue };
                let s = y - x;
                if s.norm() < MIN_SHIFT_PX {
                    continue;
                }
                tested += 1;
                hits += cells.look_alike(f1, a, y, tau) as usize;
                control_hits += cells.look_alike(f1, a, x + 0.5 * s, tau) as usize;
            }
            let c = Copies {
                tested,
                hits,
                control_hits,
            };
            let margin = |c: &Copies| c.hits as i64 - (CONTROL_FACTOR * c.control_hits) as i64;
            if best.as_ref().is_none_or(|b| margin(&c) > margin(b)) {
                best = Some(c);
            }
        }
    }
    best.filter(|c| {
        c.hits >= MIN_HITS
            && c.hits as f64 >= MIN_SHARE * c.tested as f64
            && c.hits > CONTROL_FACTOR * c.control_hits
    })
}

/// Runs [`repeated_pattern`] on a pair verified as general; where it finds copies, the pair becomes
/// `TooFewInliers` with no inliers, and `true` is returned.
pub(crate) fn set_aside(
    i: usize,
    j: usize,
    f1: &Features,
    f2: &Features,
    geometry: &mut TwoViewGeometry,
    inliers: &mut Vec<(u32, u32)>,
    opts: &TwoViewOptions,
) -> bool {
    let Some(c) = repeated_pattern(f1, f2, inliers, opts.h_threshold_px, &opts.ransac) else {
        return false;
    };
    tracing::debug!(
        "pair ({i}, {j}): left out, its {} inliers are a repeated pattern and its copy ({} of {} \
         keypoints of image {i} repeat under the planes' relation, {} under the control)",
        inliers.len(),
        c.hits,
        c.tested,
        c.control_hits
    );
    geometry.configuration = TwoViewConfiguration::TooFewInliers;
    geometry.num_inliers = 0;
    geometry.inlier_mask.iter_mut().for_each(|k| *k = false);
    inliers.clear();
    true
}

#[cfg(test)]
#[path = "copies_tests.rs"]
mod tests;
