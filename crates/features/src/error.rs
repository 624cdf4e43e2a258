//! Errors of the features crate. Options are plain data with a `validate()` that names the first
//! offending option (by its field name) and says what range it must lie in.

use thiserror::Error;

/// What can go wrong before features are detected, tracked or matched.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FeatureError {
    /// An options field is out of its valid range; `option` is the field's name.
    #[error("invalid feature option `{option}`: {reason}")]
    InvalidOption {
        option: &'static str,
        reason: String,
    },
}

impl FeatureError {
    /// The error for option `option`.
    pub(crate) fn option(option: &'static str, reason: impl Into<String>) -> Self {
        FeatureError::InvalidOption {
            option,
            reason: reason.into(),
        }
    }
}

/// `Ok(())` when `ok`, else the error for option `option` with the reason `reason()`.
pub(crate) fn check(
    ok: bool,
    option: &'static str,
    reason: impl FnOnce() -> String,
) -> Result<(), FeatureError> {
    if ok {
        Ok(())
    } else {
        Err(FeatureError::option(option, reason()))
    }
}
