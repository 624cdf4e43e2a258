//! View-dependent appearance (issue #19): the testkit scene with a glossy sphere, whose
//! Blinn–Phong highlight moves over it as the camera moves. Every `every`-th frame of an orbit is
//! held out; the others, with their exact depth maps and cameras, feed the image-based renderer
//! and the textured mesh (fused and textured from the same views). Each held-out view is scored
//! over the pixels of its highlight (specular term above `threshold`, from the ground truth) and
//! over all the pixels both cover: the image-based methods blend the neighbouring photos, in
//! which the highlight sits where it does from nearby; the single texture has it baked at one
//! place, or not at all.

use handheld_core::{NoProgress, PosedView};
use handheld_mesh::{fuse_depth_maps, texture_mesh, FusionOptions, TextureOptions};
use handheld_render::{quality, render_mesh, IbrMethod, IbrOptions, IbrScene, Rendered, Renderer};
use handheld_testkit::path::PathOptions;
use handheld_testkit::render::{highlight_map, render_sequence_with_scene, SequenceOptions};
use handheld_testkit::Scene;
use serde::{Deserialize, Serialize};

use crate::error::{EvalError, Result};

/// Options of the specular benchmark.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default)]
pub struct SpecularBenchOptions {
    /// Image width (height 3/4 of it). Default 640.
    pub width: u32,
    /// Frames of the orbit. Default 24.
    pub frames: usize,
    /// Hold out every N-th frame. Default 8.
    pub every: usize,
    pub seed: u64,
    /// A pixel belongs to the highlight when its specular term exceeds this (0..1 of white).
    pub threshold: f64,
    /// Write each held-out view here: photo | subdivided | ulr | ulr_mesh | mesh.
    pub images: Option<std::path::PathBuf>,
}

impl Default for SpecularBenchOptions {
    fn default() -> Self {
        Self {
            width: 640,
            frames: 24,
            every: 8,
            seed: 1,
            threshold: 0.15,
            images: None,
        }
    }
}

/// One method's scores, averaged over the held-out views that show the highlight.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SpecularScore {
    pub method: String,
    /// PSNR over the highlight's pixels (those the textured mesh also covers).
    pub highlight_psnr: f64,
    /// PSNR over every pixel the method and the mesh both cover.
    pub shared_psnr: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SpecularReport {
    pub width: u32,
    pub height: u32,
    pub held_out: Vec<usize>,
    /// Highlight pixels per held-out view.
    pub highlight_pixels: Vec<usize>,
    pub scores: Vec<SpecularScore>,
}

pub fn bench_specular(o: &SpecularBenchOptions) -> Result<SpecularReport> {
    if o.every < 2 || o.frames < o.every + 2 {
        return Err(EvalError::option(
            "--every",
            "must be at least 2 and leave at least two frames between held-out ones",
        ));
    }
    let seq_opts = SequenceOptions {
        seed: o.seed,
        width: o.width,
        height: o.width * 3 / 4,
        num_frames: o.frames,
        path: PathOptions::orbit(o.frames),
        ..Default::default()
    };
    let seq = render_sequence_with_scene(Scene::glossy_scene(o.seed), &seq_opts)
        .map_err(|e| EvalError::option("--width", e))?;
    let mut train = Vec::new();
    let mut held = Vec::new();
    for i in 0..seq.images.len() {
        let Some(frame) = seq.frame(i) else {
            continue;
        };
        let mut v = PosedView::from_posed(format!("{i}"), frame, seq.images[i].clone());
        v.depth = Some(seq.depths[i].clone());
        if i % o.every == 0 {
            held.push((i, v));
        } else {
            train.push(v);
        }
    }
    let (mesh, _) = fuse_depth_maps(&train, &FusionOptions::default(), &NoProgress)
        .map_err(|e| EvalError::option("fusion", e.to_string()))?;
    let (textured, _) = texture_mesh(&mesh, &train, &TextureOptions::default(), &NoProgress)
        .map_err(|e| EvalError::option("texture", e.to_string()))?;
    let points: Vec<_> = seq.gt.points.values().map(|p| p.xyz).collect();
    let scene =
        IbrScene::new(&train, &points).map_err(|e| EvalError::option("ibr", e.to_string()))?;
    let ibr = IbrOptions::default();
    let mut renderer = Renderer::new();
    let names = ["subdivided", "ulr", "ulr_mesh", "mesh"];
    let mut sums = vec![(0.0, 0.0, 0usize); names.len()];
    let mut counts = Vec::new();
    for (_, v) in &held {
        let spec = highlight_map(&seq.scene, &v.posed);
        let mesh_r = render_mesh(&textured.mesh, Some(&textured.texture), &v.posed);
        let mask: Vec<bool> = spec
            .data
            .iter()
            .zip(&mesh_r.covered)
            .map(|(s, c)| f64::from(*s) > o.threshold && *c)
            .collect();
        let n = mask.iter().filter(|m| **m).count();
        counts.push(n);
        if n < 20 {
            continue;
        }
        let mut strip = image::RgbImage::new(v.image.width() * 5, v.image.height());
        image::imageops::replace(&mut strip, &v.image, 0, 0);
        for (k, name) in names.iter().enumerate() {
            let r: Rendered = match *name {
                "mesh" => mesh_r.clone(),
                _ => {
                    let method = if *name == "subdivided" {
                        IbrMethod::Subdivided
                    } else {
                        IbrMethod::Ulr
                    };
                    let proxy = (*name == "ulr_mesh").then(|| mesh_r.depth.clone());
                    let mut out = Rendered {
                        image: image::RgbImage::new(0, 0),
                        covered: Vec::new(),
                        depth: handheld_core::FloatMap::filled(0, 0, 1, 0.0),
                    };
                    renderer
                        .render_with_proxy(&scene, &v.posed, method, &ibr, proxy.as_ref(), &mut out)
                        .map_err(|e| EvalError::option("ibr", e.to_string()))?;
                    out
                }
            };
            let hl: Vec<bool> = mask.iter().zip(&r.covered).map(|(m, c)| *m && *c).collect();
            let shared: Vec<bool> = r
                .covered
                .iter()
                .zip(&mesh_r.covered)
                .map(|(a, b)| *a && *b)
                .collect();
            image::imageops::replace(
                &mut strip,
                &r.image,
                i64::from(v.image.width()) * (k as i64 + 1),
                0,
            );
            let qh = quality(&r.image, &v.image, &hl);
            let qs = quality(&r.image, &v.image, &shared);
            sums[k].0 += qh.psnr;
            sums[k].1 += qs.psnr;
            sums[k].2 += 1;
        }
        if let Some(dir) = &o.images {
            std::fs::create_dir_all(dir).map_err(|e| handheld_io::IoError::io(dir, e))?;
            let path = dir.join(format!("specular-{}.png", v.name));
            let bytes = handheld_io::obj::encode_png(&path, &strip)?;
            handheld_io::atomic::write_bytes_atomic(&path, &bytes)?;
        }
    }
    Ok(SpecularReport {
        width: seq_opts.width,
        height: seq_opts.height,
        held_out: held.iter().map(|h| h.0).collect(),
        highlight_pixels: counts,
        scores: names
            .iter()
            .zip(&sums)
            .map(|(name, s)| SpecularScore {
                method: name.to_string(),
                highlight_psnr: s.0 / s.2.max(1) as f64,
                shared_psnr: s.1 / s.2.max(1) as f64,
            })
            .collect(),
    })
}
