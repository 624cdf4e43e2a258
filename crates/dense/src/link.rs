//! Multi-view linking (paper §4.3, eq. 28; Koch, Pollefeys & Van Gool, ECCV 1998).
//!
//! For each pixel of a reference view, correspondences are chained through the disparity maps
//! of neighbouring pairs: `m_{i+1} = R′⁻¹(R(m_i) + D(R(m_i)))`. Every link gives a new depth
//! estimate for the reference pixel, triangulated from the reference ray and the linked pixel;
//! its variance follows from the chain's accumulated matching uncertainty (`σ_px·√Σ sᵢ²`, with
//! `sᵢ` the pixel size each link's disparity was measured at: 1, or 2 for a half-size value)
//! through the depth-vs-image-position derivative along the epipolar line. The estimates are
//! fused by a Kalman filter (static state, so the update is the inverse-variance mean). A chain
//! stops when its next estimate falls outside the gate `κ·√(σ² + σᵢ²)` of the fused depth, or
//! when the match leaves the image. The visibility `V` counts the views that agree (reference
//! included); pixels below `V_min` are dropped.

use handheld_core::{Camera, FloatMap, PosedView};
use nalgebra::{Matrix3, Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{DenseError, Result};
use crate::pair::PairDisparity;

/// Options of [`link_depth`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LinkOptions {
    /// Matching uncertainty of one link, pixels (1σ).
    pub sigma_px: f64,
    /// Gate in standard deviations: a link farther than this from the fused depth ends the chain.
    pub gate: f64,
    /// `V_min`: fewest views (reference included) a kept pixel must be linked through. Default 2
    /// (one left-right-checked pair).
    pub min_visibility: usize,
    /// The `V` a view keeps when it can: if at least half of the pixels that reach
    /// `min_visibility` also reach this, a depth linked through fewer views is dropped where a
    /// view could have confirmed it and did not (a chain stopped by the gate, or ended unmatched
    /// in a view whose image holds the point). A depth whose chains ended because the point
    /// leaves the other views' images (the frame's edge under forward motion, the sequence's
    /// ends) stays. Views whose neighbours are too far apart to link further (an object ring,
    /// wide baselines) keep `min_visibility`. Default 3; at or below `min_visibility` it changes
    /// nothing.
    pub preferred_visibility: usize,
    /// Most links followed in each direction.
    pub max_links: usize,
}

impl Default for LinkOptions {
    fn default() -> Self {
        Self {
            sigma_px: 0.5,
            gate: 3.0,
            min_visibility: 2,
            preferred_visibility: 3,
            max_links: 5,
        }
    }
}

impl LinkOptions {
    /// Checks every option; the error names the first offending one.
    pub fn validate(&self) -> Result<()> {
        let bad = |option: &'static str, reason: String| {
            Err(DenseError::InvalidOption { option, reason })
        };
        if !(self.sigma_px > 0.0 && self.sigma_px.is_finite()) {
            return bad(
                "sigma_px",
                format!("must be positive, got {}", self.sigma_px),
            );
        }
        if !(self.gate > 0.0 && self.gate.is_finite()) {
            return bad("gate", format!("must be positive, got {}", self.gate));
        }
        if self.min_visibility < 1 {
            return bad("min_visibility", "must be at least 1".into());
        }
        Ok(())
    }
}

/// Linked depth of a reference view: z-depth in its camera frame, the fused variance, and the
/// visibility `V`. Pixels without a kept estimate hold `NaN` depth and variance and `V = 0`.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkedDepth {
    /// Camera-frame `z`, `NaN` where nothing was kept.
    pub depth: FloatMap,
    /// The Kalman-fused variance of `depth` (model units²), `NaN` where nothing was kept.
    pub variance: FloatMap,
    /// `V`, the number of views linked (reference included), 0 where nothing was kept.
    pub visibility: FloatMap,
}

/// Relative depth error at which [`LinkedDepth::confidence`] is ½: `σ = 0.005·z`.
pub const CONFIDENCE_RELATIVE_SIGMA: f32 = 0.005;

impl LinkedDepth {
    /// Fraction of pixels with a depth.
    pub fn fill(&self) -> f64 {
        self.depth.fill_ratio()
    }

    /// The fusion weight of each pixel, `1 / (1 + σ/(0.005·z))` (½ where the 1σ error is 0.5 % of
    /// the depth), 0 where there is no depth.
    pub fn confidence(&self) -> FloatMap {
        FloatMap {
            data: self
                .depth
                .data
                .iter()
                .zip(&self.variance.data)
                .map(|(z, var)| {
                    if z.is_finite() {
                        1.0 / (1.0 + var.sqrt() / (CONFIDENCE_RELATIVE_SIGMA * z))
                    } else {
                        0.0
                    }
                })
                .collect(),
            width: self.depth.width,
            height: self.depth.height,
            channels: self.depth.channels,
        }
    }
}

/// Whether view `g`'s image holds the world point `p` (in front of the camera, inside the frame).
fn holds(g: &Geo, p: &Vector3<f64>) -> bool {
    let pc = g.rot * p + g.trans;
    if pc.z <= 0.0 {
        return false;
    }
    let m = g
        .camera
        .intrinsics
        .normalized_to_pixel(Vector2::new(pc.x / pc.z, pc.y / pc.z));
    m.x >= 0.0
        && m.y >= 0.0
        && m.x <= g.camera.width as f64 - 1.0
        && m.y <= g.camera.height as f64 - 1.0
}

/// Precomputed geometry of one view.
struct Geo {
    camera: Camera,
    rot: Matrix3<f64>,
    trans: Vector3<f64>,
}

impl Geo {
    fn new(v: &PosedView) -> Self {
        Self {
            camera: v.posed.camera.clone(),
            rot: *v
                .posed
                .cam_from_world
                .rotation
                .to_rotation_matrix()
                .matrix(),
            trans: v.posed.cam_from_world.translation.vector,
        }
    }
}

/// Depth along the reference ray `n` (normalised, `z = 1`) of the point whose projection in
/// view `b` is closest (algebraically) to the normalised point `q`, with its derivative with
/// respect to a one-pixel shift of `q` along the epipolar line. `None` behind either camera.
fn depth_from_link(
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    q: Vector2<f64>,
    f: f64,
) -> Option<(f64, f64)> {
    // Image of X(z) = C_ref + z·ray in view b: (A + z·B) with A = P_b C_ref, B = P_b ray.
    let solve = |q: Vector2<f64>| {
        let u = b.xy() - q * b.z;
        let w = a.xy() - q * a.z;
        let uu = u.dot(&u);
        (uu > 0.0).then(|| -u.dot(&w) / uu)
    };
    let z = solve(q)?;
    if z <= 0.0 || a.z + z * b.z <= 0.0 {
        return None;
    }
    // Epipolar direction at q: the image of the ray moves from A toward B.
    let p0 = (a + b * z).xy() / (a.z + b.z * z);
    let z1 = z * 1.01;
    let p1 = (a + b * z1).xy() / (a.z + b.z * z1);
    let shift = (p1 - p0).norm() * f;
    if shift <= 0.0 {
        return None;
    }
    Some((z, (z1 - z) / shift))
}

/// Links the reference view `reference` of `views` through the adjacent pairs: `pairs[i]` holds
/// the disparity of views `i` (left) and `i + 1` (right). Only the views' cameras and poses are
/// read. Chains run up to `max_links` views in each direction, alternating sides so the gate sees
/// both directions early.
pub fn link_depth(
    views: &[PosedView],
    pairs: &[Option<PairDisparity>],
    reference: usize,
    opts: &LinkOptions,
) -> Result<LinkedDepth> {
    opts.validate()?;
    if pairs.len() + 1 != views.len() {
        return Err(DenseError::Linking {
            reason: format!(
                "{} views need {} adjacent pairs, got {}",
                views.len(),
                views.len() - 1,
                pairs.len()
            ),
        });
    }
    if reference >= views.len() {
        return Err(DenseError::Linking {
            reason: format!("reference view {reference} of {} views", views.len()),
        });
    }
    let geo: Vec<Geo> = views.iter().map(Geo::new).collect();
    let r = &geo[reference];
    let (w, h) = (r.camera.width as usize, r.camera.height as usize);
    let c_ref = -(r.rot.transpose() * r.trans);
    let r_ref_t = r.rot.transpose();
    let f_of = |g: &Geo| g.camera.intrinsics.f * (1.0 + g.camera.intrinsics.aspect) * 0.5;

    let mut depth = FloatMap::filled(w, h, 1, f32::NAN);
    let mut variance = FloatMap::filled(w, h, 1, f32::NAN);
    let mut visibility = FloatMap::filled(w, h, 1, 0.0);
    // Depths a view could have confirmed and did not: a chain stopped by the gate, or one that
    // ended unmatched in a view whose image holds the point.
    let mut doubted = vec![false; w * h];
    depth
        .data
        .par_chunks_mut(w)
        .zip(variance.data.par_chunks_mut(w))
        .zip(visibility.data.par_chunks_mut(w))
        .zip(doubted.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (((drow, vrow), visrow), crow))| {
            for x in 0..w {
                let m = Vector2::new(x as f64, y as f64);
                let n = r.camera.intrinsics.pixel_to_normalized(m);
                let ray = r_ref_t * Vector3::new(n.x, n.y, 1.0);
                // Chain state per direction: current view and pixel, the chain's accumulated
                // matching variance in units of σ_px² (one per full-size link), alive.
                let mut chains = [(reference, m, 0.0f64, true), (reference, m, 0.0f64, true)];
                let mut fused: Option<(f64, f64)> = None;
                let mut vis = 1usize;
                // Views where a chain ended without a match although the pair was matched.
                let mut unmatched_in: [Option<usize>; 2] = [None, None];
                for _ in 0..opts.max_links {
                    for (dir, chain) in chains.iter_mut().enumerate() {
                        if !chain.3 {
                            continue;
                        }
                        let (a, p) = (chain.0, chain.1);
                        let step = if dir == 0 {
                            (a + 1 < views.len())
                                .then(|| {
                                    pairs[a]
                                        .as_ref()
                                        .and_then(|pd| pd.transfer_scaled(0, p))
                                        .map(|(q, s)| (a + 1, q, s))
                                })
                                .flatten()
                        } else {
                            (a > 0)
                                .then(|| {
                                    pairs[a - 1]
                                        .as_ref()
                                        .and_then(|pd| pd.transfer_scaled(1, p))
                                        .map(|(q, s)| (a - 1, q, s))
                                })
                                .flatten()
                        };
                        let Some((b, q, scale)) = step else {
                            let next = if dir == 0 { a + 1 } else { a.wrapping_sub(1) };
                            let pair = if dir == 0 { a } else { a.wrapping_sub(1) };
                            if next < views.len() && pairs[pair].is_some() {
                                unmatched_in[dir] = Some(next);
                            }
                            chain.3 = false;
                            continue;
                        };
                        let g = &geo[b];
                        let qa = g.rot * c_ref + g.trans;
                        let qb = g.rot * ray;
                        let qn = g.camera.intrinsics.pixel_to_normalized(q);
                        let Some((z, dz_dpx)) = depth_from_link(&qa, &qb, qn, f_of(g)) else {
                            chain.3 = false;
                            continue;
                        };
                        let links = chain.2 + scale * scale;
                        let sigma = opts.sigma_px * links.sqrt() * dz_dpx.abs();
                        let var = sigma * sigma;
                        match fused {
                            None => fused = Some((z, var)),
                            Some((zf, vf)) => {
                                if (z - zf).abs() > opts.gate * (vf + var).sqrt() {
                                    crow[x] = true; // contradicted
                                    chain.3 = false;
                                    continue;
                                }
                                let k = vf / (vf + var);
                                fused = Some((zf + k * (z - zf), vf * (1.0 - k)));
                            }
                        }
                        vis += 1;
                        *chain = (b, q, links, true);
                    }
                }
                if let Some((z, v)) = fused {
                    // A chain that ended unmatched in a view whose image holds the point: that
                    // view could have confirmed the depth and did not.
                    let p = c_ref + ray * z;
                    crow[x] |= unmatched_in.iter().flatten().any(|&b| holds(&geo[b], &p));
                    if vis >= opts.min_visibility {
                        drow[x] = z as f32;
                        vrow[x] = v as f32;
                        visrow[x] = vis as f32;
                    }
                }
            }
        });
    if opts.preferred_visibility > opts.min_visibility {
        let v_pref = opts.preferred_visibility as f32;
        let kept = visibility.data.iter().filter(|&&v| v > 0.0).count();
        let strong = visibility.data.iter().filter(|&&v| v >= v_pref).count();
        if 2 * strong >= kept {
            for (((d, var), v), doubted) in depth
                .data
                .iter_mut()
                .zip(variance.data.iter_mut())
                .zip(visibility.data.iter_mut())
                .zip(doubted.iter())
            {
                if *v > 0.0 && *v < v_pref && *doubted {
                    (*d, *var, *v) = (f32::NAN, f32::NAN, 0.0);
                }
            }
        }
    }
    Ok(LinkedDepth {
        depth,
        variance,
        visibility,
    })
}
