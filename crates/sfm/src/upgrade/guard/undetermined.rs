//! When the images do not determine the calibration, why: another frame that explains them about
//! as well with another focal length ([`focal_ambiguity`]), a flat focal profile
//! ([`flat_profile`]), a camera that only translates ([`translation_only`], and the aspect ratio
//! with it, [`aspect_undetermined`]). Split from the guard's `mod.rs`.

use handheld_core::MetricReconstruction;

use super::{focal_lengths, CandidateRecord};

/// A sound candidate whose focal length differs from the kept one's by more than this fraction is
/// a different calibration, not the same one reached by another path.
pub const DISTINCT_FOCAL: f64 = 0.1;
/// Such a candidate scoring at least this fraction of the kept one's score explains the images
/// about as well: the scores of sound frames of one calibration differ by the last few outliers.
pub const CLOSE_SCORE: f64 = 0.95;

/// When the images do not decide the focal length, why: another candidate with a focal length
/// more than [`DISTINCT_FOCAL`] away from the kept one's whose full adjustment explains the images
/// about as well ([`CLOSE_SCORE`]). Near-critical motion (forward motion, a turntable, a long
/// lens) leaves such a valley: on kitti-seq1 as photos the frames at 570 px and at 1163 px score
/// within 4 % of each other (the true focal length, 707 px, fits as well as either). The kept
/// model is then a guess that must be reported as one, whatever its covariance says.
///
/// The other candidate is a sound one, or one rejected only for the observations its adjustment
/// removed ([`CandidateRecord::removals_only`]): the filters after each adjustment cut what does
/// not fit the cameras *on their way*, so a frame that starts far from its optimum loses
/// observations the converged frame explains, and its score (what it keeps, discounted by its
/// RMS) is then the fairer comparison. A 12-view synthetic orbit (320×240, seed 1) kept a frame
/// 34 % off the true focal length that way (score 8056) while a frame that converged to within
/// 5 % scored 9103 after removing 22 %.
pub fn focal_ambiguity(records: &[CandidateRecord]) -> Option<String> {
    let kept = records.iter().find(|r| r.accepted)?;
    let (ks, kf) = (kept.score?, kept.focal_after_px.first().copied()?);
    records
        .iter()
        .filter(|r| (r.sound || r.removals_only) && !r.accepted)
        .filter_map(|r| Some((r, r.score?, r.focal_after_px.first().copied()?)))
        .filter(|&(_, s, f)| (f / kf - 1.0).abs() > DISTINCT_FOCAL && s >= CLOSE_SCORE * ks)
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(r, s, f)| {
            format!(
                "the images do not determine the focal length: the frame from {} (f = {f:.0} px after adjustment) explains them about as well as the one kept (f = {kf:.0} px; scores {s:.0} and {ks:.0})",
                r.source
            )
        })
}

/// Smallest relative increase of the robust cost when the focal length is held
/// [`crate::metric::ba::PROFILE_STEP`] away from the kept value, below which the images do not
/// determine it.
pub const MIN_PROFILE_INCREASE: f64 = 0.05;

/// When the fit hardly changes with the focal length held 20 % off on either side
/// ([`crate::metric::ba::focal_profile`]), why the focal length is not determined.
pub fn flat_profile(rec: &MetricReconstruction, ratios: [f64; 2]) -> Option<String> {
    let worst = ratios[0].min(ratios[1]);
    let f = focal_lengths(rec).first().copied()?;
    (worst.is_finite() && worst < 1.0 + MIN_PROFILE_INCREASE).then(|| {
        let side = if ratios[0] <= ratios[1] { "shorter" } else { "longer" };
        format!(
            "the images do not determine the focal length: with it held 20 % {side} than the kept {f:.0} px, the adjusted model explains them almost as well (cost × {worst:.3})"
        )
    })
}

/// Largest departure of an estimated aspect ratio from 1 that a camera which only translates may
/// report without a warning.
pub const MAX_UNDETERMINED_ASPECT: f64 = 0.05;

/// When the camera only translates (`why`, from [`translation_only`]) and the aspect ratio was
/// estimated: pure translation leaves the whole calibration free (the infinite homography is the
/// identity, Sturm 1997), the aspect ratio as much as the focal length, and an estimate far from
/// square pixels is the valley's drift, not a measurement (kitti-seq1 as H.264 at crf 28: 1.31
/// where the truth is 1, the focal length 26 % off, with probes that agreed with each other).
pub fn aspect_undetermined(rec: &MetricReconstruction, why: &str) -> Option<String> {
    let c = rec
        .cameras
        .values()
        .find(|c| (c.intrinsics.aspect - 1.0).abs() > MAX_UNDETERMINED_ASPECT)?;
    Some(format!(
        "the images do not determine the focal length: {why}, and the aspect ratio estimated from          them ({:.3}) is as free as the focal length ({:.0} px); give `--aspect fixed` for square          pixels",
        c.intrinsics.aspect, c.intrinsics.f
    ))
}

/// Optical axes that all lie within this angle (degrees) of their mean: the camera translates
/// without turning. The project's sets span 21–106°; kitti-seq1, a car driving straight, 0.8°.
pub const MIN_AXIS_SPREAD_DEG: f64 = 10.0;

/// When the camera only translates, why the focal length is not determined: with no rotation the
/// infinite homography between any two views is the identity whatever the calibration, so neither
/// the Kruppa equations nor the absolute quadric constrain it (Sturm, "Critical motion sequences
/// for monocular self-calibration and uncalibrated Euclidean reconstruction", CVPR 1997: pure
/// translation is critical). The model may fit the images well and still have the wrong focal
/// length and, with it, the wrong depths.
pub fn translation_only(rec: &MetricReconstruction) -> Option<String> {
    let axes: Vec<nalgebra::Vector3<f64>> = rec
        .views
        .values()
        .map(|v| v.cam_from_world.rotation.inverse() * nalgebra::Vector3::z())
        .collect();
    if axes.len() < 2 {
        return None;
    }
    let mean = axes.iter().sum::<nalgebra::Vector3<f64>>();
    let mean = mean.try_normalize(1e-12)?;
    let spread = axes
        .iter()
        .map(|a| a.dot(&mean).clamp(-1.0, 1.0).acos().to_degrees())
        .fold(0.0f64, f64::max);
    (spread < MIN_AXIS_SPREAD_DEG).then(|| {
        format!(
            "the camera translates without turning (every optical axis within {spread:.1}° of their mean), which leaves the focal length undetermined (pure translation is critical motion)"
        )
    })
}
