//! The novel-view benchmark of issue #19 (the Mip-NeRF 360 / 3D Gaussian Splatting protocol):
//! every `every`-th registered image (in name order, starting with the first) is held out. The
//! dense and mesh stages are rerun without the held-out images (in `WS/bench/render-every-N/`,
//! reused while the held-out set is the same), so neither their depth nor their colours reach
//! the models; their cameras come from the sparse model. Each held-out view is rendered with
//! every method and scored against its photo (at the dense stage's resolution): PSNR and SSIM
//! over the pixels the method covers, and the coverage; each image-based method is also compared
//! with the textured mesh on the pixels both cover. Speed: the subdivided method along a
//! fly-through at 640 pixels wide (median over the frames), and one full-size held-out view.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use handheld_core::{Camera, FloatMap, ImageId, NoProgress, PosedCamera, Progress};
use handheld_pipeline::render::{write_png, FlightOptions, PathKind, RenderMethod, RenderScene};
use handheld_pipeline::stages::dense::{densify, DenseStageOptions};
use handheld_pipeline::stages::mesh::{build, MeshStageOptions};
use handheld_pipeline::Workspace;
use handheld_render::{quality, IbrOptions, Quality, Rendered, Renderer};
use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// Options of the render benchmark.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct RenderBenchOptions {
    pub workspace: PathBuf,
    /// Hold out every N-th registered image. Default 8.
    pub every: usize,
    /// Frames of the speed run. Default 100.
    pub speed_frames: usize,
    /// Width of the speed run. Default 640.
    pub speed_width: u32,
    pub ibr: IbrOptions,
    /// Redo the dense and mesh stages of the benchmark even when they are up to date.
    pub force: bool,
}

impl Default for RenderBenchOptions {
    fn default() -> Self {
        Self {
            workspace: PathBuf::new(),
            every: 8,
            speed_frames: 100,
            speed_width: 640,
            ibr: IbrOptions::default(),
            force: false,
        }
    }
}

/// The scores of one method on one held-out view.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MethodScore {
    pub method: RenderMethod,
    /// Over the pixels the method covers.
    pub own: Quality,
    /// Over the pixels both this method and the textured mesh cover (image-based methods only):
    /// this method's PSNR, the mesh's, and the difference.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vs_mesh: Option<VersusMesh>,
    pub seconds: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct VersusMesh {
    pub psnr: f64,
    pub mesh_psnr: f64,
    pub gain_db: f64,
    pub ssim: f64,
    pub mesh_ssim: f64,
    pub coverage: f64,
}

/// One held-out view.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeldOutView {
    pub image: String,
    pub width: u32,
    pub height: u32,
    pub methods: Vec<MethodScore>,
}

/// A method's scores averaged over the held-out views (PSNR averaged in dB).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MethodSummary {
    pub method: RenderMethod,
    pub psnr: f64,
    pub ssim: f64,
    pub coverage: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gain_over_mesh_db: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coverage_over_mesh: Option<f64>,
}

/// Rendering speed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SpeedReport {
    pub method: RenderMethod,
    pub width: u32,
    pub height: u32,
    pub frames: usize,
    pub median_seconds: f64,
    pub fps: f64,
    /// Median seconds of the support mesh (triangulation, depth search, subdivision) per frame,
    /// and median leaves (drawn triangles).
    pub median_support_seconds: f64,
    pub median_leaves: usize,
    /// One held-out view at the dense stage's resolution.
    pub full_size: Option<FullSize>,
    pub threads: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FullSize {
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
}

/// The report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RenderBenchReport {
    pub workspace: PathBuf,
    pub every: usize,
    pub registered: usize,
    pub held_out: Vec<String>,
    pub summary: Vec<MethodSummary>,
    /// The best image-based method by PSNR.
    pub best_ibr: Option<RenderMethod>,
    pub views: Vec<HeldOutView>,
    pub speed: Vec<SpeedReport>,
    /// Where the comparison images are (photo | each method).
    pub images: PathBuf,
    pub seconds_dense: f64,
    pub seconds_mesh: f64,
    pub warnings: Vec<String>,
}

/// The benchmark's own dense and mesh folders are reused when they were made for this held-out set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct HoldOutKey {
    held_out: Vec<String>,
    dense: serde_json::Value,
}

/// Checks the benchmark's options; the error names the flag.
fn validate(o: &RenderBenchOptions) -> Result<()> {
    if o.every < 2 {
        return Err(EvalError::option("--every", "must be at least 2"));
    }
    if o.speed_frames < 2 {
        return Err(EvalError::option("--speed-frames", "must be at least 2"));
    }
    o.ibr
        .validate()
        .map_err(|e| EvalError::option("--method", e.to_string()))
}

/// The registered views by name, the names of every `every`-th (held out) and the ids of the rest.
#[allow(clippy::type_complexity)]
fn hold_out_every(
    rec: &handheld_core::MetricReconstruction,
    every: usize,
) -> Result<(Vec<(String, ImageId)>, Vec<String>, Vec<ImageId>)> {
    let mut names: Vec<(String, ImageId)> = rec
        .views
        .iter()
        .map(|(id, v)| (v.name.clone(), *id))
        .collect();
    names.sort();
    if names.len() < every.max(3) {
        return Err(EvalError::option(
            "--every",
            format!(
                "the workspace has {} registered images; holding out every {}-th leaves too few",
                names.len(),
                every
            ),
        ));
    }
    let held: Vec<String> = names
        .iter()
        .enumerate()
        .filter(|(i, _)| i % every == 0)
        .map(|(_, n)| n.0.clone())
        .collect();
    let keep: Vec<ImageId> = names
        .iter()
        .filter(|n| !held.contains(&n.0))
        .map(|n| n.1)
        .collect();
    Ok((names, held, keep))
}

pub fn bench_render(o: &RenderBenchOptions, progress: &dyn Progress) -> Result<RenderBenchReport> {
    validate(o)?;
    let ws = Workspace::open(&o.workspace)?;
    let rec = ws.read_sparse_model()?;
    let paths = ws.image_paths()?;
    let (names, held, keep) = hold_out_every(&rec, o.every)?;
    let dir = ws
        .root
        .join("bench")
        .join(format!("render-every-{}", o.every));
    let dense_dir = dir.join("dense");
    let mesh_dir = dir.join("mesh");
    let images_dir = dir.join("images");
    for d in [&dense_dir, &mesh_dir, &images_dir] {
        std::fs::create_dir_all(d).map_err(|e| handheld_io::IoError::io(d, e))?;
    }
    let dense_opts = DenseStageOptions::default();
    let key = HoldOutKey {
        held_out: held.clone(),
        dense: serde_json::to_value(&dense_opts).unwrap_or_default(),
    };
    let key_path = dir.join("held_out.json");
    let reuse = !o.force
        && std::fs::read(&key_path)
            .ok()
            .and_then(|b| serde_json::from_slice::<HoldOutKey>(&b).ok())
            .is_some_and(|k| k == key)
        && mesh_dir.join("summary.json").exists();
    let (mut seconds_dense, mut seconds_mesh) = (0.0, 0.0);
    if !reuse {
        let _ = std::fs::remove_file(&key_path);
        let t = Instant::now();
        densify(&rec, &paths, &keep, &dense_opts, &dense_dir, progress)?;
        seconds_dense = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let mesh_opts = MeshStageOptions {
            view_meshes: false,
            ..Default::default()
        };
        build(&dense_dir, &paths, &mesh_opts, &mesh_dir, progress)?;
        seconds_mesh = t.elapsed().as_secs_f64();
        handheld_io::atomic::write_bytes_atomic(
            &key_path,
            &serde_json::to_vec_pretty(&key).unwrap_or_default(),
        )?;
    }
    let scene = handheld_pipeline::render::scene_from_folders(
        &rec,
        &paths,
        &dense_dir,
        Some(&mesh_dir.join(handheld_pipeline::files::MODEL_GLB)),
        &held,
        scene_max_size(&rec, &dense_opts, keep.len()),
    )?;
    let mut renderer = Renderer::new();
    let mut views = Vec::new();
    progress.start("rendering the held-out views", held.len() as u64);
    for name in &held {
        let id = names.iter().find(|n| &n.0 == name).map(|n| n.1);
        let Some(view) = id.and_then(|id| rec.views.get(&id)) else {
            continue;
        };
        let Some(cam) = rec.cameras.get(&view.camera_id) else {
            continue;
        };
        let max_size = dense_opts.max_size_for(cam.width, cam.height, keep.len());
        let (camera, photo) = held_out_photo(&paths, name, cam, max_size)?;
        views.push(score_view(
            &scene,
            &mut renderer,
            name,
            &PosedCamera::new(camera, view.cam_from_world),
            &photo,
            &o.ibr,
            &images_dir,
        )?);
        progress.inc(1);
    }
    progress.finish();
    let summary = summarise(&views);
    let best_ibr = summary
        .iter()
        .filter(|s| s.method != RenderMethod::Mesh)
        .max_by(|a, b| a.psnr.total_cmp(&b.psnr))
        .map(|s| s.method);
    let mut speed = Vec::new();
    for method in [RenderMethod::Subdivided, RenderMethod::Ulr] {
        let full = views.first().and_then(|v| {
            let name = &v.image;
            let id = names.iter().find(|n| &n.0 == name)?.1;
            let view = rec.views.get(&id)?;
            let cam = rec.cameras.get(&view.camera_id)?;
            let max_size = dense_opts.max_size_for(cam.width, cam.height, keep.len());
            let (camera, _) = held_out_photo(&paths, name, cam, max_size).ok()?;
            let mut out = empty();
            let t = Instant::now();
            scene
                .render(
                    &mut renderer,
                    &PosedCamera::new(camera.clone(), view.cam_from_world),
                    method,
                    &o.ibr,
                    &mut out,
                )
                .ok()?;
            Some(FullSize {
                width: camera.width,
                height: camera.height,
                seconds: t.elapsed().as_secs_f64(),
            })
        });
        speed.push(speed_run(&scene, &mut renderer, method, o, full)?);
    }
    Ok(RenderBenchReport {
        workspace: o.workspace.clone(),
        every: o.every,
        registered: names.len(),
        held_out: held,
        summary,
        best_ibr,
        views,
        speed,
        images: images_dir,
        seconds_dense,
        seconds_mesh,
        warnings: scene.warnings.clone(),
    })
}

fn empty() -> Rendered {
    Rendered {
        image: RgbImage::new(0, 0),
        covered: Vec::new(),
        depth: FloatMap::filled(0, 0, 1, 0.0),
    }
}

/// The dense stage's size limit for the model's largest camera (0: none).
fn scene_max_size(
    rec: &handheld_core::MetricReconstruction,
    dense_opts: &handheld_pipeline::stages::dense::DenseStageOptions,
    views: usize,
) -> u32 {
    rec.cameras
        .values()
        .map(|c| dense_opts.max_size_for(c.width, c.height, views))
        .max()
        .unwrap_or(0)
}

/// The held-out photo at the dense stage's resolution, and its camera there.
fn held_out_photo(
    paths: &BTreeMap<String, PathBuf>,
    name: &str,
    cam: &Camera,
    max_size: u32,
) -> Result<(Camera, RgbImage)> {
    let path = paths.get(name).ok_or_else(|| {
        EvalError::option(
            "--workspace",
            format!("{name}: not among the ingested images"),
        )
    })?;
    let opts = handheld_io::images::ImageIngestOptions {
        min_dimension: 1,
        ..Default::default()
    };
    let img = handheld_io::images::load_image(path, &opts)?
        .image
        .to_rgb8();
    let longer = img.width().max(img.height());
    if max_size > 0 && longer > max_size {
        let s = f64::from(max_size) / f64::from(longer);
        let w = (f64::from(img.width()) * s).round() as u32;
        let h = (f64::from(img.height()) * s).round() as u32;
        let small = image::imageops::resize(&img, w, h, image::imageops::FilterType::Triangle);
        let c = cam.scaled(
            f64::from(w) / f64::from(img.width()),
            f64::from(h) / f64::from(img.height()),
        );
        Ok((c, small))
    } else {
        Ok((cam.clone(), img))
    }
}

#[allow(clippy::too_many_arguments)]
fn score_view(
    scene: &RenderScene,
    renderer: &mut Renderer,
    name: &str,
    view: &PosedCamera,
    photo: &RgbImage,
    ibr: &IbrOptions,
    images_dir: &Path,
) -> Result<HeldOutView> {
    let mut rendered = Vec::new();
    let mut methods = Vec::new();
    for method in RenderMethod::ALL {
        if method == RenderMethod::Mesh && scene.mesh.is_none() {
            continue;
        }
        let mut out = empty();
        let t = Instant::now();
        scene
            .render(renderer, view, method, ibr, &mut out)
            .map_err(handheld_pipeline::PipelineError::from)?;
        let seconds = t.elapsed().as_secs_f64();
        methods.push(MethodScore {
            method,
            own: quality(&out.image, photo, &out.covered),
            vs_mesh: None,
            seconds,
        });
        rendered.push(out);
    }
    if let Some(mi) = methods.iter().position(|m| m.method == RenderMethod::Mesh) {
        let mesh_cov = rendered[mi].covered.clone();
        for (k, m) in methods.iter_mut().enumerate() {
            if m.method == RenderMethod::Mesh {
                continue;
            }
            let both: Vec<bool> = rendered[k]
                .covered
                .iter()
                .zip(&mesh_cov)
                .map(|(a, b)| *a && *b)
                .collect();
            let a = quality(&rendered[k].image, photo, &both);
            let b = quality(&rendered[mi].image, photo, &both);
            m.vs_mesh = Some(VersusMesh {
                psnr: a.psnr,
                mesh_psnr: b.psnr,
                gain_db: a.psnr - b.psnr,
                ssim: a.ssim,
                mesh_ssim: b.ssim,
                coverage: a.coverage,
            });
        }
    }
    // photo | methods, side by side, for a person to look at.
    let (w, h) = (photo.width(), photo.height());
    let mut strip = RgbImage::new(w * (1 + rendered.len() as u32), h);
    image::imageops::replace(&mut strip, photo, 0, 0);
    for (k, r) in rendered.iter().enumerate() {
        image::imageops::replace(&mut strip, &r.image, i64::from(w) * (k as i64 + 1), 0);
    }
    let names: Vec<&str> = methods.iter().map(|m| m.method.name()).collect();
    write_png(
        &images_dir.join(format!("{name}.photo-{}.png", names.join("-"))),
        &strip,
    )?;
    Ok(HeldOutView {
        image: name.to_string(),
        width: w,
        height: h,
        methods,
    })
}

fn summarise(views: &[HeldOutView]) -> Vec<MethodSummary> {
    RenderMethod::ALL
        .into_iter()
        .filter_map(|method| {
            let scores: Vec<&MethodScore> = views
                .iter()
                .filter_map(|v| v.methods.iter().find(|m| m.method == method))
                .collect();
            if scores.is_empty() {
                return None;
            }
            let n = scores.len() as f64;
            let mean =
                |f: &dyn Fn(&MethodScore) -> f64| scores.iter().map(|s| f(s)).sum::<f64>() / n;
            let vs: Vec<&VersusMesh> = scores.iter().filter_map(|s| s.vs_mesh.as_ref()).collect();
            let mesh_cov = views
                .iter()
                .filter_map(|v| v.methods.iter().find(|m| m.method == RenderMethod::Mesh))
                .map(|m| m.own.coverage)
                .sum::<f64>()
                / n;
            Some(MethodSummary {
                method,
                psnr: mean(&|s| s.own.psnr),
                ssim: mean(&|s| s.own.ssim),
                coverage: mean(&|s| s.own.coverage),
                gain_over_mesh_db: (!vs.is_empty())
                    .then(|| vs.iter().map(|v| v.gain_db).sum::<f64>() / vs.len() as f64),
                coverage_over_mesh: (!vs.is_empty() && mesh_cov > 0.0)
                    .then(|| mean(&|s| s.own.coverage) / mesh_cov),
            })
        })
        .collect()
}

fn speed_run(
    scene: &RenderScene,
    renderer: &mut Renderer,
    method: RenderMethod,
    o: &RenderBenchOptions,
    full_size: Option<FullSize>,
) -> Result<SpeedReport> {
    let fo = FlightOptions {
        method,
        path: PathKind::Through,
        frames: o.speed_frames,
        width: o.speed_width,
        ibr: o.ibr.clone(),
        ..Default::default()
    };
    let (camera, poses) = scene.flight_poses(&fo);
    let mut out = empty();
    let mut times = Vec::with_capacity(poses.len());
    let mut support = Vec::with_capacity(poses.len());
    let mut leaves = Vec::with_capacity(poses.len());
    for pose in &poses {
        let t = Instant::now();
        let stats = scene
            .render(
                renderer,
                &PosedCamera::new(camera.clone(), *pose),
                method,
                &o.ibr,
                &mut out,
            )
            .map_err(handheld_pipeline::PipelineError::from)?;
        times.push(t.elapsed().as_secs_f64());
        if let Some(s) = stats {
            support.push(s.seconds_support);
            leaves.push(s.leaves);
        }
    }
    support.sort_by(f64::total_cmp);
    leaves.sort_unstable();
    times.sort_by(f64::total_cmp);
    let median = times.get(times.len() / 2).copied().unwrap_or(f64::NAN);
    let _ = NoProgress;
    Ok(SpeedReport {
        method,
        width: camera.width,
        height: camera.height,
        frames: times.len(),
        median_seconds: median,
        fps: 1.0 / median,
        median_support_seconds: support.get(support.len() / 2).copied().unwrap_or(f64::NAN),
        median_leaves: leaves.get(leaves.len() / 2).copied().unwrap_or(0),
        full_size,
        threads: rayon::current_num_threads(),
    })
}
