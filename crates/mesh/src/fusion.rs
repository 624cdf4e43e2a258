//! The volumetric stage of §5.1 as one call: depth maps → TSDF ([`crate::tsdf`], Curless & Levoy
//! 1996), streamed over spatial tiles ([`crate::tiles`]) → marching cubes ([`crate::marching_cubes`], Lorensen & Cline 1987) → removal of floating
//! specks → hole filling inside observed surface ([`crate::holes`]) → quadric simplification
//! ([`mod@crate::simplify`], Garland & Heckbert 1997) → cutting out the non-manifold edges the
//! collapses leave, and closing those small holes again. The result is watertight where observed:
//! its only borders are the outlines where the views stop (and holes longer than
//! [`FusionOptions::max_hole_perimeter_voxels`]).
//!
//! Bad input fails loudly: a map whose size differs from its camera, an all-empty map, depth maps
//! that never agree on a surface ([`MeshError::NoOverlap`]) or an empty extraction are errors, never
//! an empty mesh reported as success.

use std::time::Instant;

use handheld_core::{PosedView, Progress, TriMesh};

use crate::error::{in_range, MeshError, Result};
use crate::holes::{boundary_loops, fill_holes, remove_non_manifold, HoleFillOptions, HoleReport};
use crate::marching_cubes::{ExtractOptions, Welder};
use crate::simplify::{compact, simplify, SimplifyOptions};
use crate::tiles::fuse_tiled;
use crate::topology::{edge_report, face_components, remove_small_components};
use crate::tsdf::{
    resolve_voxel_size, TsdfOptions, TsdfVolume, VoxelSize, BLOCK_BYTES, BLOCK_VOXELS,
};
use crate::view::Depth;

/// Options of [`fuse_depth_maps`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FusionOptions {
    pub tsdf: TsdfOptions,
    /// Surface extraction; `min_observations` is clamped to the number of views.
    pub extract: ExtractOptions,
    /// Connected components with fewer faces are dropped as floating specks of noise; 0 keeps
    /// everything. Default 100.
    pub min_component_faces: usize,
    /// Simplification after extraction; `None` keeps the marching-cubes mesh. Default
    /// `Some(SimplifyOptions::default())`.
    pub simplify: Option<SimplifyOptions>,
    /// Holes inside observed surface ([`crate::holes`]) with a boundary of at most this many voxel
    /// lengths are closed, before simplification and again after it (where non-manifold edges
    /// were cut out); 0 leaves every hole open. Default 1000.
    pub max_hole_perimeter_voxels: f64,
}

impl FusionOptions {
    pub fn validate(&self) -> Result<()> {
        self.tsdf.validate()?;
        self.extract.validate()?;
        in_range(
            "max_hole_perimeter_voxels",
            self.max_hole_perimeter_voxels,
            0.0,
            1e9,
        )?;
        if let Some(s) = &self.simplify {
            s.validate()?;
        }
        Ok(())
    }
}

impl Default for FusionOptions {
    fn default() -> Self {
        Self {
            tsdf: TsdfOptions::default(),
            extract: ExtractOptions::default(),
            min_component_faces: 100,
            simplify: Some(SimplifyOptions::default()),
            max_hole_perimeter_voxels: 1000.0,
        }
    }
}

/// What [`fuse_depth_maps`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FusionSummary {
    /// The views fused.
    pub views: usize,
    /// The views left out because their depth map holds no valid pixel.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub views_without_depth: Vec<String>,
    /// Voxel edge length used (world units; of level 0 where the size follows the depth).
    pub voxel_size: f64,
    /// Truncation distance (world units; of level 0).
    pub truncation: f64,
    /// Where the voxel size follows the depth: the blocks of each level (level `l` has voxels of
    /// `2^l · voxel_size`), finest first. Empty with one voxel size.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub levels: Vec<LevelReport>,
    /// The fraction of the depth samples left out of fusion because their uncertainty exceeds
    /// twice `max_depth_std` truncations (far background, too little parallax); those between
    /// one and two times count with a reduced weight.
    pub uncertain_fraction: f64,
    /// Allocated voxel blocks and the voxels they hold (over the whole scene).
    pub blocks: usize,
    pub voxels: usize,
    /// Voxels that received any weight.
    pub observed_voxels: usize,
    /// The spatial tiles fused one at a time ([`crate::tiles`]), and the most blocks alive at
    /// once (a tile and its halo).
    pub tiles: usize,
    pub peak_blocks: usize,
    /// Approximate bytes held by the volume at its peak (one tile).
    pub volume_bytes: usize,
    /// Effective `min_observations` (after clamping to the number of views).
    pub min_observations: usize,
    /// Marching-cubes faces, after speck removal, and after simplification.
    pub faces_extracted: usize,
    pub faces_cleaned: usize,
    pub faces_final: usize,
    /// Hole filling on the marching-cubes mesh.
    pub holes: HoleReport,
    /// Faces cut out around non-manifold edges after simplification, and the refill.
    pub non_manifold_faces_removed: usize,
    pub holes_after_simplify: HoleReport,
    /// The final mesh's edges: open borders, non-manifold, inconsistently oriented
    /// ([`crate::topology::edge_report`]); its connected pieces; and its boundary loops, split
    /// into outer outlines (where the views stop) and holes left open ([`crate::holes`]).
    pub border_edges: usize,
    pub non_manifold_edges: usize,
    pub flipped_edges: usize,
    pub components: usize,
    pub outer_boundaries: usize,
    pub open_holes: usize,
    pub vertices_final: usize,
    /// Integration and marching cubes (interleaved, tile by tile).
    pub integrate_seconds: f64,
    /// Speck removal and hole filling.
    pub extract_seconds: f64,
    pub simplify_seconds: f64,
}

/// The blocks of one resolution level.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LevelReport {
    pub level: i32,
    pub voxel_size: f64,
    pub blocks: usize,
}

/// Fuses the views' depth maps (weighted by their confidence maps where present; images are not
/// read) into one mesh in the world (sparse model) frame, counter-clockwise seen from outside
/// (the free-space side), with vertex normals. Every view needs a depth map; one without any
/// valid pixel is left out (named in the summary), and only a set where none has any is an
/// error ([`MeshError::EmptyDepth`]). To hold a view out
/// of the model, leave it out of `views` (e.g. `Vec::remove` it first).
pub fn fuse_depth_maps(
    views: &[PosedView],
    opts: &FusionOptions,
    progress: &dyn Progress,
) -> Result<(TriMesh, FusionSummary)> {
    opts.validate()?;
    if views.is_empty() {
        return Err(MeshError::NoViews { what: "depth maps" });
    }
    // A view whose depth map holds nothing (its pairs all failed) adds nothing to the volume: it
    // is left out and named in the summary; only a set without any depth is an error.
    let mut without_depth = Vec::new();
    for (i, v) in views.iter().enumerate() {
        let d = Depth::of(v, i)?;
        if !(0..d.depth.data.len()).any(|p| d.weight(p, opts.tsdf.min_confidence) > 0.0) {
            without_depth.push(i);
        }
    }
    if without_depth.len() == views.len() {
        return Err(MeshError::EmptyDepth { view: 0 });
    }
    let used: Vec<(usize, &PosedView)> = views
        .iter()
        .enumerate()
        .filter(|(i, _)| !without_depth.contains(i))
        .collect();
    if !without_depth.is_empty() {
        tracing::warn!(
            "fusion: {} of {} views have no depth and are left out: {}",
            without_depth.len(),
            views.len(),
            without_depth
                .iter()
                .map(|&i| views[i].name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let t0 = Instant::now();
    let voxel_size = resolve_voxel_size(views, &opts.tsdf)?;
    let mut vol = TsdfVolume::new(voxel_size, &opts.tsdf)?;
    if let (true, VoxelSize::PixelFootprint(factor)) = (opts.tsdf.adaptive, opts.tsdf.voxel_size) {
        let used_views: Vec<PosedView> = used.iter().map(|&(_, v)| v.clone()).collect();
        vol.set_levels(&used_views, voxel_size / factor, &opts.tsdf);
    }
    let min_obs = opts.extract.min_observations.clamp(1, used.len());
    let extract = ExtractOptions {
        min_observations: min_obs,
        ..opts.extract.clone()
    };
    let mut welder = Welder::default();
    let pass = fuse_tiled(
        &mut vol,
        &used,
        opts.tsdf.tile_blocks,
        &extract,
        &mut welder,
        progress,
    )?;
    if !pass.seen {
        return Err(MeshError::NoOverlap {
            views: used.len(),
            min_observations: min_obs,
        });
    }
    let mut summary = FusionSummary {
        views: used.len(),
        views_without_depth: without_depth
            .iter()
            .map(|&i| views[i].name.clone())
            .collect(),
        voxel_size,
        truncation: vol.truncation,
        blocks: pass.blocks,
        voxels: pass.blocks * BLOCK_VOXELS,
        observed_voxels: pass.observed_voxels,
        tiles: pass.tiles,
        peak_blocks: pass.peak_blocks,
        volume_bytes: pass.peak_blocks * (BLOCK_BYTES + 40),
        levels: if vol.levels().is_some() {
            pass.blocks_per_level
                .iter()
                .map(|&(l, n)| LevelReport {
                    level: l as i32,
                    voxel_size: vol.level_voxel_size(l),
                    blocks: n,
                })
                .collect()
        } else {
            Vec::new()
        },
        uncertain_fraction: {
            let (n, bad) = vol.sample_counts();
            bad as f64 / n.max(1) as f64
        },
        min_observations: min_obs,
        integrate_seconds: t0.elapsed().as_secs_f64(),
        ..Default::default()
    };
    drop(vol);
    tracing::debug!(?summary, "TSDF integrated and meshed over tiles");
    let t1 = Instant::now();
    let mut mesh = welder.finish(&extract)?;
    summary.faces_extracted = mesh.faces.len();
    if opts.min_component_faces > 1 {
        let kept = remove_small_components(&mesh, opts.min_component_faces);
        if kept.is_empty() {
            return Err(MeshError::EmptyResult {
                stage: "speck removal",
                reason: format!(
                    "every connected component has fewer than {} faces",
                    opts.min_component_faces
                ),
            });
        }
        if kept.len() < mesh.faces.len() {
            mesh = compact(&mesh, &kept);
        }
    }
    summary.faces_cleaned = mesh.faces.len();
    let hole_opts = HoleFillOptions {
        max_perimeter: opts.max_hole_perimeter_voxels * voxel_size,
        ..Default::default()
    };
    if opts.max_hole_perimeter_voxels > 0.0 {
        summary.holes = fill_holes(&mut mesh, &hole_opts);
        tracing::debug!(holes = ?summary.holes, "holes filled");
    }
    summary.extract_seconds = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    if let Some(s) = &opts.simplify {
        progress.start("simplification", 0);
        mesh = simplify(&mesh, s)?.0;
        let (kept, removed) = remove_non_manifold(&mesh);
        if removed > 0 {
            summary.non_manifold_faces_removed = removed;
            mesh = compact(&mesh, &kept);
            if opts.max_hole_perimeter_voxels > 0.0 {
                summary.holes_after_simplify = fill_holes(&mut mesh, &hole_opts);
            }
        }
        progress.finish();
    }
    summary.simplify_seconds = t2.elapsed().as_secs_f64();
    summary.faces_final = mesh.faces.len();
    summary.vertices_final = mesh.vertices.len();
    (
        summary.border_edges,
        summary.non_manifold_edges,
        summary.flipped_edges,
    ) = edge_report(&mesh);
    summary.components = face_components(&mesh).1;
    let loops = boundary_loops(&mesh, hole_opts.closed_piece_ratio);
    summary.open_holes = loops.iter().filter(|l| !l.outer).count();
    summary.outer_boundaries = loops.len() - summary.open_holes;
    Ok((mesh, summary))
}
