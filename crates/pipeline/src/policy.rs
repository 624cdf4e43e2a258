//! The decisions between the stages: which pairs to match, how images are numbered, which images
//! share intrinsics, how descriptors are stored for SfM, and when a result deserves a warning.

use handheld_core::ImageId;
use handheld_io::images::ImageInfo;
use handheld_io::ingest::InputKind;
use handheld_sfm::ModelSummary;
use serde::{Deserialize, Serialize};

use crate::warning::{code, Warning};

/// Largest photo set matched exhaustively under [`PairMode::Auto`].
pub const EXHAUSTIVE_MAX_PHOTOS: usize = 40;

/// Which image pairs the matches stage matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PairMode {
    /// Exhaustive up to [`EXHAUSTIVE_MAX_PHOTOS`] photos; a sequential window for video; for larger
    /// photo sets, whose file names need not follow the capture, the window over the order the
    /// images' content gives (spectral seriation) together with retrieval's most similar images.
    Auto,
    /// Every pair.
    Exhaustive,
    /// Each image with its window of successors (plus §3.2's close views).
    Sequential,
    /// Each image with its most similar images (VLAD retrieval) only: for any order of the files.
    Retrieval,
}

/// How the pairs of one input are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairPlan {
    Exhaustive,
    Sequential,
    Retrieval,
    /// A large photo set: the sequential window over the order recovered from the images'
    /// content, and retrieval (`handheld_features::retrieval::unordered_pairs`).
    Unordered,
}

impl PairMode {
    /// The plan for `n` images of this kind.
    pub fn plan(self, kind: InputKind, n: usize) -> PairPlan {
        match (self, kind) {
            (PairMode::Exhaustive, _) => PairPlan::Exhaustive,
            (PairMode::Retrieval, _) => PairPlan::Retrieval,
            (PairMode::Sequential, _) | (PairMode::Auto, InputKind::Video) => PairPlan::Sequential,
            (PairMode::Auto, InputKind::Photos) if n > EXHAUSTIVE_MAX_PHOTOS => PairPlan::Unordered,
            (PairMode::Auto, InputKind::Photos) => PairPlan::Exhaustive,
        }
    }
}

impl PairPlan {
    /// Whether verification runs the repeated-pattern test (`handheld_features::copies`): not
    /// where the pairs are sequential. Sequential pairs (a video's frames, or photos matched in
    /// their order) hold each view's neighbours, and a wider pair whose copies the test finds still
    /// carries right wall matches that the model needs: on the wallpaper video (`handheld demo
    /// --scene wallpaper --width 720 --height 1280 --fov 66 --k1 0.05 --frames 40 --video --crf 23
    /// --seed 7`) the test left out 63 of its 190 general pairs (22–54 % of their inliers copies)
    /// and two frames went from 0.015° to 1.2–1.9° off. The same 40 frames as photos, matched
    /// exhaustively, need it (33/40 views, up to 6.6° off, without it; 40/40 within 0.035° with it).
    pub fn tests_repeated_patterns(self) -> bool {
        self != PairPlan::Sequential
    }
}

/// The id of the image at `index` in ingest order (COLMAP ids start at 1).
pub fn image_id(index: usize) -> ImageId {
    ImageId(index as u32 + 1)
}

/// The ingest index of an image id (inverse of [`image_id`]).
pub fn image_index(id: ImageId) -> usize {
    (id.0 as usize).saturating_sub(1)
}

/// A key telling apart physical cameras, zoom settings and image sizes: images with the same key
/// share one intrinsics group.
pub fn camera_key(info: &ImageInfo) -> String {
    format!("{}|{}x{}", info.exif.camera_key(), info.width, info.height)
}

/// RootSIFT descriptors (unit L2 norm, components ≤ 0.5 in practice) quantised to bytes, as SfM
/// stores them for its descriptor checks.
pub fn quantize_descriptor(values: &[f32]) -> Vec<u8> {
    values
        .iter()
        .map(|v| (512.0 * v).round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// The focal guess of a camera without EXIF: 1.2 × the longer side (a normal lens).
pub fn focal_guess_px(width: u32, height: u32) -> f64 {
    1.2 * f64::from(width.max(height))
}

/// Relative standard deviation of the focal length below which a degenerate self-calibration only
/// earns a note: the bundle adjustment pins the focal length.
pub const FOCAL_WELL_DETERMINED: f64 = 0.01;

/// How sure the run is of a focal length chosen under critical motion (§3.4).
#[derive(Debug, Clone, PartialEq)]
pub enum FocalVerdict {
    /// Self-calibration was not degenerate, or the calibration was given.
    Calibrated,
    /// Degenerate, but the final adjustment determines the focal length well: a note.
    WellDetermined(String),
    /// Degenerate and uncertain: a warning with what to do.
    Doubtful(Warning),
}

/// Under critical motion (§3.4) the focal length comes from the priors and the focal hypotheses,
/// not from the data: a wrong one gives a consistent-looking but distorted model (dinoSparseRing,
/// where the BA leaves f uncertain by 4.5 %). A focal that the final adjustment determines to
/// [`FOCAL_WELL_DETERMINED`] or better is only noted.
pub fn focal_verdict(best: &ModelSummary, calibration_given: bool) -> FocalVerdict {
    if let (Some(w), false) = (&best.self_calibration.focal_ambiguity, calibration_given) {
        return FocalVerdict::Doubtful(
            Warning::new(
                code::FOCAL_UNDETERMINED,
                "the images do not fix the focal length, so it, and with it the depths and the camera's speed, may be wrong",
            )
            .advice("give the calibration with --intrinsics FX,FY,CX,CY, or add views that rotate the camera")
            .details(w.clone()),
        );
    }
    let Some(why) = &best.self_calibration.degenerate else {
        return FocalVerdict::Calibrated;
    };
    if calibration_given {
        return FocalVerdict::Calibrated;
    }
    let rel: Vec<Option<f64>> = best
        .groups
        .iter()
        .map(|g| {
            best.uncertainty
                .as_ref()
                .and_then(|u| u.relative_focal_sigma(g.camera_id, g.f))
        })
        .collect();
    let f: Vec<String> = best
        .groups
        .iter()
        .zip(&rel)
        .map(|(g, r)| match r {
            Some(r) => format!("{:.0} px ± {:.2} %", g.f, 100.0 * r),
            None => format!("{:.0} px", g.f),
        })
        .collect();
    if rel
        .iter()
        .all(|r| r.is_some_and(|r| r <= FOCAL_WELL_DETERMINED))
    {
        FocalVerdict::WellDetermined(format!(
            "self-calibration was degenerate ({why}); the focal length ({}) was chosen among the priors' hypotheses, and the bundle adjustment determines it well",
            f.join(", ")
        ))
    } else {
        FocalVerdict::Doubtful(
            Warning::new(
                code::FOCAL_UNDETERMINED,
                format!(
                    "the camera's motion does not fix the focal length by itself; {} was chosen among the candidates and may be wrong",
                    f.join(", ")
                ),
            )
            .advice("check it, or give the calibration with --intrinsics FX,FY,CX,CY")
            .details(format!("self-calibration was degenerate: {why}")),
        )
    }
}

/// The features-per-image count below which an image is called out as hard to match.
pub const FEW_FEATURES: usize = 50;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_repeated_pattern_test_runs_on_unordered_photos_but_not_on_a_sequence() {
        let tested = |mode: PairMode, kind, n| mode.plan(kind, n).tests_repeated_patterns();
        assert!(tested(PairMode::Auto, InputKind::Photos, 40));
        assert!(tested(PairMode::Auto, InputKind::Photos, 400));
        assert!(tested(PairMode::Retrieval, InputKind::Video, 400));
        assert!(!tested(PairMode::Auto, InputKind::Video, 400));
        assert!(!tested(PairMode::Sequential, InputKind::Photos, 40));
    }
}
