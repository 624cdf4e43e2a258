//! Verified matching of image pairs: Table 1 end to end. Putative matches from the descriptor
//! matcher (step 1), RANSAC + model selection + eq. 12/13 refinement (steps 2–3, in
//! `handheld-robust`), guided matching along the epipolar lines (step 4) and a final refinement on
//! all correct matches (step 5). Runs in parallel over pairs.
//!
//! Seeded matching: with [`PairVerificationOptions::seed_features`], step 1 runs brute force only
//! over the strongest keypoints of each image (by detector response). Those putative matches are
//! enough for a reliable `F`, and step 4 then matches *every* keypoint along its epipolar band,
//! which costs a few candidates per keypoint instead of a row of the full distance matrix. A pair
//! the seeds cannot verify well enough for guided matching (too few inliers, or not a general
//! configuration: planar scenes and pure rotation have no epipolar band) is matched again from
//! four times as many seeds, and keeps what that verifies: such pairs overlap little, and brute
//! force over every keypoint would cost four times more again for a few more matches.

use handheld_core::Progress;
use handheld_geometry::EpipolarUncertainty;
use handheld_robust::{
    estimate_two_view_geometry, refine_two_view, Match2d2d, TwoViewConfiguration, TwoViewGeometry,
    TwoViewOptions,
};
use nalgebra::{Matrix3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::detector::{Descriptors, Features};
use crate::epipolar_grid::Grid;
use crate::error::{check, FeatureError};
use crate::matching::{match_descriptors, Match, MatchOptions};

/// Options of [`verify_pairs`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PairVerificationOptions {
    pub matching: MatchOptions,
    pub two_view: TwoViewOptions,
    /// Look for additional matches near the epipolar lines (Table 1 step 4). Default true.
    pub guided: bool,
    /// Largest distance from the epipolar line of a guided candidate, pixels. Default 2.0.
    pub guided_max_epipolar_px: f64,
    /// Ratio test among the guided candidates of one keypoint. Default 0.8, as the global one:
    /// 0.9 added 10–20 % more matches on fountain-P11 and herzjesu-P8, but fewer of them within
    /// 1 px of the true epipolar line (herzjesu 80 % against 87 %), and the models got worse.
    pub guided_ratio: f32,
    /// Largest descriptor distance of a guided match (RootSIFT: in [0, √2]). Default 0.7.
    pub guided_max_distance: f32,
    /// Guided matching runs only when the RANSAC verification kept at least this many inliers: a
    /// weakly supported `F` may be wrong, and matching along wrong epipolar lines invents thousands
    /// of consistent-looking false matches. Default 50.
    pub guided_min_inliers: usize,
    /// Brute-force step 1 only over this many strongest keypoints per image, then guided matching
    /// over all of them (see the module notes); `None` matches all keypoints by brute force.
    /// Default `Some(2048)`. Needs `guided`.
    pub seed_features: Option<usize>,
}

impl Default for PairVerificationOptions {
    fn default() -> Self {
        Self {
            matching: MatchOptions::default(),
            two_view: TwoViewOptions::default(),
            guided: true,
            guided_max_epipolar_px: 2.0,
            guided_ratio: 0.8,
            guided_max_distance: 0.7,
            guided_min_inliers: 50,
            seed_features: Some(2048),
        }
    }
}

impl PairVerificationOptions {
    /// Checks the matching and two-view options and the guided-matching fields; the error names
    /// the offending option (`two_view` for any of the two-view options).
    pub fn validate(&self) -> Result<(), FeatureError> {
        self.matching.validate()?;
        self.two_view
            .validate()
            .map_err(|reason| FeatureError::option("two_view", reason))?;
        let e = self.guided_max_epipolar_px;
        check(!e.is_nan() && e > 0.0, "guided_max_epipolar_px", || {
            format!("must be positive, got {e}")
        })?;
        check(
            self.seed_features.is_none_or(|k| k >= 64),
            "seed_features",
            || "must be at least 64".into(),
        )
    }
}

/// The outcome for one pair.
#[derive(Clone, Debug)]
pub struct VerifiedPair {
    /// Image indices (into the feature list).
    pub i: usize,
    pub j: usize,
    /// Putative matches from descriptor matching.
    pub putative: Vec<Match>,
    pub geometry: TwoViewGeometry,
    /// Verified matches `(keypoint in i, keypoint in j)`, guided ones included.
    pub inliers: Vec<(u32, u32)>,
    /// How many of the inliers came from guided matching.
    pub guided_added: usize,
}

/// A serialisable summary of a verified pair (for manifests and benches).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PairSummary {
    pub i: usize,
    pub j: usize,
    pub putative: usize,
    pub inliers: usize,
    pub guided_added: usize,
    pub configuration: TwoViewConfiguration,
    pub view_distance_px: Option<f64>,
}

impl VerifiedPair {
    pub fn summary(&self) -> PairSummary {
        PairSummary {
            i: self.i,
            j: self.j,
            putative: self.putative.len(),
            inliers: self.inliers.len(),
            guided_added: self.guided_added,
            configuration: self.geometry.configuration,
            view_distance_px: self.geometry.view_distance_px,
        }
    }

    /// The same result with the two images swapped: `(j, i)`, Fᵀ, H⁻¹, every match reversed.
    pub fn transposed(self) -> Self {
        let mut geometry = self.geometry;
        geometry.f = geometry.f.map(|f| f.transpose());
        geometry.h = geometry.h.and_then(|h| h.try_inverse());
        Self {
            i: self.j,
            j: self.i,
            putative: self
                .putative
                .into_iter()
                .map(|m| Match {
                    i: m.j,
                    j: m.i,
                    distance: m.distance,
                })
                .collect(),
            geometry,
            inliers: self.inliers.into_iter().map(|(a, b)| (b, a)).collect(),
            guided_added: self.guided_added,
        }
    }
}

/// A key of an image's content (its keypoints and descriptors), the same whatever the file is
/// called. [`verify_pairs`] orders each pair by it, so that a pair is matched and verified the
/// same way, with the same random draws, under any naming or ordering of the files.
pub fn content_key(f: &Features) -> u64 {
    // FNV-1a over the keypoint positions and the first descriptor bytes.
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |b: u64| {
        for k in 0..8 {
            h ^= (b >> (8 * k)) & 0xff;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(f.keypoints.len() as u64);
    for kp in f.keypoints.iter().take(256) {
        eat(u64::from(kp.x.to_bits()) << 32 | u64::from(kp.y.to_bits()));
    }
    for &d in f.descriptors.data.iter().take(1024) {
        eat(u64::from(d.to_bits()));
    }
    h
}

fn point(f: &Features, k: u32) -> Vector2<f64> {
    let kp = &f.keypoints[k as usize];
    Vector2::new(kp.x as f64, kp.y as f64)
}

/// Euclidean distance, summed in eight independent lanes so the compiler can vectorise it.
fn dist(a: &[f32], b: &[f32]) -> f32 {
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
    // How well F fixes each line, from the matches it was estimated on (`existing`).
    let (x1, x2): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = existing
        .iter()
        .map(|&(a, b)| (point(f1, a), point(f2, b)))
        .unzip();
    let uncertainty = EpipolarUncertainty::new(f, &x1, &x2).ok();
    let d1 = &f1.descriptors;
    let d2 = &f2.descriptors;
    if d1.dim == 0
        || d1.dim != d2.dim
        || d1.len() != f1.keypoints.len()
        || d2.len() != f2.keypoints.len()
    {
        return Vec::new();
    }
    let mut used1 = vec![false; f1.keypoints.len()];
    let mut used2 = vec![false; f2.keypoints.len()];
    for &(a, b) in existing {
        used1[a as usize] = true;
        used2[b as usize] = true;
    }
    let grid = Grid::new(f2, 16.0);
    let mut cand = Vec::new();
    let mut best: Vec<(f32, u32, u32)> = Vec::new();
    // Visit the keypoints in the order of their epipolar lines across image 2, so consecutive
    // queries read the same cells and descriptors (cache locality; the result does not depend on
    // the order).
    let mut order: Vec<(bool, f64, u32)> = (0..f1.keypoints.len() as u32)
        .filter(|&a| !used1[a as usize])
        .map(|a| {
            let x1 = point(f1, a);
            let l = f * Vector3::new(x1.x, x1.y, 1.0);
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
        grid.near_line(&l, band, &mut cand);
        let (mut b1, mut s1, mut s2) = (u32::MAX, f32::INFINITY, f32::INFINITY);
        for &b in &cand {
            if off(&point(f2, b)) > band {
                continue;
            }
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
            grid.near_line(&l, rival_band, &mut wide);
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

/// Verifies one pair from its putative matches.
pub fn verify_pair(
    i: usize,
    j: usize,
    f1: &Features,
    f2: &Features,
    putative: Vec<Match>,
    opts: &PairVerificationOptions,
) -> VerifiedPair {
    let m: Vec<Match2d2d> = putative
        .iter()
        .map(|p| Match2d2d::new(point(f1, p.i), point(f2, p.j)))
        .collect();
    let t_ransac = std::time::Instant::now();
    let mut geometry = match estimate_two_view_geometry(&m, &opts.two_view) {
        Ok(g) => g,
        Err(e) => {
            tracing::warn!("pair ({i}, {j}): {e}");
            return VerifiedPair {
                i,
                j,
                putative,
                geometry: TwoViewGeometry::too_few(0),
                inliers: Vec::new(),
                guided_added: 0,
            };
        }
    };
    let mut inliers: Vec<(u32, u32)> = putative
        .iter()
        .zip(&geometry.inlier_mask)
        .filter(|(_, &k)| k)
        .map(|(p, _)| (p.i, p.j))
        .collect();
    let mut guided_added = 0;
    if opts.guided
        && geometry.configuration == TwoViewConfiguration::General
        && inliers.len() >= opts.guided_min_inliers
    {
        if let Some(fm) = geometry.f {
            let t_guided = std::time::Instant::now();
            let extra = guided_matches(f1, f2, &fm, &inliers, opts);
            tracing::trace!(
                "pair ({i}, {j}): RANSAC {:.3} s on {} matches, guided search {:.3} s",
                t_guided.duration_since(t_ransac).as_secs_f64(),
                m.len(),
                t_guided.elapsed().as_secs_f64()
            );
            if !extra.is_empty() {
                // Step 5: refine F on all correct matches and keep those it explains.
                let all: Vec<(u32, u32)> = inliers.iter().chain(&extra).copied().collect();
                let am: Vec<Match2d2d> = all
                    .iter()
                    .map(|&(a, b)| Match2d2d::new(point(f1, a), point(f2, b)))
                    .collect();
                let (f_ref, mask) = refine_two_view(&fm, &am, opts.two_view.f_threshold_px);
                let kept: Vec<(u32, u32)> = all
                    .iter()
                    .zip(&mask)
                    .filter(|(_, &k)| k)
                    .map(|(p, _)| *p)
                    .collect();
                if kept.len() >= inliers.len() {
                    guided_added = kept.len().saturating_sub(inliers.len());
                    inliers = kept;
                    geometry.f = Some(f_ref);
                    geometry.num_inliers = inliers.len();
                }
            }
        }
    }
    VerifiedPair {
        i,
        j,
        putative,
        geometry,
        inliers,
        guided_added,
    }
}

/// Indices of the `k` keypoints with the largest detector response, in index order.
fn strongest(f: &Features, k: usize) -> Vec<u32> {
    let mut idx: Vec<u32> = (0..f.keypoints.len() as u32).collect();
    if idx.len() > k {
        idx.select_nth_unstable_by(k, |&a, &b| {
            let (ra, rb) = (
                f.keypoints[a as usize].response,
                f.keypoints[b as usize].response,
            );
            rb.total_cmp(&ra).then(a.cmp(&b))
        });
        idx.truncate(k);
        idx.sort_unstable();
    }
    idx
}

fn select_rows(d: &Descriptors, idx: &[u32]) -> Descriptors {
    Descriptors {
        dim: d.dim,
        data: idx
            .iter()
            .flat_map(|&i| d.row(i as usize).iter().copied())
            .collect(),
    }
}

/// Steps 1–5 for one pair, seeded when [`PairVerificationOptions::seed_features`] says so.
pub fn match_and_verify(
    i: usize,
    j: usize,
    f1: &Features,
    f2: &Features,
    opts: &PairVerificationOptions,
) -> VerifiedPair {
    let Some(k) = opts.seed_features.filter(|_| opts.guided) else {
        let putative = match_descriptors(&f1.descriptors, &f2.descriptors, &opts.matching);
        return verify_pair(i, j, f1, f2, putative, opts);
    };
    // Seeds of k, then 4k, keypoints per image; the last level is whatever brute force over up to
    // 4k keypoints verifies (all keypoints when there are no more than that).
    let most = f1.descriptors.len().max(f2.descriptors.len());
    let levels = [k, 4 * k];
    let mut last = None;
    for &seeds in &levels {
        let t0 = std::time::Instant::now();
        let (s1, s2) = (strongest(f1, seeds), strongest(f2, seeds));
        let putative: Vec<Match> = match_descriptors(
            &select_rows(&f1.descriptors, &s1),
            &select_rows(&f2.descriptors, &s2),
            &opts.matching,
        )
        .into_iter()
        .map(|m| Match {
            i: s1[m.i as usize],
            j: s2[m.j as usize],
            distance: m.distance,
        })
        .collect();
        let t1 = t0.elapsed().as_secs_f64();
        let v = verify_pair(i, j, f1, f2, putative, opts);
        tracing::debug!(
            "pair ({i}, {j}): {seeds} seeds matched in {:.3} s, verification with guided matching {:.3} s, {} inliers ({} guided)",
            t1,
            t0.elapsed().as_secs_f64() - t1,
            v.inliers.len(),
            v.guided_added
        );
        if v.guided_added > 0 || seeds >= most {
            return v;
        }
        last = Some(v);
    }
    last.unwrap_or_else(|| {
        let putative = match_descriptors(&f1.descriptors, &f2.descriptors, &opts.matching);
        verify_pair(i, j, f1, f2, putative, opts)
    })
}

/// Matches and verifies every pair, in parallel, reporting progress per pair.
pub fn verify_pairs(
    features: &[Features],
    pairs: &[(usize, usize)],
    opts: &PairVerificationOptions,
    progress: &dyn Progress,
) -> Vec<VerifiedPair> {
    progress.start("matching pairs", pairs.len() as u64);
    let keys: Vec<u64> = features.par_iter().map(content_key).collect();
    let out = pairs
        .par_iter()
        .filter_map(|&(i, j)| {
            // Matched in the order of the images' content, not of their indices (file names).
            let swap = (keys.get(j)?, j) < (keys.get(i)?, i);
            let (a, b) = if swap { (j, i) } else { (i, j) };
            let (f1, f2) = (features.get(a)?, features.get(b)?);
            let v = match_and_verify(a, b, f1, f2, opts);
            progress.inc(1);
            Some(if swap { v.transposed() } else { v })
        })
        .collect();
    progress.finish();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::Keypoint;
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
            let p = Vector2::new(rng.random_range(0.0..seed_box), rng.random_range(0.0..seed_box));
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
