//! Frame-to-frame feature tracking for video (paper §2.1): pyramidal Lucas–Kanade minimising the SSD
//! of eq. 8 over a translation, with an affine consistency check against each track's first
//! appearance.
//!
//! * **Translation, frame to frame** — Lucas & Kanade, "An iterative image registration technique"
//!   (IJCAI 1981), in Bouguet's pyramidal formulation ("Pyramidal implementation of the Lucas Kanade
//!   feature tracker", Intel 2000): the displacement found at a coarse level, doubled, seeds the next
//!   finer one; at each level Newton–Raphson steps `η = G⁻¹ b` refine it to sub-pixel precision. A
//!   feature is dropped when the smallest eigenvalue of `G` (per window pixel) is too small, when it
//!   leaves the image, or when tracking back from the new frame misses its old position
//!   (forward–backward check).
//! * **Affine, against the first appearance** — Shi & Tomasi, "Good features to track" (CVPR 1994):
//!   "to evaluate the accumulated difference from the start of the track it is advised to use an affine
//!   motion model" (§2.1). The window stored at the track's birth is registered to the current frame by
//!   Gauss–Newton over an affine warp plus an intensity offset; the track dies when the mean absolute
//!   residual exceeds a threshold. With `affine_refine` the registered centre also becomes the track's
//!   position, which removes the drift that frame-to-frame translation steps accumulate.
//! * **Re-detection** — Harris corners ([`crate::harris`]) away from the live tracks keep the number of
//!   tracks at the target.
//!
//! Coordinates use the pixel-centre convention of [`crate::Keypoint`]; a position `p` at pyramid level
//! `l` is `(p + ½)/2ˡ − ½` there (see [`GrayImage::downsample2`]).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{check, FeatureError};
use crate::gray::GrayImage;
use crate::harris::{detect_harris, HarrisOptions};
use crate::klt_align::{affine_register, build_pyramid, lk_translation, Level};
use crate::zncc::sample_patch;

/// Options of [`KltTracker`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KltOptions {
    /// Half-size of the integration window: `(2r+1)²` pixels. Default 7 (15×15).
    pub window_radius: usize,
    /// Pyramid levels including full resolution. Default 4.
    pub levels: usize,
    /// Newton–Raphson iterations per pyramid level. Default 30.
    pub max_iterations: usize,
    /// Iterations stop when the update is shorter than this (pixels). Default 0.01.
    pub epsilon: f32,
    /// Minimum smallest eigenvalue of the gradient matrix `G` divided by the window area (intensities
    /// in [0, 1]); weaker features are dropped (Shi & Tomasi). Default 1e-4.
    pub min_eigenvalue: f32,
    /// Maximum forward–backward error in pixels; `None` skips the backward tracking. Default 0.5.
    pub forward_backward_max: Option<f32>,
    /// Maximum mean absolute residual (intensities in [0, 1]) of the affine registration of the first
    /// appearance; `None` disables the affine stage. Default 0.02 (about 5 grey levels; 0.04 lets a
    /// tail of unstable fits through on the rendered test video).
    pub affine_max_residual: Option<f32>,
    /// Maximum distance (pixels) between the translational estimate and the affine registration's
    /// centre; a larger disagreement marks an unstable fit. Default 0.5.
    pub affine_max_shift: f32,
    /// Replace the translational position by the centre of the affine registration (anchors the track
    /// to its first appearance). Default true.
    pub affine_refine: bool,
    /// Gauss–Newton iterations of the affine registration. Default 20.
    pub affine_max_iterations: usize,
    /// σ (pixels) of a Gaussian pre-smoothing of every frame before tracking; it damps noise and the
    /// aliased fine texture that biases bilinear interpolation, but also blurs the corners (on the
    /// rendered test video 0.7 raises the share of tracks beyond 0.3 px). 0 disables. Default 0.
    pub image_sigma: f32,
    /// Number of live tracks that re-detection maintains. Default 500.
    pub target_features: usize,
    /// New features keep at least this distance (pixels) from live tracks and from each other.
    /// Default 8.
    pub redetect_min_distance: f32,
    /// Corner detector for new tracks; its border is raised to clear the tracking window.
    pub detector: HarrisOptions,
}

impl Default for KltOptions {
    fn default() -> Self {
        Self {
            window_radius: 7,
            levels: 4,
            max_iterations: 30,
            epsilon: 0.01,
            min_eigenvalue: 1e-4,
            forward_backward_max: Some(0.5),
            affine_max_residual: Some(0.02),
            affine_max_shift: 0.5,
            affine_refine: true,
            affine_max_iterations: 20,
            image_sigma: 0.0,
            target_features: 500,
            redetect_min_distance: 8.0,
            detector: HarrisOptions::default(),
        }
    }
}

impl KltOptions {
    /// Checks that every field is in range.
    pub fn validate(&self) -> Result<(), FeatureError> {
        check(
            (1..=32).contains(&self.window_radius),
            "window_radius",
            || format!("must be in 1..=32, got {}", self.window_radius),
        )?;
        check((1..=8).contains(&self.levels), "levels", || {
            format!("must be in 1..=8, got {}", self.levels)
        })?;
        check(self.max_iterations != 0, "max_iterations", || {
            "must be positive".into()
        })?;
        check(
            self.epsilon > 0.0 && self.epsilon.is_finite(),
            "epsilon",
            || format!("must be finite and positive, got {}", self.epsilon),
        )?;
        check(
            self.min_eigenvalue >= 0.0 && self.min_eigenvalue.is_finite(),
            "min_eigenvalue",
            || {
                format!(
                    "must be finite and non-negative, got {}",
                    self.min_eigenvalue
                )
            },
        )?;
        for (name, v) in [
            ("forward_backward_max", self.forward_backward_max),
            ("affine_max_residual", self.affine_max_residual),
        ] {
            if let Some(v) = v {
                check(v > 0.0 && v.is_finite(), name, || {
                    format!("must be finite and positive, got {v}")
                })?;
            }
        }
        check(
            self.affine_max_shift > 0.0 && self.affine_max_shift.is_finite(),
            "affine_max_shift",
            || format!("must be finite and positive, got {}", self.affine_max_shift),
        )?;
        check(
            self.image_sigma >= 0.0 && self.image_sigma <= 10.0,
            "image_sigma",
            || format!("must be in [0, 10], got {}", self.image_sigma),
        )?;
        check(
            self.redetect_min_distance >= 0.0 && self.redetect_min_distance.is_finite(),
            "redetect_min_distance",
            || {
                format!(
                    "must be finite and non-negative, got {}",
                    self.redetect_min_distance
                )
            },
        )?;
        self.detector.validate()
    }
}

/// One feature track: its positions in consecutive frames.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Track2d {
    /// Stable identifier, increasing in order of birth.
    pub id: u64,
    /// `(frame_index, x, y)` for every frame since birth (consecutive frame indices).
    pub positions: Vec<(usize, f32, f32)>,
    /// False once the track is lost; it never comes back.
    pub alive: bool,
}

/// State of a live track beyond its public history.
struct Live {
    /// Index into `KltTracker::tracks`.
    index: usize,
    /// Position in the previous frame.
    x: f32,
    y: f32,
    /// Level-0 window at the first appearance (row-major, `(2r+1)²`).
    template: Vec<f32>,
    /// Affine map from template offsets to current image offsets, `[a00, a01, a10, a11]`.
    affine: [f32; 4],
}

/// Pyramidal KLT tracker fed one frame at a time.
pub struct KltTracker {
    options: KltOptions,
    frame: usize,
    prev: Option<Vec<Level>>,
    tracks: Vec<Track2d>,
    live: Vec<Live>,
    next_id: u64,
}

impl KltTracker {
    /// A tracker with validated options.
    pub fn new(options: KltOptions) -> Result<Self, FeatureError> {
        options.validate()?;
        Ok(Self {
            options,
            frame: 0,
            prev: None,
            tracks: Vec::new(),
            live: Vec::new(),
            next_id: 0,
        })
    }

    pub fn options(&self) -> &KltOptions {
        &self.options
    }

    /// Number of frames processed so far (the index the next frame will get).
    pub fn frame_count(&self) -> usize {
        self.frame
    }

    /// Every track kept so far, alive or not, in order of birth.
    pub fn tracks(&self) -> &[Track2d] {
        &self.tracks
    }

    /// Number of live tracks.
    pub fn alive_count(&self) -> usize {
        self.live.len()
    }

    /// Removes and returns the finished (dead) tracks, so long videos do not accumulate them.
    pub fn drain_finished(&mut self) -> Vec<Track2d> {
        let old = std::mem::take(&mut self.tracks);
        let mut remap = vec![usize::MAX; old.len()];
        let mut dead = Vec::new();
        for (i, t) in old.into_iter().enumerate() {
            if t.alive {
                remap[i] = self.tracks.len();
                self.tracks.push(t);
            } else {
                dead.push(t);
            }
        }
        for l in &mut self.live {
            l.index = remap[l.index];
        }
        dead
    }

    /// Tracks the features into `image` (the next frame), drops lost ones, starts new ones and returns
    /// every track. A frame of a different size than the previous one ends all tracks.
    pub fn process(&mut self, image: &GrayImage) -> &[Track2d] {
        let frame = self.frame;
        self.frame += 1;
        let pyr = build_pyramid(
            image,
            self.options.image_sigma,
            self.options.levels,
            2 * self.options.window_radius + 1,
        );
        if let Some(prev) = self.prev.take() {
            if prev[0].img.width == image.width && prev[0].img.height == image.height {
                self.track(&prev, &pyr, frame);
            } else {
                self.end_all();
            }
        }
        self.replenish(&pyr, frame);
        self.prev = Some(pyr);
        &self.tracks
    }

    fn end_all(&mut self) {
        for l in self.live.drain(..) {
            self.tracks[l.index].alive = false;
        }
    }

    fn track(&mut self, prev: &[Level], next: &[Level], frame: usize) {
        let opts = &self.options;
        let results: Vec<Option<(f32, f32, [f32; 4])>> = self
            .live
            .par_iter()
            .map(|l| track_one(opts, prev, next, l))
            .collect();
        let mut kept = Vec::with_capacity(self.live.len());
        for (mut l, res) in std::mem::take(&mut self.live).into_iter().zip(results) {
            match res {
                Some((x, y, a)) => {
                    (l.x, l.y, l.affine) = (x, y, a);
                    self.tracks[l.index].positions.push((frame, x, y));
                    kept.push(l);
                }
                None => self.tracks[l.index].alive = false,
            }
        }
        self.live = kept;
    }

    /// Starts tracks at Harris corners away from the live ones until `target_features` are alive.
    fn replenish(&mut self, pyr: &[Level], frame: usize) {
        let need = self.options.target_features.saturating_sub(self.live.len());
        if need == 0 {
            return;
        }
        let r = self.options.window_radius;
        let img = &pyr[0].img;
        let mut det = self.options.detector.clone();
        det.border = det.border.max(r + 2);
        let corners = detect_harris(img, &det);
        let d = self.options.redetect_min_distance.max(1.0);
        let cols = (img.width as f32 / d) as usize + 1;
        let rows = (img.height as f32 / d) as usize + 1;
        let mut grid: Vec<Vec<(f32, f32)>> = vec![Vec::new(); cols * rows];
        let cell = |x: f32, y: f32| {
            (
                (x / d).clamp(0.0, (cols - 1) as f32) as usize,
                (y / d).clamp(0.0, (rows - 1) as f32) as usize,
            )
        };
        for l in &self.live {
            let (cx, cy) = cell(l.x, l.y);
            grid[cy * cols + cx].push((l.x, l.y));
        }
        let side = 2 * r + 1;
        let mut added = 0;
        for kp in corners {
            if added == need {
                break;
            }
            let (cx, cy) = cell(kp.x, kp.y);
            let near = (cy.saturating_sub(1)..=(cy + 1).min(rows - 1)).any(|yy| {
                (cx.saturating_sub(1)..=(cx + 1).min(cols - 1)).any(|xx| {
                    grid[yy * cols + xx]
                        .iter()
                        .any(|&(px, py)| (px - kp.x).powi(2) + (py - kp.y).powi(2) < d * d)
                })
            });
            if near {
                continue;
            }
            grid[cy * cols + cx].push((kp.x, kp.y));
            let mut template = vec![0f32; side * side];
            sample_patch(img, kp.x, kp.y, r, &mut template);
            let index = self.tracks.len();
            self.tracks.push(Track2d {
                id: self.next_id,
                positions: vec![(frame, kp.x, kp.y)],
                alive: true,
            });
            self.next_id += 1;
            self.live.push(Live {
                index,
                x: kp.x,
                y: kp.y,
                template,
                affine: [1.0, 0.0, 0.0, 1.0],
            });
            added += 1;
        }
    }
}

/// Tracks one live feature from `prev` to `next`: translation LK, forward–backward and affine checks.
fn track_one(
    opts: &KltOptions,
    prev: &[Level],
    next: &[Level],
    l: &Live,
) -> Option<(f32, f32, [f32; 4])> {
    let margin = opts.window_radius as f32 + 1.0;
    let (x, y) = lk_translation(opts, prev, next, l.x, l.y)?;
    if !next[0].img.inside(x, y, margin) {
        return None;
    }
    if let Some(max_fb) = opts.forward_backward_max {
        let (bx, by) = lk_translation(opts, next, prev, x, y)?;
        if (bx - l.x).powi(2) + (by - l.y).powi(2) > max_fb * max_fb {
            return None;
        }
    }
    let Some(max_res) = opts.affine_max_residual else {
        return Some((x, y, l.affine));
    };
    let (ax, ay, a, residual) = affine_register(
        &next[0],
        &l.template,
        opts.window_radius,
        x,
        y,
        l.affine,
        opts,
    )?;
    if residual > max_res || (ax - x).powi(2) + (ay - y).powi(2) > opts.affine_max_shift.powi(2) {
        return None;
    }
    if opts.affine_refine {
        next[0].img.inside(ax, ay, margin).then_some((ax, ay, a))
    } else {
        Some((x, y, a))
    }
}
