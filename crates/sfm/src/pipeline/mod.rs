//! The top of the SfM stage: [`reconstruct`] builds models one after the other from the views
//! still free, each by the steps of [`model`] (Table 2, then §3.4 and the metric adjustments):
//!
//! 1. `projective_step`: Table 2 steps 2–4 on the views still free (`projective/`);
//! 2. `upgrade::frame::adjust_metric_frame`: the upgrade of eq. 27 from the linear
//!    self-calibration (§3.4, eqs. 24–27), or from a known calibration (eq. 26 with `K` given),
//!    with the fall-backs on the priors and the focal hypotheses when the motion is critical, the
//!    best-explaining candidate kept (`upgrade/`); a start whose frame no candidate survives is
//!    abandoned and the model built again from the next initial pair ([`model::MAX_STARTS`]);
//! 3. metric bundle adjustment (`metric/ba.rs`);
//! 4. `calibrated_registration_step`: views the projective stage could not add, by calibrated
//!    resection (`metric/register.rs`), then adjusted again;
//! 5. `predicted_matches_step`: more observations at the predicted projections (§3.2,
//!    `metric/predict.rs`), then a final adjustment;
//! 6. `metric::consistency::take_out`: views whose pose disagrees with their verified pairs are
//!    taken out, the model built again without them ([`model::MAX_REBUILDS`]) and the views
//!    registered again and judged once more;
//! 7. `video_frames_step`: a video's in-between frames from their tracks (`video.rs`);
//! 8. the principal point's test on the finished model (`metric/principal_point.rs`), the
//!    focal-length warnings (`upgrade/guard/`), and `uncertainty_step`: per-point and intrinsics
//!    uncertainty (`metric/uncertainty.rs`).
//!
//! `calibrated_net.rs` holds the calibrated incremental candidate's part in these steps (the
//! safety net under step 2, and its challenge of a kept fall-back frame).
//!
//! Then the models are merged where they share points (`merge/`), sorted largest first, and their
//! ids restored to the input's (`canonical.rs`). [`crate::StepError`] says which step stopped a
//! model and why.

mod calibrated_net;
pub(crate) mod model;
pub(crate) mod steps;

use std::collections::BTreeMap;

use handheld_core::Progress;

use crate::canonical::Canonical;
use crate::context::Context;
use crate::error::{SfmError, StepError};
use crate::graph::CorrespondenceGraph;
use crate::input::SfmInput;
use crate::merge::merge_models;
use crate::options::SfmOptions;
use crate::summary::{DuplicateShot, SfmModel, SfmResult};
use steps::Search;

/// Runs Table 2 and §3.4 end to end: models are built one after the other from the views still
/// free (the steps of [`model`]) until `max_models`, or until no view is left to start one.
/// Deterministic for a given input and seed, and for photos independent of their order (see
/// `canonical.rs`).
pub fn reconstruct(
    input: &SfmInput,
    options: &SfmOptions,
    progress: &dyn Progress,
) -> Result<SfmResult, SfmError> {
    options.validate()?;
    input.validate().map_err(SfmError::InvalidInput)?;
    let usable = input
        .images
        .iter()
        .filter(|im| !im.keypoints.is_empty())
        .count();
    if usable < 2 {
        return Err(SfmError::TooFewImages(usable));
    }
    if options.split.applies(input) {
        return crate::split::reconstruct_split(input, options, progress);
    }
    let canonical = Canonical::new(input);
    let input = canonical.as_ref().map_or(input, |c| &c.input);
    let graph = CorrespondenceGraph::build(input, 8);
    let ctx = Context::new(input, &graph, options);
    let mut search = Search::new(&ctx);
    let mut models = Vec::new();
    // The last failure, reported when no model could be built.
    let mut last_err: Option<StepError> = None;
    for _ in 0..options.max_models {
        if search.free() < 2 {
            break;
        }
        let before = search.allowed.clone();
        match model::build_model(&ctx, &mut search, progress) {
            Ok(Some(model)) => models.push(model),
            Ok(None) => break,
            Err(e) => {
                // A failure that took no view would be met again, step for step, by the next
                // attempt on the same free views (a corridor walk: five identical failures).
                let ends = e.ends_search() || search.allowed == before;
                last_err = Some(e);
                if ends {
                    break;
                }
            }
        }
    }
    if models.is_empty() {
        let n = input.images.len();
        return Err(match last_err {
            Some(e) => SfmError::NoModel(e),
            None => SfmError::NoOverlap {
                linked: (0..n).filter(|&i| !graph.neighbours(i).is_empty()).count(),
                total: n,
            },
        });
    }
    merge_models(&ctx, &mut models);
    models.sort_by_key(|m| std::cmp::Reverse(m.summary.registered));
    let unregistered = unregistered(input, &graph, &models, &search.failures);
    if let Some(c) = &canonical {
        for m in &mut models {
            c.restore(&mut m.reconstruction);
        }
    }
    let duplicates = ctx
        .duplicates
        .iter()
        .map(|d| DuplicateShot {
            image: input.images[d.image].name.clone(),
            of: input.images[d.of].name.clone(),
            shift_px: d.shift_px,
            identical: d.identical(),
        })
        .collect();
    Ok(SfmResult {
        models,
        unregistered,
        duplicates,
        split: None,
    })
}

/// The images in no model, each with the reason.
fn unregistered(
    input: &SfmInput,
    graph: &CorrespondenceGraph,
    models: &[SfmModel],
    failures: &BTreeMap<usize, String>,
) -> Vec<(String, String)> {
    let registered: std::collections::BTreeSet<_> = models
        .iter()
        .flat_map(|m| m.reconstruction.views.keys().copied())
        .collect();
    input
        .images
        .iter()
        .enumerate()
        .filter(|(_, im)| !registered.contains(&im.id))
        .map(|(i, im)| {
            let why = if im.keypoints.is_empty() {
                "no features".to_string()
            } else if let Some(f) = failures.get(&i) {
                f.clone()
            } else if graph.neighbours(i).is_empty() {
                "no verified matches with any other image".to_string()
            } else {
                "not connected to a model".to_string()
            };
            (im.name.clone(), why)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use handheld_core::{ImageId, NoProgress};
    use nalgebra::Vector2;

    use super::*;
    use crate::input::SfmImage;

    fn image(i: u32) -> SfmImage {
        SfmImage {
            id: ImageId(i),
            name: format!("{i}.png"),
            width: 64,
            height: 48,
            keypoints: vec![Vector2::new(1.0, 2.0); 10],
            keypoint_scales: Vec::new(),
            camera_key: "cam".into(),
            focal_prior_px: None,
            frame: None,
            track_ids: Vec::new(),
            descriptors: Vec::new(),
            descriptor_dim: 0,
        }
    }

    #[test]
    fn images_without_pairs_give_the_no_overlap_error() {
        let input = SfmInput {
            images: (0..3).map(image).collect(),
            ..Default::default()
        };
        let err = reconstruct(&input, &SfmOptions::default(), &NoProgress).unwrap_err();
        assert!(
            matches!(
                err,
                SfmError::NoOverlap {
                    linked: 0,
                    total: 3
                }
            ),
            "{err:?}"
        );
        assert_eq!(
            err.to_string(),
            "no model could be built: only 0 of 3 images have verified matches with another image \
             (need 2): the images do not overlap, or the camera hardly moves (video: too few \
             key-frames)"
        );
    }
}
