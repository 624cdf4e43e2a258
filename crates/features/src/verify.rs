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
use handheld_robust::{
    estimate_two_view_geometry, refine_two_view, Match2d2d, TwoViewConfiguration, TwoViewGeometry,
    TwoViewOptions,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::detector::{Descriptors, Features};
use crate::error::{check, FeatureError};
use crate::guided::line_shift;
use crate::guided::point;
pub use crate::guided::{guided_matches, GUIDED_RIVAL_BAND_FACTOR, GUIDED_STABLE_FRACTION};
use crate::matching::{
    distinct, match_descriptors, match_prepared, prepare, Match, MatchOptions, Prepared, TwinCache,
    Twins,
};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

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
    /// Rounds of guided matching and refinement of F (Table 1 steps 4–5) at most; they stop
    /// earlier once a round adds no verified match or the refined F hardly moves the lines
    /// ([`GUIDED_STABLE_FRACTION`]). Default 3. One round draws every epipolar line from the F of
    /// the RANSAC inliers alone, which on a pair with few of them is a rough F. Over six RANSAC
    /// seeds of the matching, templeSparseRing's AUC@1 rose on every one (mean 76.71 → 77.75);
    /// fountain-P11's matching took 5 % longer.
    #[serde(default = "default_guided_rounds")]
    pub guided_rounds: usize,
    /// Brute-force step 1 only over this many strongest keypoints per image, then guided matching
    /// over all of them (see the module notes); `None` matches all keypoints by brute force.
    /// Default `Some(2048)`. Needs `guided`.
    pub seed_features: Option<usize>,
    /// Keep a match only when it is nearer than both keypoints' twins, the nearest descriptors in
    /// their own images ([`crate::matching::Twins`]): a repeated pattern's copies then no longer
    /// pass as matches. Default true.
    #[serde(default = "yes")]
    pub twin_test: bool,
    /// Leave out a general pair whose inliers are a repeated pattern and its copy a period away
    /// ([`crate::copies`]): its F fits both and its relative pose is wrong. Default true.
    #[serde(default = "yes")]
    pub repeated_pattern_test: bool,
}

fn yes() -> bool {
    true
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
            guided_rounds: default_guided_rounds(),
            seed_features: Some(2048),
            twin_test: true,
            repeated_pattern_test: true,
        }
    }
}

fn default_guided_rounds() -> usize {
    3
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
        check(self.guided_rounds >= 1, "guided_rounds", || {
            "must be at least 1 (set `guided` to false for none)".into()
        })?;
        check(
            self.seed_features.is_none_or(|k| k >= 64),
            "seed_features",
            || "must be at least 64".into(),
        )
    }
}

/// The outcome for one pair (serialisable for the work units of a distributed run; use an exact
/// binary format: `gric_*` may be infinite and `sigma_px` NaN).
#[derive(Clone, Debug, Serialize, Deserialize)]
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
    /// Verified as general, then left out as a repeated pattern's copies ([`crate::copies`]).
    pub repeated_pattern: bool,
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
    #[serde(default)]
    pub repeated_pattern: bool,
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
            repeated_pattern: self.repeated_pattern,
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
            repeated_pattern: self.repeated_pattern,
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

/// The ratio of the twin test ([`distinct`]): a match must be nearer than every look-alike in
/// its keypoints' own images. Lowe's 0.8 took more right matches than copies: templeSparseRing's
/// repeated columns gave AUC@1 70.7 against 77.6 (fountain-P11 and herzjesu-P8 the same), and
/// the wallpaper orbit was right with either.
const TWIN_RATIO: f32 = 1.0;

/// Both images' twins ([`crate::matching::Twins`]), when the twin test runs.
pub type PairTwins<'a> = Option<(&'a Twins, &'a Twins)>;

/// Verifies one pair from its putative matches; with `twins`, from those nearer than both
/// keypoints' twins alone ([`distinct`]), and guided matches likewise.
pub fn verify_pair(
    i: usize,
    j: usize,
    f1: &Features,
    f2: &Features,
    putative: Vec<Match>,
    opts: &PairVerificationOptions,
    twins: PairTwins<'_>,
) -> VerifiedPair {
    let mut putative = putative;
    if let Some(t) = twins {
        putative.retain(|p| distinct(f1, f2, t, TWIN_RATIO, p.i, p.j));
    }
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
                repeated_pattern: false,
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
        if let Some(mut fm) = geometry.f {
            let t_guided = std::time::Instant::now();
            // The RANSAC inliers: every round searches from them, with lines drawn from the
            // latest F.
            let seeds = inliers.clone();
            // Steps 4 and 5, repeated while the refined F admits more (Hartley & Zisserman 2004,
            // Alg. 11.4 (v): "iterated until the number of correspondences is stable"). The
            // first F comes from the RANSAC inliers alone; refitted on every verified match it is
            // pinned by the whole set. Each round searches again from the RANSAC inliers, whose
            // spread bounds how well a line is known (`guided_matches`' rival band), so a later
            // round uses the first one's acceptance rules along better lines. Searching from the
            // grown set instead narrowed the bands it derives from that spread, and admitted
            // weaker matches: on monstree-phone every metric candidate then lost 16 % of its
            // observations in its adjustment.
            for _ in 0..opts.guided_rounds {
                let mut extra = guided_matches(f1, f2, &fm, &seeds, opts);
                if let Some(t) = twins {
                    extra.retain(|&(a, b)| distinct(f1, f2, t, TWIN_RATIO, a, b));
                }
                if extra.is_empty() {
                    break;
                }
                // Step 5: refine F on all correct matches and keep those it explains.
                let all: Vec<(u32, u32)> = seeds.iter().chain(&extra).copied().collect();
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
                if kept.len() < inliers.len() {
                    break;
                }
                let grew = kept.len() > inliers.len();
                // Only a round that added matches may be followed by another.
                let shift = if grew {
                    line_shift(&fm, &f_ref, f1, f2, &kept)
                } else {
                    0.0
                };
                tracing::trace!(
                    "pair ({i}, {j}): guided round: {} -> {} inliers ({} of the {} seeds), lines moved {shift:.3} px",
                    inliers.len(),
                    kept.len(),
                    mask.iter().take(seeds.len()).filter(|&&k| k).count(),
                    seeds.len()
                );
                inliers = kept;
                fm = f_ref;
                geometry.f = Some(f_ref);
                geometry.num_inliers = inliers.len();
                // Stable: the next round would search along lines within a small part of the
                // band of where this one searched.
                if !grew || shift < GUIDED_STABLE_FRACTION * opts.guided_max_epipolar_px {
                    break;
                }
            }
            guided_added = inliers.len().saturating_sub(seeds.len());
            tracing::trace!(
                "pair ({i}, {j}): RANSAC {:.3} s on {} matches, guided search {:.3} s",
                t_guided.duration_since(t_ransac).as_secs_f64(),
                m.len(),
                t_guided.elapsed().as_secs_f64()
            );
        }
    }
    let repeated_pattern = opts.repeated_pattern_test
        && geometry.configuration == TwoViewConfiguration::General
        && crate::copies::set_aside(i, j, f1, f2, &mut geometry, &mut inliers, &opts.two_view);
    VerifiedPair {
        i,
        j,
        putative,
        geometry,
        inliers,
        guided_added,
        repeated_pattern,
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
    let mut data = Vec::with_capacity(idx.len() * d.dim);
    for &i in idx {
        data.extend_from_slice(d.row(i as usize));
    }
    Descriptors { dim: d.dim, data }
}

/// The seeds of one image (the indices of its strongest keypoints) prepared for brute force.
struct SeedSet {
    idx: Vec<u32>,
    prepared: Prepared,
}

/// Every image's seeds of both levels, each selected and prepared ([`prepare`]: quantised and
/// packed) the first time a pair needs them and then shared by all its pairs: an image is in many
/// pairs, and preparing its seeds for each of them was a quarter of a low-texture set's matching
/// (most of its pairs end after the first level), and 7 % of monstree-phone's (12 MP, 8 192
/// keypoints: 182 of its 253 pairs reach the second level, each image in 16 of them). The second
/// level's sets (about 3 MB each at 8 192 keypoints) are kept within [`SECOND_LEVEL_BYTES`];
/// beyond it a pair prepares its own, as before.
struct SeedCache {
    k: usize,
    sets: Vec<[OnceLock<SeedSet>; 2]>,
    /// Bytes the second level's sets may still take.
    budget: AtomicUsize,
}

/// What [`SeedCache`]'s second-level sets may take in all.
const SECOND_LEVEL_BYTES: usize = 512 << 20;

impl SeedCache {
    fn new(images: usize, k: usize) -> Self {
        Self {
            k,
            sets: (0..images)
                .map(|_| [OnceLock::new(), OnceLock::new()])
                .collect(),
            budget: AtomicUsize::new(SECOND_LEVEL_BYTES),
        }
    }

    /// The `seeds` strongest keypoints of `image` prepared: `seeds` is the first level's `k` or
    /// the second's `4k`; `None` for any other, or when the second level's budget is spent.
    fn get(&self, seeds: usize, image: usize, f: &Features) -> Option<&SeedSet> {
        let level = [self.k, 4 * self.k].iter().position(|&s| s == seeds)?;
        let cell = &self.sets.get(image)?[level];
        if let Some(set) = cell.get() {
            return Some(set);
        }
        if level == 1 {
            // The quantised rows, their packed copy and (for the AVX-512 kernel) their row layout.
            let bytes = 3 * seeds.min(f.descriptors.len()) * f.descriptors.dim;
            self.budget
                .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |b| {
                    b.checked_sub(bytes)
                })
                .ok()?;
        }
        Some(cell.get_or_init(|| {
            let idx = strongest(f, seeds);
            let prepared = prepare(&select_rows(&f.descriptors, &idx));
            SeedSet { idx, prepared }
        }))
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
    let twins = opts.twin_test.then(|| (Twins::of(f1), Twins::of(f2)));
    let twins = twins.as_ref().map(|(a, b)| (a, b));
    match_and_verify_with(i, j, f1, f2, opts, None, twins)
}

/// [`match_and_verify`], with the seeds from `cache` where given (images `i`, `j`).
fn match_and_verify_with(
    i: usize,
    j: usize,
    f1: &Features,
    f2: &Features,
    opts: &PairVerificationOptions,
    cache: Option<&SeedCache>,
    twins: PairTwins<'_>,
) -> VerifiedPair {
    let Some(k) = opts.seed_features.filter(|_| opts.guided) else {
        let putative = match_descriptors(&f1.descriptors, &f2.descriptors, &opts.matching);
        return verify_pair(i, j, f1, f2, putative, opts, twins);
    };
    // Seeds of k, then 4k, keypoints per image; the last level is whatever brute force over up to
    // 4k keypoints verifies (all keypoints when there are no more than that).
    let most = f1.descriptors.len().max(f2.descriptors.len());
    let levels = [k, 4 * k];
    let mut last = None;
    for &seeds in &levels {
        let t0 = std::time::Instant::now();
        let cached = cache
            .and_then(|c| Some((c.get(seeds, i, f1)?, c.get(seeds, j, f2)?)))
            // Seeds quantised in one image and not in the other (descriptors outside [0, 1]) are
            // matched raw, both of them, by the path below.
            .filter(|(a, b)| a.prepared.alike(&b.prepared));
        let owned: (Vec<u32>, Vec<u32>);
        let (s1, s2, found): (&[u32], &[u32], Vec<Match>) = match cached {
            Some((a, b)) => (
                &a.idx,
                &b.idx,
                match_prepared(&a.prepared, &b.prepared, &opts.matching),
            ),
            None => {
                owned = (strongest(f1, seeds), strongest(f2, seeds));
                let found = match_descriptors(
                    &select_rows(&f1.descriptors, &owned.0),
                    &select_rows(&f2.descriptors, &owned.1),
                    &opts.matching,
                );
                (&owned.0, &owned.1, found)
            }
        };
        let putative: Vec<Match> = found
            .into_iter()
            .map(|m| Match {
                i: s1[m.i as usize],
                j: s2[m.j as usize],
                distance: m.distance,
            })
            .collect();
        let t1 = t0.elapsed().as_secs_f64();
        let v = verify_pair(i, j, f1, f2, putative, opts, twins);
        tracing::debug!(
            "pair ({i}, {j}): {seeds} seeds matched in {:.3} s, verification with guided matching {:.3} s, {} of {} putative matches verified ({} guided)",
            t1,
            t0.elapsed().as_secs_f64() - t1,
            v.inliers.len(),
            v.putative.len(),
            v.guided_added
        );
        if v.guided_added > 0 || seeds >= most {
            return v;
        }
        last = Some(v);
    }
    last.unwrap_or_else(|| {
        let putative = match_descriptors(&f1.descriptors, &f2.descriptors, &opts.matching);
        verify_pair(i, j, f1, f2, putative, opts, twins)
    })
}

/// Matches and verifies every pair, in parallel, reporting progress per pair.
pub fn verify_pairs(
    features: &[Features],
    pairs: &[(usize, usize)],
    opts: &PairVerificationOptions,
    progress: &dyn Progress,
) -> Vec<VerifiedPair> {
    let twins = TwinCache::new(features.len());
    verify_pairs_with(features, pairs, opts, &twins, progress)
}

/// [`verify_pairs`] with the images' twin distances kept in `twins` (for a caller that verifies
/// several lists of pairs over the same images).
pub fn verify_pairs_with(
    features: &[Features],
    pairs: &[(usize, usize)],
    opts: &PairVerificationOptions,
    twins: &TwinCache,
    progress: &dyn Progress,
) -> Vec<VerifiedPair> {
    progress.start("matching pairs", pairs.len() as u64);
    let keys: Vec<u64> = features.par_iter().map(content_key).collect();
    let twins = opts.twin_test.then_some(twins);
    if let Some(c) = twins {
        c.fill(features, pairs);
    }
    let cache = opts
        .seed_features
        .filter(|_| opts.guided)
        .map(|k| SeedCache::new(features.len(), k));
    let out = pairs
        .par_iter()
        .filter_map(|&(i, j)| {
            // Matched in the order of the images' content, not of their indices (file names).
            let swap = (keys.get(j)?, j) < (keys.get(i)?, i);
            let (a, b) = if swap { (j, i) } else { (i, j) };
            let (f1, f2) = (features.get(a)?, features.get(b)?);
            let t = match twins {
                Some(c) => Some((c.get(a, f1)?, c.get(b, f2)?)),
                None => None,
            };
            let v = match_and_verify_with(a, b, f1, f2, opts, cache.as_ref(), t);
            progress.inc(1);
            Some(if swap { v.transposed() } else { v })
        })
        .collect();
    progress.finish();
    out
}
