//! The two-view geometry facade of Table 1: one call turns putative matches into a verified
//! relation and says which configuration the pair is in.
//!
//! Steps: RANSAC for F (7-point, LO, optional T(d,d)) and for H (4-point) on the same matches
//! (Table 1 step 2); F refined on its inliers by eq. 12 then by the Gold Standard of eq. 13 (step 3);
//! inliers re-collected under the refined F; GRIC (Torr 1998) chooses between F and H; a winning H is
//! called a pure rotation when it is conjugate to a rotation (eigenvalues of equal modulus), else
//! planar. Guided matching (step 4) needs descriptors and lives with the matcher, which calls
//! [`refine_two_view`] again afterwards (step 5).

use handheld_geometry::{
    gold_standard_fundamental, refine_fundamental, sampson_distance, view_distance,
    GoldStandardOptions, RefineFOptions,
};
use nalgebra::{Matrix3, Vector2};

use crate::consensus::Msac;
use crate::estimator::Estimator;
use crate::gric::{estimate_sigma, f_residuals_sq, gric, h_residuals_sq, GricModel};
use crate::options::{RansacError, RansacOptions};
use crate::ransac::run;
use crate::sampler::UniformSampler;
use crate::two_view::{FundamentalEstimator, HomographyEstimator, Match2d2d};

/// Options of [`estimate_two_view_geometry`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TwoViewOptions {
    /// Inlier threshold on the Sampson distance for F, pixels. Default 1.5.
    pub f_threshold_px: f64,
    /// Inlier threshold on the symmetric transfer error for H, pixels. Default 4.0.
    pub h_threshold_px: f64,
    /// Fewest inliers for a verified pair. Default 15.
    pub min_inliers: usize,
    /// The RANSAC loop (its `max_error` is replaced by the thresholds above). Default: 99 %
    /// confidence, LO on, T(1,1) on.
    pub ransac: RansacOptions,
    /// Refine F by eq. 12 and then eq. 13 (default true).
    pub refine: bool,
    /// Floor of the noise estimate used by GRIC, pixels. Default 0.3.
    pub min_sigma_px: f64,
    /// A winning H is a pure rotation when the moduli of its eigenvalues (det H = 1) differ by less
    /// than this fraction. Default 0.03.
    pub rotation_tolerance: f64,
}

impl Default for TwoViewOptions {
    fn default() -> Self {
        Self {
            f_threshold_px: 1.5,
            h_threshold_px: 4.0,
            min_inliers: 15,
            ransac: RansacOptions {
                tdd: Some(1),
                ..Default::default()
            },
            refine: true,
            min_sigma_px: 0.3,
            rotation_tolerance: 0.03,
        }
    }
}

impl TwoViewOptions {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.f_threshold_px > 0.0 && self.h_threshold_px > 0.0) {
            return Err("two-view thresholds must be positive".into());
        }
        if self.min_inliers < 8 {
            return Err(format!(
                "min_inliers must be at least 8, got {}",
                self.min_inliers
            ));
        }
        self.ransac.validate().map_err(|e| e.to_string())
    }
}

/// The configuration of a view pair (§2.2, §3.4's critical motions start here).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TwoViewConfiguration {
    /// F explains the matches better than any homography: usable for reconstruction.
    General,
    /// A homography explains the matches (a dominant plane or too little parallax).
    Planar,
    /// A homography conjugate to a rotation explains the matches: the camera only turned.
    PureRotation,
    /// Not enough inliers for any relation.
    TooFewInliers,
}

/// The verified relation of a pair.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TwoViewGeometry {
    pub configuration: TwoViewConfiguration,
    /// Refined fundamental matrix (`x2ᵀ F x1 = 0`), when one was found.
    pub f: Option<Matrix3<f64>>,
    /// Best homography (`x2 ~ H x1`), when one was found.
    pub h: Option<Matrix3<f64>>,
    /// Inliers of the relation that won (F for `General`, H otherwise).
    pub inlier_mask: Vec<bool>,
    pub num_inliers: usize,
    pub gric_f: f64,
    pub gric_h: f64,
    /// Noise estimated from the F inliers, pixels.
    pub sigma_px: f64,
    /// Image-based view distance of eq. 14 (median transfer error, pixels), for `General` pairs.
    pub view_distance_px: Option<f64>,
}

impl TwoViewGeometry {
    /// The result for `n` matches when no relation could be established.
    pub fn too_few(n: usize) -> Self {
        Self {
            configuration: TwoViewConfiguration::TooFewInliers,
            f: None,
            h: None,
            inlier_mask: vec![false; n],
            num_inliers: 0,
            gric_f: f64::INFINITY,
            gric_h: f64::INFINITY,
            sigma_px: f64::NAN,
            view_distance_px: None,
        }
    }
}

fn inliers_of(f: &Matrix3<f64>, matches: &[Match2d2d], thr: f64) -> Vec<bool> {
    matches
        .iter()
        .map(|m| sampson_distance(f, &m.x1, &m.x2) <= thr)
        .collect()
}

fn select(matches: &[Match2d2d], mask: &[bool]) -> (Vec<Vector2<f64>>, Vec<Vector2<f64>>) {
    matches
        .iter()
        .zip(mask)
        .filter(|(_, &k)| k)
        .map(|(m, _)| (m.x1, m.x2))
        .unzip()
}

/// Most correspondences the gold-standard step (eq. 13) adjusts: it estimates one 3D point per
/// correspondence, and past a couple of thousand evenly spread ones F no longer changes measurably,
/// while the cost keeps growing with every point (guided matching gives 5–10 k per pair).
const GOLD_STANDARD_MAX_POINTS: usize = 2000;

/// Table 1 steps 3 and 5: refines F on the matches it currently explains (eq. 12 on all of them,
/// then eq. 13 on at most [`GOLD_STANDARD_MAX_POINTS`], every k-th) and re-collects its inliers.
/// Returns the refined F and its inlier mask.
pub fn refine_two_view(
    f: &Matrix3<f64>,
    matches: &[Match2d2d],
    threshold_px: f64,
) -> (Matrix3<f64>, Vec<bool>) {
    let mask = inliers_of(f, matches, threshold_px);
    let (x1, x2) = select(matches, &mask);
    let mut best = *f;
    if let Ok(r) = refine_fundamental(&best, &x1, &x2, &RefineFOptions::default()) {
        best = r.f;
    }
    let (x1, x2) = if x1.len() > GOLD_STANDARD_MAX_POINTS {
        let step = x1.len().div_ceil(GOLD_STANDARD_MAX_POINTS);
        (
            x1.iter().step_by(step).copied().collect(),
            x2.iter().step_by(step).copied().collect(),
        )
    } else {
        (x1, x2)
    };
    if let Ok(g) = gold_standard_fundamental(&best, &x1, &x2, &GoldStandardOptions::default()) {
        best = g.f;
    }
    let refined_mask = inliers_of(&best, matches, threshold_px);
    // Keep the refinement only if it does not lose support.
    if refined_mask.iter().filter(|&&k| k).count() >= mask.iter().filter(|&&k| k).count() {
        (best, refined_mask)
    } else {
        (*f, mask)
    }
}

/// True when `h` (scaled to det 1) has eigenvalues of equal modulus within `tol`.
pub fn is_rotation_homography(h: &Matrix3<f64>, tol: f64) -> bool {
    let det = h.determinant();
    if det.abs() < 1e-300 || !det.is_finite() {
        return false;
    }
    let hn = h / det.cbrt();
    let ev = hn.complex_eigenvalues();
    let mods: Vec<f64> = ev.iter().map(|c| c.norm()).collect();
    let (lo, hi) = mods.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &m| {
        (lo.min(m), hi.max(m))
    });
    lo > 0.0 && hi / lo - 1.0 < tol
}

fn ransac<E: Estimator<Sample = Match2d2d>>(
    est: &E,
    matches: &[Match2d2d],
    opts: &RansacOptions,
) -> Result<crate::ransac::RansacReport<E::Model>, RansacError> {
    let mut sampler = UniformSampler::new(opts.seed);
    run(est, &Msac, &mut sampler, matches, opts)
}

/// Estimates the two-view geometry of putative matches (Table 1 steps 2–3 plus model selection).
pub fn estimate_two_view_geometry(
    matches: &[Match2d2d],
    opts: &TwoViewOptions,
) -> Result<TwoViewGeometry, RansacError> {
    let n = matches.len();
    if n < opts.min_inliers {
        return Ok(TwoViewGeometry::too_few(n));
    }
    let f_rep = ransac(
        &FundamentalEstimator,
        matches,
        &RansacOptions {
            max_error: opts.f_threshold_px,
            min_support: opts.ransac.min_support.max(opts.min_inliers),
            ..opts.ransac.clone()
        },
    )?;
    // A 4-point sample needs far fewer draws; capping them stops a scene without a dominant plane
    // from spending the whole budget (1 000 draws give 99 % confidence down to 26 % inliers).
    let h_opts = RansacOptions {
        max_error: opts.h_threshold_px,
        max_iterations: opts.ransac.max_iterations.min(1000),
        min_support: opts.ransac.min_support.max(opts.min_inliers),
        ..opts.ransac.clone()
    };
    let h_rep = ransac(&HomographyEstimator, matches, &h_opts)?;
    let h = h_rep
        .model
        .filter(|_| h_rep.success && h_rep.support >= opts.min_inliers);
    let f = f_rep
        .model
        .filter(|_| f_rep.success && f_rep.support >= opts.min_inliers);
    let (f, f_mask) = match f {
        Some(f0) if opts.refine => {
            let (f, m) = refine_two_view(&f0, matches, opts.f_threshold_px);
            (Some(f), m)
        }
        Some(f0) => (Some(f0), f_rep.inlier_mask.clone()),
        None => (None, vec![false; n]),
    };
    let f_sq = f.as_ref().map(|f| f_residuals_sq(f, matches));
    let sigma = match &f_sq {
        Some(e) => {
            let inl: Vec<f64> = e
                .iter()
                .zip(&f_mask)
                .filter(|(_, &k)| k)
                .map(|(v, _)| *v)
                .collect();
            estimate_sigma(&inl, opts.min_sigma_px)
        }
        None => opts.min_sigma_px.max(opts.h_threshold_px / 4.0),
    };
    // GRIC over the matches that at least one model explains: gross outliers of both carry no
    // information on the choice, yet the capped ρ would charge H twice as much for each of them.
    let h_sq = h.as_ref().map(|h| h_residuals_sq(h, matches));
    let used: Vec<bool> = (0..n)
        .map(|i| f_mask[i] || h_rep.inlier_mask.get(i).copied().unwrap_or(false))
        .collect();
    let pick = |e: &[f64]| {
        e.iter()
            .zip(&used)
            .filter(|(_, &k)| k)
            .map(|(v, _)| *v)
            .collect::<Vec<f64>>()
    };
    let gric_f = f_sq.as_ref().map_or(f64::INFINITY, |e| {
        gric(GricModel::Fundamental, &pick(e), sigma)
    });
    let gric_h = h_sq.as_ref().map_or(f64::INFINITY, |e| {
        gric(GricModel::Homography, &pick(e), sigma)
    });
    let mut out = TwoViewGeometry {
        f,
        h,
        sigma_px: sigma,
        gric_f,
        gric_h,
        ..TwoViewGeometry::too_few(n)
    };
    if f.is_none() && h.is_none() {
        return Ok(out);
    }
    if gric_h < gric_f {
        let hm = h.unwrap_or_else(Matrix3::identity);
        out.configuration = if is_rotation_homography(&hm, opts.rotation_tolerance) {
            TwoViewConfiguration::PureRotation
        } else {
            TwoViewConfiguration::Planar
        };
        out.inlier_mask = h_rep.inlier_mask;
    } else {
        out.configuration = TwoViewConfiguration::General;
        out.inlier_mask = f_mask;
        if let Some(fm) = &f {
            let (x1, x2) = select(matches, &out.inlier_mask);
            out.view_distance_px = view_distance(fm, &x1, &x2)
                .ok()
                .map(|v| v.median_transfer_px);
        }
    }
    out.num_inliers = out.inlier_mask.iter().filter(|&&k| k).count();
    if out.num_inliers < opts.min_inliers {
        out.configuration = TwoViewConfiguration::TooFewInliers;
    }
    Ok(out)
}
