//! Typed warnings: what a stage tells the user, as a stable code (which the report and `--json`
//! key on), a message in plain language, what to do about it, and the numbers behind it in a
//! details field that the report folds away.
//!
//! A leaf module: it imports nothing of the crate.

use serde::{Deserialize, Deserializer, Serialize};

/// One warning of a stage.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Warning {
    /// Stable, snake_case: what kind of warning this is (see [`code`]).
    pub code: String,
    /// What happened, in plain language.
    pub message: String,
    /// What to do about it, when there is something to do.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub advice: Option<String>,
    /// The figures behind it (eigenvalues, ratios, per-candidate reasons), for the expert.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub details: Option<String>,
}

/// The warning codes of the standard stages.
pub mod code {
    /// An image could not be read or has too few features.
    pub const IMAGE: &str = "image";
    /// The input video or its frames: sizes, strides, audio.
    pub const VIDEO: &str = "video";
    /// KLT tracking did not hold over the video; matching fell back to SIFT.
    pub const TRACKING: &str = "tracking";
    /// An image was not registered in the model.
    pub const UNREGISTERED: &str = "unregistered";
    /// Photos that are copies of others (the same keypoints under another name).
    pub const DUPLICATE_PHOTOS: &str = "duplicate_photos";
    /// The images form several models.
    pub const SEPARATE_MODELS: &str = "separate_models";
    /// A merge of two pieces that no verified pair between them confirms.
    pub const UNCONFIRMED_MERGE: &str = "unconfirmed_merge";
    /// Views whose only checkable pairs were with views taken out as misplaced.
    pub const UNCONFIRMED_VIEWS: &str = "unconfirmed_views";
    /// More views were first placed against their own verified pairs than the model kept, or the
    /// model's principal point lies outside the image: the model may be wrong as a whole.
    pub const MODEL_DOUBTFUL: &str = "model_doubtful";
    /// Split-and-merge: the clusters' own focal lengths disagree, or views of the merged model
    /// disagree with their verified pairs.
    pub const SPLIT_DISAGREEMENT: &str = "split_disagreement";
    /// The preferred metric frame failed its checks; another one was kept.
    pub const METRIC_FRAME_REJECTED: &str = "metric_frame_rejected";
    /// The data do not fix the focal length.
    pub const FOCAL_UNDETERMINED: &str = "focal_undetermined";
    /// A view of the dense or mesh stage gave nothing.
    pub const VIEW_SKIPPED: &str = "view_skipped";
    /// Depth samples left out of the fused mesh as too uncertain (far, too little parallax).
    pub const DEPTH_LEFT_OUT: &str = "depth_left_out";
    /// A stage went on without an input it uses when it is there.
    pub const INPUT_MISSING: &str = "input_missing";
    /// A fallback: a method or output replaced by a simpler one.
    pub const FALLBACK: &str = "fallback";
    /// A warning without a more specific code (also every warning of an older workspace).
    pub const NOTE: &str = "note";
}

impl Warning {
    /// A warning with a code and a message.
    pub fn new(code: &str, message: impl Into<String>) -> Self {
        Self {
            code: code.into(),
            message: message.into(),
            advice: None,
            details: None,
        }
    }

    /// What to do.
    pub fn advice(mut self, advice: impl Into<String>) -> Self {
        self.advice = Some(advice.into());
        self
    }

    /// The figures behind it.
    pub fn details(mut self, details: impl Into<String>) -> Self {
        self.details = Some(details.into());
        self
    }

    /// A library's warning text, which has no code of its own.
    pub fn note(message: impl Into<String>) -> Self {
        Self::new(code::NOTE, message)
    }
}

impl std::fmt::Display for Warning {
    /// The message, then what to do.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)?;
        if let Some(a) = &self.advice {
            write!(f, ". What to do: {a}")?;
        }
        Ok(())
    }
}

/// Reads the typed form, or a plain string (manifests written before warnings had codes).
impl<'de> Deserialize<'de> for Warning {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        struct Typed {
            code: String,
            message: String,
            #[serde(default)]
            advice: Option<String>,
            #[serde(default)]
            details: Option<String>,
        }
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Repr {
            Typed(Typed),
            Text(String),
        }
        Ok(match Repr::deserialize(d)? {
            Repr::Typed(t) => Warning {
                code: t.code,
                message: t.message,
                advice: t.advice,
                details: t.details,
            },
            Repr::Text(s) => Warning::note(s),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_reads_plain_strings() {
        let w = Warning::new(code::FOCAL_UNDETERMINED, "the focal length is not fixed")
            .advice("give --intrinsics")
            .details("eigenvalues 1e-9, 3.2");
        let back: Warning = serde_json::from_str(&serde_json::to_string(&w).unwrap()).unwrap();
        assert_eq!(back, w);
        let old: Vec<Warning> = serde_json::from_str(r#"["an old warning"]"#).unwrap();
        assert_eq!(old, vec![Warning::note("an old warning")]);
        assert_eq!(
            w.to_string(),
            "the focal length is not fixed. What to do: give --intrinsics"
        );
    }
}
