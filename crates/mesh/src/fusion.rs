//! The volumetric stage of §5.1 as one call: depth maps → TSDF ([`crate::tsdf`], Curless & Levoy
//! 1996), streamed over spatial tiles ([`crate::tiles`]) → marching cubes
//! ([`crate::marching_cubes`], Lorensen & Cline 1987) — twice, the second time with finer voxels,
//! where the first mesh is under the face budget and the depth precise enough
//! ([`FusionOptions::finest_footprints`]) → removal of floating specks → hole filling inside
//! observed surface ([`crate::holes`]) → quadric simplification ([`mod@crate::simplify`], Garland &
//! Heckbert 1997) → cutting out the non-manifold edges the collapses leave, and closing those
//! small holes again. The result is watertight where observed: its only borders are the outlines
//! where the views stop (and holes longer than [`FusionOptions::max_hole_perimeter_voxels`]).
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
    noise_footprints_quantile, resolve_voxel_size, TsdfOptions, TsdfVolume, VoxelSize, BLOCK_BYTES,
    BLOCK_VOXELS,
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
    /// everything. Counted at the first pass's voxel size (a finer second pass scales it by the
    /// ratio of the voxel areas). Default 100.
    pub min_component_faces: usize,
    /// Simplification after extraction; `None` keeps the marching-cubes mesh. Default
    /// `Some(SimplifyOptions::default())`.
    pub simplify: Option<SimplifyOptions>,
    /// Holes inside observed surface ([`crate::holes`]) with a boundary of at most this many voxel
    /// lengths (of the first pass, where there are two) are closed, before simplification and
    /// again after it (where non-manifold edges were cut out); 0 leaves every hole open. Default
    /// 1000.
    pub max_hole_perimeter_voxels: f64,
    /// Where the voxel size is a number of pixel footprints ([`VoxelSize::PixelFootprint`]) and
    /// the mesh is simplified to a face budget: a model whose marching cubes come out under the
    /// budget is fused again with finer voxels, as fine as the budget allows (faces grow as the
    /// inverse square of the voxel size), down to this many footprints, and never finer than the
    /// depth's standard deviation that 90 % of the samples are within (a voxel finer than the
    /// noise resolves only the noise; known from the variance maps, and without them there is no
    /// second pass). A pass less than a tenth finer is not made. 0: one pass. Default 1.5, about
    /// what a depth map resolves. Small models of precise depth (640×480 rings) get their detail;
    /// large ones (over the budget) and noisy ones (forward motion, short baselines) keep one pass.
    pub finest_footprints: f64,
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
        in_range("finest_footprints", self.finest_footprints, 0.0, 1000.0)?;
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
            finest_footprints: 1.5,
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
    /// Where a first pass at the default size came out under the face budget and the model was
    /// fused again finer ([`FusionOptions::finest_footprints`]): that pass's voxel size and faces.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_pass: Option<FirstPass>,
    /// Truncation distance (world units; of level 0).
    pub truncation: f64,
    /// Where the voxel size follows the depth: the blocks of each level (level `l` has voxels of
    /// `2^l · voxel_size`), finest first. Empty with one voxel size.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub levels: Vec<LevelReport>,
    /// The fraction of the depth samples left out of fusion because their uncertainty exceeds
    /// `max(2, √n)` times `max_depth_std` truncations, `n` the views that see the place (far
    /// background, too little parallax); those between one and that many times count with a
    /// reduced weight.
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

/// The first fusion pass of a model fused again with finer voxels.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FirstPass {
    pub voxel_size: f64,
    pub faces_extracted: usize,
    /// Its integration and marching cubes (included in the summary's `integrate_seconds`).
    pub seconds: f64,
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
    let (mut mesh, mut summary) =
        integrate(views, &used, &without_depth, opts, &opts.tsdf, progress)?;
    if let Some(finer) = finer_footprints(views, opts, summary.faces_extracted)? {
        tracing::info!(
            "fusion: {} faces at voxel size {:.4} is under the budget; fusing again at {finer:.2} pixel footprints",
            summary.faces_extracted,
            summary.voxel_size
        );
        let tsdf = TsdfOptions {
            voxel_size: VoxelSize::PixelFootprint(finer),
            ..opts.tsdf.clone()
        };
        let first = FirstPass {
            voxel_size: summary.voxel_size,
            faces_extracted: summary.faces_extracted,
            seconds: summary.integrate_seconds,
        };
        (mesh, summary) = integrate(views, &used, &without_depth, opts, &tsdf, progress)?;
        summary.integrate_seconds += first.seconds;
        summary.first_pass = Some(first);
    }
    let voxel_size = summary.voxel_size;
    let t1 = Instant::now();
    // A speck is a piece of the area `min_component_faces` covers at the first pass's voxels:
    // finer voxels put more faces on it.
    let min_faces = match &summary.first_pass {
        Some(first) => {
            let per_face = (first.voxel_size / voxel_size).powi(2);
            (opts.min_component_faces as f64 * per_face).round() as usize
        }
        None => opts.min_component_faces,
    };
    if min_faces > 1 {
        let kept = remove_small_components(&mesh, min_faces);
        if kept.is_empty() {
            return Err(MeshError::EmptyResult {
                stage: "speck removal",
                reason: format!("every connected component has fewer than {min_faces} faces"),
            });
        }
        if kept.len() < mesh.faces.len() {
            mesh = compact(&mesh, &kept);
        }
    }
    summary.faces_cleaned = mesh.faces.len();
    let hole_opts = HoleFillOptions {
        // In the first pass's voxels, like the specks: the same holes close at either size.
        max_perimeter: opts.max_hole_perimeter_voxels
            * summary
                .first_pass
                .as_ref()
                .map_or(voxel_size, |f| f.voxel_size),
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

/// One fusion pass at `tsdf`'s voxel size: integration and marching cubes over tiles, and the
/// mesh as it comes out of them.
fn integrate(
    views: &[PosedView],
    used: &[(usize, &PosedView)],
    without_depth: &[usize],
    opts: &FusionOptions,
    tsdf: &TsdfOptions,
    progress: &dyn Progress,
) -> Result<(TriMesh, FusionSummary)> {
    let t0 = Instant::now();
    let voxel_size = resolve_voxel_size(views, tsdf)?;
    let mut vol = TsdfVolume::new(voxel_size, tsdf)?;
    if let (true, VoxelSize::PixelFootprint(factor)) = (tsdf.adaptive, tsdf.voxel_size) {
        let used_views: Vec<PosedView> = used.iter().map(|&(_, v)| v.clone()).collect();
        vol.set_levels(&used_views, voxel_size / factor, tsdf);
    }
    let min_obs = opts.extract.min_observations.clamp(1, used.len());
    let extract = ExtractOptions {
        min_observations: min_obs,
        ..opts.extract.clone()
    };
    let mut welder = Welder::default();
    let pass = fuse_tiled(
        &mut vol,
        used,
        tsdf.tile_blocks,
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
    let mesh = welder.finish(&extract)?;
    summary.faces_extracted = mesh.faces.len();
    Ok((mesh, summary))
}

/// The share of depth samples whose standard deviation the finer voxel size must not go below.
const NOISE_QUANTILE: f64 = 0.9;

/// The finer voxel size (in pixel footprints) for a second pass, where the first one's
/// `faces` came out under the face budget ([`FusionOptions::finest_footprints`]); `None` for one
/// pass.
fn finer_footprints(
    views: &[PosedView],
    opts: &FusionOptions,
    faces: usize,
) -> Result<Option<f64>> {
    let (VoxelSize::PixelFootprint(first), Some(simplify)) = (opts.tsdf.voxel_size, &opts.simplify)
    else {
        return Ok(None);
    };
    let budget = first * (faces as f64 / simplify.target_faces as f64).sqrt();
    let floor = budget.max(opts.finest_footprints);
    // A pass for less than a tenth finer is not worth its time (nor reading the noise for).
    if opts.finest_footprints <= 0.0 || faces == 0 || floor >= 0.9 * first {
        return Ok(None);
    }
    // A voxel finer than the depth's noise resolves only the noise: the size stays above the
    // standard deviation that 90 % of the samples are within.
    let Some(noise) = noise_footprints_quantile(views, NOISE_QUANTILE)? else {
        return Ok(None);
    };
    let finer = floor.max(noise);
    Ok((finer < 0.9 * first).then_some(finer))
}
