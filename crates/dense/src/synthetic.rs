//! Test-only synthetic rectified pair with exact disparities: a textured fronto-parallel background
//! plane and a textured foreground box (both at constant disparity).

use handheld_core::FloatMap;

/// A rendered pair and its ground truth.
pub(crate) struct SyntheticPair {
    pub left: FloatMap,
    pub right: FloatMap,
    /// True left disparity per pixel.
    pub truth: Vec<f32>,
    /// Left pixels whose surface point is hidden in the right view.
    pub occluded: Vec<bool>,
}

/// Scene description: image size, background disparity, box `[x0, x1) × [y0, y1)` (in the left
/// image) and its disparity.
pub(crate) struct Scene {
    pub width: usize,
    pub height: usize,
    pub d_bg: f32,
    pub d_fg: f32,
    pub box_x: (usize, usize),
    pub box_y: (usize, usize),
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            width: 160,
            height: 120,
            d_bg: 7.3,
            d_fg: 18.0,
            box_x: (60, 110),
            box_y: (35, 85),
        }
    }
}

fn hash(ix: i64, iy: i64, seed: u64) -> f32 {
    let mut z = (ix as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add(seed.wrapping_mul(0x1656_67B1_9E37_79F9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 40) as f32 / (1u64 << 24) as f32
}

/// Bilinearly interpolated value noise with cell size `s`, continuous in `u`.
fn noise(u: f32, v: f32, s: f32, seed: u64) -> f32 {
    let (fu, fv) = (u / s, v / s);
    let (iu, iv) = (fu.floor(), fv.floor());
    let (a, b) = (fu - iu, fv - iv);
    let (iu, iv) = (iu as i64, iv as i64);
    let h = |i, j| hash(iu + i, iv + j, seed);
    (1.0 - b) * ((1.0 - a) * h(0, 0) + a * h(1, 0)) + b * ((1.0 - a) * h(0, 1) + a * h(1, 1))
}

/// Texture of surface `seed` at texture coordinate `(u, v)`, in `0..=255`.
fn texture(u: f32, v: f32, seed: u64) -> f32 {
    20.0 + 150.0 * noise(u, v, 1.6, seed) + 85.0 * noise(u, v, 5.0, seed + 7)
}

/// Renders the scene; texture coordinates are left-image coordinates, so the right pixel `x_r`
/// shows the surface point of left abscissa `x_r + d`.
pub(crate) fn render(s: &Scene) -> SyntheticPair {
    let (w, h) = (s.width, s.height);
    let in_box = |x: f32, y: usize| {
        x >= s.box_x.0 as f32 && x < s.box_x.1 as f32 && y >= s.box_y.0 && y < s.box_y.1
    };
    let mut left = FloatMap::filled(w, h, 1, 0.0);
    let mut right = FloatMap::filled(w, h, 1, 0.0);
    let mut truth = vec![0f32; w * h];
    let mut occluded = vec![false; w * h];
    for y in 0..h {
        let yf = y as f32;
        for x in 0..w {
            let xf = x as f32;
            if in_box(xf, y) {
                left.set(x, y, 0, texture(xf, yf, 2));
                truth[y * w + x] = s.d_fg;
            } else {
                left.set(x, y, 0, texture(xf, yf, 1));
                truth[y * w + x] = s.d_bg;
                // Hidden in the right view when the box covers its right-image position.
                let xr = xf - s.d_bg;
                occluded[y * w + x] =
                    in_box(xr.floor() + s.d_fg, y) || in_box(xr.ceil() + s.d_fg, y);
            }
            let xfg = xf + s.d_fg;
            let v = if in_box(xfg, y) {
                texture(xfg, yf, 2)
            } else {
                texture(xf + s.d_bg, yf, 1)
            };
            right.set(x, y, 0, v);
        }
    }
    SyntheticPair {
        left,
        right,
        truth,
        occluded,
    }
}

/// Percentage of the selected pixels whose estimate is missing or off by more than `t`.
pub(crate) fn bad_percent(
    est: &[f32],
    truth: &[f32],
    select: impl Fn(usize) -> bool,
    t: f32,
) -> f64 {
    let (mut n, mut bad) = (0usize, 0usize);
    for (i, (e, g)) in est.iter().zip(truth).enumerate() {
        if select(i) {
            n += 1;
            if !e.is_finite() || (e - g).abs() > t {
                bad += 1;
            }
        }
    }
    100.0 * bad as f64 / n.max(1) as f64
}
