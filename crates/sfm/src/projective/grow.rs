//! Table 2 steps 2–4 on the views allowed: initial pairs tried in order (`init.rs`) until one grows
//! into a model, views added while one can be registered (`resection.rs`), projective bundle
//! adjustment whenever the model grew by `SfmOptions::ba_growth_factor` (`ba.rs`), and at the end
//! the structure completed and its tracks merged (`tracks.rs`).

use crate::context::Context;

use super::init::{initial_pair_candidates, initialize};
use super::model::ProjectiveModel;

/// Table 2 steps 2–4 on the `allowed` images: tries initial pairs in order until one grows into a
/// model of at least 3 views (or the only 2 allowed), then adds views until none can be registered.
pub(crate) fn reconstruct_projective(
    ctx: &Context,
    allowed: &[bool],
    excluded: &[(usize, usize)],
    progress: &dyn handheld_core::Progress,
) -> Result<ProjectiveModel, String> {
    let mut candidates = initial_pair_candidates(ctx, allowed);
    candidates.retain(|&(a, b, _)| !excluded.contains(&(a, b)));
    if candidates.is_empty() {
        return Err(
            "no image pair has enough verified, non-degenerate matches to start a model".into(),
        );
    }
    let n_allowed = allowed.iter().filter(|a| **a).count();
    let mut last_err = String::new();
    let mut best: Option<ProjectiveModel> = None;
    for &(a, b, _) in candidates.iter().take(ctx.opts.max_initial_pairs) {
        let Some(mut model) = initialize(ctx, a, b) else {
            last_err = format!(
                "initial pair ({}, {}) gave too few points",
                ctx.input.images[a].name, ctx.input.images[b].name
            );
            tracing::debug!("{last_err}");
            continue;
        };
        model.bundle(ctx, 30)?;
        grow(ctx, &mut model, allowed, progress)?;
        let good = model.order.len() >= 3.min(n_allowed);
        if good {
            return Ok(model);
        }
        last_err = format!(
            "initial pair ({}, {}) could not be extended",
            ctx.input.images[a].name, ctx.input.images[b].name
        );
        if best
            .as_ref()
            .is_none_or(|b| model.order.len() > b.order.len())
        {
            best = Some(model);
        }
    }
    best.ok_or(last_err)
}

fn grow(
    ctx: &Context,
    model: &mut ProjectiveModel,
    allowed: &[bool],
    progress: &dyn handheld_core::Progress,
) -> Result<(), String> {
    let mut last_ba = model.order.len();
    let mut attempts = vec![0usize; ctx.input.images.len()];
    let mut structure_changed = true;
    progress.start(
        "projective reconstruction",
        allowed.iter().filter(|a| **a).count() as u64,
    );
    progress.inc(2);
    while structure_changed {
        structure_changed = false;
        // Unregistered images by number of 2D–3D candidates, best first.
        let mut cands: Vec<(usize, usize)> = (0..ctx.input.images.len())
            .filter(|&i| {
                allowed[i]
                    && model.cams[i].is_none()
                    && attempts[i] < ctx.opts.max_resection_attempts
            })
            .map(|i| (i, model.candidates(ctx, i).len()))
            .filter(|c| c.1 >= ctx.opts.min_resection_inliers)
            .collect();
        cands.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        for (img, _) in cands {
            attempts[img] += 1;
            match model.register(ctx, img) {
                Ok(n) => {
                    tracing::debug!("registered {} with {n} inliers", ctx.input.images[img].name);
                    model.failures.remove(&img);
                    progress.inc(1);
                    let r = model.order.len();
                    if r <= 5 || r as f64 >= last_ba as f64 * ctx.opts.ba_growth_factor {
                        model.bundle(ctx, 30)?;
                        last_ba = r;
                    }
                    structure_changed = true;
                    break;
                }
                Err(e) => {
                    tracing::debug!("{}: {e}", ctx.input.images[img].name);
                    model.failures.insert(img, e);
                }
            }
        }
    }
    // The growth schedule may have just adjusted the complete model; otherwise adjust it now.
    if last_ba != model.order.len() {
        model.bundle(ctx, 100)?;
    }
    // A second pass of structure refinement after the final adjustment: new points, then every
    // point completed with all the registered views that match it (see `tracks`).
    for &img in &model.order.clone() {
        model.triangulate_image(ctx, img);
    }
    let growth = model.complete_and_merge_tracks(ctx);
    tracing::debug!(?growth, "track completion");
    model.bundle(ctx, 100)?;
    progress.finish();
    Ok(())
}
