//! The errors of the SfM stage: [`SfmError`], why [`crate::reconstruct`] gave no model at all, and
//! [`StepError`], which step of `pipeline/` stopped one model and why. A leaf: the options, the
//! phases and the pipeline all name these without importing one another.

/// Why the SfM stage could not produce any model.
#[derive(Debug, thiserror::Error)]
pub enum SfmError {
    /// A [`crate::SfmOptions`] field is out of its valid range; `option` is the field's name
    /// (`self_calibration.<field>` for the nested self-calibration options).
    #[error("invalid SfM option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
    #[error("invalid SfM input: {0}")]
    InvalidInput(String),
    #[error("need at least 2 images with features, got {0}; add more overlapping photos")]
    TooFewImages(usize),
    /// Model building stopped at a step, for every model attempted (the last failure).
    #[error("no model could be built: {0}")]
    NoModel(StepError),
    /// Fewer than 2 images are matched to another one, so no model can start.
    #[error(
        "no model could be built: only {linked} of {total} images have verified matches with \
         another image (need 2): the images do not overlap, or the camera hardly moves (video: too \
         few key-frames)"
    )]
    NoOverlap { linked: usize, total: usize },
}

/// The step that stopped one model, with the reason it gave.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StepError {
    /// Table 2 steps 2–4: no initial pair could start a model, or a projective bundle adjustment
    /// failed. The views left cannot start another model, so the search ends.
    #[error("projective reconstruction: {0}")]
    Projective(String),
    /// §3.4: the metric upgrade (linear self-calibration, eq. 27) failed.
    #[error("metric upgrade: {0}")]
    MetricUpgrade(String),
    /// The first metric bundle adjustment of the upgraded model failed.
    #[error("metric adjustment of the upgraded model: {0}")]
    MetricAdjustment(String),
    /// The adjustment after `added` views were registered by calibrated resection failed.
    #[error("adjustment after the calibrated registration of {added} more views: {reason}")]
    CalibratedRegistration { added: usize, reason: String },
    /// The final adjustment after `added` observations were found at their predicted projections
    /// failed.
    #[error("final adjustment after {added} observations at predicted projections: {reason}")]
    PredictedMatches { added: usize, reason: String },
    /// The adjustment after `added` in-between video frames were registered failed.
    #[error("adjustment after registering {added} in-between video frames: {reason}")]
    VideoFrames { added: usize, reason: String },
}

impl StepError {
    /// The same failure with `more` appended to its reason.
    pub(crate) fn with_note(self, more: &str) -> Self {
        match self {
            Self::Projective(m) => Self::Projective(format!("{m}; {more}")),
            Self::MetricUpgrade(m) => Self::MetricUpgrade(format!("{m}; {more}")),
            Self::MetricAdjustment(m) => Self::MetricAdjustment(format!("{m}; {more}")),
            other => other,
        }
    }

    /// Whether no further model should be attempted after this failure (the others only discard
    /// the current model).
    pub fn ends_search(&self) -> bool {
        matches!(self, Self::Projective(_))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn step_errors_name_the_step_and_keep_the_reason() {
        let e = SfmError::NoModel(StepError::CalibratedRegistration {
            added: 2,
            reason: "metric bundle adjustment (final): diverged".into(),
        });
        assert_eq!(
            e.to_string(),
            "no model could be built: adjustment after the calibrated registration of 2 more \
             views: metric bundle adjustment (final): diverged"
        );
        assert!(StepError::Projective("x".into()).ends_search());
        assert!(!StepError::MetricUpgrade("x".into()).ends_search());
    }
}
