//! The mesh stage (§5.1): reads `dense/` (cameras.json, depth and confidence maps) and the
//! images, and writes `mesh/`:
//! - `model.obj` + `model.mtl` + `model.png` (texture atlas), `model.glb` (texture embedded),
//!   `model.ply` (binary, vertex colours): the fused surface (TSDF → marching cubes →
//!   simplification → texturing), in the sparse model's frame and units;
//! - `views/<image>.glb`: each key view's own §5.1 mesh, textured with its image;
//! - `summary.json`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use handheld_core::PosedView;
use handheld_io::dense_folder::MapKind;
use handheld_io::workspace::{Fingerprint, Workspace};
use handheld_mesh::{
    fuse_depth_maps, mesh_from_depth_map, texture_mesh, FusionOptions, SimplifyOptions,
    SingleMeshOptions, TextureOptions, TsdfOptions, VoxelSize,
};
use image::RgbImage;
use serde_json::json;

use crate::args::{MeshArgs, MeshMode, MeshStageArgs};
use crate::pipeline::{run_stage, Stage, StageOutput, StageReport};
use crate::ui::Bars;

/// The mesh stage's options.
pub struct MeshStageOptions {
    pub mode: MeshMode,
    pub fusion: FusionOptions,
    pub single: SingleMeshOptions,
    pub texture: TextureOptions,
    pub view_meshes: bool,
    pub hold_out: Option<String>,
    pub fingerprint: serde_json::Value,
}

pub fn options(a: &MeshArgs) -> Result<MeshStageOptions> {
    if a.target_faces < 100 {
        anyhow::bail!(
            "--target-faces must be at least 100, got {}",
            a.target_faces
        );
    }
    let voxel_size = match a.voxel_size {
        Some(v) if !(v.is_finite() && v > 0.0) => {
            anyhow::bail!("--voxel-size must be positive, got {v}")
        }
        Some(v) => VoxelSize::Absolute(v),
        None => TsdfOptions::default().voxel_size,
    };
    if !(a.max_hole_perimeter.is_finite() && a.max_hole_perimeter >= 0.0) {
        anyhow::bail!(
            "--max-hole-perimeter must be zero or positive (voxel lengths), got {}",
            a.max_hole_perimeter
        );
    }
    let fusion = FusionOptions {
        tsdf: TsdfOptions {
            voxel_size,
            ..Default::default()
        },
        simplify: Some(SimplifyOptions {
            target_faces: a.target_faces,
            ..Default::default()
        }),
        max_hole_perimeter_voxels: a.max_hole_perimeter,
        ..Default::default()
    };
    Ok(MeshStageOptions {
        mode: a.mode,
        fusion,
        single: SingleMeshOptions::default(),
        texture: TextureOptions::default(),
        view_meshes: !a.no_view_meshes,
        hold_out: a.hold_out.clone(),
        fingerprint: json!({
            "hold_out": a.hold_out,
            "mode": format!("{:?}", a.mode),
            "target_faces": a.target_faces,
            "voxel_size": a.voxel_size,
            "max_hole_perimeter": a.max_hole_perimeter,
            "view_meshes": !a.no_view_meshes,
        }),
    })
}

/// The key views of `dense/` with their depth and confidence maps and images.
fn load_key_views(dense: &Path, paths: &BTreeMap<String, PathBuf>) -> Result<Vec<PosedView>> {
    Ok(handheld_io::dense_folder::read_views(
        dense,
        |name| paths.get(name).cloned(),
        &[MapKind::Confidence],
    )?)
}

pub fn run(
    ws: &Workspace,
    opts: &MeshStageOptions,
    force: bool,
    bars: &Bars,
) -> Result<StageReport> {
    run_stage(
        ws,
        Stage::Mesh,
        Fingerprint::new(),
        opts.fingerprint.clone(),
        force,
        |dir| {
            let paths = super::load_ingest(ws)?
                .images
                .into_iter()
                .map(|i| (i.info.name, i.info.path))
                .collect();
            build(
                &ws.root.join(Stage::Dense.dir_name()),
                &paths,
                opts,
                dir,
                bars,
            )
        },
    )
}

/// Builds the meshes of the dense folder `dense` into `dir`.
pub fn build(
    dense: &Path,
    paths: &BTreeMap<String, PathBuf>,
    opts: &MeshStageOptions,
    dir: &Path,
    bars: &Bars,
) -> Result<StageOutput> {
    let mut views = load_key_views(dense, paths)?;
    if views.is_empty() {
        anyhow::bail!(
            "{}: no depth maps (run the dense stage first)",
            dense.display()
        );
    }
    let mut outputs = Vec::new();
    let mut summary = json!({ "views": views.len() });
    if opts.view_meshes || opts.mode == MeshMode::Single {
        std::fs::create_dir_all(dir.join("views"))?;
        let mut faces = Vec::new();
        for v in &views {
            // A view whose depth map gives no triangle is skipped with a warning, not fatal.
            let (mesh, s) = match mesh_from_depth_map(v, &opts.single, bars) {
                Ok(r) if !r.0.faces.is_empty() => r,
                Ok(_) => {
                    tracing::warn!("{}: the depth map gives no triangles", v.name);
                    continue;
                }
                Err(e) => {
                    tracing::warn!("{}: no single-view mesh: {e}", v.name);
                    continue;
                }
            };
            let out = format!("views/{}.glb", v.name);
            handheld_io::glb::write_glb(&dir.join(&out), &mesh, Some(&v.image))?;
            outputs.push(out);
            faces.push(json!({ "image": v.name, "faces": mesh.faces.len(), "dropped_discontinuity": s.dropped_angle }));
        }
        summary["view_meshes"] = json!(faces);
    }
    let held = match &opts.hold_out {
        Some(name) => Some(
            views
                .iter()
                .position(|v| &v.name == name)
                .with_context(|| format!("--hold-out {name}: not among the dense views"))?,
        ),
        None => None,
    };
    if opts.mode == MeshMode::Fused {
        // The held-out view is left out of the model.
        let held = held.map(|h| views.remove(h));
        let (mesh, fs) =
            fuse_depth_maps(&views, &opts.fusion, bars).context("volumetric fusion")?;
        let hole_json = |h: &handheld_mesh::HoleReport| {
            json!({
                "outer_loops": h.outer_loops,
                "holes": h.holes,
                "filled": h.filled,
                "left_open": h.holes_open,
                "largest_open_perimeter": h.largest_open_perimeter,
                "faces_added": h.faces_added,
            })
        };
        let (textured, ts) =
            texture_mesh(&mesh, &views, &opts.texture, bars).context("texturing")?;
        let files = handheld_io::obj::write_obj(
            &dir.join("model.obj"),
            &textured.mesh,
            Some(&textured.texture),
        )?;
        for p in [Some(files.obj), files.mtl, files.png]
            .into_iter()
            .flatten()
        {
            if let Some(n) = p.file_name() {
                outputs.push(n.to_string_lossy().into_owned());
            }
        }
        handheld_io::glb::write_glb(
            &dir.join("model.glb"),
            &textured.mesh,
            Some(&textured.texture),
        )?;
        handheld_io::ply::write_mesh(
            &dir.join("model.ply"),
            &textured.mesh,
            handheld_io::ply::PlyFormat::BinaryLittleEndian,
        )?;
        outputs.extend(["model.glb".into(), "model.ply".into()]);
        if let Some(h) = &held {
            summary["hold_out"] = hold_out_check(h, &textured, dir)?;
            outputs.push("holdout.png".into());
        }
        summary["fusion"] = json!({
            "voxel_size": fs.voxel_size,
            "blocks": fs.blocks,
            "voxels": fs.voxels,
            "faces_extracted": fs.faces_extracted,
            "faces_final": fs.faces_final,
            "vertices_final": fs.vertices_final,
            "integrate_seconds": fs.integrate_seconds,
            "extract_seconds": fs.extract_seconds,
            "simplify_seconds": fs.simplify_seconds,
            // Watertight where observed: no non-manifold or flipped edge, no open hole; borders
            // only where the views stop (counted before texturing splits chart seams).
            "border_edges": fs.border_edges,
            "non_manifold_edges": fs.non_manifold_edges,
            "flipped_edges": fs.flipped_edges,
            "components": fs.components,
            "outer_boundaries": fs.outer_boundaries,
            "open_holes": fs.open_holes,
            "hole_filling": hole_json(&fs.holes),
            "non_manifold_faces_removed": fs.non_manifold_faces_removed,
            "hole_filling_after_simplify": hole_json(&fs.holes_after_simplify),
        });
        summary["texture"] = json!({
            "atlas": [textured.texture.width(), textured.texture.height()],
            "untextured_faces": ts.untextured_faces,
            "charts": ts.charts,
            "seconds": ts.seconds,
        });
    }
    handheld_io::atomic::write_bytes_atomic(
        &dir.join("summary.json"),
        &serde_json::to_vec_pretty(&summary)?,
    )?;
    outputs.push("summary.json".into());
    if let Some(v) = summary.get_mut("view_meshes") {
        *v = json!(v.as_array().map_or(0, Vec::len));
    }
    Ok(StageOutput { outputs, summary })
}

/// Renders the textured model from a view left out of it and compares with the photo; writes
/// `holdout.png` (rendering | photo | 4× absolute difference).
fn hold_out_check(
    v: &PosedView,
    textured: &handheld_mesh::TexturedMesh,
    dir: &Path,
) -> Result<serde_json::Value> {
    let r = handheld_render::render_mesh(
        &textured.mesh,
        Some(&textured.texture),
        &v.camera,
        &v.cam_from_world,
    );
    let (mad, covered) = handheld_render::mean_absolute_difference(&r, &v.image);
    let (w, h) = (v.image.width(), v.image.height());
    let mut strip = RgbImage::new(3 * w, h);
    for y in 0..h {
        for x in 0..w {
            let a = r.image.get_pixel(x, y).0;
            let b = v.image.get_pixel(x, y).0;
            let k = (y * w + x) as usize;
            let d = if r.covered[k] {
                [0, 1, 2].map(|c| (4 * (i32::from(a[c]) - i32::from(b[c])).abs()).min(255) as u8)
            } else {
                [0, 0, 60]
            };
            strip.put_pixel(x, y, image::Rgb(a));
            strip.put_pixel(w + x, y, image::Rgb(b));
            strip.put_pixel(2 * w + x, y, image::Rgb(d));
        }
    }
    let bytes = handheld_io::obj::encode_png(&dir.join("holdout.png"), &strip)?;
    handheld_io::atomic::write_bytes_atomic(&dir.join("holdout.png"), &bytes)?;
    tracing::info!(
        "held-out {}: mean absolute colour difference {mad:.1} over {:.1} % of the image",
        v.name,
        covered * 100.0
    );
    Ok(json!({ "image": v.name, "mean_absolute_difference": mad, "covered_fraction": covered }))
}

/// `handheld mesh --depth-maps DENSE --images I -o OUT`: the mesh stage alone.
pub fn run_standalone(a: &MeshStageArgs, bars: &Bars) -> Result<serde_json::Value> {
    let opts = options(&a.mesh)?;
    let entries = handheld_io::dense_folder::read_cameras(&a.depth_maps)?;
    let paths = entries
        .iter()
        .map(|e| (e.image.clone(), a.images.join(&e.image)))
        .collect();
    std::fs::create_dir_all(&a.output)
        .with_context(|| format!("{}: cannot create", a.output.display()))?;
    Ok(build(&a.depth_maps, &paths, &opts, &a.output, bars)?.summary)
}
