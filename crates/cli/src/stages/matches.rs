//! The matches stage: choose the pairs (exhaustive for small sets, a sequential window for video and
//! long sequences), match and verify them (Table 1), and write everything into COLMAP's
//! `matches/database.db` plus a `pairs.json` summary.

use anyhow::{Context, Result};
use handheld_features::close_views::{propose_close_views, CloseViewOptions};
use handheld_features::matching::{exhaustive_pairs, sequential_pairs};
use handheld_features::verify::{verify_pairs, PairVerificationOptions, VerifiedPair};
use handheld_features::video::{keyframe_pairs, VideoTrackingOptions};
use handheld_features::{Descriptors, Features, Keypoint};
use handheld_io::database::{Database, StoredTwoViewGeometry, TwoViewConfig};
use handheld_io::features_file::read_features;
use handheld_io::ingest::InputKind;
use handheld_io::workspace::{Fingerprint, Workspace};
use handheld_robust::TwoViewConfiguration;
use serde::{Deserialize, Serialize};

use crate::args::{InputArgs, PairMode};
use crate::pipeline::{run_stage, Stage, StageOutput, StageReport};
use crate::stages::features::feature_file_name;
use crate::ui::Bars;

/// Options of the matches stage.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MatchStageOptions {
    pub pairs: PairMode,
    /// Neighbours on each side for sequential matching.
    pub window: usize,
    /// Ratio test of the putative matcher.
    pub ratio: f32,
    pub guided: bool,
    /// Brute force over this many strongest features per image, then guided matching over all.
    pub seed_features: Option<usize>,
    /// With sequential matching, also propose and verify close views outside the window (§3.2).
    pub close_views: bool,
}

pub fn options(a: &InputArgs) -> Result<MatchStageOptions> {
    if !(a.ratio > 0.0 && a.ratio <= 1.0) {
        anyhow::bail!("--ratio must be in (0, 1], got {}", a.ratio);
    }
    if a.seed_features > 0 && a.seed_features < 64 {
        anyhow::bail!(
            "--seed-features must be 0 (brute force over all) or at least 64, got {}",
            a.seed_features
        );
    }
    Ok(MatchStageOptions {
        pairs: a.pairs,
        window: a.window,
        ratio: a.ratio,
        guided: !a.no_guided,
        seed_features: (a.seed_features > 0).then_some(a.seed_features),
        close_views: !a.no_close_views,
    })
}

fn verification_options(o: &MatchStageOptions) -> PairVerificationOptions {
    let mut v = PairVerificationOptions {
        guided: o.guided,
        seed_features: o.seed_features,
        ..Default::default()
    };
    v.matching.ratio = o.ratio;
    v
}

fn to_features(f: handheld_io::features_file::FeatureFile) -> Features {
    Features {
        keypoints: f
            .keypoints
            .iter()
            .map(|k| Keypoint {
                x: k[0],
                y: k[1],
                scale: k[2],
                orientation: k[3],
                response: k[4],
            })
            .collect(),
        descriptors: Descriptors {
            dim: f.dim,
            data: f.descriptors,
        },
    }
}

fn colmap_config(c: TwoViewConfiguration) -> i64 {
    (match c {
        TwoViewConfiguration::General => TwoViewConfig::Uncalibrated,
        TwoViewConfiguration::Planar => TwoViewConfig::PlanarOrPanoramic,
        TwoViewConfiguration::PureRotation => TwoViewConfig::Panoramic,
        TwoViewConfiguration::TooFewInliers => TwoViewConfig::Degenerate,
    }) as i64
}

pub fn run(
    ws: &Workspace,
    opts: &MatchStageOptions,
    force: bool,
    bars: &Bars,
) -> Result<StageReport> {
    let ingest = super::load_ingest(ws)?;
    let n = ingest.images.len();
    let sequential = match (opts.pairs, ingest.kind) {
        (PairMode::Exhaustive, _) => false,
        (PairMode::Sequential, _) | (PairMode::Auto, InputKind::Video) => true,
        (PairMode::Auto, InputKind::Photos) => n > 40,
    };
    run_stage(
        ws,
        Stage::Matches,
        Fingerprint::new(),
        serde_json::to_value(opts)?,
        force,
        |dir| {
            let fdir = ws.root.join(Stage::Features.dir_name());
            let features: Vec<Features> = (0..n)
                .map(|k| read_features(&fdir.join(feature_file_name(k))).map(to_features))
                .collect::<std::result::Result<_, _>>()
                .context("reading features (rerun the features stage with --force)")?;
            if let Some(tracks) = super::tracks::load_tracks(ws)? {
                // Video: key-frame pairs from the KLT tracks (§3.1).
                let verified = keyframe_pairs(
                    &tracks,
                    &VideoTrackingOptions::default(),
                    &verification_options(opts),
                    bars,
                );
                return finish(dir, &ingest, &features, &verified, verified.len(), 0, opts);
            }
            let mut pairs = if sequential {
                sequential_pairs(n, opts.window)
            } else {
                exhaustive_pairs(n)
            };
            let mut proposed = 0;
            if sequential && opts.close_views {
                let extra =
                    propose_close_views(&features, opts.window, &CloseViewOptions::default());
                proposed = extra.len();
                pairs.extend(extra);
            }
            let verified = verify_pairs(&features, &pairs, &verification_options(opts), bars);
            finish(
                dir,
                &ingest,
                &features,
                &verified,
                pairs.len(),
                proposed,
                opts,
            )
        },
    )
}

/// Writes the database and `pairs.json`, and summarises the verified pairs.
fn finish(
    dir: &std::path::Path,
    ingest: &handheld_io::ingest::IngestResult,
    features: &[Features],
    verified: &[VerifiedPair],
    num_pairs: usize,
    proposed: usize,
    opts: &MatchStageOptions,
) -> Result<StageOutput> {
    write_database(&dir.join("database.db"), ingest, features, verified)?;
    let summaries: Vec<_> = verified.iter().map(VerifiedPair::summary).collect();
    handheld_io::atomic::write_bytes_atomic(
        &dir.join("pairs.json"),
        &serde_json::to_vec_pretty(&summaries)?,
    )?;
    let good = summaries
        .iter()
        .filter(|s| s.configuration == TwoViewConfiguration::General)
        .count();
    let mut inl: Vec<usize> = summaries
        .iter()
        .filter(|s| s.configuration != TwoViewConfiguration::TooFewInliers)
        .map(|s| s.inliers)
        .collect();
    inl.sort_unstable();
    Ok(StageOutput {
        outputs: vec!["database.db".into(), "pairs.json".into()],
        summary: serde_json::json!({
            "pairs": num_pairs,
            "close_view_pairs_proposed": proposed,
            "close_view_pairs_verified": verified.iter().filter(|v| proposed > 0 && v.j > v.i + opts.window && v.geometry.configuration == TwoViewConfiguration::General).count(),
            "verified_general": good,
            "verified_planar_or_rotation": summaries.iter().filter(|s| matches!(s.configuration, TwoViewConfiguration::Planar | TwoViewConfiguration::PureRotation)).count(),
            "inliers_per_verified_pair_median": inl.get(inl.len() / 2),
        }),
    })
}

fn write_database(
    path: &std::path::Path,
    ingest: &handheld_io::ingest::IngestResult,
    features: &[Features],
    verified: &[VerifiedPair],
) -> Result<()> {
    let db = Database::create(path)?;
    // One SIMPLE_RADIAL camera per physical camera / zoom (EXIF), with a focal guess or EXIF prior.
    let mut cams: std::collections::HashMap<String, u32> = Default::default();
    let mut ids = Vec::with_capacity(ingest.images.len());
    for img in &ingest.images {
        let key = format!(
            "{}|{}x{}",
            img.info.exif.camera_key(),
            img.info.width,
            img.info.height
        );
        let cam = match cams.get(&key) {
            Some(&c) => c,
            None => {
                let (w, h) = (img.info.width as f64, img.info.height as f64);
                let f = img.info.focal_prior_px.unwrap_or(1.2 * w.max(h));
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
