//! The mesh stage (§5.1): reads `dense/` (cameras.json, depth and confidence maps) and the
//! images, and writes `mesh/`:
//! - `model.obj` + `model.mtl` + `model.png` (texture atlas), `model.glb` (texture embedded),
//!   `model.ply` (binary, vertex colours): the fused surface (TSDF → marching cubes →
//!   simplification → texturing), in the sparse model's frame and units;
//! - `views/<image>.glb`: each key view's own §5.1 mesh, textured with its image;
//! - `holdout.png` with a held-out view: the model rendered from its camera, the photo, and their
//!   difference;
//! - `summary.json`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use handheld_core::{PosedView, Progress};
use handheld_io::dense_folder::{read_cameras, read_views, MapKind};
use handheld_mesh::{
    fuse_depth_maps, mesh_from_depth_map, texture_mesh, FusionOptions, FusionSummary,
    SingleMeshOptions, TextureOptions, TextureSummary, TexturedMesh, VoxelSize,
};
use image::RgbImage;
use serde::{Deserialize, Serialize};

use crate::error::{Context, PipelineError, Result};
use crate::files::{stage, HOLDOUT_PNG, MODEL_GLB, MODEL_OBJ, MODEL_PLY, VIEWS_DIR};
use crate::stage::{Produced, Stage, StageContext, SummaryFile};
use crate::warning::{code, Warning};

/// Which surface models the mesh stage builds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MeshMode {
    /// One volumetric model from all depth maps, textured from all views; per-view meshes too.
    Fused,
    /// Only the per-view meshes of §5.1.
    Single,
}

/// Options of the mesh stage.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct MeshStageOptions {
    pub mode: MeshMode,
    pub fusion: FusionOptions,
    pub single: SingleMeshOptions,
    pub texture: TextureOptions,
    /// Also build each key view's own §5.1 mesh (`mesh/views/`).
    pub view_meshes: bool,
    /// Leave this image out of the fused model, render the model from its camera and compare.
    pub hold_out: Option<String>,
}

impl Default for MeshStageOptions {
    fn default() -> Self {
        Self {
            mode: MeshMode::Fused,
            fusion: FusionOptions::default(),
            single: SingleMeshOptions::default(),
            texture: TextureOptions::default(),
            view_meshes: true,
            hold_out: None,
        }
    }
}

/// Above this fraction of depth samples left out as uncertain, the mesh stage says so.
const REPORT_LEFT_OUT: f64 = 0.05;

/// The smallest face budget of the simplified model.
pub const MIN_TARGET_FACES: usize = 100;

impl MeshStageOptions {
    /// The face count after simplification (`None`: not simplified).
    pub fn target_faces(&self) -> Option<usize> {
        self.fusion.simplify.as_ref().map(|s| s.target_faces)
    }

    pub fn validate(&self) -> Result<()> {
        if let Some(t) = self.target_faces() {
            if t < MIN_TARGET_FACES {
                return Err(PipelineError::option(
                    "--target-faces",
                    format!("must be at least {MIN_TARGET_FACES}, got {t}"),
                ));
            }
        }
        if let VoxelSize::Absolute(v) = self.fusion.tsdf.voxel_size {
            if !(v.is_finite() && v > 0.0) {
                return Err(PipelineError::option(
                    "--voxel-size",
                    format!("must be positive, got {v}"),
                ));
            }
        }
        let p = self.fusion.max_hole_perimeter_voxels;
        if !(p.is_finite() && p >= 0.0) {
            return Err(PipelineError::option(
                "--max-hole-perimeter",
                format!("must be zero or positive (voxel lengths), got {p}"),
            ));
        }
        Ok(())
    }
}

/// One per-view mesh.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ViewMesh {
    pub image: String,
    pub faces: usize,
    pub dropped_discontinuity: usize,
}

/// The held-out view's comparison.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct HoldOut {
    pub image: String,
    pub mean_absolute_difference: f64,
    pub covered_fraction: f64,
}

/// The texture atlas.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TextureReport {
    pub atlas: [u32; 2],
    #[serde(flatten)]
    pub summary: TextureSummary,
}

/// What the mesh stage built (`mesh/summary.json` lists every view mesh).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct MeshStageSummary {
    pub views: usize,
    /// The number of per-view meshes.
    pub view_meshes: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view_mesh_list: Option<Vec<ViewMesh>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hold_out: Option<HoldOut>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fusion: Option<FusionSummary>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<TextureReport>,
}

/// The mesh stage.
pub struct Mesh {
    pub options: MeshStageOptions,
}

impl Stage for Mesh {
    type Options = MeshStageOptions;
    type Summary = MeshStageSummary;

    const NAME: &'static str = stage::MESH;
    const READS: &'static [&'static str] = &[stage::INGEST, stage::DENSE];
    const ABOUT: &'static str =
        "surface models (§5.1): fused textured mesh (OBJ, glTF, PLY) and per-view meshes";

    fn options(&self) -> &MeshStageOptions {
        &self.options
    }

    fn validate(&self) -> Result<()> {
        self.options.validate()
    }

    fn run(&self, ctx: &StageContext, dir: &Path) -> Result<Produced<MeshStageSummary>> {
        let paths = ctx.ws.image_paths()?;
        build(
            &ctx.ws.root.join(stage::DENSE),
            &paths,
            &self.options,
            dir,
            ctx.progress,
        )
    }
}

/// Builds the meshes of the dense folder `dense` into `dir`.
pub fn build(
    dense: &Path,
    paths: &BTreeMap<String, PathBuf>,
    opts: &MeshStageOptions,
    dir: &Path,
    bars: &dyn Progress,
) -> Result<Produced<MeshStageSummary>> {
    let mut views = read_views(
        dense,
        |n| paths.get(n).cloned(),
        &[MapKind::Confidence, MapKind::Variance],
    )?;
    if views.is_empty() {
        return Err(PipelineError::workspace(
            dense,
            "no depth maps (run the dense stage first)",
        ));
    }
    let mut outputs = Vec::new();
    let mut summary = MeshStageSummary {
        views: views.len(),
        view_meshes: 0,
        view_mesh_list: None,
        hold_out: None,
        fusion: None,
        texture: None,
    };
    let mut warnings = Vec::new();
    if opts.view_meshes || opts.mode == MeshMode::Single {
        let vdir = dir.join(VIEWS_DIR);
        std::fs::create_dir_all(&vdir).map_err(|e| handheld_io::IoError::io(&vdir, e))?;
        let mut list = Vec::new();
        for v in &views {
            // A view whose depth map gives no triangle is skipped with a warning, not fatal.
            let (mesh, s) = match mesh_from_depth_map(v, &opts.single, bars) {
                Ok(r) if !r.0.faces.is_empty() => r,
                Ok(_) => {
                    warnings.push(Warning::new(
                        code::VIEW_SKIPPED,
                        format!("{}: the depth map gives no triangles", v.name),
                    ));
                    continue;
                }
                Err(e) => {
                    warnings.push(Warning::new(
                        code::VIEW_SKIPPED,
                        format!("{}: no single-view mesh: {e}", v.name),
                    ));
                    continue;
                }
            };
            let out = format!("{VIEWS_DIR}/{}.glb", v.name);
            handheld_io::glb::write_glb(&dir.join(&out), &mesh, Some(&v.image))?;
            outputs.push(out);
            list.push(ViewMesh {
                image: v.name.clone(),
                faces: mesh.faces.len(),
                dropped_discontinuity: s.dropped_angle,
            });
        }
        summary.view_meshes = list.len();
        summary.view_mesh_list = Some(list);
    }
    let held = match &opts.hold_out {
        Some(name) => Some(views.iter().position(|v| &v.name == name).ok_or_else(|| {
            PipelineError::option("--hold-out", format!("{name}: not among the dense views"))
        })?),
        None => None,
    };
    if opts.mode == MeshMode::Fused {
        // The held-out view leaves the set: neither its depth nor its colours reach the model.
        let held = held.map(|h| views.remove(h));
        let (mesh, fs) =
            fuse_depth_maps(&views, &opts.fusion, bars).context("volumetric fusion")?;
        let (textured, ts) =
            texture_mesh(&mesh, &views, &opts.texture, bars).context("texturing")?;
        let files = handheld_io::obj::write_obj(
            &dir.join(MODEL_OBJ),
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
            &dir.join(MODEL_GLB),
            &textured.mesh,
            Some(&textured.texture),
        )?;
        handheld_io::ply::write_mesh(
            &dir.join(MODEL_PLY),
            &textured.mesh,
            handheld_io::ply::PlyFormat::BinaryLittleEndian,
        )?;
        outputs.extend([MODEL_GLB.into(), MODEL_PLY.into()]);
        if let Some(h) = &held {
            summary.hold_out = Some(hold_out_check(h, &textured, dir)?);
            outputs.push(HOLDOUT_PNG.into());
        }
        summary.texture = Some(TextureReport {
            atlas: [textured.texture.width(), textured.texture.height()],
            summary: ts,
        });
        if !fs.views_without_depth.is_empty() {
            warnings.push(
                Warning::new(
                    code::VIEW_SKIPPED,
                    format!(
                        "{} of {} views have no depth and are not in the mesh: {}",
                        fs.views_without_depth.len(),
                        fs.views_without_depth.len() + fs.views,
                        fs.views_without_depth.join(", ")
                    ),
                )
                .advice("see the dense stage's failed pairs: a view whose every pair failed has no depth"),
            );
        }
        if fs.uncertain_fraction > REPORT_LEFT_OUT {
            warnings.push(
                Warning::new(
                    code::DEPTH_LEFT_OUT,
                    format!(
                        "{:.0} % of the depth samples were left out of the mesh: far background or surfaces seen \
                         with too little parallax, whose depth is less certain than the mesh's resolution there",
                        100.0 * fs.uncertain_fraction
                    ),
                )
                .advice(
                    "to model the far parts, film them from closer or with more sideways motion; \
                     `--max-depth-std 0` counts every sample fully",
                ),
            );
        }
        summary.fusion = Some(fs);
    }
    // `summary.json` keeps the per-view list; the manifest does not.
    let file = SummaryFile::full(&summary)?;
    summary.view_mesh_list = None;
    Ok(Produced::new(outputs, summary)
        .warn(warnings)
        .summary_file(file))
}

/// Renders the textured model from a view left out of it and compares with the photo; writes
/// `holdout.png` (rendering | photo | 4× absolute difference).
fn hold_out_check(v: &PosedView, textured: &TexturedMesh, dir: &Path) -> Result<HoldOut> {
    let r = handheld_render::render_mesh(&textured.mesh, Some(&textured.texture), &v.posed);
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
    let path = dir.join(HOLDOUT_PNG);
    let bytes = handheld_io::obj::encode_png(&path, &strip)?;
    handheld_io::atomic::write_bytes_atomic(&path, &bytes)?;
    tracing::info!(
        "held-out {}: mean absolute colour difference {mad:.1} over {:.1} % of the image",
        v.name,
        covered * 100.0
    );
    Ok(HoldOut {
        image: v.name.clone(),
        mean_absolute_difference: mad,
        covered_fraction: covered,
    })
}

/// The mesh stage alone, on a dense folder (`WS/dense` or the output of [`super::dense::densify_model`])
/// whose images are in `images`, into `out` (the layout of `WS/mesh`).
pub fn mesh_dense_folder(
    dense: &Path,
    images: &Path,
    opts: &MeshStageOptions,
    out: &Path,
    progress: &dyn Progress,
) -> Result<MeshStageSummary> {
    opts.validate()?;
    let paths = read_cameras(dense)?
        .into_iter()
        .map(|e| (images.join(&e.image), e.image))
        .map(|(path, image)| (image, path))
        .collect();
    std::fs::create_dir_all(out).map_err(|e| handheld_io::IoError::io(out, e))?;
    let produced = build(dense, &paths, opts, out, progress)?;
    produced.write_summary_file(out)?;
    Ok(produced.summary)
}
