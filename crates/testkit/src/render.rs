//! Ray-cast rendering of a synthetic hand-held sequence with exact ground truth.
//!
//! Per pixel area, `samples_per_axis²` rays are cast at stratified sub-pixel positions (a regular
//! grid). Each position is a *distorted* pixel position, mapped through
//! [`Intrinsics::pixel_to_normalized`] (inverse of `K`, then undistortion) to a viewing ray and
//! intersected with the scene — so the images carry the real radial distortion of their [`Camera`].
//! Samples are reconstructed with a separable **tent filter** of 2-pixel support (weights
//! `(1−|dx|)(1−|dy|)` over the samples within one pixel of the centre, so every ray contributes to up
//! to 3×3 pixels). Unlike a box filter, the tent reproduces linear functions, so the intensity
//! centroid of a rendered blob equals the centroid of the point-sampled scene (no pixel locking), and
//! it adds the mild blur of real optics. Shading is `albedo · (AMBIENT + DIFFUSE·|n·l|)` with one
//! directional light, plus a grey sky gradient where nothing is hit; seeded Gaussian noise is added
//! before rounding to `u8`.
//!
//! Depth maps hold, per pixel, the camera-frame `z` of the first hit along the ray through the pixel
//! **centre**, and `0.0` where the ray hits nothing. The ground-truth [`MetricReconstruction`] has one
//! [`Camera`] per distinct focal length (`CameraId(0)`, `CameraId(1)`, … in order of first use; one
//! shared camera without zoom), view `ImageId(i)` named `frame_{i:04}.png` for frame `i`, and one
//! point per landmark (`PointId(i)` is `scene.landmarks()[i]`) seen unoccluded and front-facing in at
//! least `min(2, num_frames)` frames; observations are the exact projections.

use std::collections::BTreeMap;

use handheld_core::pose::center_of;
use handheld_core::{
    Camera, CameraId, FloatMap, ImageId, Intrinsics, MetricReconstruction, Observation, Point3D,
    PointId, PosedCamera, TrackElement, TriMesh, View,
};
use image::RgbImage;
use nalgebra::{Point3, Rotation3, Vector2, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::scene::{Hit, Landmark, Scene};
pub use crate::sequence::SequenceOptions;
use crate::shutter::FrameMotion;
use crate::texture::LANDMARK_DARK;
use crate::util::{gaussian, hash_words};

/// Ambient term of the shading.
pub const AMBIENT: f64 = 0.4;
/// Weight of the Lambertian term.
pub const DIFFUSE: f64 = 0.6;

fn light_dir() -> Vector3<f64> {
    Vector3::new(0.35, -0.5, 0.8).normalize()
}

/// A rendered sequence with its ground truth.
#[derive(Clone, Debug)]
pub struct SyntheticSequence {
    pub scene: Scene,
    pub gt: MetricReconstruction,
    pub images: Vec<RgbImage>,
    /// Per frame: camera-frame `z` of the hit through each pixel centre, `0.0` for no hit.
    pub depths: Vec<FloatMap>,
    pub mesh: TriMesh,
}

impl SyntheticSequence {
    /// The camera of frame `i` in its pose (a copy of the ground truth's).
    pub fn frame(&self, i: usize) -> Option<PosedCamera> {
        let view = self.gt.views.get(&ImageId(i as u32))?;
        let camera = self.gt.cameras.get(&view.camera_id)?;
        Some(PosedCamera::new(camera.clone(), view.cam_from_world))
    }
}

/// World-space ray through pixel `px` (distorted pixel coordinates): origin at the camera centre and a
/// direction whose camera-frame `z` is 1, so the hit parameter `t` is the depth.
pub fn pixel_ray(view: &PosedCamera, px: Vector2<f64>) -> (Point3<f64>, Vector3<f64>) {
    let (camera, cam_from_world) = (&view.camera, &view.cam_from_world);
    let n = camera.intrinsics.pixel_to_normalized(px);
    (
        center_of(cam_from_world),
        cam_from_world.rotation.inverse() * Vector3::new(n.x, n.y, 1.0),
    )
}

/// Blinn–Phong exponent of the glossy highlights.
pub const SHININESS: f64 = 80.0;

/// The specular term at a hit seen along `dir`: `gloss · max(0, n·h)^SHININESS`, `h` halfway
/// between the light and the viewer (white, added to the diffuse shading). It moves over the
/// surface as the viewpoint moves.
pub fn highlight(scene: &Scene, hit: &Hit, dir: &Vector3<f64>, light: &Vector3<f64>) -> f64 {
    let g = scene.gloss(hit);
    if g <= 0.0 {
        return 0.0;
    }
    let v = -dir.normalize();
    let n = if hit.normal.dot(&v) < 0.0 {
        -hit.normal
    } else {
        hit.normal
    };
    let h = (v + light).normalize();
    g * n.dot(&h).max(0.0).powf(SHININESS)
}

/// The specular term through each pixel centre of a view (0 where there is none): the mask of
/// the highlights.
pub fn highlight_map(scene: &Scene, view: &PosedCamera) -> FloatMap {
    let camera = &view.camera;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let light = light_dir();
    let data = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (o, dir) = pixel_ray(view, Vector2::new((i % w) as f64, (i / w) as f64));
            scene
                .intersect(&o, &dir)
                .map_or(0.0, |hit| highlight(scene, &hit, &dir, &light) as f32)
        })
        .collect();
    FloatMap {
        width: w,
        height: h,
        channels: 1,
        data,
    }
}

/// Linear radiance in `[0, 1]` of the first hit along a ray, or of the sky.
fn radiance(
    scene: &Scene,
    origin: &Point3<f64>,
    dir: &Vector3<f64>,
    light: &Vector3<f64>,
) -> ([f64; 3], f64) {
    match scene.intersect(origin, dir) {
        Some(hit) => {
            let a = scene.albedo(&hit);
            let s = AMBIENT + DIFFUSE * hit.normal.dot(light).abs();
            let h = highlight(scene, &hit, dir, light);
            ([a[0] * s + h, a[1] * s + h, a[2] * s + h], hit.t)
        }
        None => {
            let g = 0.5 + 0.15 * dir.z / dir.norm();
            ([g; 3], 0.0)
        }
    }
}

/// Normalised (undistorted) image coordinates of every sub-pixel sample of an image plus a one-pixel
/// border (the tent filter reaches one pixel out): the expensive, pose-independent part of ray
/// generation, shared by all frames with the same intrinsics.
pub struct RayTable {
    intrinsics: Intrinsics,
    samples_per_axis: usize,
    width: usize,
    height: usize,
    /// Row-major over padded pixels `(x + 1, y + 1)`, then sub-rows, then sub-columns.
    normalized: Vec<Vector2<f64>>,
}

/// Sub-pixel sample offsets from the pixel centre: a regular grid `(i + ½)/n − ½`.
fn sample_offsets(n: usize) -> Vec<f64> {
    (0..n).map(|i| (i as f64 + 0.5) / n as f64 - 0.5).collect()
}

impl RayTable {
    /// Computes the table for `camera` with `samples_per_axis²` samples per pixel.
    pub fn new(camera: &Camera, samples_per_axis: u32) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let n = samples_per_axis.max(1) as usize;
        let offsets = sample_offsets(n);
        let rows: Vec<Vec<Vector2<f64>>> = (0..h + 2)
            .into_par_iter()
            .map(|yy| {
                let y = yy as f64 - 1.0;
                let mut row = Vec::with_capacity((w + 2) * n * n);
                for xx in 0..w + 2 {
                    let x = xx as f64 - 1.0;
                    for oy in &offsets {
                        for ox in &offsets {
                            row.push(
                                camera
                                    .intrinsics
                                    .pixel_to_normalized(Vector2::new(x + ox, y + oy)),
                            );
                        }
                    }
                }
                row
            })
            .collect();
        Self {
            intrinsics: camera.intrinsics,
            samples_per_axis: n,
            width: w,
            height: h,
            normalized: rows.concat(),
        }
    }
}

/// Renders one frame: the anti-aliased noisy image and the pixel-centre depth map.
pub fn render_frame(
    scene: &Scene,
    view: &PosedCamera,
    samples_per_axis: u32,
    noise_sigma: f64,
    noise_seed: u64,
) -> (RgbImage, FloatMap) {
    render_frame_with_rays(
        scene,
        view,
        &RayTable::new(&view.camera, samples_per_axis),
        None,
        noise_sigma,
        noise_seed,
    )
}

/// [`render_frame`] with a precomputed [`RayTable`] (recomputed here if it does not match `camera`),
/// each ray cast from its own time's pose when `motion` is given (a rolling shutter and motion
/// blur: [`crate::shutter`]; `view`'s pose is then the depth map's).
pub fn render_frame_with_rays(
    scene: &Scene,
    view: &PosedCamera,
    rays: &RayTable,
    motion: Option<&FrameMotion>,
    noise_sigma: f64,
    noise_seed: u64,
) -> (RgbImage, FloatMap) {
    let (camera, cam_from_world) = (&view.camera, &view.cam_from_world);
    let (w, h) = (camera.width as usize, camera.height as usize);
    if rays.width != w || rays.height != h || rays.intrinsics != camera.intrinsics {
        return render_frame_with_rays(
            scene,
            view,
            &RayTable::new(camera, rays.samples_per_axis as u32),
            motion,
            noise_sigma,
            noise_seed,
        );
    }
    let n = rays.samples_per_axis;
    let nn = n * n;
    let offsets = sample_offsets(n);
    // 1D tent weights of the samples of a pixel for itself and its two neighbours; the 1D sum is the
    // normalisation (it equals n for the symmetric grid).
    let tent = |d: f64| (1.0 - d.abs()).max(0.0);
    let norm_1d: f64 = [-1.0, 0.0, 1.0]
        .iter()
        .flat_map(|m| offsets.iter().map(move |o| tent(m + o)))
        .sum();
    let centre_idx = (n % 2 == 1).then_some((n / 2) * n + n / 2);
    let world_from_cam = cam_from_world.rotation.inverse().to_rotation_matrix();
    let origin = center_of(cam_from_world);
    let moving = motion.filter(|m| !m.shutter.is_global());
    // The pose of each sample of padded row `yy`: its sub-row's read-out time, and an exposure
    // slot that a stride coprime to the sample count spreads over the pixel's sub-samples.
    let poses_of_row = |yy: usize| -> Vec<(Rotation3<f64>, Point3<f64>)> {
        match moving {
            None => vec![(world_from_cam, origin); nn],
            Some(m) => (0..nn)
                .map(|s| {
                    let y = yy as f64 - 1.0 + offsets[s / n];
                    let pose = m.pose_at(m.shutter.time(y, h, (s * 257) % nn, nn));
                    (
                        pose.rotation.inverse().to_rotation_matrix(),
                        center_of(&pose),
                    )
                })
                .collect(),
        }
    };
    let light = light_dir();
    // Pass 1: per padded row, cast the rays and filter each sub-row horizontally.
    let filtered: Vec<(Vec<[f32; 3]>, Vec<f32>)> = (0..h + 2)
        .into_par_iter()
        .map(|yy| {
            let mut sub = vec![[0f32; 3]; n * w];
            let mut depth = vec![0f32; w];
            let inner_row = yy >= 1 && yy <= h;
            let poses = poses_of_row(yy);
            for xx in 0..w + 2 {
                let base = (yy * (w + 2) + xx) * nn;
                for (s, (rotation, centre)) in poses.iter().enumerate() {
                    let nrm = rays.normalized[base + s];
                    let dir = rotation * Vector3::new(nrm.x, nrm.y, 1.0);
                    let (c, t) = radiance(scene, centre, &dir, &light);
                    let (i, j) = (s % n, s / n);
                    if inner_row && centre_idx == Some(s) && xx >= 1 && xx <= w && moving.is_none()
                    {
                        depth[xx - 1] = t as f32;
                    }
                    // Target pixels xx−1, xx, xx+1 in padded coordinates → image x = target − 1.
                    for m in 0..3usize {
                        let Some(tx) = (xx + m).checked_sub(2) else {
                            continue;
                        };
                        if tx >= w {
                            continue;
                        }
                        let wgt = tent(offsets[i] + 1.0 - m as f64);
                        if wgt > 0.0 {
                            let acc = &mut sub[j * w + tx];
                            for k in 0..3 {
                                acc[k] += (wgt * c[k]) as f32;
                            }
                        }
                    }
                }
            }
            if inner_row && (centre_idx.is_none() || moving.is_some()) {
                for (x, d) in depth.iter_mut().enumerate() {
                    let (o, dir) = pixel_ray(view, Vector2::new(x as f64, (yy - 1) as f64));
                    *d = scene.intersect(&o, &dir).map_or(0.0, |hit| hit.t as f32);
                }
            }
            (sub, depth)
        })
        .collect();
    // Pass 2: vertical filtering of the sub-rows of the row and its two neighbours, noise, rounding.
    let scale = 255.0 / (norm_1d * norm_1d);
    let rows: Vec<Vec<u8>> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut rng = ChaCha8Rng::seed_from_u64(hash_words(&[noise_seed, y as u64]));
            let mut rgb = Vec::with_capacity(3 * w);
            for x in 0..w {
                let mut acc = [0.0f64; 3];
                for m in 0..3usize {
                    let sub = &filtered[y + m].0;
                    for (j, oj) in offsets.iter().enumerate() {
                        let wgt = tent(oj + m as f64 - 1.0);
                        if wgt > 0.0 {
                            let v = sub[j * w + x];
                            for k in 0..3 {
                                acc[k] += wgt * v[k] as f64;
                            }
                        }
                    }
                }
                for a in acc {
                    let noise = if noise_sigma > 0.0 {
                        noise_sigma * gaussian(&mut rng)
                    } else {
                        0.0
                    };
                    rgb.push((a * scale + noise).round().clamp(0.0, 255.0) as u8);
                }
            }
            rgb
        })
        .collect();
    let mut depth = FloatMap {
        width: w,
        height: h,
        channels: 1,
        data: Vec::with_capacity(w * h),
    };
    for (_, d) in &filtered[1..=h] {
        depth.data.extend_from_slice(d);
    }
    // The buffer has exactly 3·w·h bytes by construction.
    let image = RgbImage::from_raw(camera.width, camera.height, rows.concat())
        .unwrap_or_else(|| RgbImage::new(camera.width, camera.height));
    (image, depth)
}

/// Exact projection of a landmark when it is visible: in front of the camera, inside the image and
/// inside the distortion model's valid radius, front-facing, and not occluded.
pub fn landmark_projection(
    scene: &Scene,
    view: &PosedCamera,
    lm: &Landmark,
) -> Option<Vector2<f64>> {
    let (camera, cam_from_world) = (&view.camera, &view.cam_from_world);
    let c = center_of(cam_from_world);
    if lm.normal.dot(&(c - lm.position)) <= 0.0 {
        return None;
    }
    let p = cam_from_world.transform_point(&lm.position);
    if p.z <= 0.0 {
        return None;
    }
    let k = &camera.intrinsics;
    let corner = k.pixel_to_normalized(Vector2::new(-0.5, -0.5)).norm().max(
        k.pixel_to_normalized(Vector2::new(
            camera.width as f64 - 0.5,
            camera.height as f64 - 0.5,
        ))
        .norm(),
    );
    if Vector2::new(p.x / p.z, p.y / p.z).norm() > 1.05 * corner {
        return None;
    }
    let px = camera.project(cam_from_world, &lm.position)?;
    if !camera.contains(&px) {
        return None;
    }
    let hit = scene.intersect(&c, &(lm.position - c))?;
    ((hit.t - 1.0).abs() < 1e-6 && hit.primitive == lm.primitive && hit.face == lm.face)
        .then_some(px)
}

/// The ground-truth reconstruction of a scene seen by the given frames.
pub fn ground_truth(scene: &Scene, frames: &[PosedCamera]) -> MetricReconstruction {
    let mut rec = MetricReconstruction::default();
    for (i, frame) in frames.iter().enumerate() {
        let (cam, pose) = (&frame.camera, &frame.cam_from_world);
        let existing = rec
            .cameras
            .values()
            .find(|c| {
                c.intrinsics == cam.intrinsics && c.width == cam.width && c.height == cam.height
            })
            .map(|c| c.id);
        let camera_id = existing.unwrap_or_else(|| {
            let id = CameraId(rec.cameras.len() as u32);
            rec.cameras.insert(id, Camera { id, ..cam.clone() });
            id
        });
        let id = ImageId(i as u32);
        rec.views.insert(
            id,
            View {
                id,
                name: format!("frame_{i:04}.png"),
                camera_id,
                cam_from_world: *pose,
                observations: Vec::new(),
                frame: None,
            },
        );
    }
    let min_track = frames.len().min(2);
    let grey = (LANDMARK_DARK * 255.0).round() as u8;
    for (li, lm) in scene.landmark_info().iter().enumerate() {
        let seen: Vec<(ImageId, Vector2<f64>)> = frames
            .iter()
            .enumerate()
            .filter_map(|(i, view)| {
                landmark_projection(scene, view, lm).map(|px| (ImageId(i as u32), px))
            })
            .collect();
        if seen.len() < min_track || seen.is_empty() {
            continue;
        }
        let pid = PointId(li as u64);
        let mut elements = Vec::with_capacity(seen.len());
        for (image_id, px) in seen {
            let Some(view) = rec.views.get_mut(&image_id) else {
                continue;
            };
            elements.push(TrackElement {
                image_id,
                point2d_idx: view.observations.len() as u32,
            });
            view.observations.push(Observation {
                xy: px,
                point_id: Some(pid),
            });
        }
        rec.points.insert(
            pid,
            Point3D {
                xyz: lm.position,
                color: [grey; 3],
                error: 0.0,
                track: handheld_core::Track { elements },
            },
        );
    }
    rec
}

/// Renders a sequence of the default scene for `opts.seed`.
pub fn render_sequence(opts: &SequenceOptions) -> Result<SyntheticSequence, String> {
    render_sequence_with_scene(Scene::default_scene(opts.seed), opts)
}

/// Renders a sequence of a given scene.
pub fn render_sequence_with_scene(
    scene: Scene,
    opts: &SequenceOptions,
) -> Result<SyntheticSequence, String> {
    opts.validate()?;
    let traj = opts.effective_path().generate()?;
    let frames: Vec<PosedCamera> = traj
        .cam_from_world
        .iter()
        .zip(&traj.focal_factor)
        .map(|(pose, &factor)| {
            let camera = Camera {
                id: CameraId(0),
                width: opts.width,
                height: opts.height,
                intrinsics: opts.intrinsics(factor),
            };
            PosedCamera::new(camera, *pose)
        })
        .collect();
    let gt = ground_truth(&scene, &frames);
    let mut images = Vec::with_capacity(frames.len());
    let mut depths = Vec::with_capacity(frames.len());
    let mut table: Option<(Intrinsics, RayTable)> = None;
    let poses: Vec<_> = frames.iter().map(|f| f.cam_from_world).collect();
    for (i, view) in frames.iter().enumerate() {
        let cam = &view.camera;
        let stale = match &table {
            Some((k, _)) => *k != cam.intrinsics,
            None => true,
        };
        if stale {
            table = Some((cam.intrinsics, RayTable::new(cam, opts.samples_per_axis)));
        }
        let Some((_, rays)) = table.as_ref() else {
            continue;
        };
        let motion = FrameMotion::of(&poses, i, opts.shutter);
        let (img, depth) = render_frame_with_rays(
            &scene,
            view,
            rays,
            motion.as_ref(),
            opts.image_noise_sigma,
            hash_words(&[opts.seed, 0x1A6E, i as u64]),
        );
        images.push(img);
        depths.push(depth);
    }
    let mesh = scene.to_mesh(opts.mesh_resolution);
    Ok(SyntheticSequence {
        scene,
        gt,
        images,
        depths,
        mesh,
    })
}

/// Per-view lists of `(PointId, exact pixel)` — a convenience for matching tests.
pub fn observations_by_view(
    gt: &MetricReconstruction,
) -> BTreeMap<ImageId, Vec<(PointId, Vector2<f64>)>> {
    gt.views
        .iter()
        .map(|(id, v)| {
            (
                *id,
                v.observations
                    .iter()
                    .filter_map(|o| o.point_id.map(|p| (p, o.xy)))
                    .collect(),
            )
        })
        .collect()
}
