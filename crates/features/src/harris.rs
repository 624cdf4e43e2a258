//! Harris corners for still images (paper §2.1; Harris & Stephens, "A combined corner and edge
//! detector", Alvey 1988), and the [`HarrisZncc`] detector that describes each corner by its
//! normalised 7×7 patch (eq. 9).
//!
//! The structure tensor `M` of eq. 8's second-order approximation is built from the gradients of a
//! lightly pre-smoothed image, weighted by a Gaussian window (σ = 0.7, as the paper suggests for still
//! images). The response is `R = det M − k (trace M)²` with Harris' `k = 0.04`. Only local maxima are
//! kept; each is refined to sub-pixel precision by a least-squares quadratic fit to its 3×3 response
//! neighbourhood ("quadratic approximation of the neighborhood of the local maxima"). Corners are spread
//! over the image by grid bucketing: every cell first gets its share of the strongest corners, then
//! the remaining budget goes to the strongest leftovers.
//!
//! Split from [`crate::zncc`] (the patch descriptor and its matcher) so that the KLT tracker can reuse
//! the detector without the descriptor.

use rayon::prelude::*;

use crate::detector::{Descriptors, FeatureDetector, Features, Keypoint};
use crate::error::{check, FeatureError};
use crate::gray::GrayImage;
use crate::zncc::zncc_patch_into;

/// Options of [`detect_harris`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HarrisOptions {
    /// Harris' `k` in `R = det M − k (trace M)²`. Default 0.04 (paper §2.1).
    pub k: f32,
    /// σ in pixels of the Gaussian pre-smoothing before the gradients are taken. Default 0.7.
    pub derivative_sigma: f32,
    /// σ in pixels of the Gaussian window `w(x, y)` on the gradient products. Default 1.5. (Paper §2.1
    /// suggests 0.7; after the 0.7 pre-smoothing such a window leaves a hole in `M` at X-junctions, whose
    /// Harris maxima then land up to 1.4 px off the corner, and on the rendered test views it matches
    /// less reliably: ZNCC precision 0.94 against 0.96 with 1.5.)
    pub window_sigma: f32,
    /// Non-maximum suppression radius: a corner is the maximum of its `(2r+1)²` neighbourhood.
    /// Default 2 (5×5).
    pub nms_radius: usize,
    /// Maximum number of corners returned. Default 2000.
    pub max_features: usize,
    /// Side in pixels of the square bucketing cells. Default 32.
    pub cell_size: usize,
    /// Corners weaker than this fraction of the strongest response are dropped. Default 0.001.
    pub min_relative_response: f32,
    /// Absolute response floor (intensities in [0, 1]; image noise of one grey level gives about
    /// 1e-11). Default 1e-8.
    pub min_response: f32,
    /// Corners closer than this many pixels to the image border are dropped. Default 8.
    pub border: usize,
    /// After the quadratic fit, refine by [`refine_corner_gradient`] over a `(2r+1)²` window of this
    /// radius; 0 keeps the paper's quadratic fit alone. Default 3 (checkerboard corners: mean error
    /// 0.03 px against 0.08 px for the quadratic fit alone).
    pub gradient_refine_radius: usize,
    /// The gradient refinement is kept only when it moves the corner by at most this many pixels per
    /// axis (it can otherwise jump to a neighbouring corner of a busy texture). Default 1.
    pub refine_guard: f32,
}

impl Default for HarrisOptions {
    fn default() -> Self {
        Self {
            k: 0.04,
            derivative_sigma: 0.7,
            window_sigma: 1.5,
            nms_radius: 2,
            max_features: 2000,
            cell_size: 32,
            min_relative_response: 0.001,
            min_response: 1e-8,
            border: 8,
            gradient_refine_radius: 3,
            refine_guard: 1.0,
        }
    }
}

impl HarrisOptions {
    /// Checks that every field is in range.
    pub fn validate(&self) -> Result<(), FeatureError> {
        check(self.k > 0.0 && self.k < 0.25, "k", || {
            format!("harris k must be in (0, 0.25), got {}", self.k)
        })?;
        let (d, w) = (self.derivative_sigma, self.window_sigma);
        check(d >= 0.0 && d.is_finite(), "derivative_sigma", || {
            format!("must be finite and non-negative, got {d}")
        })?;
        check(w > 0.0 && w.is_finite(), "window_sigma", || {
            format!("must be finite and positive, got {w}")
        })?;
        check(self.nms_radius != 0, "nms_radius", || {
            "must be at least 1".into()
        })?;
        let g = self.refine_guard;
        check(g >= 0.0 && g.is_finite(), "refine_guard", || {
            format!("must be finite and non-negative, got {g}")
        })?;
        check(self.cell_size != 0, "cell_size", || {
            "must be positive".into()
        })?;
        let r = self.min_relative_response;
        check((0.0..1.0).contains(&r), "min_relative_response", || {
            format!("must be in [0, 1), got {r}")
        })?;
        let m = self.min_response;
        check(m >= 0.0 && m.is_finite(), "min_response", || {
            format!("must be finite and non-negative, got {m}")
        })
    }
}

/// The Harris response `R = det M − k (trace M)²` of every pixel (row-major, same size as `img`).
pub fn harris_response(img: &GrayImage, options: &HarrisOptions) -> GrayImage {
    response_and_gradients(img, options).0
}

/// The response and the gradients of the pre-smoothed image it was computed from.
fn response_and_gradients(
    img: &GrayImage,
    options: &HarrisOptions,
) -> (GrayImage, GrayImage, GrayImage) {
    let smooth = img.gaussian_blur(options.derivative_sigma);
    let (gx, gy) = smooth.gradients();
    let n = img.width * img.height;
    let mut xx = GrayImage::new(img.width, img.height);
    let mut yy = GrayImage::new(img.width, img.height);
    let mut xy = GrayImage::new(img.width, img.height);
    for i in 0..n {
        let (a, b) = (gx.data[i], gy.data[i]);
        xx.data[i] = a * a;
        yy.data[i] = b * b;
        xy.data[i] = a * b;
    }
    let s = options.window_sigma;
    let (xx, (yy, xy)) = rayon::join(
        || xx.gaussian_blur(s),
        || rayon::join(|| yy.gaussian_blur(s), || xy.gaussian_blur(s)),
    );
    let k = options.k;
    let data = xx
        .data
        .iter()
        .zip(&yy.data)
        .zip(&xy.data)
        .map(|((&a, &b), &c)| a * b - c * c - k * (a + b) * (a + b))
        .collect();
    (
        GrayImage {
            width: img.width,
            height: img.height,
            data,
        },
        gx,
        gy,
    )
}

/// Gradient-based sub-pixel corner position (Förstner & Gülch, "A fast operator for detection and
/// precise location of distinct points, corners and centres of circular features", 1987): the point
/// `q` minimising `Σ w(p) (∇I(p)ᵀ (p − q))²` over a Gaussian-weighted window, i.e. the least-squares
/// intersection of the edge lines through the window; iterated with the window re-centred. `None` when
/// the system is singular or the point moves more than `radius` pixels.
pub fn refine_corner_gradient(
    gx: &GrayImage,
    gy: &GrayImage,
    x: f32,
    y: f32,
    radius: usize,
) -> Option<(f32, f32)> {
    let r = radius as isize;
    let sigma2 = (0.5 * radius as f64 + 0.5).powi(2);
    let (mut qx, mut qy) = (x as f64, y as f64);
    for _ in 0..5 {
        let (cx, cy) = (qx.round() as isize, qy.round() as isize);
        let (mut a, mut b, mut c, mut u, mut v) = (0f64, 0f64, 0f64, 0f64, 0f64);
        for py in cy - r..=cy + r {
            for px in cx - r..=cx + r {
                let (ix, iy) = (gx.get_clamped(px, py) as f64, gy.get_clamped(px, py) as f64);
                let (dx, dy) = (px as f64 - qx, py as f64 - qy);
                let w = (-(dx * dx + dy * dy) / (2.0 * sigma2)).exp();
                let (gxx, gxy, gyy) = (w * ix * ix, w * ix * iy, w * iy * iy);
                a += gxx;
                b += gxy;
                c += gyy;
                u += gxx * px as f64 + gxy * py as f64;
                v += gxy * px as f64 + gyy * py as f64;
            }
        }
        let det = a * c - b * b;
        if det.is_nan() || det <= 1e-12 * (a + c) * (a + c) {
            return None;
        }
        let (nx, ny) = ((c * u - b * v) / det, (a * v - b * u) / det);
        let step = (nx - qx).hypot(ny - qy);
        (qx, qy) = (nx, ny);
        if !((qx - x as f64).abs() <= radius as f64 && (qy - y as f64).abs() <= radius as f64) {
            return None;
        }
        if step < 1e-3 {
            break;
        }
    }
    Some((qx as f32, qy as f32))
}

/// Sub-pixel offset of the maximum of the least-squares quadratic `a + bx + cy + dx² + exy + fy²`
/// through the 3×3 values `v` (row-major, centre `v[4]`); `None` when the fit has no maximum within
/// one pixel.
pub fn quadratic_peak_offset(v: &[f32; 9]) -> Option<(f32, f32)> {
    let col = |i: usize| v[i] + v[i + 3] + v[i + 6];
    let row = |j: usize| v[3 * j] + v[3 * j + 1] + v[3 * j + 2];
    let b = (col(2) - col(0)) / 6.0;
    let c = (row(2) - row(0)) / 6.0;
    let d = (col(0) + col(2) - 2.0 * col(1)) / 6.0;
    let f = (row(0) + row(2) - 2.0 * row(1)) / 6.0;
    let e = (v[8] - v[6] - v[2] + v[0]) / 4.0;
    // Gradient (b, c), Hessian [[2d, e], [e, 2f]] must be negative definite.
    let det = 4.0 * d * f - e * e;
    if !(d < 0.0 && det > 0.0) {
        return None;
    }
    let ox = -(2.0 * f * b - e * c) / det;
    let oy = -(2.0 * d * c - e * b) / det;
    (ox.abs() <= 1.0 && oy.abs() <= 1.0).then_some((ox, oy))
}

/// Harris corners of `img`, strongest first, with sub-pixel positions; at most `options.max_features`,
/// spread over the image by grid bucketing. Invalid options or a tiny image give no corners.
pub fn detect_harris(img: &GrayImage, options: &HarrisOptions) -> Vec<Keypoint> {
    if options.validate().is_err() || options.max_features == 0 {
        return Vec::new();
    }
    let (w, h) = (img.width, img.height);
    let margin = options.border.max(options.nms_radius).max(1);
    if w <= 2 * margin || h <= 2 * margin {
        return Vec::new();
    }
    let (resp, gx, gy) = response_and_gradients(img, options);
    let max_r = (margin..h - margin)
        .into_par_iter()
        .map(|y| {
            resp.data[y * w + margin..y * w + w - margin]
                .iter()
                .copied()
                .fold(f32::MIN, f32::max)
        })
        .reduce(|| f32::MIN, f32::max);
    let threshold = (max_r * options.min_relative_response).max(options.min_response);
    let r = options.nms_radius as isize;
    // Local maxima: strictly larger than the neighbours before it in scan order, not smaller than those
    // after it, so plateaus yield exactly one corner.
    let mut candidates: Vec<Keypoint> = (margin..h - margin)
        .into_par_iter()
        .flat_map_iter(|y| {
            let resp = &resp;
            (margin..w - margin).filter_map(move |x| {
                let v = resp.data[y * w + x];
                if v <= threshold {
                    return None;
                }
                for dy in -r..=r {
                    for dx in -r..=r {
                        if dx == 0 && dy == 0 {
                            continue;
                        }
                        let n = resp.get_clamped(x as isize + dx, y as isize + dy);
                        let before = dy < 0 || (dy == 0 && dx < 0);
                        if n > v || (before && n == v) {
                            return None;
                        }
                    }
                }
                let mut nb = [0f32; 9];
                for (i, o) in nb.iter_mut().enumerate() {
                    *o = resp.data[(y + i / 3 - 1) * w + x + i % 3 - 1];
                }
                let (ox, oy) = quadratic_peak_offset(&nb).unwrap_or((0.0, 0.0));
                Some(Keypoint {
                    x: x as f32 + ox,
                    y: y as f32 + oy,
                    scale: 1.0,
                    orientation: 0.0,
                    response: v,
                })
            })
        })
        .collect();
    candidates.sort_by(|a, b| {
        b.response
            .total_cmp(&a.response)
            .then(a.y.total_cmp(&b.y))
            .then(a.x.total_cmp(&b.x))
    });
    let mut corners = bucket(candidates, w, h, options.cell_size, options.max_features);
    if options.gradient_refine_radius == 0 {
        return corners;
    }
    let guard = options.refine_guard;
    corners.par_iter_mut().for_each(|kp| {
        if let Some((rx, ry)) =
            refine_corner_gradient(&gx, &gy, kp.x, kp.y, options.gradient_refine_radius)
        {
            if (rx - kp.x).abs() <= guard && (ry - kp.y).abs() <= guard {
                (kp.x, kp.y) = (rx, ry);
            }
        }
    });
    suppress_duplicates(corners, w, h, options.nms_radius as f32)
}

/// Drops corners within `d` pixels of a stronger one (refinement can move neighbouring maxima of one
/// corner onto the same point). `sorted` must be strongest first.
fn suppress_duplicates(sorted: Vec<Keypoint>, w: usize, h: usize, d: f32) -> Vec<Keypoint> {
    let d = d.max(0.5);
    let cols = (w as f32 / d) as usize + 1;
    let rows = (h as f32 / d) as usize + 1;
    let cell = |x: f32, y: f32| {
        (
            (x / d).clamp(0.0, (cols - 1) as f32) as usize,
            (y / d).clamp(0.0, (rows - 1) as f32) as usize,
        )
    };
    let mut grid: Vec<Vec<(f32, f32)>> = vec![Vec::new(); cols * rows];
    let mut out = Vec::with_capacity(sorted.len());
    for kp in sorted {
        let (cx, cy) = cell(kp.x, kp.y);
        let taken = (cy.saturating_sub(1)..=(cy + 1).min(rows - 1)).any(|yy| {
            (cx.saturating_sub(1)..=(cx + 1).min(cols - 1)).any(|xx| {
                grid[yy * cols + xx]
                    .iter()
                    .any(|&(px, py)| (px - kp.x).powi(2) + (py - kp.y).powi(2) < d * d)
            })
        });
        if !taken {
            grid[cy * cols + cx].push((kp.x, kp.y));
            out.push(kp);
        }
    }
    out
}

/// Grid bucketing: each cell keeps its strongest `⌈max / cells⌉` corners, the leftover budget goes to
/// the strongest of the rest. `sorted` must be strongest first; the result is strongest first.
fn bucket(sorted: Vec<Keypoint>, w: usize, h: usize, cell: usize, max: usize) -> Vec<Keypoint> {
    if sorted.len() <= max {
        return sorted;
    }
    let cols = w.div_ceil(cell);
    let rows = h.div_ceil(cell);
    let quota = max.div_ceil(cols * rows);
    let mut count = vec![0usize; cols * rows];
    let mut keep = vec![false; sorted.len()];
    let mut kept = 0;
    for (i, kp) in sorted.iter().enumerate() {
        let c = ((kp.y.max(0.0) as usize / cell).min(rows - 1)) * cols
            + (kp.x.max(0.0) as usize / cell).min(cols - 1);
        if count[c] < quota && kept < max {
            count[c] += 1;
            keep[i] = true;
            kept += 1;
        }
    }
    for k in keep.iter_mut() {
        if kept >= max {
            break;
        }
        if !*k {
            *k = true;
            kept += 1;
        }
    }
    sorted
        .into_iter()
        .zip(keep)
        .filter_map(|(kp, k)| k.then_some(kp))
        .collect()
}

/// Harris corners described by their `(2·patch_radius+1)²` patches normalised to zero mean and unit
/// norm (see [`crate::zncc`]): the dot product of two descriptors is their ZNCC (eq. 9). Corners whose
/// patch is nearly uniform are dropped.
#[derive(Clone, Debug, PartialEq)]
pub struct HarrisZncc {
    pub options: HarrisOptions,
    /// Patch radius in pixels; 3 gives the paper's 7×7 windows.
    pub patch_radius: usize,
}

impl Default for HarrisZncc {
    fn default() -> Self {
        Self {
            options: HarrisOptions::default(),
            patch_radius: 3,
        }
    }
}

impl FeatureDetector for HarrisZncc {
    fn name(&self) -> &'static str {
        "harris-zncc"
    }

    fn detect(&self, image: &GrayImage) -> Features {
        let mut opts = self.options.clone();
        opts.border = opts.border.max(self.patch_radius + 1);
        let corners = detect_harris(image, &opts);
        let side = 2 * self.patch_radius + 1;
        let dim = side * side;
        let described: Vec<(Keypoint, Vec<f32>)> = corners
            .into_par_iter()
            .filter_map(|kp| {
                let mut d = vec![0f32; dim];
                zncc_patch_into(image, kp.x, kp.y, self.patch_radius, &mut d).then_some((kp, d))
            })
            .collect();
        let mut keypoints = Vec::with_capacity(described.len());
        let mut data = Vec::with_capacity(described.len() * dim);
        for (kp, d) in described {
            keypoints.push(kp);
            data.extend_from_slice(&d);
        }
        Features {
            keypoints,
            descriptors: Descriptors { dim, data },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadratic_fit_recovers_an_exact_paraboloid() {
        let (px, py) = (0.3f32, -0.2f32);
        let mut v = [0f32; 9];
        for (i, o) in v.iter_mut().enumerate() {
            let (x, y) = ((i % 3) as f32 - 1.0, (i / 3) as f32 - 1.0);
            *o = 5.0 - 2.0 * (x - px).powi(2) - 1.5 * (y - py).powi(2) + 0.5 * (x - px) * (y - py);
        }
        let (ox, oy) = quadratic_peak_offset(&v).expect("has a maximum");
        assert!(
            (ox - px).abs() < 1e-5 && (oy - py).abs() < 1e-5,
            "{ox} {oy}"
        );
        assert!(quadratic_peak_offset(&[0.0; 9]).is_none());
    }

    #[test]
    fn options_validate_and_tiny_images_give_nothing() {
        assert!(HarrisOptions::default().validate().is_ok());
        assert!(HarrisOptions {
            k: 0.0,
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(HarrisOptions {
            cell_size: 0,
            ..Default::default()
        }
        .validate()
        .is_err());
        assert!(detect_harris(&GrayImage::new(10, 10), &HarrisOptions::default()).is_empty());
    }
}
