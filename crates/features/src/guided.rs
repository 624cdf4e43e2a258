//! Guided matching (Table 1 step 4): every keypoint not yet matched is matched along its
//! epipolar line under the seeds' `F`, with a ratio test against every keypoint that may lie on
//! the true line (`EpipolarUncertainty`). Called by `verify.rs` after RANSAC, before the final
//! refinement (step 5).

use handheld_geometry::EpipolarUncertainty;
use nalgebra::{Matrix3, Vector2, Vector3};

use crate::detector::Features;
use crate::epipolar_grid::{bounds, Grid, Pencil, Radial};
use crate::verify::PairVerificationOptions;

pub(crate) fn point(f: &Features, k: u32) -> Vector2<f64> {
    let kp = &f.keypoints[k as usize];
    Vector2::new(kp.x as f64, kp.y as f64)
}

/// Euclidean distance, summed in eight independent lanes so the compiler can vectorise it.
pub(crate) fn dist(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| (x - y) * (x - y))
        .sum();
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            let d = x[k] - y[k];
            acc[k] += d * d;
        }
    }
    (acc.iter().sum::<f32>() + tail).sqrt()
}

/// The widest band, as a multiple of `guided_max_epipolar_px`, searched for rivals of a guided
/// match. A guided match is the nearest descriptor within `guided_max_epipolar_px` of the
/// epipolar line, and Lowe's ratio test needs the rivals it could be confused with: every
/// keypoint that may lie on the *true* line, i.e. within the acceptance band plus three standard
/// deviations of the line's position there ([`EpipolarUncertainty`], from the seeds' inliers).
/// Where the seeds do not sample the scene (a façade's far end, the ground), the seeds' line can
/// be pixels off; with rivals taken from the acceptance band only, the wrong keypoint that lay
/// on it passed the test, and these matches, all along the seeds' lines, pulled the principal
/// point (herzjesu-P8 at 1536×1024: 11 px off, AUC@1 70; 1 px off without guided matching).
/// Where the line is more uncertain than this band allows, no guided match is made.
pub const GUIDED_RIVAL_BAND_FACTOR: f64 = 4.0;

/// Cell size of the grid the rivals are gathered from (see `guided_matches`).
const RIVAL_CELL_PX: f64 = 16.0;

/// Table 1 step 4: for every keypoint of image 1 not yet matched, the nearest descriptor among the
/// keypoints of image 2 within `guided_max_epipolar_px` of its epipolar line `F x1`, with a
/// distance limit, image-2 keypoints used at most once, and a ratio test against every keypoint
/// that may lie on the true line (see [`GUIDED_RIVAL_BAND_FACTOR`]). `existing` are the matches
/// `F` was estimated from: they fix how well each line is known.
pub fn guided_matches(
    f1: &Features,
    f2: &Features,
    f: &Matrix3<f64>,
    existing: &[(u32, u32)],
    opts: &PairVerificationOptions,
) -> Vec<(u32, u32)> {
    let d1 = &f1.descriptors;
    let d2 = &f2.descriptors;
    if d1.dim == 0
        || d1.dim != d2.dim
        || d1.len() != f1.keypoints.len()
        || d2.len() != f2.keypoints.len()
    {
        return Vec::new();
    }
    // How well F fixes each line, from the matches it was estimated on (`existing`).
    let (x1, x2): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = existing
        .iter()
        .map(|&(a, b)| (point(f1, a), point(f2, b)))
        .unzip();
    let uncertainty = EpipolarUncertainty::new(f, &x1, &x2).ok();
    let mut used1 = vec![false; f1.keypoints.len()];
    let mut used2 = vec![false; f2.keypoints.len()];
    for &(a, b) in existing {
        used1[a as usize] = true;
        used2[b as usize] = true;
    }
    // The band query tests exactly the keypoints' distance from the line, so its grid is sized for
    // speed. The rivals are every keypoint of the 16 px cells the wider band crosses that lies
    // within its own reach of the line (`reach` may pass `rival_band`, and then the cells decide):
    // that set is kept as it was measured, on its own grid.
    let grid = Grid::for_keypoints(f2);
    let pencil = Pencil::new(f2, f);
    // Where the epipole is inside the keypoints' extent or near it, its radial pencil.
    let radial = match pencil {
        Some(_) => None,
        None => Radial::new(f2, f),
    };
    let rival_grid = Grid::new(f2, RIVAL_CELL_PX);
    // The corners of image 2's keypoints' extent: a line's σ is largest at one of them.
    let corners: Vec<Vector2<f64>> = {
        let (lo, hi) = bounds(f2);
        vec![
            Vector2::new(lo[0], lo[1]),
            Vector2::new(hi[0], lo[1]),
            Vector2::new(lo[0], hi[1]),
            Vector2::new(hi[0], hi[1]),
        ]
    };
    let mut cand = Vec::new();
    let mut best: Vec<(f32, u32, u32)> = Vec::new();
    // Visit the keypoints in the order of their epipolar lines across image 2, so consecutive
    // queries read the same cells and descriptors (cache locality; the matches do not depend on
    // the order, the order of equally near ones does). Lines through an epipole inside the
    // image ([`Radial`]) go by their direction: they all cross the middle row near the epipole,
    // so ordered there they came in no order at all, and the radial rings look for each query's
    // wedges from where the last one's were.
    let mut order: Vec<(bool, f64, u32)> = (0..f1.keypoints.len() as u32)
        .filter(|&a| !used1[a as usize])
        .map(|a| {
            let x1 = point(f1, a);
            let l = f * Vector3::new(x1.x, x1.y, 1.0);
            if radial.is_some() {
                let t = (-l.x).atan2(l.y);
                let t = if t < 0.0 { t + std::f64::consts::PI } else { t };
                return (false, if t.is_finite() { t } else { 0.0 }, a);
            }
            let steep = l.x.abs() >= l.y.abs();
            let key = if steep {
                -(l.y * grid.mid.1 + l.z) / l.x
            } else {
                -(l.x * grid.mid.0 + l.z) / l.y
            };
            (steep, if key.is_finite() { key } else { 0.0 }, a)
        })
        .collect();
    order.sort_by(|p, q| p.0.cmp(&q.0).then(p.1.total_cmp(&q.1)));
    let band = opts.guided_max_epipolar_px;
    let rival_band = GUIDED_RIVAL_BAND_FACTOR * band;
    let mut wide = Vec::new();
    for &(_, _, a) in &order {
        let x1 = point(f1, a);
        let l = f * Vector3::new(x1.x, x1.y, 1.0);
        let n = (l.x * l.x + l.y * l.y).sqrt();
        let off = |x2: &Vector2<f64>| ((l.x * x2.x + l.y * x2.y + l.z) / n).abs();
        // The nearest descriptor within the acceptance band, and the second nearest there
        // (taken keypoints included: they are rivals too).
        // Exactly the keypoints within the band (the grid tests them as `off` would).
        match (&pencil, &radial) {
            (Some(p), _) => p.within_band(&l, band, &mut cand),
            (None, Some(r)) => r.within_band(&l, band, &mut cand),
            (None, None) => grid.within_band(&l, band, &mut cand),
        }
        let (mut b1, mut s1, mut s2) = (u32::MAX, f32::INFINITY, f32::INFINITY);
        for &b in &cand {
            let d = dist(d1.row(a as usize), d2.row(b as usize));
            if d < s1 {
                s2 = s1;
                s1 = d;
                b1 = b;
            } else if d < s2 {
                s2 = d;
            }
        }
        if b1 == u32::MAX
            || used2[b1 as usize]
            || s1 > opts.guided_max_distance
            || s1 >= opts.guided_ratio * s2
        {
            continue;
        }
        // Rivals off the acceptance band: every keypoint that may lie on the true line, within
        // the band plus 3σ of the line's position there. One nearer than the match rejects it;
        // the others take part in the ratio test.
        if let Some(u) = &uncertainty {
            let line = u.line(&x1);
            let reach = |x2: &Vector2<f64>| band + 3.0 * line.sigma(x2);
            if reach(&point(f2, b1)) > rival_band {
                // The line is too uncertain there for its rivals to be seen.
                continue;
            }
            // The farthest any keypoint's reach goes: σ is the norm of an affine function of the
            // position (the line's covariance as a quadratic form, `LineUncertainty`), convex, so
            // largest at a corner of the keypoints' extent (widened against rounding). Where that
            // stays inside the rival band, every rival lies within it of the line, in a cell the
            // band crosses: the epipole's pencil finds exactly those keypoints by two binary
            // searches, where the grid walk hands back every keypoint of the cells along the
            // whole line (most of guided matching's cost on fountain-P11). The same rivals.
            let widest = corners.iter().map(&reach).fold(0.0, f64::max) * (1.0 + 1e-6) + 1e-9;
            match (&pencil, &radial) {
                (Some(p), _) if widest <= rival_band => p.within_band(&l, widest, &mut wide),
                (None, Some(r)) if widest <= rival_band => r.within_band(&l, widest, &mut wide),
                _ => rival_grid.near_line(&l, rival_band, &mut wide),
            }
            let mut rejected = false;
            for &b in &wide {
                let x2 = point(f2, b);
                let o = off(&x2);
                if o <= band || o > reach(&x2) {
                    continue;
                }
                let d = dist(d1.row(a as usize), d2.row(b as usize));
                if d <= s1 {
                    rejected = true;
                    break;
                }
                s2 = s2.min(d);
            }
            if rejected || s1 >= opts.guided_ratio * s2 {
                continue;
            }
        }
        best.push((s1, a, b1));
    }
    // Greedy one-to-one by descriptor distance.
    best.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut out = Vec::new();
    for (_, a, b) in best {
        if !used2[b as usize] {
            used2[b as usize] = true;
            out.push((a, b));
        }
    }
    out
}

/// Guided matching's rounds stop once the refined F moves the epipolar lines by less than this
/// share of the search band (`guided_max_epipolar_px`) where the verified matches lie
/// ([`line_shift`]): another round would search almost the same bands.
pub const GUIDED_STABLE_FRACTION: f64 = 0.05;

/// How far `g`'s epipolar lines lie from `f`'s, pixels: the 90th percentile, over the matches
/// (`a` in image 1, `b` in image 2), of the change in the signed distance of `b` from the line of
/// `a`.
pub(crate) fn line_shift(
    f: &Matrix3<f64>,
    g: &Matrix3<f64>,
    f1: &Features,
    f2: &Features,
    matches: &[(u32, u32)],
) -> f64 {
    // F is defined up to scale and sign: compare like with like.
    let g = if f.dot(g) < 0.0 { -g } else { *g };
    let signed = |m: &Matrix3<f64>, x1: &Vector2<f64>, x2: &Vector2<f64>| {
        let l = m * Vector3::new(x1.x, x1.y, 1.0);
        (l.x * x2.x + l.y * x2.y + l.z) / (l.x * l.x + l.y * l.y).sqrt()
    };
    let mut d: Vec<f64> = matches
        .iter()
        .map(|&(a, b)| {
            let (x1, x2) = (point(f1, a), point(f2, b));
            (signed(&g, &x1, &x2) - signed(f, &x1, &x2)).abs()
        })
        .filter(|v| v.is_finite())
        .collect();
    if d.is_empty() {
        return f64::INFINITY;
    }
    let k = (d.len() * 9 / 10).min(d.len() - 1);
    *d.select_nth_unstable_by(k, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::Descriptors;
    use crate::detector::Keypoint;
    use crate::verify::PairVerificationOptions;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const DIM: usize = 8;

    fn keypoint(p: Vector2<f64>) -> Keypoint {
        Keypoint {
            x: p.x as f32,
            y: p.y as f32,
            scale: 2.0,
            orientation: 0.0,
            response: 1.0,
        }
    }

    fn unit(v: [f32; DIM]) -> [f32; DIM] {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.map(|x| x / n)
    }

    /// A rectified pair (epipolar lines are the rows), seeds with 0.3 px noise inside `seed_box`,
    /// and one more keypoint at (900, 900) in image 1. Image 2 holds a look-alike on the seeds'
    /// line of that keypoint (descriptor distance 0.5) and the true match 5 px off that line
    /// (descriptor distance 0). Returns the guided matches of the last keypoint of image 1.
    fn guided_for_far_keypoint(seed_box: f64) -> Vec<(u32, u32)> {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut k1, mut k2, mut d1, mut d2) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut x1s = Vec::new();
        let mut x2s = Vec::new();
        for _ in 0..60 {
            let p = Vector2::new(
                rng.random_range(0.0..seed_box),
                rng.random_range(0.0..seed_box),
            );
            let disparity = rng.random_range(20.0..80.0);
            let mut noise = || rng.random_range(-0.5..0.5);
            let a = p + Vector2::new(noise(), noise());
            let b = p + Vector2::new(-disparity + noise(), noise());
            k1.push(keypoint(a));
            k2.push(keypoint(b));
            x1s.push(a);
            x2s.push(b);
            let desc = unit(std::array::from_fn(|_| rng.random_range(0.0..1.0f32)));
            d1.extend(desc);
            d2.extend(desc);
        }
        let f = handheld_geometry::fundamental_8point(&x1s, &x2s).expect("seeds fix F");
        let seeds: Vec<(u32, u32)> = (0..60).map(|i| (i, i)).collect();
        // The far keypoint, and where the seeds' F puts its line at x = 850 in image 2.
        let q = Vector2::new(900.0, 900.0);
        let l = f * Vector3::new(q.x, q.y, 1.0);
        let on_line = |x: f64| Vector2::new(x, -(l.x * x + l.z) / l.y);
        let base = unit([1.0, 0.2, 0.0, 0.0, 0.3, 0.0, 0.1, 0.0]);
        let lookalike = unit([1.0, 0.2, 0.5, 0.0, 0.3, 0.0, 0.1, 0.2]);
        k1.push(keypoint(q));
        d1.extend(base);
        k2.push(keypoint(on_line(850.0)));
        d2.extend(lookalike);
        k2.push(keypoint(on_line(852.0) + Vector2::new(0.0, 5.0)));
        d2.extend(base);
        let features = |k: Vec<Keypoint>, d: Vec<f32>| Features {
            keypoints: k,
            descriptors: Descriptors { dim: DIM, data: d },
        };
        let (f1, f2) = (features(k1, d1), features(k2, d2));
        let opts = PairVerificationOptions::default();
        guided_matches(&f1, &f2, &f, &seeds, &opts)
    }

    #[test]
    fn a_guided_match_needs_no_nearer_rival_where_the_line_is_uncertain() {
        // Seeds everywhere: the line at the far keypoint is known to a fraction of a pixel, so a
        // keypoint 5 px off it cannot be its match, and the one on it is taken.
        assert_eq!(guided_for_far_keypoint(1000.0), vec![(60, 60)]);
        // Seeds only in the top-left corner: the line there may be pixels off, the keypoint 5 px
        // away may be the true match and is nearer in descriptor space, so no match is made.
        assert_eq!(guided_for_far_keypoint(100.0), Vec::<(u32, u32)>::new());
    }
}
