//! Whether every registered view agrees with its own verified image pairs.
//!
//! A view can be registered to the wrong place and still fit: resection against a repeated
//! structure, or a partner's points seen from the far side of an object, gives a pose whose few
//! observations reproject well, and every check on the adjustment (removed observations,
//! reprojection error, focal length) passes. The view's verified pairs still carry the truth: the
//! fundamental matrix of each pair, with the model's calibration, is an essential matrix
//! `E = K_bᵀ F K_a` (H&Z eq. 9.12), whose rotation (H&Z §9.6.2, the one of four that puts the
//! inliers in front of both cameras) is the pair's relative rotation, found without the model.
//! A sound view agrees with its partners to a degree or two (the model's calibration is not exact
//! and a two-view rotation is noisy); a misplaced view disagrees with nearly all of them by much
//! more.
//!
//! A view is flagged when the median of its disagreements over its partners, weighted by their
//! inlier counts, exceeds [`MAX_DISAGREEMENT_DEG`]. A misplaced view also raises its partners'
//! medians, so views are judged one at a time: the one with the largest share of disagreeing
//! inliers first (a misplaced view has all of its pairs against it, a partner only the one pair
//! with it); its pairs are then set aside and the others judged again.
//!
//! A pair's two-view rotation is not always the better witness: under a long lens it is fixed
//! only along some axes, and wrong matches within its epipolar tolerance can move it by degrees to
//! tens of degrees. Where the model's points hold most of the pair's matches (reprojecting onto
//! both), most of those off its dominant plane too, and enough of them are seen by a third view as
//! well, the model's relative pose is confirmed by more than two views, and the pair allows what it
//! shows ([`held_by_structure`], [`exempt_held`]): only inside the largest piece that agreeing or
//! held pairs join, since a group of views misplaced together holds its own pairs through one
//! another.
//!
//! A repeated texture makes wrong general pairs too, with confident rotations: on a phone-like
//! video of a patterned wallpaper, the general pairs of a few early frames matched the motif to
//! its copies a lattice vector away (more than half of even the RANSAC seeds a pixel or more off
//! the true epipolar lines), and their rotations were 7–12° off with standard deviations of 0.1°;
//! four frames, right to 0.02°, were taken out. Their rotation-only pairs with their neighbours
//! (no usable `F`, a short baseline over which copies lie far apart) were right. Such a pair
//! confirms the model's relative pose when the pose carries most of its matches through one plane
//! (`rotation_only.rs`); it never counts against it.
//!
//! What is done with a flagged view is the pipeline's (`pipeline/model.rs`): the model is built
//! again without it, the view registered into the sound model by calibrated resection and judged
//! once more, and one that still disagrees is taken out ([`take_out`]). A merge is also checked
//! across its two pieces ([`across`]): each piece agrees with its own pairs even when the two are
//! put together at the wrong angle.

use std::collections::{BTreeMap, BTreeSet};

use handheld_core::{ImageId, MetricReconstruction};
use handheld_robust::TwoViewConfiguration;
use nalgebra::Vector2;
use serde::Serialize;

use crate::context::Context;
use crate::metric::ba::{self as metric_ba, MetricBaRecord};
use crate::metric::pair_rotation;
use crate::upgrade::guard;

/// Largest weighted-median disagreement (degrees) between a view's relative rotations in the model
/// and those of its verified pairs. Sound views on the project's data sets stay within 1.8°
/// (templeSparseRing, whose ring turns 23° between neighbours) and within 0.3° on the Strecha and
/// KITTI sets; a view registered to the wrong side of templeSparseRing disagreed by 13–24° with
/// every partner.
pub const MAX_DISAGREEMENT_DEG: f64 = 5.0;
/// Fewest inlier matches of a pair whose rotation is trusted.
pub const MIN_PAIR_INLIERS: usize = 30;

/// One view's agreement with its verified pairs.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct ViewDisagreement {
    pub image: String,
    /// Weighted median over its partners, degrees.
    pub median_deg: f64,
    /// Weighted median of what its pairs allow: [`MAX_DISAGREEMENT_DEG`] widened by each pair's
    /// rotation uncertainty ([`SIGMAS`] standard deviations), degrees.
    pub allowed_deg: f64,
    /// Partners compared (registered, general configuration, enough inliers).
    pub partners: usize,
}

/// The check's result for the summary.
#[derive(Clone, Debug, Default, Serialize, serde::Deserialize)]
pub struct ConsistencyReport {
    /// The largest weighted-median disagreement among the views kept, degrees.
    pub max_kept_deg: Option<f64>,
    /// Views taken out of the model because their pose disagreed with their pairs.
    pub removed: Vec<ViewDisagreement>,
    /// Views whose first registration disagreed with their pairs: the model was built again
    /// without them, then they were registered into it by calibrated resection where possible
    /// (and judged again).
    pub rebuilt_without: Vec<ViewDisagreement>,
    /// Views kept whose every checkable pair is with a view taken out ([`unconfirmed`]): nothing
    /// confirms their poses, which were found beside misplaced views.
    #[serde(default)]
    pub unconfirmed: Vec<String>,
}

impl ConsistencyReport {
    /// How many views were first placed where their own verified pairs disagree (taken out, or
    /// the model built again without them), when they outnumber the `registered` views the model
    /// kept; `None` otherwise. The kept views were placed by the same resections from the same
    /// matches: when those failed on most views, agreeing with one another says little (a
    /// synthetic hemisphere at 11°, seed 0: 29 views taken out, and 18 of the 19 kept were wrong
    /// too, each agreeing with its remaining pairs). No set of `scripts/regress_sparse.sh` comes
    /// near (dinoSparseRing: 2 of 6).
    pub fn misplaced_majority(&self, registered: usize) -> Option<usize> {
        let names: BTreeSet<&str> = self
            .removed
            .iter()
            .chain(&self.rebuilt_without)
            .map(|d| d.image.as_str())
            .collect();
        (names.len() > registered).then_some(names.len())
    }
}

/// The registered views of `rec` that no usable pair (general, enough inliers) ties to the rest of
/// the model once the views of `removed` are gone, and that were registered beside them: the kept
/// views joined by usable pairs fall into pieces, and every piece but the largest that has a
/// verified pair with a removed view is unconfirmed. Such views were placed beside misplaced views,
/// often through their points, and nothing confirms them once those are gone.
///
/// A piece may hold one view (the first case seen: a synthetic hemisphere at an 11° field of view
/// kept one 50° off this way, silently) or several that agree with one another: the same
/// hemisphere (seed 3) kept four views of its lowest ring, joined by strong pairs among themselves,
/// at 90° from the truth; their only usable pairs with the rest were with views taken out. Flagging
/// them instead of warning sent a model down another path that kept two other views wrong
/// (2026-11-28), so they are only named.
///
/// A view joined to the model by a usable pair may still rest on nothing else: once its
/// neighbours were out, the hemisphere's seed 0 kept a view 153° off whose points were seen by
/// one other view each (58 of them with the one partner its usable pair joins it to, whose
/// two-view rotation it matched: a long lens leaves a two-view pose this uncertain). A view beside
/// a removed one that sees fewer points held by two other views than its registration needed
/// (`min_resection_inliers`) is named too. The kept views of dinoSparseRing, beside its two
/// removed ones, see 167–346 such points each.
pub(crate) fn unconfirmed(
    ctx: &Context,
    rec: &MetricReconstruction,
    removed: &BTreeSet<usize>,
) -> Vec<usize> {
    if removed.is_empty() {
        return Vec::new();
    }
    let n = ctx.input.images.len();
    let kept: Vec<bool> = (0..n)
        .map(|i| rec.views.contains_key(&ctx.input.images[i].id) && !removed.contains(&i))
        .collect();
    // The pieces: union-find over the usable pairs between kept views.
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut beside_removed = vec![false; n];
    for p in &ctx.input.pairs {
        let usable = p.configuration == TwoViewConfiguration::General
            && p.matches.len() >= MIN_PAIR_INLIERS
            && p.f.is_some();
        if usable && kept[p.a] && kept[p.b] {
            let (ra, rb) = (root(&mut parent, p.a), root(&mut parent, p.b));
            parent[ra.max(rb)] = ra.min(rb);
        }
        for (me, other) in [(p.a, p.b), (p.b, p.a)] {
            if kept[me] && removed.contains(&other) {
                beside_removed[me] = true;
            }
        }
    }
    let mut pieces: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for i in (0..n).filter(|&i| kept[i]) {
        pieces.entry(root(&mut parent, i)).or_default().push(i);
    }
    // The largest piece (the first of equals) is the model.
    let main = pieces
        .iter()
        .max_by(|x, y| x.1.len().cmp(&y.1.len()).then(y.0.cmp(x.0)))
        .map(|(r, _)| *r);
    let mut out: Vec<usize> = pieces
        .into_iter()
        .filter(|(r, views)| Some(*r) != main && views.iter().any(|&i| beside_removed[i]))
        .flat_map(|(_, views)| views)
        .collect();
    // A view beside a removed one that no longer sees enough points held by two other views
    // (what its registration needed: `min_resection_inliers`) is posed by two-view tracks alone.
    let kept_ids: BTreeSet<ImageId> = (0..n)
        .filter(|&i| kept[i])
        .map(|i| ctx.input.images[i].id)
        .collect();
    let loose: Vec<usize> = (0..n)
        .filter(|&i| kept[i] && beside_removed[i] && !out.contains(&i))
        .filter(|&i| {
            let id = ctx.input.images[i].id;
            anchored_observations(rec, id, &kept_ids) < ctx.opts.min_resection_inliers
        })
        .collect();
    out.extend(loose);
    out.sort_unstable();
    out
}

/// Observations of the view `id` whose points at least two other `kept` views observe.
fn anchored_observations(
    rec: &MetricReconstruction,
    id: ImageId,
    kept: &BTreeSet<ImageId>,
) -> usize {
    let others = |p: &handheld_core::Point3D| {
        p.track
            .elements
            .iter()
            .filter(|e| e.image_id != id && kept.contains(&e.image_id))
            .count()
    };
    rec.views.get(&id).map_or(0, |v| {
        v.observations
            .iter()
            .filter_map(|o| o.point_id)
            .filter(|pid| rec.points.get(pid).is_some_and(|p| others(p) >= 2))
            .count()
    })
}

/// The angle (degrees) between the relative rotation of views `a` → `b` in `rec` and the one of
/// their verified pair; `None` when the pair is not usable.
fn pair_disagreement(
    ctx: &Context,
    rec: &MetricReconstruction,
    pair: &crate::input::SfmPair,
) -> Option<Disagreement> {
    let checked = matches!(
        pair.configuration,
        TwoViewConfiguration::General | TwoViewConfiguration::PureRotation
    );
    if !checked || pair.matches.len() < MIN_PAIR_INLIERS {
        return None;
    }
    let (ia, ib) = (&ctx.input.images[pair.a], &ctx.input.images[pair.b]);
    let (va, vb) = (rec.views.get(&ia.id)?, rec.views.get(&ib.id)?);
    let ka = &rec.cameras.get(&va.camera_id)?.intrinsics;
    let kb = &rec.cameras.get(&vb.camera_id)?.intrinsics;
    // The cheirality test and the covariance need a sample, not every inlier.
    let step = pair.matches.len().div_ceil(SAMPLE).max(1);
    let (xa, xb): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = pair
        .matches
        .iter()
        .step_by(step)
        .map(|&(i, j)| {
            (
                ka.pixel_to_normalized(ia.keypoints[i as usize]),
                kb.pixel_to_normalized(ib.keypoints[j as usize]),
            )
        })
        .unzip();
    let rel = vb.cam_from_world * va.cam_from_world.inverse();
    // A match farther from its line than the model's outlier threshold is an outlier of that pose.
    let cap = 2.0 * ctx.opts.metric_max_error_px / (ka.f + kb.f);
    if pair.configuration == TwoViewConfiguration::PureRotation {
        // No F: the pair can only confirm the model's relative pose (`rotation_only.rs`).
        let (r, t) = (
            rel.rotation.to_rotation_matrix().into_inner(),
            rel.translation.vector,
        );
        let support = rotation_only::plane_support(&r, &t, &xa, &xb, cap)?;
        tracing::trace!(a = %ia.name, b = %ib.name, support, "a rotation-only pair against the model");
        return (support >= rotation_only::CONFIRMING_SUPPORT).then_some(Disagreement {
            deg: 0.0,
            allowed_deg: MAX_DISAGREEMENT_DEG,
            held: false,
        });
    }
    let f = pair.f?;
    // x_bᵀ F x_a = 0 in pixels; in normalised coordinates x_bᵀ (K_bᵀ F K_a) x_a = 0.
    let e = kb.k_matrix().transpose() * f * ka.k_matrix();
    let (_, r, t) = crate::projective::init::essential_pose(&e, &xa, &xb)?;
    // E = K_bᵀ F K_a is an essential matrix only up to the model's calibration error and F's
    // noise: the pose it is projected to is refined on the inliers' Sampson errors, and so is the
    // model's own relative pose; the pair's rotation is the better fit of the two
    // (`pair_rotation::best_pose`).
    let scale = pair.matches.len() as f64 / xa.len().max(1) as f64;
    let starts = [
        (r, t),
        (
            rel.rotation.to_rotation_matrix().into_inner(),
            rel.translation
                .vector
                .try_normalize(1e-12)
                .unwrap_or_default(),
        ),
    ];
    let (r, sigma) = pair_rotation::best_pose(&starts, &xa, &xb, scale, cap)?;
    let model =
        (vb.cam_from_world.rotation * va.cam_from_world.rotation.inverse()).to_rotation_matrix();
    let cos = (((r * model.matrix().transpose()).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    let deg = cos.acos().to_degrees();
    let sigma_deg = sigma.map_or(f64::INFINITY, f64::to_degrees);
    let allowed_deg = MAX_DISAGREEMENT_DEG.hypot(SIGMAS * sigma_deg);
    tracing::trace!(
        a = %ia.name,
        b = %ib.name,
        deg,
        sigma_deg,
        allowed_deg,
        "a pair's rotation against the model's"
    );
    deg.is_finite().then(|| Disagreement {
        deg,
        allowed_deg,
        // Only a pair that disagrees needs the structure's word.
        held: deg > allowed_deg && held_by_structure(ctx, rec, pair, (va, vb)),
    })
}

/// Inliers of a pair used for the cheirality test and the covariance.
const SAMPLE: usize = 400;
/// A pair's rotation may differ from the model's by this many of its standard deviations beyond
/// [`MAX_DISAGREEMENT_DEG`] (added in quadrature).
pub const SIGMAS: f64 = 3.0;

/// How a pair's relative rotation compares with the model's.
#[derive(Clone, Copy, Debug)]
struct Disagreement {
    /// The angle between the two, degrees.
    deg: f64,
    /// What the pair allows: [`MAX_DISAGREEMENT_DEG`] and [`SIGMAS`] × its rotation's standard
    /// deviation, in quadrature.
    allowed_deg: f64,
    /// Whether the model's structure holds the pair's matches ([`held_by_structure`]).
    held: bool,
}

/// The weighted median (by inliers) of the disagreements of the verified pairs between the views
/// `a` and the views `b` of `rec`, and how many pairs were usable; `None` when none was. A merged
/// model whose two pieces sit at the wrong angle to each other agrees with the pairs inside each
/// piece, so every view's own median ([`inconsistent_views`]) passes; only the pairs across show it.
pub(crate) fn across(
    ctx: &Context,
    rec: &MetricReconstruction,
    a: &BTreeSet<ImageId>,
    b: &BTreeSet<ImageId>,
) -> Option<(f64, usize)> {
    let side = |i: usize| {
        let id = ctx.input.images[i].id;
        (a.contains(&id), b.contains(&id))
    };
    let v: Vec<(f64, f64)> = ctx
        .input
        .pairs
        .iter()
        .filter(|p| {
            let (x, y) = (side(p.a), side(p.b));
            (x.0 && y.1) || (x.1 && y.0)
        })
        .filter_map(|p| pair_disagreement(ctx, rec, p).map(|d| (d.deg, p.matches.len() as f64)))
        .collect();
    let n = v.len();
    (n > 0).then(|| (weighted_median(v), n))
}

/// The weighted median of `(value, weight)`.
fn weighted_median(mut v: Vec<(f64, f64)>) -> f64 {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let half = v.iter().map(|x| x.1).sum::<f64>() / 2.0;
    let mut acc = 0.0;
    for (x, w) in &v {
        acc += w;
        if acc >= half {
            return *x;
        }
    }
    v.last().map_or(0.0, |x| x.0)
}

/// The views flagged (input index and disagreement, worst first) and the largest disagreement
/// among the others.
pub(crate) type Judged = (Vec<(usize, ViewDisagreement)>, Option<f64>);

/// The registered views (input indices) whose pose disagrees with their verified pairs, worst
/// first, and the largest disagreement among the others.
pub(crate) fn inconsistent_views(ctx: &Context, rec: &MetricReconstruction) -> Judged {
    // (a, b, disagreement, inliers) of every usable pair.
    let pairs: Vec<(usize, usize, Disagreement, f64)> = ctx
        .input
        .pairs
        .iter()
        .filter_map(|p| {
            pair_disagreement(ctx, rec, p).map(|d| (p.a, p.b, d, p.matches.len() as f64))
        })
        .collect();
    let pairs = exempt_held(pairs);
    let mut flagged: Vec<(usize, ViewDisagreement)> = Vec::new();
    loop {
        let out = |i: usize| flagged.iter().any(|(j, _)| *j == i);
        let mut per_view: BTreeMap<usize, Vec<(Disagreement, f64)>> = BTreeMap::new();
        for &(a, b, d, w) in &pairs {
            if out(a) || out(b) {
                continue;
            }
            per_view.entry(a).or_default().push((d, w));
            per_view.entry(b).or_default().push((d, w));
        }
        // The view with the largest share of its inliers in pairs that disagree beyond what they
        // allow goes first (a misplaced view disagrees with all its partners, each of them only
        // with it), then the one with the larger median (in units of what its pairs allow).
        let worst = per_view
            .into_iter()
            .map(|(i, v)| {
                let total: f64 = v.iter().map(|x| x.1).sum();
                let bad: f64 = v
                    .iter()
                    .filter(|x| x.0.deg > x.0.allowed_deg)
                    .map(|x| x.1)
                    .sum();
                let ratio =
                    weighted_median(v.iter().map(|x| (x.0.deg / x.0.allowed_deg, x.1)).collect());
                let deg = weighted_median(v.iter().map(|x| (x.0.deg, x.1)).collect());
                let allowed = weighted_median(v.iter().map(|x| (x.0.allowed_deg, x.1)).collect());
                (i, v.len(), bad / total.max(1.0), ratio, deg, allowed)
            })
            .max_by(|x, y| x.2.total_cmp(&y.2).then(x.3.total_cmp(&y.3)));
        let Some((i, partners, _, ratio, median_deg, allowed_deg)) = worst else {
            return (flagged, None);
        };
        if ratio <= 1.0 || rec.views.len() - flagged.len() <= 2 {
            return (flagged, Some(median_deg));
        }
        flagged.push((
            i,
            ViewDisagreement {
                image: ctx.input.images[i].name.clone(),
                median_deg,
                allowed_deg,
                partners,
            },
        ));
    }
}

/// Views whose pose disagrees with their verified pairs (`judged` by [`inconsistent_views`] on
/// `rec`) are taken out of the
/// model, recorded in `failures`, and the model is adjusted again without them (intrinsics
/// included: the misplaced view pulled them too). When that adjustment fails or collapses, the
/// model is kept as it was and a warning says which views it does not trust.
pub(crate) fn take_out(
    ctx: &Context,
    rec: &mut MetricReconstruction,
    failures: &mut BTreeMap<usize, String>,
    estimate_aspect: bool,
    (flagged, max_kept_deg): Judged,
) -> (ConsistencyReport, Vec<MetricBaRecord>) {
    let mut report = ConsistencyReport {
        max_kept_deg,
        ..Default::default()
    };
    if flagged.is_empty() {
        return (report, Vec::new());
    }
    let before = rec.clone();
    let out: BTreeSet<ImageId> = flagged
        .iter()
        .map(|(i, _)| ctx.input.images[*i].id)
        .collect();
    *rec = metric_ba::without_views(rec, &out);
    let list = flagged
        .iter()
        .map(|(_, d)| format!("{} ({:.1}°)", d.image, d.median_deg))
        .collect::<Vec<_>>()
        .join(", ");
    let adjusted = metric_ba::refine_metric(ctx, rec, estimate_aspect).and_then(|records| {
        match guard::collapsed(rec, &records) {
            Some(why) => Err(why),
            None => Ok(records),
        }
    });
    match adjusted {
        Ok(records) => {
            tracing::warn!(
                "taken out of the model because their poses disagree with their verified image pairs (median over their partners): {list}"
            );
            for (i, d) in flagged {
                failures.insert(
                    i,
                    format!(
                        "registered with a pose that disagreed with its verified image pairs by {:.1}° (median over {} partners), so it was taken out of the model",
                        d.median_deg, d.partners
                    ),
                );
                report.removed.push(d);
            }
            (report, records)
        }
        Err(why) => {
            *rec = before;
            tracing::warn!(
                "these views disagree with their verified image pairs, so their poses are not trustworthy, but the model without them could not be adjusted ({why}): {list}"
            );
            report.max_kept_deg = flagged.first().map(|(_, d)| d.median_deg);
            (report, Vec::new())
        }
    }
}

mod held;
mod rotation_only;
use held::{exempt_held, held_by_structure};

#[cfg(test)]
mod tests;
