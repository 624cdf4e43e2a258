//! The model-specific part of RANSAC: a minimal solver, a residual and a non-minimal refit. Kept in
//! its own file because every estimator in the workspace (F, H, projective resection, ...) implements
//! it while the loop in [`crate::ransac`] stays the only one.

/// A model that RANSAC can hypothesise from minimal samples and verify on all samples.
pub trait Estimator {
    /// The estimated model (e.g. a 3×3 matrix).
    type Model: Clone;
    /// One datum (e.g. a [`crate::Match2d2d`]).
    type Sample: Clone;
    /// Size of a minimal sample (7 for F, 4 for H).
    const SAMPLE_SIZE: usize;

    /// Pushes every model consistent with a minimal sample of `SAMPLE_SIZE` items onto `out`
    /// (minimal solvers return 0 to 3 solutions). Degenerate samples push nothing.
    fn fit(&self, samples: &[Self::Sample], out: &mut Vec<Self::Model>);

    /// Residual of one sample under a model, in the units of [`crate::RansacOptions::max_error`]
    /// (pixels for the two-view estimators). Must be non-negative; `f64::INFINITY` is allowed.
    fn residual(&self, model: &Self::Model, s: &Self::Sample) -> f64;

    /// [`Self::residual`] of every sample in turn, handed to `each`. An estimator whose residual
    /// shares work across samples (a homography's inverse) does that work once here; the values
    /// are the same.
    fn residuals<F: FnMut(f64)>(&self, model: &Self::Model, samples: &[Self::Sample], mut each: F) {
        for s in samples {
            each(self.residual(model, s));
        }
    }

    /// Non-minimal estimate from (usually many more than `SAMPLE_SIZE`) inliers, used by local
    /// optimisation; `model` is the current hypothesis, a starting point for iterative refits.
    /// `None` when the refit fails (too few or degenerate samples).
    fn refit(&self, samples: &[Self::Sample], model: &Self::Model) -> Option<Self::Model>;
}
