//! One merge of two models: the similarity from their 3D–3D correspondences first, and when there
//! is none, or its merged model fails a check, the one from their 2D–3D links; the union adjusted
//! and checked (`union.rs`).

use handheld_core::MetricReconstruction;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::correspondences::{
    correspondences, explains, similarity, MIN_MERGE_INLIERS, MIN_MERGE_INLIER_FRACTION,
};
use super::record::MergeRecord;
use super::sightings;
use super::union::{adjusted_union, Attachments};
use crate::context::Context;
use crate::metric::ba::MetricBaRecord;

/// Tries to merge `b` into `a`: the merged, adjusted model with its adjustment records and the
/// merge record, or why not. The similarity from the 3D–3D correspondences is tried first; when
/// there is none, or its merged model fails a check, the one from the 2D–3D links.
pub(crate) fn merge(
    ctx: &Context,
    a: &MetricReconstruction,
    b: &MetricReconstruction,
    estimate_aspect: bool,
) -> Result<(MetricReconstruction, Vec<MetricBaRecord>, MergeRecord), String> {
    let corr = correspondences(ctx, a, b);
    let mut why = Vec::new();
    match similarity(ctx, a, b, &corr) {
        Some((sim, inliers)) => {
            let record = MergeRecord {
                views_added: b.views.len(),
                correspondences: corr.len(),
                inliers: inliers.len(),
                sightings: 0,
                sighting_inliers: 0,
                cross_pairs: 0,
                cross_disagreement_deg: None,
                scale: sim.scale,
            };
            match adjusted_union(ctx, a, b, &corr, &sim, &inliers, &Attachments::default(), estimate_aspect) {
                Ok((merged, records, across)) => return Ok((merged, records, record.across(across))),
                Err(e) => why.push(format!(
                    "through {} of {} 3D–3D correspondences, {e}",
                    inliers.len(),
                    corr.len()
                )),
            }
        }
        None => why.push(format!(
            "{} 3D–3D correspondences through the verified pairs, fewer than {MIN_MERGE_INLIERS} (or under half) explained by one similarity",
            corr.len()
        )),
    }
    let links = sightings::Links::new(ctx, a, b);
    let mut rng = ChaCha8Rng::seed_from_u64(ctx.opts.seed ^ 0x5349_4748);
    let Some((sim, (ib, ia))) =
        sightings::similarity(ctx, a, b, &links, MIN_MERGE_INLIER_FRACTION, &mut rng)
    else {
        why.push(format!(
            "{} 2D–3D links, too few (or under half) explained by one similarity",
            links.len()
        ));
        return Err(why.join("; "));
    };
    let key = |s: &sightings::Sighting| (s.view, s.key, s.point);
    let attach = Attachments {
        to_a: ib.iter().map(|&k| key(&links.b_sees_a[k])).collect(),
        to_b: ia.iter().map(|&k| key(&links.a_sees_b[k])).collect(),
    };
    let thr = ctx.opts.metric_max_error_px;
    let explained: Vec<usize> = (0..corr.len())
        .filter(|&k| explains(a, b, &sim, &corr[k], thr))
        .collect();
    let record = MergeRecord {
        views_added: b.views.len(),
        correspondences: corr.len(),
        inliers: explained.len(),
        sightings: links.len(),
        sighting_inliers: ib.len() + ia.len(),
        cross_pairs: 0,
        cross_disagreement_deg: None,
        scale: sim.scale,
    };
    match adjusted_union(ctx, a, b, &corr, &sim, &explained, &attach, estimate_aspect) {
        Ok((merged, records, across)) => Ok((merged, records, record.across(across))),
        Err(e) => {
            why.push(format!(
                "through {} of {} 2D–3D links, {e}",
                record.sighting_inliers,
                links.len()
            ));
            Err(why.join("; "))
        }
    }
}
