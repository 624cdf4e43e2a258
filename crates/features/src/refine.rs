//! Multi-view keypoint refinement: every keypoint of a track is moved onto the image point that
//! corresponds to one reference keypoint of the track, by affine patch registration (Shi & Tomasi
//! 1994, the KLT alignment of eq. 8 with an affine warp).
//!
//! A SIFT keypoint is located by the extremum of the difference of Gaussians at its own scale, so its
//! error grows with that scale (against the ground-truth cameras of herzjesu-P8, about 0.17 √s px in
//! median). The errors of the keypoints of one track are independent, and they are what bends the
//! cameras of a shallow scene. After refinement, every observation of a track is registered to the
//! same texture as the reference, so the remaining error is mostly the reference's own offset, which
//! is common to all views and only moves the 3D point. This is the idea of the "keypoint adjustment"
//! of Pixel-Perfect SfM (Lindenberger et al. 2021), here on image intensities instead of learned
//! feature maps.
//!
//! Tracks are the connected components of the match graph. Each track's reference is its keypoint
//! with the most matches (ties: the finest scale). Registration runs on the pyramid level where the
//! reference's detection scale is about [`KeypointRefinementOptions::level_scale`] pixels, from the
//! similarity transform that the two SIFT frames (scale and orientation) imply. Images are loaded one
//! at a time, twice (templates, then registration), so memory stays at one image pyramid.

use std::collections::HashMap;

use rayon::prelude::*;

use crate::error::{check, FeatureError};
use crate::gray::GrayImage;
use crate::klt::KltOptions;
use crate::klt_align::{affine_register, build_pyramid, Level};
use crate::zncc::sample_patch;

/// Options of [`refine_track_keypoints`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeypointRefinementOptions {
    /// Half-size of the registration window on the chosen pyramid level: `(2r+1)²` samples.
    /// Default 7.
    pub window_radius: usize,
    /// The reference keypoint's detection scale (pixels) that maps to pyramid level 0; each doubling
    /// moves one level up. Default 2.
    pub level_scale: f32,
    /// Highest pyramid level used. Default 4.
    pub max_level: usize,
    /// A registration that moves a keypoint further than this many detection scales (of the moved
    /// keypoint), or further than `max_shift_px`, is rejected. Default 1.
    pub max_shift_scales: f32,
    /// See `max_shift_scales`. Default 4.
    pub max_shift_px: f32,
    /// Smallest zero-mean normalised cross-correlation between the reference window and the
    /// registered window. Default 0.8.
    pub min_zncc: f32,
    /// Gauss–Newton iterations of each registration. Default 20.
    pub max_iterations: usize,
}

impl Default for KeypointRefinementOptions {
    fn default() -> Self {
        Self {
            window_radius: 7,
            level_scale: 2.0,
            max_level: 4,
            max_shift_scales: 1.0,
            max_shift_px: 4.0,
            min_zncc: 0.8,
            max_iterations: 20,
        }
    }
}

impl KeypointRefinementOptions {
    /// Checks that every field is in range, naming the offending one.
    pub fn validate(&self) -> Result<(), FeatureError> {
        check(
            (2..=32).contains(&self.window_radius),
            "window_radius",
            || format!("must be in 2..=32, got {}", self.window_radius),
        )?;
        for (name, v) in [
            ("level_scale", self.level_scale),
            ("max_shift_scales", self.max_shift_scales),
            ("max_shift_px", self.max_shift_px),
        ] {
            check(v.is_finite() && v > 0.0, name, || {
                format!("must be positive and finite, got {v}")
            })?;
        }
        check((-1.0..=1.0).contains(&self.min_zncc), "min_zncc", || {
            format!("must be in [-1, 1], got {}", self.min_zncc)
        })?;
        check(self.max_iterations != 0, "max_iterations", || {
            "must be at least 1".into()
        })
    }
}

/// A keypoint's detection frame: position (pixels, Handheld convention), scale (pixels) and
/// orientation (radians).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeypointFrame {
    pub x: f32,
    pub y: f32,
    pub scale: f32,
    pub orientation: f32,
}

/// Matches of one image pair: indices into the keypoints of images `a` and `b`.
#[derive(Clone, Copy, Debug)]
pub struct PairMatches<'a> {
    pub a: usize,
    pub b: usize,
    pub matches: &'a [(u32, u32)],
}

/// What [`refine_track_keypoints`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RefinementSummary {
    /// Tracks (connected components with at least two keypoints).
    pub tracks: usize,
    /// Keypoints registered to their track's reference (the references themselves excluded).
    pub attempted: usize,
    /// Registrations accepted; the others keep their detected position.
    pub moved: usize,
    /// Median and 90th percentile distance (pixels) that accepted keypoints moved.
    pub median_shift_px: f64,
    pub p90_shift_px: f64,
}

/// Refined positions `[x, y]` of every keypoint of every image.
pub type RefinedKeypoints = Vec<Vec<[f32; 2]>>;

/// One registration: keypoint `node` (global index) to the template of reference `reference`.
struct Job {
    node: usize,
    template: usize,
}

/// Refines the keypoints of every track of the match graph (module docs). `load(i)` returns image
/// `i` in grey levels in [0, 1] at the resolution of its keypoints; `progress` is called once per
/// image pass (twice per image). Returns the refined positions, indexed like `keypoints`.
pub fn refine_track_keypoints<E: Send>(
    keypoints: &[Vec<KeypointFrame>],
    pairs: &[PairMatches<'_>],
    load: &(dyn Fn(usize) -> Result<GrayImage, E> + Sync),
    opts: &KeypointRefinementOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<(RefinedKeypoints, RefinementSummary), E> {
    let mut out: Vec<Vec<[f32; 2]>> = keypoints
        .iter()
        .map(|k| k.iter().map(|p| [p.x, p.y]).collect())
        .collect();
    let offsets: Vec<usize> = keypoints
        .iter()
        .scan(0usize, |acc, k| {
            let o = *acc;
            *acc += k.len();
            Some(o)
        })
        .collect();
    let total: usize = keypoints.iter().map(Vec::len).sum();
    let node_image: Vec<usize> = keypoints
        .iter()
        .enumerate()
        .flat_map(|(i, k)| std::iter::repeat_n(i, k.len()))
        .collect();
    let frame = |n: usize| keypoints[node_image[n]][n - offsets[node_image[n]]];

    // Tracks: connected components of the match graph, and the degree of every keypoint.
    let mut parent: Vec<usize> = (0..total).collect();
    let mut degree = vec![0u32; total];
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    for p in pairs {
        let (Some(&oa), Some(&ob)) = (offsets.get(p.a), offsets.get(p.b)) else {
            continue;
        };
        for &(i, j) in p.matches {
            let (i, j) = (i as usize, j as usize);
            if i >= keypoints[p.a].len() || j >= keypoints[p.b].len() {
                continue;
            }
            let (u, v) = (oa + i, ob + j);
            degree[u] += 1;
            degree[v] += 1;
            let (ru, rv) = (find(&mut parent, u), find(&mut parent, v));
            if ru != rv {
                parent[ru] = rv;
            }
        }
    }
    let mut members: HashMap<usize, Vec<usize>> = HashMap::new();
    for (n, &d) in degree.iter().enumerate() {
        if d > 0 {
            let r = find(&mut parent, n);
            members.entry(r).or_default().push(n);
        }
    }
    let mut tracks: Vec<Vec<usize>> = members.into_values().filter(|m| m.len() >= 2).collect();
    tracks.sort_unstable_by_key(|m| m[0]);

    // References and jobs.
    let mut references: Vec<usize> = Vec::with_capacity(tracks.len());
    let mut jobs_of_image: Vec<Vec<Job>> = (0..keypoints.len()).map(|_| Vec::new()).collect();
    for m in &tracks {
        let Some(&r) = m.iter().min_by(|&&a, &&b| {
            degree[b]
                .cmp(&degree[a])
                .then(frame(a).scale.total_cmp(&frame(b).scale))
                .then(a.cmp(&b))
        }) else {
            continue;
        };
        let t = references.len();
        references.push(r);
        for &n in m {
            if node_image[n] != node_image[r] {
                jobs_of_image[node_image[n]].push(Job {
                    node: n,
                    template: t,
                });
            }
        }
    }
    let level_of = |s: f32| -> usize {
        let l = (s / opts.level_scale).max(1.0).log2().floor();
        (l as usize).min(opts.max_level)
    };
    let levels_needed = |nodes: &mut dyn Iterator<Item = usize>| -> usize {
        nodes.map(|n| level_of(frame(n).scale)).max().unwrap_or(0) + 1
    };
    let klt = KltOptions {
        window_radius: opts.window_radius,
        affine_max_iterations: opts.max_iterations,
        ..Default::default()
    };
    let r = opts.window_radius;
    let side = 2 * r + 1;

    // Pass 1: the reference windows, one image at a time.
    let mut refs_of_image: Vec<Vec<usize>> = (0..keypoints.len()).map(|_| Vec::new()).collect();
    for (t, &n) in references.iter().enumerate() {
        refs_of_image[node_image[n]].push(t);
    }
    let mut templates: Vec<Option<Vec<f32>>> = vec![None; references.len()];
    for (img, ts) in refs_of_image.iter().enumerate() {
        if ts.is_empty() {
            progress();
            continue;
        }
        let levels = levels_needed(&mut ts.iter().map(|&t| references[t]));
        let pyr = build_pyramid(&load(img)?, 0.0, levels, 2 * side);
        let made: Vec<(usize, Option<Vec<f32>>)> = ts
            .par_iter()
            .map(|&t| {
                let f = frame(references[t]);
                let l = level_of(f.scale);
                let Some(level) = pyr.get(l) else {
                    return (t, None);
                };
                let (x, y) = to_level(f.x, f.y, l);
                if !level.img.inside(x, y, r as f32 + 1.0) {
                    return (t, None);
                }
                let mut w = vec![0f32; side * side];
                sample_patch(&level.img, x, y, r, &mut w);
                (t, Some(w))
            })
            .collect();
        for (t, w) in made {
            templates[t] = w;
        }
        progress();
    }

    // Pass 2: register every other keypoint of each track to its reference window.
    let mut shifts: Vec<f64> = Vec::new();
    let mut attempted = 0usize;
    for (img, jobs) in jobs_of_image.iter().enumerate() {
        let jobs: Vec<&Job> = jobs
            .iter()
            .filter(|j| templates[j.template].is_some())
            .collect();
        attempted += jobs.len();
        if jobs.is_empty() {
            progress();
            continue;
        }
        let levels = levels_needed(&mut jobs.iter().map(|j| references[j.template]));
        let pyr = build_pyramid(&load(img)?, 0.0, levels, 2 * side);
        let moved: Vec<Option<(usize, [f32; 2])>> = jobs
            .par_iter()
            .map(|j| {
                let template = templates[j.template].as_deref()?;
                let (fr, fnode) = (frame(references[j.template]), frame(j.node));
                let l = level_of(fr.scale);
                register(&pyr, l, template, fr, fnode, &klt, opts).map(|p| (j.node, p))
            })
            .collect();
        for (n, p) in moved.into_iter().flatten() {
            let k = n - offsets[img];
            let old = out[img][k];
            shifts.push(f64::from((p[0] - old[0]).hypot(p[1] - old[1])));
            out[img][k] = p;
        }
        progress();
    }
    let moved = shifts.len();
    shifts.sort_by(f64::total_cmp);
    let q = |f: f64| {
        shifts
            .get(((shifts.len() as f64 - 1.0) * f).round().max(0.0) as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let summary = RefinementSummary {
        tracks: tracks.len(),
        attempted,
        moved,
        median_shift_px: q(0.5),
        p90_shift_px: q(0.9),
    };
    Ok((out, summary))
}

/// Full-resolution pixel → pyramid level `l` (pixel centres at integers on both).
fn to_level(x: f32, y: f32, l: usize) -> (f32, f32) {
    let s = 0.5f32.powi(l as i32);
    ((x + 0.5) * s - 0.5, (y + 0.5) * s - 0.5)
}

/// Registers the window of keypoint `fnode` to the reference window `template` (of `fr`) on level
/// `l`; the refined full-resolution position, or `None` when the fit fails a check.
fn register(
    pyr: &[Level],
    l: usize,
    template: &[f32],
    fr: KeypointFrame,
    fnode: KeypointFrame,
    klt: &KltOptions,
    opts: &KeypointRefinementOptions,
) -> Option<[f32; 2]> {
    let level = pyr.get(l)?;
    let r = opts.window_radius;
    let (x0, y0) = to_level(fnode.x, fnode.y, l);
    // The similarity of the two SIFT frames: reference window offsets → this image's offsets.
    let s = fnode.scale / fr.scale;
    let (sin, cos) = (fnode.orientation - fr.orientation).sin_cos();
    let a0 = [s * cos, -s * sin, s * sin, s * cos];
    let reach = r as f32 * s.max(1.0) * std::f32::consts::SQRT_2 + 2.0;
    if !level.img.inside(x0, y0, reach) {
        return None;
    }
    let (cx, cy, a, _) = affine_register(level, template, r, x0, y0, a0, klt)?;
    let f = 2f32.powi(l as i32);
    let (x, y) = ((cx + 0.5) * f - 0.5, (cy + 0.5) * f - 0.5);
    let shift = (x - fnode.x).hypot(y - fnode.y);
    if !(shift <= opts.max_shift_px && shift <= opts.max_shift_scales * fnode.scale) {
        return None;
    }
    if !level.img.inside(cx, cy, r as f32 * 2.0 + 1.0) {
        return None;
    }
    // ZNCC of the registered window against the reference window.
    let side = 2 * r + 1;
    let (mut st, mut sw, mut stt, mut sww, mut stw) = (0f64, 0f64, 0f64, 0f64, 0f64);
    for (k, &tv) in template.iter().enumerate().take(side * side) {
        let (u, v) = ((k % side) as f32 - r as f32, (k / side) as f32 - r as f32);
        let wv = level
            .img
            .sample(cx + a[0] * u + a[1] * v, cy + a[2] * u + a[3] * v);
        let (tv, wv) = (f64::from(tv), f64::from(wv));
        st += tv;
        sw += wv;
        stt += tv * tv;
        sww += wv * wv;
        stw += tv * wv;
    }
    let n = (side * side) as f64;
    let cov = stw - st * sw / n;
    let var = ((stt - st * st / n) * (sww - sw * sw / n)).sqrt();
    let zncc = if var > 0.0 { cov / var } else { 0.0 };
    if zncc < f64::from(opts.min_zncc) {
        return None;
    }
    Some([x, y])
}
