//! The one RANSAC loop of the workspace (paper §2.2, Table 1, step 2): draw a minimal sample, fit,
//! verify, keep the best, stop adaptively. LO-RANSAC and the T(d,d) test are options of this loop,
//! not separate implementations.

use rand::Rng;

use crate::consensus::Consensus;
use crate::estimator::Estimator;
use crate::options::{RansacError, RansacOptions};
use crate::sampler::Sampler;

/// The outcome of [`run`]. `success == false` (no model with enough support) is a normal outcome.
#[derive(Clone, Debug, PartialEq)]
pub struct RansacReport<M> {
    /// A model with enough support (see [`RansacOptions::min_inlier_ratio`]) was found.
    pub success: bool,
    /// The best model, `None` unless `success`.
    pub model: Option<M>,
    /// Minimal samples drawn.
    pub num_trials: usize,
    /// Models produced by the minimal solver (0 to 3 per trial for the 7-point F).
    pub num_hypotheses: usize,
    /// Hypotheses verified on all samples (those that passed T(d,d) when it is enabled).
    pub num_verifications: usize,
    /// Hypotheses discarded by the T(d,d) test without full verification.
    pub num_tdd_rejections: usize,
    /// Full verifications spent by local optimisation.
    pub num_lo_verifications: usize,
    /// Inliers of the best model (`residual ≤ max_error`). On failure, the support of the best
    /// hypothesis that fell short (0 if none was verified), to show how far the run was from success.
    pub support: usize,
    /// Consensus score of the best model (the inlier count for [`crate::InlierCount`]); on failure,
    /// that of the best hypothesis, as for `support`.
    pub score: f64,
    /// Per-sample inlier flags of the best model; all false on failure.
    pub inlier_mask: Vec<bool>,
}

/// Number of minimal samples needed so that with probability `confidence` at least one of them is
/// all-inlier: `m = log(1 − Γ) / log(1 − γᵖ)` (paper §2.2). `usize::MAX` when `γᵖ` vanishes.
pub fn required_iterations(inlier_ratio: f64, sample_size: usize, confidence: f64) -> usize {
    let w = inlier_ratio.clamp(0.0, 1.0);
    let good = w.powi(i32::try_from(sample_size).unwrap_or(i32::MAX));
    if good >= 1.0 {
        return 1;
    }
    let denom = (-good).ln_1p();
    if denom == 0.0 || !denom.is_finite() {
        return usize::MAX;
    }
    let m = ((1.0 - confidence).ln() / denom).ceil();
    if m.is_finite() && m < usize::MAX as f64 {
        (m as usize).max(1)
    } else {
        usize::MAX
    }
}

struct Scored<M> {
    model: M,
    score: f64,
    support: usize,
}

fn evaluate<E: Estimator, C: Consensus>(
    estimator: &E,
    consensus: &C,
    model: &E::Model,
    samples: &[E::Sample],
    t: f64,
) -> (f64, usize) {
    let mut score = 0.0;
    let mut support = 0;
    estimator.residuals(model, samples, |r| {
        if r <= t {
            support += 1;
            score += consensus.score(r, t);
        }
    });
    (score, support)
}

/// Runs RANSAC: minimal samples from `sampler`, hypotheses from `estimator.fit`, scores from
/// `consensus` at threshold `opts.max_error`.
///
/// - **Adaptive stopping** (paper §2.2, Table 1 step 2): after each new best model the number of
///   trials is bounded by [`required_iterations`] at its inlier ratio, within
///   `[min_iterations, max_iterations]`.
/// - **LO-RANSAC** (Chum, Matas & Kittler 2003), if enabled: each sampled hypothesis that scores
///   better than every earlier sampled hypothesis is refitted with
///   `estimator.refit`, iteratively on its inliers at `lo_threshold_factor · max_error` and on random
///   subsets of its inliers (the inner RANSAC); refits that score better at the real threshold
///   replace it.
/// - **T(d,d)** (Chum & Matas 2002), if `opts.tdd = Some(d)`: a hypothesis is verified on all samples
///   only if `d` random samples (drawn from the sampler's generator) are all inliers.
///
/// Errors only for invalid options; too few samples or no supported model give `success = false`.
pub fn run<E, C, S>(
    estimator: &E,
    consensus: &C,
    sampler: &mut S,
    samples: &[E::Sample],
    opts: &RansacOptions,
) -> Result<RansacReport<E::Model>, RansacError>
where
    E: Estimator,
    C: Consensus,
    S: Sampler,
{
    opts.validate()?;
    let n = samples.len();
    let p = E::SAMPLE_SIZE;
    let t = opts.max_error;
    let mut report = RansacReport {
        success: false,
        model: None,
        num_trials: 0,
        num_hypotheses: 0,
        num_verifications: 0,
        num_tdd_rejections: 0,
        num_lo_verifications: 0,
        support: 0,
        score: 0.0,
        inlier_mask: vec![false; n],
    };
    if n < p || p == 0 {
        return Ok(report);
    }
    let stop_exponent = p + opts.tdd.unwrap_or(0);
    // The least support a returned model needs, and the samples that would have found one that
    // has it: past them a run whose best model falls short stops (a hopeless pair, see
    // `RansacOptions::min_support`).
    let min_support = ((opts.min_inlier_ratio * n as f64).ceil() as usize)
        .max(p + 1)
        .max(opts.min_support);
    if min_support > n {
        return Ok(report);
    }
    let enough = required_iterations(
        min_support as f64 / n as f64,
        stop_exponent,
        1.0 - (1.0 - opts.confidence) / 10.0,
    );
    let mut best: Option<Scored<E::Model>> = None;
    let mut best_sampled_score = f64::NEG_INFINITY;
    let mut required = opts.max_iterations.min(enough);
    let mut indices = Vec::with_capacity(p);
    let mut minimal: Vec<E::Sample> = Vec::with_capacity(p);
    let mut models: Vec<E::Model> = Vec::new();

    while report.num_trials < opts.max_iterations
        && (report.num_trials < opts.min_iterations || report.num_trials < required)
    {
        report.num_trials += 1;
        sampler.sample(n, p, &mut indices);
        minimal.clear();
        minimal.extend(indices.iter().map(|&i| samples[i].clone()));
        models.clear();
        estimator.fit(&minimal, &mut models);
        report.num_hypotheses += models.len();
        for model in models.drain(..) {
            if let Some(d) = opts.tdd {
                let rng = sampler.rng();
                let passes = (0..d)
                    .all(|_| estimator.residual(&model, &samples[rng.random_range(0..n)]) <= t);
                if !passes {
                    report.num_tdd_rejections += 1;
                    continue;
                }
            }
            let (score, support) = evaluate(estimator, consensus, &model, samples, t);
            report.num_verifications += 1;
            // Local optimisation runs on every record among the sampled hypotheses, compared with
            // each other rather than with the (higher) locally optimised scores: otherwise one early
            // refinement that climbed into a wrong basin would keep every later all-inlier sample
            // from being refined.
            if score <= best_sampled_score {
                continue;
            }
            best_sampled_score = score;
            let mut candidate = Scored {
                model,
                score,
                support,
            };
            if opts.local_optimization {
                candidate = local_optimization(
                    estimator,
                    consensus,
                    sampler,
                    samples,
                    candidate,
                    opts,
                    &mut report,
                );
            }
            if best.as_ref().is_some_and(|b| candidate.score <= b.score) {
                continue;
            }
            required = required_iterations(
                candidate.support as f64 / n as f64,
                stop_exponent,
                opts.confidence,
            )
            .min(enough);
            best = Some(candidate);
        }
    }

    let Some(best) = best else {
        return Ok(report);
    };
    report.support = best.support;
    report.score = best.score;
    if best.support < min_support {
        return Ok(report);
    }
    let mut mask = Vec::with_capacity(samples.len());
    estimator.residuals(&best.model, samples, |r| mask.push(r <= t));
    report.inlier_mask = mask;
    report.success = true;
    report.model = Some(best.model);
    Ok(report)
}

/// LO step (LO-RANSAC, Chum, Matas & Kittler 2003, with the fixes of Lebeda, Matas & Chum 2012):
/// 1. iterate from the new best model: collect the inliers of the current model at the looser LO
///    threshold and refit on them;
/// 2. inner RANSAC: `lo_inner_samples` times, refit on a random subset of the best model's inliers
///    (half of them, between `SAMPLE_SIZE + 1` and `4·SAMPLE_SIZE` samples) and iterate from there.
///    The subsets let the search leave a basin where a few high-leverage outliers pull the
///    least-squares refit towards themselves.
///
/// Every refit is scored at the real threshold and the best-scoring model is kept.
fn local_optimization<E: Estimator, C: Consensus, S: Sampler>(
    estimator: &E,
    consensus: &C,
    sampler: &mut S,
    samples: &[E::Sample],
    best: Scored<E::Model>,
    opts: &RansacOptions,
    report: &mut RansacReport<E::Model>,
) -> Scored<E::Model> {
    let p = E::SAMPLE_SIZE;
    let start = best.model.clone();
    let mut best = iterate_refits(estimator, consensus, samples, start, best, opts, report);
    let mut keep = Vec::with_capacity(samples.len());
    estimator.residuals(&best.model, samples, |r| keep.push(r <= opts.max_error));
    let inliers: Vec<E::Sample> = samples
        .iter()
        .zip(&keep)
        .filter(|(_, &k)| k)
        .map(|(s, _)| s.clone())
        .collect();
    let k = (inliers.len() / 2).clamp(p + 1, 4 * p);
    if inliers.len() <= k {
        return best;
    }
    let mut indices = Vec::with_capacity(k);
    let mut subset: Vec<E::Sample> = Vec::with_capacity(k);
    for _ in 0..opts.lo_inner_samples {
        sampler.sample(inliers.len(), k, &mut indices);
        subset.clear();
        subset.extend(indices.iter().map(|&i| inliers[i].clone()));
        let Some(model) = estimator.refit(&subset, &best.model) else {
            continue;
        };
        let (score, support) = evaluate(estimator, consensus, &model, samples, opts.max_error);
        report.num_lo_verifications += 1;
        if score > best.score {
            best = Scored {
                model: model.clone(),
                score,
                support,
            };
        }
        best = iterate_refits(estimator, consensus, samples, model, best, opts, report);
    }
    best
}

/// From `current`, repeatedly collects its inliers at `lo_threshold_factor · max_error` and refits on
/// them, until the inlier set stops changing, a refit fails or `lo_iterations` refits were made.
/// Each refit is scored at the real threshold; returns the better of `best` and every refit.
fn iterate_refits<E: Estimator, C: Consensus>(
    estimator: &E,
    consensus: &C,
    samples: &[E::Sample],
    mut current: E::Model,
    mut best: Scored<E::Model>,
    opts: &RansacOptions,
    report: &mut RansacReport<E::Model>,
) -> Scored<E::Model> {
    let t = opts.max_error;
    let lo_t = t * opts.lo_threshold_factor;
    let mut inliers: Vec<E::Sample> = Vec::new();
    let mut mask: Vec<bool> = Vec::new();
    let mut previous_mask: Vec<bool> = Vec::new();
    for _ in 0..opts.lo_iterations {
        mask.clear();
        estimator.residuals(&current, samples, |r| mask.push(r <= lo_t));
        if mask == previous_mask {
            break;
        }
        inliers.clear();
        inliers.extend(
            samples
                .iter()
                .zip(&mask)
                .filter(|(_, &m)| m)
                .map(|(s, _)| s.clone()),
        );
        if inliers.len() <= E::SAMPLE_SIZE {
            break;
        }
        let Some(model) = estimator.refit(&inliers, &current) else {
            break;
        };
        let (score, support) = evaluate(estimator, consensus, &model, samples, t);
        report.num_lo_verifications += 1;
        if score > best.score {
            best = Scored {
                model: model.clone(),
                score,
                support,
            };
        }
        current = model;
        std::mem::swap(&mut mask, &mut previous_mask);
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{InlierCount, Msac, UniformSampler};

    /// A toy estimator: 2D lines `a x + b y = c` with unit normal, from 2 points.
    struct Line;

    impl Estimator for Line {
        type Model = (f64, f64, f64);
        type Sample = (f64, f64);
        const SAMPLE_SIZE: usize = 2;

        fn fit(&self, s: &[(f64, f64)], out: &mut Vec<Self::Model>) {
            let (dx, dy) = (s[1].0 - s[0].0, s[1].1 - s[0].1);
            let n = (dx * dx + dy * dy).sqrt();
            if n > 0.0 {
                let (a, b) = (-dy / n, dx / n);
                out.push((a, b, a * s[0].0 + b * s[0].1));
            }
        }

        fn residual(&self, m: &Self::Model, s: &(f64, f64)) -> f64 {
            (m.0 * s.0 + m.1 * s.1 - m.2).abs()
        }

        fn refit(&self, s: &[(f64, f64)], _m: &Self::Model) -> Option<Self::Model> {
            // Total least squares.
            let n = s.len() as f64;
            let (mx, my) = (
                s.iter().map(|p| p.0).sum::<f64>() / n,
                s.iter().map(|p| p.1).sum::<f64>() / n,
            );
            let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
            for p in s {
                let (x, y) = (p.0 - mx, p.1 - my);
                sxx += x * x;
                sxy += x * y;
                syy += y * y;
            }
            let theta = 0.5 * (2.0 * sxy).atan2(sxx - syy);
            let (a, b) = (-theta.sin(), theta.cos());
            Some((a, b, a * mx + b * my))
        }
    }

    fn line_data(seed: u64) -> Vec<(f64, f64)> {
        let mut r = UniformSampler::new(seed);
        let rng = r.rng();
        (0..100)
            .map(|i| {
                if i % 3 == 0 {
                    (rng.random_range(0.0..10.0), rng.random_range(0.0..10.0))
                } else {
                    let x = rng.random_range(0.0..10.0);
                    (x, 0.5 * x + 1.0 + rng.random_range(-0.05..0.05))
                }
            })
            .collect()
    }

    #[test]
    fn required_iterations_matches_formula() {
        // 1 − (1 − 0.5⁷)^m ≥ 0.99 ⇒ m = 588.
        assert_eq!(required_iterations(0.5, 7, 0.99), 588);
        assert_eq!(required_iterations(1.0, 7, 0.99), 1);
        assert_eq!(required_iterations(0.0, 7, 0.99), usize::MAX);
        assert!(required_iterations(0.6, 8, 0.99) > required_iterations(0.6, 7, 0.99));
    }

    #[test]
    fn finds_a_line_with_both_consensus_kinds() {
        let data = line_data(1);
        let opts = RansacOptions {
            max_error: 0.1,
            ..Default::default()
        };
        for msac in [false, true] {
            let mut sampler = UniformSampler::new(opts.seed);
            let rep = if msac {
                run(&Line, &Msac, &mut sampler, &data, &opts)
            } else {
                run(&Line, &InlierCount, &mut sampler, &data, &opts)
            }
            .expect("valid options");
            assert!(rep.success);
            let m = rep.model.expect("success");
            assert!((m.1 / m.0 + 2.0).abs() < 0.02, "{m:?}"); // y = 0.5x + 1 ⇔ −0.5x + y = 1
            let true_inliers = (0..100).filter(|i| i % 3 != 0).count();
            assert!(rep.support >= true_inliers);
            assert_eq!(rep.inlier_mask.iter().filter(|&&b| b).count(), rep.support);
            assert!(
                rep.num_trials < 100,
                "adaptive stopping: {} trials",
                rep.num_trials
            );
        }
    }

    /// A hopeless run (no line through enough of the points) stops once it has drawn the samples
    /// that would have found the weakest model it may return, at 10× the adaptive stop's
    /// confidence, instead of drawing `max_iterations`; a run whose model just reaches the bar
    /// still finds it.
    #[test]
    fn a_hopeless_run_stops_once_the_weakest_acceptable_model_would_have_been_found() {
        let mut r = UniformSampler::new(7);
        let rng = r.rng();
        let scatter: Vec<(f64, f64)> = (0..60)
            .map(|_| (rng.random_range(0.0..10.0), rng.random_range(0.0..10.0)))
            .collect();
        let opts = RansacOptions {
            max_error: 0.01,
            min_support: 30,
            ..Default::default()
        };
        let mut sampler = UniformSampler::new(0);
        let rep = run(&Line, &InlierCount, &mut sampler, &scatter, &opts).expect("valid");
        assert!(!rep.success);
        // 1 − (1 − 0.5²)^m ≥ 0.999 ⇒ m = 25.
        assert_eq!(rep.num_trials, required_iterations(0.5, 2, 0.999));
        assert_eq!(rep.num_trials, 25);
        // 30 of the 60 points on a line: found, with all of them.
        let mut half = scatter.clone();
        for (k, p) in half.iter_mut().enumerate().filter(|(k, _)| k % 2 == 0) {
            *p = (0.15 * k as f64, 0.3 * k as f64 - 1.0);
        }
        let mut sampler = UniformSampler::new(0);
        let rep = run(&Line, &InlierCount, &mut sampler, &half, &opts).expect("valid");
        assert!(rep.success && rep.support >= 30, "{} inliers", rep.support);
        // More points needed than there are: no sample is drawn.
        let many = RansacOptions {
            min_support: 61,
            ..opts
        };
        let rep = run(&Line, &InlierCount, &mut sampler, &half, &many).expect("valid");
        assert!(!rep.success && rep.num_trials == 0);
    }

    #[test]
    fn too_few_samples_and_invalid_options() {
        let mut sampler = UniformSampler::new(0);
        let rep = run(
            &Line,
            &InlierCount,
            &mut sampler,
            &[(0.0, 0.0)],
            &RansacOptions::default(),
        )
        .expect("valid");
        assert!(!rep.success && rep.model.is_none() && rep.num_trials == 0);
        let bad = RansacOptions {
            confidence: 2.0,
            ..Default::default()
        };
        assert!(run(&Line, &InlierCount, &mut sampler, &line_data(0), &bad).is_err());
    }
}
