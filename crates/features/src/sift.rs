//! SIFT-class wide-baseline features with RootSIFT descriptors (issue #3).
//!
//! Follows Lowe, "Distinctive image features from scale-invariant keypoints", IJCV 60(2), 2004:
//! a difference-of-Gaussians (DoG) scale space (§3), extrema in 3×3×3 neighbourhoods refined by a
//! quadratic fit in position and scale (§4, eq. 3), low-contrast and edge rejection (§4.1, eq. 4),
//! a 36-bin orientation histogram keeping every peak within 80 % of the highest (§5), and a
//! 4×4×8 gradient histogram with trilinear interpolation, normalised, clipped at 0.2 and renormalised
//! (§6.1). Thresholds follow OpenCV's conventions (contrast threshold divided by the layer count).
//! Descriptors are then mapped to RootSIFT (Arandjelović & Zisserman, "Three things everyone should
//! know to improve object retrieval", CVPR 2012): L1-normalise and take square roots, so the dot
//! product of two descriptors is the Hellinger kernel of the SIFT histograms and squared Euclidean
//! distance is `2 − 2·dot`.
//!
//! One file, split by stage: options, the scale space (parallel separable blurs with incremental
//! sigmas, 2×2-average decimation so that `x_img = (x_o + 0.5)·2^o − 0.5`), detection and
//! refinement, precomputed gradient magnitude/orientation per layer, then orientation and descriptor
//! per keypoint in parallel with stack-only scratch.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::detector::{Descriptors, FeatureDetector, Features, Keypoint};
use crate::error::{check, FeatureError};
use crate::gray::GrayImage;

mod descriptor;
mod scale_space;
use descriptor::{describe, orientations};
#[cfg(test)]
use scale_space::fast_atan2;
use scale_space::{blur, downsample, upsample2, OctaveGrad};

/// Length of a SIFT descriptor (4 × 4 spatial cells × 8 orientation bins).
pub const SIFT_DIM: usize = DESC_WIDTH * DESC_WIDTH * DESC_BINS;
const DESC_WIDTH: usize = 4;
const DESC_BINS: usize = 8;
const ORI_BINS: usize = 36;
/// Pixels at the octave border where no extremum is searched (OpenCV's `SIFT_IMG_BORDER`).
const IMG_BORDER: usize = 5;
const MAX_INTERP_STEPS: usize = 5;
/// Orientation window: Gaussian σ = 1.5 × scale, radius 3σ (Lowe §5).
const ORI_SIG_FACTOR: f32 = 1.5;
/// Width of one descriptor cell in units of the keypoint scale (Lowe §6.1).
const DESC_SCALE_FACTOR: f32 = 3.0;
const DESC_MAG_THRESHOLD: f32 = 0.2;
/// Largest window radius kept on the stack; larger windows are truncated (needs scale > 6 px per octave).
const MAX_RADIUS: usize = 64;
/// The smallest octave keeps at least this many pixels along its shorter side.
const MIN_OCTAVE_SIZE: usize = 16;

/// Options of [`Sift`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SiftOptions {
    /// Number of octaves; `None` (default) uses every octave whose shorter side is at least 16 px.
    pub num_octaves: Option<usize>,
    /// Scales sampled per octave, `s` in Lowe §3.2 (default 3).
    pub octave_layers: usize,
    /// DoG contrast threshold for images in [0, 1], divided by `octave_layers` as in OpenCV (default 0.04).
    pub contrast_threshold: f32,
    /// Largest ratio `r` of principal curvatures kept (Lowe eq. 4; default 10).
    pub edge_threshold: f32,
    /// Blur of each octave's base level, σ₀ (default 1.6).
    pub sigma: f32,
    /// Blur assumed already present in the input image (default 0.5).
    pub input_sigma: f32,
    /// Doubles the image first (octave −1): about 4× the keypoints of small scale, 4× the time (default false).
    pub upsample_first_octave: bool,
    /// Keeps at most this many keypoints, strongest DoG response first (default `Some(8192)`).
    pub max_features: Option<usize>,
    /// Orientation peaks at least this fraction of the highest one spawn a keypoint (default 0.8).
    pub orientation_peak_ratio: f32,
    /// Output RootSIFT (default true); false gives L2-normalised SIFT.
    pub root_sift: bool,
}

impl Default for SiftOptions {
    fn default() -> Self {
        Self {
            num_octaves: None,
            octave_layers: 3,
            contrast_threshold: 0.04,
            edge_threshold: 10.0,
            sigma: 1.6,
            input_sigma: 0.5,
            upsample_first_octave: false,
            max_features: Some(8192),
            orientation_peak_ratio: 0.8,
            root_sift: true,
        }
    }
}

impl SiftOptions {
    /// Checks that every field is in range; the error names the first offending one.
    pub fn validate(&self) -> Result<(), FeatureError> {
        check(self.num_octaves != Some(0), "num_octaves", || {
            "must be at least 1".into()
        })?;
        check(
            (1..=16).contains(&self.octave_layers),
            "octave_layers",
            || format!("must be in 1..=16, got {}", self.octave_layers),
        )?;
        for (name, v) in [
            ("contrast_threshold", self.contrast_threshold),
            ("sigma", self.sigma),
        ] {
            check(v.is_finite() && v > 0.0, name, || {
                format!("must be positive and finite, got {v}")
            })?;
        }
        let (e, i, p) = (
            self.edge_threshold,
            self.input_sigma,
            self.orientation_peak_ratio,
        );
        check(e.is_finite() && e >= 1.0, "edge_threshold", || {
            format!("must be ≥ 1, got {e}")
        })?;
        check(i.is_finite() && i >= 0.0, "input_sigma", || {
            format!("must be ≥ 0, got {i}")
        })?;
        check(p > 0.0 && p <= 1.0, "orientation_peak_ratio", || {
            format!("must be in (0, 1], got {p}")
        })?;
        check(self.max_features != Some(0), "max_features", || {
            "must be at least 1 (use None for no limit)".into()
        })
    }
}

/// The SIFT detector and (Root)SIFT descriptor.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Sift {
    pub options: SiftOptions,
}

impl Sift {
    pub fn new(options: SiftOptions) -> Self {
        Self { options }
    }
}

impl FeatureDetector for Sift {
    fn name(&self) -> &'static str {
        if self.options.root_sift {
            "rootsift"
        } else {
            "sift"
        }
    }

    /// Invalid options give no features (and a warning); use [`SiftOptions::validate`] up front.
    fn detect(&self, image: &GrayImage) -> Features {
        if let Err(e) = self.options.validate() {
            tracing::warn!("invalid SIFT options: {e}");
            return Features::default();
        }
        sift_detect(image, &self.options)
    }
}

/// A refined DoG extremum in its octave's coordinates.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// Index into the gradient pyramid.
    grad: usize,
    layer: usize,
    x: f32,
    y: f32,
    /// σ in this octave's pixels.
    scale: f32,
    response: f32,
}

fn sift_detect(image: &GrayImage, o: &SiftOptions) -> Features {
    let (first_octave, mut base) = if o.upsample_first_octave {
        (-1, upsample2(image))
    } else {
        (0, image.clone())
    };
    if base.width < MIN_OCTAVE_SIZE || base.height < MIN_OCTAVE_SIZE {
        return Features {
            keypoints: Vec::new(),
            descriptors: Descriptors {
                dim: SIFT_DIM,
                data: Vec::new(),
            },
        };
    }
    let s = o.octave_layers;
    let mut max_octaves = 1;
    while base.width.min(base.height) >> max_octaves >= MIN_OCTAVE_SIZE {
        max_octaves += 1;
    }
    let num_octaves = o.num_octaves.map_or(max_octaves, |n| n.min(max_octaves));
    // Incremental blurs: level i has total σ₀·k^i, k = 2^{1/s}, reached from level i−1 by σ₀·k^{i−1}·√(k²−1).
    let k = 2f32.powf(1.0 / s as f32);
    let sig_inc: Vec<f32> = (1..s + 3)
        .map(|i| o.sigma * k.powi(i as i32 - 1) * (k * k - 1.0).sqrt())
        .collect();
    let input_sigma = o.input_sigma * if o.upsample_first_octave { 2.0 } else { 1.0 };
    let sig0 = (o.sigma * o.sigma - input_sigma * input_sigma)
        .max(0.01)
        .sqrt();
    base.data = blur(&base.data, base.width, base.height, sig0);

    let mut grads: Vec<OctaveGrad> = Vec::with_capacity(num_octaves);
    let mut cands: Vec<Candidate> = Vec::new();
    for oi in 0..num_octaves {
        let (w, h) = (base.width, base.height);
        let mut gauss: Vec<Vec<f32>> = Vec::with_capacity(s + 3);
        gauss.push(std::mem::take(&mut base.data));
        for &si in &sig_inc {
            let next = blur(&gauss[gauss.len() - 1], w, h, si);
            gauss.push(next);
        }
        let levels: Vec<Vec<f32>> = gauss[1..=s].to_vec();
        if oi + 1 < num_octaves {
            base = downsample(&gauss[s], w, h);
        }
        // DoG in place (level i becomes G[i+1] − G[i]; the last level is dropped), saving s+2 buffers.
        for i in 0..s + 2 {
            let (lo, hi) = gauss.split_at_mut(i + 1);
            lo[i]
                .par_chunks_mut(w)
                .zip(hi[0].par_chunks(w))
                .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(a, b)| *a = b - *a));
        }
        gauss.truncate(s + 2);
        cands.extend(detect_octave(&gauss, w, h, grads.len(), o));
        grads.push(OctaveGrad {
            octave: first_octave + oi as i32,
            w,
            h,
            levels,
        });
    }

    // Strongest first; stable sort keeps the deterministic detection order among equals.
    cands.sort_by(|a, b| b.response.total_cmp(&a.response));
    if let Some(m) = o.max_features {
        cands.truncate(m);
    }
    // Windows are read in scan order of the blurred levels (octave, layer, row), not in order of
    // strength: strongest-first jumps across levels of tens of MB (25 MB for the first octave of
    // a 6 MP image), and the describe loop waited on memory for a third of its time (`perf` on
    // fountain-P11). Each window's result is the same whatever the order.
    let by_place = |a: &Candidate, b: &Candidate| {
        (a.grad, a.layer)
            .cmp(&(b.grad, b.layer))
            .then(a.y.total_cmp(&b.y))
            .then(a.x.total_cmp(&b.x))
    };
    let mut order: Vec<usize> = (0..cands.len()).collect();
    order.sort_by(|&a, &b| by_place(&cands[a], &cands[b]));
    let mut angles = vec![([0f32; ORI_BINS / 2], 0usize); cands.len()];
    let found: Vec<([f32; ORI_BINS / 2], usize)> = order
        .par_iter()
        .map(|&ci| {
            let c = &cands[ci];
            orientations(&grads[c.grad], c, o.orientation_peak_ratio)
        })
        .collect();
    for (&ci, a) in order.iter().zip(found) {
        angles[ci] = a;
    }
    let mut oriented: Vec<(usize, f32)> = angles
        .iter()
        .enumerate()
        .flat_map(|(ci, (a, n))| a[..*n].iter().map(move |&angle| (ci, angle)))
        .collect();
    if let Some(m) = o.max_features {
        oriented.truncate(m);
    }
    // `oriented` lists each candidate's angles together, in candidate order: its order by place
    // is the candidates' order mapped through `rank`, stable within a candidate.
    let mut rank = vec![0usize; cands.len()];
    for (k, &ci) in order.iter().enumerate() {
        rank[ci] = k;
    }
    let mut placed: Vec<usize> = (0..oriented.len()).collect();
    placed.sort_by_key(|&k| rank[oriented[k].0]);
    let mut sorted = vec![0f32; oriented.len() * SIFT_DIM];
    sorted
        .par_chunks_mut(SIFT_DIM)
        .zip(placed.par_iter())
        .for_each(|(out, &k)| {
            let (ci, angle) = oriented[k];
            let c = &cands[ci];
            describe(&grads[c.grad], c, angle, o.root_sift, out);
        });
    let mut data = vec![0f32; oriented.len() * SIFT_DIM];
    for (src, &k) in sorted.chunks_exact(SIFT_DIM).zip(&placed) {
        data[k * SIFT_DIM..(k + 1) * SIFT_DIM].copy_from_slice(src);
    }
    let keypoints = oriented
        .iter()
        .map(|&(ci, angle)| {
            let c = &cands[ci];
            let f = 2f32.powi(grads[c.grad].octave);
            Keypoint {
                x: (c.x + 0.5) * f - 0.5,
                y: (c.y + 0.5) * f - 0.5,
                scale: c.scale * f,
                orientation: angle,
                response: c.response,
            }
        })
        .collect();
    Features {
        keypoints,
        descriptors: Descriptors {
            dim: SIFT_DIM,
            data,
        },
    }
}

/// Pixels of a DoG row tested at once for a value beyond the contrast threshold.
const SCAN_CHUNK: usize = 16;

/// Scale-space extrema of one octave, refined and filtered, in parallel over (layer, row).
fn detect_octave(
    dog: &[Vec<f32>],
    w: usize,
    h: usize,
    grad: usize,
    o: &SiftOptions,
) -> Vec<Candidate> {
    let s = o.octave_layers;
    if w <= 2 * IMG_BORDER || h <= 2 * IMG_BORDER {
        return Vec::new();
    }
    let threshold = 0.5 * o.contrast_threshold / s as f32;
    let rows: Vec<(usize, usize)> = (1..=s)
        .flat_map(|l| (IMG_BORDER..h - IMG_BORDER).map(move |r| (l, r)))
        .collect();
    rows.par_iter()
        .flat_map_iter(|&(l, r)| {
            let mut found = Vec::new();
            let (prev, cur, next) = (&dog[l - 1], &dog[l], &dog[l + 1]);
            let (lo, hi) = (r * w + IMG_BORDER, (r + 1) * w - IMG_BORDER);
            let mut start = lo;
            while start < hi {
                let end = (start + SCAN_CHUNK).min(hi);
                // Most chunks hold no value beyond the threshold: a branch-free test of the whole
                // chunk (it vectorises) skips them. NaN fails both this and the tests below.
                let beyond = |a: bool, v: &f32| a | (v.abs() > threshold);
                let any = match <&[f32; SCAN_CHUNK]>::try_from(&cur[start..end]) {
                    Ok(chunk) => chunk.iter().fold(false, beyond),
                    Err(_) => cur[start..end].iter().fold(false, beyond),
                };
                if any {
                    for i in start..end {
                        let v = cur[i];
                        // Cheap same-row tests first; most pixels fail them.
                        let candidate = (v > threshold && v >= cur[i - 1] && v >= cur[i + 1])
                            || (v < -threshold && v <= cur[i - 1] && v <= cur[i + 1]);
                        if candidate && is_extremum(prev, cur, next, i, w) {
                            if let Some(c) = refine(dog, w, h, l, r, i - r * w, grad, o) {
                                found.push(c);
                            }
                        }
                    }
                }
                start = end;
            }
            found
        })
        .collect()
}

/// `cur[i]` is ≥ (or ≤, when negative) its 26 neighbours in the 3×3×3 DoG neighbourhood.
#[inline]
fn is_extremum(prev: &[f32], cur: &[f32], next: &[f32], i: usize, w: usize) -> bool {
    let v = cur[i];
    let offsets = [
        i - w - 1,
        i - w,
        i - w + 1,
        i - 1,
        i + 1,
        i + w - 1,
        i + w,
        i + w + 1,
    ];
    if v > 0.0 {
        offsets.iter().all(|&j| v >= cur[j])
            && [prev, next]
                .iter()
                .all(|p| v >= p[i] && offsets.iter().all(|&j| v >= p[j]))
    } else {
        offsets.iter().all(|&j| v <= cur[j])
            && [prev, next]
                .iter()
                .all(|p| v <= p[i] && offsets.iter().all(|&j| v <= p[j]))
    }
}

/// Gradient and Hessian of the DoG at `(layer, i)` by central differences (order x, y, σ).
fn dog_derivatives(dog: &[Vec<f32>], l: usize, i: usize, w: usize) -> ([f32; 3], [[f32; 3]; 3]) {
    let (p, c, n) = (&dog[l - 1], &dog[l], &dog[l + 1]);
    let g = [
        (c[i + 1] - c[i - 1]) * 0.5,
        (c[i + w] - c[i - w]) * 0.5,
        (n[i] - p[i]) * 0.5,
    ];
    let v2 = 2.0 * c[i];
    let dxx = c[i + 1] + c[i - 1] - v2;
    let dyy = c[i + w] + c[i - w] - v2;
    let dss = n[i] + p[i] - v2;
    let dxy = (c[i + w + 1] - c[i + w - 1] - c[i - w + 1] + c[i - w - 1]) * 0.25;
    let dxs = (n[i + 1] - n[i - 1] - p[i + 1] + p[i - 1]) * 0.25;
    let dys = (n[i + w] - n[i - w] - p[i + w] + p[i - w]) * 0.25;
    (g, [[dxx, dxy, dxs], [dxy, dyy, dys], [dxs, dys, dss]])
}

/// Solves `H x = g` (LU with partial pivoting); `None` when `H` is singular.
fn solve3(hm: &[[f32; 3]; 3], g: &[f32; 3]) -> Option<[f32; 3]> {
    let x = Matrix3::from_fn(|r, c| hm[r][c])
        .lu()
        .solve(&Vector3::from(*g))?;
    x.iter().all(|v| v.is_finite()).then(|| [x[0], x[1], x[2]])
}

/// Quadratic sub-pixel/sub-scale refinement (Lowe eq. 3), moving to a neighbour while an offset
/// exceeds 0.5, then the contrast (|D(x̂)|·s ≥ threshold) and edge (eq. 4) tests.
#[allow(clippy::too_many_arguments)]
fn refine(
    dog: &[Vec<f32>],
    w: usize,
    h: usize,
    layer: usize,
    r: usize,
    c: usize,
    grad: usize,
    o: &SiftOptions,
) -> Option<Candidate> {
    let s = o.octave_layers;
    let (mut l, mut r, mut c) = (layer, r, c);
    let mut step = 0;
    let (offset, g, hm) = loop {
        let (g, hm) = dog_derivatives(dog, l, r * w + c, w);
        let x = solve3(&hm, &g)?.map(|v| -v);
        if x.iter().all(|v| v.abs() < 0.5) {
            break (x, g, hm);
        }
        step += 1;
        if step >= MAX_INTERP_STEPS || x.iter().any(|v| !v.is_finite() || v.abs() > 1e4) {
            return None;
        }
        let nc = c as i64 + x[0].round() as i64;
        let nr = r as i64 + x[1].round() as i64;
        let nl = l as i64 + x[2].round() as i64;
        let b = IMG_BORDER as i64;
        if nl < 1
            || nl > s as i64
            || nc < b
            || nc >= (w - IMG_BORDER) as i64
            || nr < b
            || nr >= (h - IMG_BORDER) as i64
        {
            return None;
        }
        (l, r, c) = (nl as usize, nr as usize, nc as usize);
    };
    let contrast =
        dog[l][r * w + c] + 0.5 * (g[0] * offset[0] + g[1] * offset[1] + g[2] * offset[2]);
    if contrast.abs() * (s as f32) < o.contrast_threshold {
        return None;
    }
    let (tr, det) = (
        hm[0][0] + hm[1][1],
        hm[0][0] * hm[1][1] - hm[0][1] * hm[0][1],
    );
    let e = o.edge_threshold;
    if det <= 0.0 || tr * tr * e >= (e + 1.0) * (e + 1.0) * det {
        return None;
    }
    Some(Candidate {
        grad,
        layer: l,
        x: c as f32 + offset[0],
        y: r as f32 + offset[1],
        scale: o.sigma * 2f32.powf((l as f32 + offset[2]) / s as f32),
        response: contrast.abs(),
    })
}

#[cfg(test)]
#[path = "sift_tests.rs"]
mod tests;
