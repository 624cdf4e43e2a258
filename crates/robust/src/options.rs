//! RANSAC options as plain data: every field documented with its unit and default, and a
//! `validate()` that the loop calls before it starts.

/// A rejected option value.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RansacError {
    #[error("invalid RANSAC option `{name}` = {value}: {reason}")]
    InvalidOption {
        name: &'static str,
        value: String,
        reason: &'static str,
    },
}

/// Options of [`crate::run`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RansacOptions {
    /// Inlier threshold on [`crate::Estimator::residual`], in its units (pixels for the two-view
    /// estimators). Default 1.0, the 1-pixel criterion of the paper's Fig. 1; with noise `σ`, about
    /// `2.5σ–3σ` for the Sampson distance and `5σ` for the symmetric transfer error.
    pub max_error: f64,
    /// Required probability `Γ` that at least one all-inlier sample was drawn (paper §2.2,
    /// `Γ = 1 − (1 − γᵖ)ᵐ`, after Rousseeuw 1987). In (0, 1); default 0.99.
    pub confidence: f64,
    /// Minimal samples drawn before adaptive stopping may end the run. Default 0.
    pub min_iterations: usize,
    /// Hard cap on the number of minimal samples. At least 1; default 10 000.
    pub max_iterations: usize,
    /// The run succeeds only when the best model has at least `⌈min_inlier_ratio · n⌉` inliers (and
    /// more than the minimal sample, which every hypothesis explains by construction). It must sit
    /// above the support that chance gives a wrong model: for 200 random matches in a 640×480 image
    /// the best of 10 000 7-point hypotheses (after local optimisation) reaches up to 0.09 of them at
    /// a 1 px Sampson threshold and 0.14 at 3 px; a homography at 6.5 px about 0.03. Inlier ratios
    /// below 0.2 are also hard to reach by sampling (the 7-point F needs about 4·10⁵ samples at
    /// 0.2 for 99 % confidence). In [0, 1]; default 0.2.
    pub min_inlier_ratio: f64,
    /// The run succeeds only when the best model has at least this many inliers, besides
    /// `min_inlier_ratio` (the two-view verification passes its `min_inliers`). Default 0.
    ///
    /// Together the two give the least support `s` a model needs to be returned, and with it a
    /// bail-out for a hopeless run (few putative matches, none consistent): once it has drawn the
    /// samples that would have found a model with `s` inliers at confidence `1 − (1 − Γ)/10`, it
    /// stops, where it would otherwise draw all `max_iterations` (paper §2.2's rule applied to the
    /// weakest model that could succeed; at 10× the miss rate of the adaptive stop, so a pair
    /// near the bar is lost no more often than a sound one stops early).
    #[serde(default)]
    pub min_support: usize,
    /// LO-RANSAC (Chum, Matas & Kittler 2003): whenever a new best model is found, refit it with
    /// [`crate::Estimator::refit`] on its inliers and keep the refit while it scores better.
    /// Default true.
    pub local_optimization: bool,
    /// Maximum refits in one iterative refinement of local optimisation (each stops earlier once
    /// its inlier set no longer changes). Default 10.
    pub lo_iterations: usize,
    /// Random inlier subsets refitted by the inner RANSAC of local optimisation, each followed by an
    /// iterative refinement (Chum, Matas & Kittler 2003; Lebeda, Matas & Chum 2012). Default 10;
    /// 0 keeps only the iterative refinement.
    pub lo_inner_samples: usize,
    /// Local optimisation collects the refit's inliers at `lo_threshold_factor · max_error`,
    /// slightly looser than the scoring threshold so that inliers just outside it under a minimal
    /// model are recovered. At least 1; default 1.5.
    pub lo_threshold_factor: f64,
    /// The preemptive T(d,d) test (Chum & Matas 2002): a hypothesis is scored on all samples only
    /// if `d` randomly drawn samples are all inliers. The stopping rule then asks for `γᵖ⁺ᵈ` instead
    /// of `γᵖ`, since a good hypothesis also has to pass the test. `None` (the default) disables it;
    /// `Some(1)` is the usual choice. `d ≥ 1`.
    pub tdd: Option<usize>,
    /// Seed of the default sampler ([`crate::UniformSampler::new`]`(seed)`). Default 0.
    pub seed: u64,
}

impl Default for RansacOptions {
    fn default() -> Self {
        Self {
            max_error: 1.0,
            confidence: 0.99,
            min_iterations: 0,
            max_iterations: 10_000,
            min_inlier_ratio: 0.2,
            min_support: 0,
            local_optimization: true,
            lo_iterations: 10,
            lo_inner_samples: 10,
            lo_threshold_factor: 1.5,
            tdd: None,
            seed: 0,
        }
    }
}

fn invalid(name: &'static str, value: impl std::fmt::Display, reason: &'static str) -> RansacError {
    RansacError::InvalidOption {
        name,
        value: value.to_string(),
        reason,
    }
}

impl RansacOptions {
    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<(), RansacError> {
        if !(self.max_error.is_finite() && self.max_error > 0.0) {
            return Err(invalid(
                "max_error",
                self.max_error,
                "must be positive and finite",
            ));
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(invalid("confidence", self.confidence, "must lie in (0, 1)"));
        }
        if self.max_iterations == 0 {
            return Err(invalid(
                "max_iterations",
                self.max_iterations,
                "must be at least 1",
            ));
        }
        if self.min_iterations > self.max_iterations {
            return Err(invalid(
                "min_iterations",
                self.min_iterations,
                "must not exceed max_iterations",
            ));
        }
        if !(0.0..=1.0).contains(&self.min_inlier_ratio) {
            return Err(invalid(
                "min_inlier_ratio",
                self.min_inlier_ratio,
                "must lie in [0, 1]",
            ));
        }
        if !(self.lo_threshold_factor.is_finite() && self.lo_threshold_factor >= 1.0) {
            return Err(invalid(
                "lo_threshold_factor",
                self.lo_threshold_factor,
                "must be finite and at least 1",
            ));
        }
        if self.tdd == Some(0) {
            return Err(invalid(
                "tdd",
                0,
                "d must be at least 1 (use None to disable the test)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_is_valid_and_bad_values_are_named() {
        assert!(RansacOptions::default().validate().is_ok());
        let bad = [
            RansacOptions {
                max_error: 0.0,
                ..Default::default()
            },
            RansacOptions {
                max_error: f64::NAN,
                ..Default::default()
            },
            RansacOptions {
                confidence: 1.0,
                ..Default::default()
            },
            RansacOptions {
                max_iterations: 0,
                ..Default::default()
            },
            RansacOptions {
                min_iterations: 20_000,
                ..Default::default()
            },
            RansacOptions {
                min_inlier_ratio: 1.5,
                ..Default::default()
            },
            RansacOptions {
                lo_threshold_factor: 0.5,
                ..Default::default()
            },
            RansacOptions {
                tdd: Some(0),
                ..Default::default()
            },
        ];
        let names = [
            "max_error",
            "max_error",
            "confidence",
            "max_iterations",
            "min_iterations",
            "min_inlier_ratio",
            "lo_threshold_factor",
            "tdd",
        ];
        for (o, name) in bad.iter().zip(names) {
            match o.validate() {
                Err(RansacError::InvalidOption { name: n, .. }) => assert_eq!(n, name),
                Ok(()) => panic!("{name} accepted"),
            }
        }
    }
}
