//! The matches stage: choose the pairs ([`PairMode`]: exhaustive for small sets, a sequential
//! window plus §3.2's close views for video and long sequences, or image retrieval), match and
//! verify them (Table 1),
//! and write everything into COLMAP's `matches/database.db` plus `pairs.json`. Video workspaces
//! verify key-frame pairs from their shared KLT tracks (§3.1).

use std::collections::HashMap;
use std::path::Path;

use handheld_features::close_views::{propose_close_views, CloseViewOptions};
use handheld_features::matching::{exhaustive_pairs, sequential_pairs, TwinCache};
use handheld_features::retrieval::{retrieval_pairs, unordered_pairs, RetrievalOptions};
use handheld_features::second_round::weak_image_pairs;
use handheld_features::verify::{
    verify_pairs, verify_pairs_with, PairVerificationOptions, VerifiedPair,
};
use handheld_features::video::{keyframe_pairs, VideoTrackingOptions};
use handheld_features::Features;
use handheld_io::database::{Database, StoredTwoViewGeometry, TwoViewConfig};
use handheld_io::ingest::{IngestResult, InputKind};
use handheld_robust::TwoViewConfiguration;
use serde::{Deserialize, Serialize};

use crate::error::{PipelineError, Result};
use crate::files::{stage, write_json, DATABASE, PAIRS_JSON};
use crate::policy::{camera_key, focal_guess_px, PairMode, PairPlan};
use crate::stage::{Produced, Stage, StageContext};
use crate::stages::features::from_file;

/// Options of the matches stage.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct MatchesStageOptions {
    pub pairs: PairMode,
    /// Neighbours on each side for sequential matching.
    pub window: usize,
    /// With sequential matching, also propose and verify close views outside the window (§3.2).
    pub close_views: bool,
    /// Retrieval: the most similar images each image is matched with.
    pub retrieval: RetrievalOptions,
    /// With retrieval or the unordered photo pairs: after the first round, an image that verified
    /// fewer pairs than `window` is matched with every other image ([`weak_image_pairs`]).
    pub second_round: bool,
    /// Putative matching, guided matching and two-view verification (Table 1).
    pub verification: PairVerificationOptions,
}

impl Default for MatchesStageOptions {
    fn default() -> Self {
        Self {
            pairs: PairMode::Auto,
            window: 8,
            close_views: true,
            retrieval: RetrievalOptions::default(),
            second_round: true,
            verification: PairVerificationOptions::default(),
        }
    }
}

/// The fewest seed features that still give a usable first estimate of F.
pub const MIN_SEED_FEATURES: usize = 64;

impl MatchesStageOptions {
    pub fn validate(&self) -> Result<()> {
        let ratio = self.verification.matching.ratio;
        if !(ratio > 0.0 && ratio <= 1.0) {
            return Err(PipelineError::option(
                "--ratio",
                format!("must be in (0, 1], got {ratio}"),
            ));
        }
        if let Some(s) = self.verification.seed_features {
            if s < MIN_SEED_FEATURES {
                return Err(PipelineError::option(
                    "--seed-features",
                    format!(
                        "must be 0 (brute force over all) or at least {MIN_SEED_FEATURES}, got {s}"
                    ),
                ));
            }
        }
        if self.window == 0 {
            return Err(PipelineError::option("--window", "must be at least 1"));
        }
        if self.retrieval.neighbours == 0 {
            return Err(PipelineError::option("--neighbours", "must be at least 1"));
        }
        self.retrieval
            .validate()
            .map_err(|e| PipelineError::invalid(stage::MATCHES, e))?;
        self.verification
            .validate()
            .map_err(|e| PipelineError::invalid(stage::MATCHES, e))
    }
}

/// What the matches stage verified.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MatchesSummary {
    pub pairs: usize,
    pub close_view_pairs_proposed: usize,
    pub close_view_pairs_verified: usize,
    pub verified_general: usize,
    pub verified_planar_or_rotation: usize,
    pub inliers_per_verified_pair_median: Option<usize>,
    /// Pairs of the second round (the images that verified few pairs, with every other image),
    /// and how many of them verified; both included above.
    #[serde(default)]
    pub second_round_pairs: usize,
    #[serde(default)]
    pub second_round_verified: usize,
    /// Pairs verified as general and then left out: their inliers were a repeated pattern and its
    /// copy ([`handheld_features::copies`]).
    #[serde(default)]
    pub repeated_pattern_pairs: usize,
}

/// The matches stage.
pub struct Matches {
    pub options: MatchesStageOptions,
}

impl Stage for Matches {
    type Options = MatchesStageOptions;
    type Summary = MatchesSummary;

    const NAME: &'static str = stage::MATCHES;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::FEATURES];
    const ABOUT: &'static str =
        "match image pairs and verify them (Table 1); writes COLMAP's database.db";

    fn options(&self) -> &MatchesStageOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    fn units(&self, ctx: &StageContext) -> Result<usize> {
        let ws = ctx.ws;
        if ws.read_tracks()?.is_some() {
            return Ok(0);
        }
        let ingest = ws.read_ingest()?;
        let features = read_all_features(ctx, ingest.images.len())?;
        let plan = self.pair_list(&ingest, &features)?;
        let n = plan.pairs.len().div_ceil(PAIRS_PER_UNIT);
        // The pair list is written once, so that the units and the stage need no retrieval again.
        if let Some(units) = &ctx.units {
            let bytes = postcard::to_stdvec(&plan).map_err(|e| {
                PipelineError::Graph(format!("matches: the pair plan does not serialise: {e}"))
            })?;
            handheld_io::atomic::write_bytes_atomic(&units.join(PLAN_FILE), &bytes)?;
        }
        Ok(n)
    }

    fn run_unit(
        &self,
        ctx: &StageContext,
        dir: &Path,
        k: usize,
    ) -> Result<(Vec<String>, serde_json::Value)> {
        let ws = ctx.ws;
        let ingest = ws.read_ingest()?;
        let n = ingest.images.len();
        let plan = match read_plan(ctx) {
            Some(p) => p,
            None => self.pair_list(&ingest, &read_all_features(ctx, n)?)?,
        };
        let Some(block) = plan.pairs.chunks(PAIRS_PER_UNIT).nth(k) else {
            return Err(PipelineError::Graph(format!(
                "matches: no unit {k} ({} pairs in units of {PAIRS_PER_UNIT})",
                plan.pairs.len()
            )));
        };
        // Only the images of this block's pairs are read; the others stay empty.
        let mut needed = vec![false; n];
        for &(i, j) in block {
            needed[i] = true;
            needed[j] = true;
        }
        let features: Vec<Features> = (0..n)
            .map(|i| {
                if needed[i] {
                    ws.read_features(i).map(from_file)
                } else {
                    Ok(Features::default())
                }
            })
            .collect::<Result<_>>()?;
        let verification = self.verification(&ingest);
        let verified = verify_pairs(&features, block, &verification, ctx.progress);
        let name = block_file(k);
        write_block(&dir.join(&name), &verified)?;
        Ok((vec![name], serde_json::json!({ "pairs": verified.len() })))
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<MatchesSummary>> {
        let opts = &self.options;
        let ws = ctx.ws;
        let ingest = ws.read_ingest()?;
        let n = ingest.images.len();
        let features = read_all_features(ctx, n)?;
        if let Some(tracks) = ws.read_tracks()? {
            // Video: key-frame pairs from the KLT tracks (§3.1).
            let verified = keyframe_pairs(
                &tracks,
                &VideoTrackingOptions::default(),
                &opts.verification,
                ctx.progress,
            );
            return finish(dir, &ingest, &features, &verified, verified.len(), 0, opts);
        }
        let plan = match read_plan(ctx) {
            Some(p) => p,
            None => self.pair_list(&ingest, &features)?,
        };
        // Blocks verified apart (work units) are taken; the rest is verified here, in one call.
        let mut blocks: Vec<Option<Vec<VerifiedPair>>> = Vec::new();
        for (k, _) in plan.pairs.chunks(PAIRS_PER_UNIT).enumerate() {
            let name = block_file(k);
            blocks.push(match ctx.take_unit(k, std::slice::from_ref(&name), dir)? {
                Some(_) => crate::stage::read_unit_outcome(&dir.join(&name)),
                None => None,
            });
        }
        let missing: Vec<(usize, usize)> = plan
            .pairs
            .chunks(PAIRS_PER_UNIT)
            .zip(&blocks)
            .filter(|(_, b)| b.is_none())
            .flat_map(|(p, _)| p.iter().copied())
            .collect();
        // Each image's twin distances, computed once for both rounds.
        let twins = TwinCache::new(n);
        let verification = self.verification(&ingest);
        let mut computed =
            verify_pairs_with(&features, &missing, &verification, &twins, ctx.progress).into_iter();
        let mut verified = Vec::with_capacity(plan.pairs.len());
        for (pairs, block) in plan.pairs.chunks(PAIRS_PER_UNIT).zip(blocks) {
            match block {
                Some(b) => verified.extend(b),
                None => verified.extend(computed.by_ref().take(pairs.len())),
            }
        }
        // The second round runs here, on the first round's result (not in work units).
        let extra = self.second_round(ingest.kind, n, &plan, &verified);
        let more = verify_pairs_with(&features, &extra, &verification, &twins, ctx.progress);
        let found = more
            .iter()
            .filter(|v| v.geometry.configuration != TwoViewConfiguration::TooFewInliers)
            .count();
        if !extra.is_empty() {
            tracing::info!(
                "second round: {} more pairs (images that verified fewer than {} pairs, each with every other image), {found} verified",
                extra.len(),
                opts.window
            );
        }
        verified.extend(more);
        let mut produced = finish(
            dir,
            &ingest,
            &features,
            &verified,
            plan.pairs.len() + extra.len(),
            plan.proposed,
            opts,
        )?;
        produced.summary.second_round_pairs = extra.len();
        produced.summary.second_round_verified = found;
        Ok(produced)
    }
}

/// Pairs per work unit of a distributed run.
pub const PAIRS_PER_UNIT: usize = 16;
/// The pair list, in the stage's unit folder.
const PLAN_FILE: &str = "pairs.plan";

/// The pairs to verify, and how many of them are §3.2's proposed close views.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct PairList {
    pairs: Vec<(usize, usize)>,
    proposed: usize,
}

impl Matches {
    /// The second round's pairs ([`weak_image_pairs`]) after the first round `verified` the
    /// `plan`: only for retrieval and auto's larger photo sets, at most as many pairs as the first
    /// round (matching costs at most twice as much) but always room for one whole row.
    fn second_round(
        &self,
        kind: InputKind,
        n: usize,
        plan: &PairList,
        verified: &[VerifiedPair],
    ) -> Vec<(usize, usize)> {
        let opts = &self.options;
        if !opts.second_round
            || !matches!(
                opts.pairs.plan(kind, n),
                PairPlan::Unordered | PairPlan::Retrieval
            )
        {
            return Vec::new();
        }
        let links: Vec<(usize, usize)> = verified
            .iter()
            .filter(|v| v.geometry.configuration != TwoViewConfiguration::TooFewInliers)
            .map(|v| (v.i, v.j))
            .collect();
        let budget = plan.pairs.len().max(n.saturating_sub(1));
        let round = weak_image_pairs(n, &links, &plan.pairs, opts.window, budget);
        if round.left_out > 0 {
            tracing::info!(
                "second round: {} image(s) that verified fewer than {} pairs were not matched with every other image (the round stops at as many pairs as the first, or one image's row)",
                round.left_out,
                opts.window
            );
        }
        round.pairs
    }

    /// The verification options for this input ([`PairPlan::tests_repeated_patterns`]).
    fn verification(&self, ingest: &IngestResult) -> PairVerificationOptions {
        let plan = self.options.pairs.plan(ingest.kind, ingest.images.len());
        let mut v = self.options.verification.clone();
        v.repeated_pattern_test &= plan.tests_repeated_patterns();
        v
    }

    /// The pairs to verify ([`PairMode`]): a pure function of the options and the features.
    fn pair_list(&self, ingest: &IngestResult, features: &[Features]) -> Result<PairList> {
        let opts = &self.options;
        let n = ingest.images.len();
        let plan = opts.pairs.plan(ingest.kind, n);
        let mut pairs = match plan {
            PairPlan::Sequential => sequential_pairs(n, opts.window),
            PairPlan::Exhaustive => exhaustive_pairs(n),
            PairPlan::Unordered => {
                let p = unordered_pairs(features, opts.window, &opts.retrieval)
                    .map_err(|e| PipelineError::invalid(stage::MATCHES, e))?;
                tracing::info!(
                    "{} pairs of {} photos: a window of {} over the order their content gives, and the {} most similar images of each",
                    p.len(),
                    n,
                    opts.window,
                    opts.retrieval.neighbours
                );
                p
            }
            PairPlan::Retrieval => {
                let p = retrieval_pairs(features, &opts.retrieval)
                    .map_err(|e| PipelineError::invalid(stage::MATCHES, e))?;
                tracing::info!(
                    "retrieval: {} pairs of {} images ({} most similar each)",
                    p.len(),
                    n,
                    opts.retrieval.neighbours
                );
                p
            }
        };
        let mut proposed = 0;
        if plan == PairPlan::Sequential && opts.close_views {
            let extra = propose_close_views(features, opts.window, &CloseViewOptions::default());
            proposed = extra.len();
            pairs.extend(extra);
        }
        Ok(PairList { pairs, proposed })
    }
}

fn read_all_features(ctx: &StageContext, n: usize) -> Result<Vec<Features>> {
    (0..n)
        .map(|k| ctx.ws.read_features(k).map(from_file))
        .collect()
}

/// The pair list the driver wrote into the unit folder, if any. One that cannot be read or
/// decoded (another version's driver) is made again here, with a warning naming the file: the
/// pair list is a function of the images and the options, so both sides make the same one.
fn read_plan(ctx: &StageContext) -> Option<PairList> {
    let path = ctx.units.as_ref()?.join(PLAN_FILE);
    let bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
        Err(e) => {
            tracing::warn!(
                "{}: the pair list cannot be read ({e}): it is made again here",
                path.display()
            );
            return None;
        }
    };
    match postcard::from_bytes(&bytes) {
        Ok(plan) => Some(plan),
        Err(e) => {
            tracing::warn!(
                "{}: a pair list that does not decode ({e}; written by another version of Handheld?): it is made again here",
                path.display()
            );
            None
        }
    }
}

fn block_file(k: usize) -> String {
    format!("block-{k}.bin")
}

/// A block of verified pairs, in an exact binary form (postcard: infinities and NaN survive).
fn write_block(path: &Path, verified: &[VerifiedPair]) -> Result<()> {
    let bytes = postcard::to_stdvec(verified).map_err(|e| {
        PipelineError::workspace(path, format!("cannot encode verified pairs: {e}"))
    })?;
    handheld_io::atomic::write_bytes_atomic(path, &bytes)?;
    Ok(())
}

/// Writes the database and `pairs.json`, and summarises the verified pairs.
fn finish(
    dir: &Path,
    ingest: &IngestResult,
    features: &[Features],
    verified: &[VerifiedPair],
    num_pairs: usize,
    proposed: usize,
    opts: &MatchesStageOptions,
) -> Result<Produced<MatchesSummary>> {
    write_database(&dir.join(DATABASE), ingest, features, verified)?;
    let summaries: Vec<_> = verified.iter().map(VerifiedPair::summary).collect();
    write_json(&dir.join(PAIRS_JSON), &summaries)?;
    let mut inl: Vec<usize> = summaries
        .iter()
        .filter(|s| s.configuration != TwoViewConfiguration::TooFewInliers)
        .map(|s| s.inliers)
        .collect();
    inl.sort_unstable();
    let close_verified = verified
        .iter()
        .filter(|v| {
            proposed > 0
                && v.j > v.i + opts.window
                && v.geometry.configuration == TwoViewConfiguration::General
        })
        .count();
    Ok(Produced::new(
        vec![DATABASE.into(), PAIRS_JSON.into()],
        MatchesSummary {
            pairs: num_pairs,
            close_view_pairs_proposed: proposed,
            close_view_pairs_verified: close_verified,
            verified_general: summaries
                .iter()
                .filter(|s| s.configuration == TwoViewConfiguration::General)
                .count(),
            verified_planar_or_rotation: summaries
                .iter()
                .filter(|s| {
                    matches!(
                        s.configuration,
                        TwoViewConfiguration::Planar | TwoViewConfiguration::PureRotation
                    )
                })
                .count(),
            inliers_per_verified_pair_median: inl.get(inl.len() / 2).copied(),
            second_round_pairs: 0,
            second_round_verified: 0,
            repeated_pattern_pairs: verified.iter().filter(|v| v.repeated_pattern).count(),
        },
    ))
}

/// COLMAP's two-view configuration code.
fn colmap_config(c: TwoViewConfiguration) -> i64 {
    (match c {
        TwoViewConfiguration::General => TwoViewConfig::Uncalibrated,
        TwoViewConfiguration::Planar => TwoViewConfig::PlanarOrPanoramic,
        TwoViewConfiguration::PureRotation => TwoViewConfig::Panoramic,
        TwoViewConfiguration::TooFewInliers => TwoViewConfig::Degenerate,
    }) as i64
}

fn write_database(
    path: &Path,
    ingest: &IngestResult,
    features: &[Features],
    verified: &[VerifiedPair],
) -> Result<()> {
    let db = Database::create(path)?;
    // One SIMPLE_RADIAL camera per physical camera / zoom (EXIF), with a focal guess or EXIF prior.
    let mut cams: HashMap<String, u32> = HashMap::new();
    let mut ids = Vec::with_capacity(ingest.images.len());
    for img in &ingest.images {
        let key = camera_key(&img.info);
        let cam = match cams.get(&key) {
            Some(&c) => c,
            None => {
                let (w, h) = (f64::from(img.info.width), f64::from(img.info.height));
                let f = img
                    .info
                    .focal_prior_px
                    .unwrap_or_else(|| focal_guess_px(img.info.width, img.info.height));
                let c = db.add_camera(
                    2,
                    img.info.width,
                    img.info.height,
                    &[f, w / 2.0, h / 2.0, 0.0],
                    img.info.focal_prior_px.is_some(),
                )?;
                cams.insert(key, c);
                c
            }
        };
        ids.push(db.add_image(&img.info.name, cam)?);
    }
    for (k, f) in features.iter().enumerate() {
        let kps: Vec<[f32; 4]> = f
            .keypoints
            .iter()
            .map(|p| [p.x, p.y, p.scale, p.orientation])
            .collect();
        db.write_keypoints(ids[k], &kps)?;
        db.write_descriptors(ids[k], f.descriptors.dim, &f.descriptors.data)?;
    }
    for v in verified {
        let putative: Vec<(u32, u32)> = v.putative.iter().map(|m| (m.i, m.j)).collect();
        db.write_matches(ids[v.i], ids[v.j], &putative)?;
        let g = StoredTwoViewGeometry {
            config: colmap_config(v.geometry.configuration),
            inliers: v.inliers.clone(),
            f: v.geometry.f,
            h: v.geometry.h,
        };
        db.write_two_view_geometry(ids[v.i], ids[v.j], &g)?;
    }
    db.finish()?;
    Ok(())
}
