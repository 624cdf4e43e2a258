//! Volumetric fusion of many depth maps into a truncated signed distance function (paper §5.1;
//! Curless & Levoy, *A volumetric method for building complex models from range images*,
//! SIGGRAPH 1996), stored in sparse voxel blocks so memory follows the surface (voxel hashing:
//! Nießner, Zollhöfer, Izadi and Stamminger, SIGGRAPH Asia 2013).
//!
//! The world is cut into blocks of [`BLOCK`]³ voxels; a hash map from block coordinates to a
//! boxed block holds only the blocks within the truncation band of some observed surface.
//! Voxel `g = (i, j, k)` has its centre at `g · voxel_size` in the world (= sparse model) frame.
//!
//! Depth maps are integrated in two passes (the fusion runs the first over all views before the
//! second, so every view updates every block and the result does not depend on the view order):
//! 1. *allocation*: every (strided) valid pixel's ray is sampled within `±truncation` of its depth
//!    and the blocks it crosses are created;
//! 2. *update*: every voxel of every block is projected into the view (with the lens distortion);
//!    its signed distance along the line of sight `sdf = (z_map − z_voxel)·|p_cam|/z_voxel` (positive
//!    in front of the surface, in free space) is truncated to `[−1, 1]·truncation`, skipped when
//!    below `−truncation` (hidden behind the surface), and averaged with the running weight
//!    (Curless & Levoy eq. 4–5): `D ← (W·D + w·d)/(W + w)`, `W ← min(W + w, max_weight)`, with the
//!    per-pixel confidence as `w`. Voxels within the band also count one *observation* of that view,
//!    which lets extraction require a surface to be seen by several depth maps.
//!
//! Values are stored as `f32` (normalised distance and weight): the volume is the memory-bound
//! part of the stage, and its precision (1e-7 of the truncation) is far below the voxel size.

use std::collections::{HashMap, HashSet};

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::error::{in_range, positive, MeshError, Result};
use crate::levels::{scale, LevelField};

mod alloc;
mod update;
use crate::view::{incidence_map, Depth, Projector};
use handheld_core::PosedView;
use update::{update_block, UpdateContext};

/// Voxels per block edge.
pub const BLOCK: usize = 8;
/// Voxels per block.
pub const BLOCK_VOXELS: usize = BLOCK * BLOCK * BLOCK;
/// Bytes per block (distance, weight, observation count per voxel, plus the key and level).
pub const BLOCK_BYTES: usize = BLOCK_VOXELS * 9 + 16;

/// How the voxel edge length is chosen.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VoxelSize {
    /// A fixed edge length in world (sparse model) units.
    Absolute(f64),
    /// This many pixel footprints at the median depth, `factor · median(depth)/f`, taking the
    /// median over the views (the sparse model's scale is arbitrary, so this is the portable default).
    PixelFootprint(f64),
}

/// Options of [`TsdfVolume`] and of the fusion stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TsdfOptions {
    /// Voxel edge length. Default `PixelFootprint(3.0)`.
    pub voxel_size: VoxelSize,
    /// Half-width of the truncation band, in voxels (Curless & Levoy's ramp). Must exceed the
    /// depth noise. Default 4.
    pub truncation_voxels: f64,
    /// Pixels whose confidence is not above this are ignored (only with confidence maps). Default 0.
    pub min_confidence: f64,
    /// Cap on the accumulated weight of a voxel (keeps the average responsive). Default 1e4.
    pub max_weight: f64,
    /// Upper bound on the number of blocks alive at once (those of one spatial tile and its halo
    /// in [`crate::fuse_depth_maps`]); exceeding it is an error, not a silent crop. Default
    /// 300 000 (about 1.4 GB of voxels).
    pub max_blocks: usize,
    /// The fusion streams over cubic tiles of this many level-0 blocks a side: one tile's
    /// blocks are in memory at a time, so peak memory is set by a tile, not by the scene.
    /// Default 64 (512 voxels a side).
    pub tile_blocks: usize,
    /// The voxel size follows the depth ([`crate::levels`]): space seen at twice the median
    /// footprint gets voxels twice the size, and so on. Only with [`VoxelSize::PixelFootprint`]; an
    /// absolute voxel size is one size everywhere. Default true.
    pub adaptive: bool,
    /// The finest and coarsest levels (voxels of `2^level` times the base size). Default 0 and 6.
    pub finest_level: i32,
    pub coarsest_level: i32,
    /// Depth samples whose standard deviation `σ` (from the variance maps, where present) is at
    /// most this many truncation half-widths `t` of their voxel size count fully. A surface is
    /// seen by about ten views, and their average has about a third of one sample's noise, so
    /// samples up to three bands wide still average into the band. Noisier samples count with
    /// the weight `(K·t/σ)²` (inverse-variance weighting), so that they shape the surface only
    /// where nothing better sees it, and beyond `max(2, √n)·K·t` they are left out, with `n` the
    /// views whose frustum holds the place: far background and surfaces seen with too little
    /// parallax, which even the average of every view that sees them could not bring within K
    /// bands. 0 counts every sample fully. Default 3. On the synthetic street (`handheld bench
    /// mesh`), leaving out every sample beyond `K·t` lost 11–13 % of the surface at K = 3 and a
    /// quarter at K = 1; a fixed `2·K·t` left out 4.8 % of the drive's samples and half a point
    /// of its completeness, which the twenty views that see its far façades recover.
    pub max_depth_std: f64,
}

impl Default for TsdfOptions {
    fn default() -> Self {
        Self {
            voxel_size: VoxelSize::PixelFootprint(3.0),
            truncation_voxels: 4.0,
            min_confidence: 0.0,
            max_weight: 1e4,
            max_blocks: 300_000,
            tile_blocks: 64,
            adaptive: true,
            finest_level: 0,
            coarsest_level: 6,
            max_depth_std: 3.0,
        }
    }
}

impl TsdfOptions {
    pub fn validate(&self) -> Result<()> {
        match self.voxel_size {
            VoxelSize::Absolute(v) => positive("voxel_size", v)?,
            VoxelSize::PixelFootprint(f) => in_range("voxel_size", f, 0.05, 1000.0)?,
        }
        in_range("truncation_voxels", self.truncation_voxels, 1.0, 64.0)?;
        positive("max_weight", self.max_weight)?;
        if !self.min_confidence.is_finite() {
            return Err(MeshError::InvalidOption {
                option: "min_confidence",
                reason: "must be finite".into(),
            });
        }
        in_range("max_depth_std", self.max_depth_std, 0.0, 1e6)?;
        if !(-8..=0).contains(&self.finest_level) || !(0..=16).contains(&self.coarsest_level) {
            return Err(MeshError::InvalidOption {
                option: "finest_level",
                reason: format!(
                    "levels must satisfy -8 <= finest_level <= 0 <= coarsest_level <= 16, got {} and {}",
                    self.finest_level, self.coarsest_level
                ),
            });
        }
        if self.max_blocks == 0 {
            return Err(MeshError::InvalidOption {
                option: "max_blocks",
                reason: "must be positive".into(),
            });
        }
        if !(1..=1 << 20).contains(&self.tile_blocks) {
            return Err(MeshError::InvalidOption {
                option: "tile_blocks",
                reason: format!("must be in 1..=1048576, got {}", self.tile_blocks),
            });
        }
        Ok(())
    }
}

/// A block's coordinates and level.
pub type BlockKey = ([i32; 3], i8);

/// One block of voxels, x fastest: local index `x + BLOCK·(y + BLOCK·z)`.
pub struct Block {
    pub key: [i32; 3],
    /// The block's level: its voxels are `2^level` times the base size ([`crate::levels`]).
    pub level: i8,
    /// Signed distance divided by the truncation, in `[−1, 1]`.
    pub tsdf: [f32; BLOCK_VOXELS],
    pub weight: [f32; BLOCK_VOXELS],
    /// Number of views that saw the voxel within the truncation band (saturating).
    pub observations: [u8; BLOCK_VOXELS],
    /// Number of views whose frustum holds the block's centre (0 without [`LevelField`]): how many
    /// depth maps can average here, which sets how noisy a sample may be and still count
    /// ([`TsdfOptions::max_depth_std`]).
    pub views: u16,
}

impl Block {
    fn new(key: [i32; 3], level: i8) -> Self {
        Self {
            key,
            level,
            tsdf: [1.0; BLOCK_VOXELS],
            weight: [0.0; BLOCK_VOXELS],
            observations: [0; BLOCK_VOXELS],
            views: 0,
        }
    }
}

/// A sparse TSDF volume.
pub struct TsdfVolume {
    /// The voxel size of level 0.
    pub voxel_size: f64,
    /// Truncation distance of level 0 in world units.
    pub truncation: f64,
    max_weight: f32,
    min_confidence: f64,
    max_blocks: usize,
    max_depth_std: f64,
    /// Which level owns each point of space; `None`: one level (0) everywhere.
    levels: Option<LevelField>,
    index: HashMap<([i32; 3], i8), usize>,
    blocks: Vec<Box<Block>>,
    /// Allocation samples seen, and those left out as too uncertain (`max_depth_std`).
    samples: usize,
    samples_uncertain: usize,
}

/// The voxel size `opts` asks for, given the views (the median over the views with depth of `median depth / f`
/// for [`VoxelSize::PixelFootprint`]).
pub fn resolve_voxel_size(views: &[PosedView], opts: &TsdfOptions) -> Result<f64> {
    match opts.voxel_size {
        VoxelSize::Absolute(v) => Ok(v),
        VoxelSize::PixelFootprint(factor) => {
            let mut per_view: Vec<f64> = Vec::with_capacity(views.len());
            for (i, v) in views.iter().enumerate() {
                let v = Depth::of(v, i)?;
                // A view without depth says nothing about the scale (fusion leaves it out).
                if let Some(z) = depth_quantile(&v, 0.5) {
                    per_view.push(z / v.posed.camera.intrinsics.f);
                }
            }
            per_view.sort_by(f64::total_cmp);
            let m = per_view
                .get(per_view.len() / 2)
                .copied()
                .ok_or(MeshError::EmptyDepth { view: 0 })?;
            Ok(factor * m)
        }
    }
}

/// A quantile `q` over the views' (strided) valid pixels of the depth's standard deviation in
/// pixel footprints, `σ·f/z`; `None` where no view has a variance map.
pub fn noise_footprints_quantile(views: &[PosedView], q: f64) -> Result<Option<f64>> {
    let mut all: Vec<f64> = Vec::new();
    for (i, v) in views.iter().enumerate() {
        let v = Depth::of(v, i)?;
        if v.variance.is_none() {
            continue;
        }
        let f = v.posed.camera.intrinsics.f;
        let n = v.depth.data.len();
        let stride = (n / 20_000).max(1);
        all.extend(
            (0..n)
                .step_by(stride)
                .filter(|&j| v.weight(j, f64::NEG_INFINITY) > 0.0)
                .filter_map(|j| {
                    let (z, s) = (v.depth.data[j] as f64, v.std(j));
                    (s > 0.0).then_some(s * f / z)
                }),
        );
    }
    if all.is_empty() {
        return Ok(None);
    }
    let k = ((all.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    Ok(Some(*all.select_nth_unstable_by(k, f64::total_cmp).1))
}

/// A quantile of the valid depths of a view, from a strided sample of its pixels.
fn depth_quantile(view: &Depth, q: f64) -> Option<f64> {
    let n = view.depth.data.len();
    let stride = (n / 20_000).max(1);
    let mut d: Vec<f64> = (0..n)
        .step_by(stride)
        .filter(|&i| view.weight(i, f64::NEG_INFINITY) > 0.0)
        .map(|i| view.depth.data[i] as f64)
        .collect();
    if d.is_empty() {
        return None;
    }
    d.sort_by(f64::total_cmp);
    Some(d[((d.len() - 1) as f64 * q).round() as usize])
}

impl TsdfVolume {
    /// An empty volume with a resolved voxel size (see [`resolve_voxel_size`]).
    pub fn new(voxel_size: f64, opts: &TsdfOptions) -> Result<Self> {
        opts.validate()?;
        positive("voxel_size", voxel_size)?;
        Ok(Self {
            voxel_size,
            truncation: opts.truncation_voxels * voxel_size,
            max_weight: opts.max_weight as f32,
            min_confidence: opts.min_confidence,
            max_blocks: opts.max_blocks,
            max_depth_std: opts.max_depth_std,
            levels: None,
            index: HashMap::new(),
            blocks: Vec::new(),
            samples: 0,
            samples_uncertain: 0,
        })
    }

    /// Makes the voxel size follow the depth over these views ([`crate::levels`]): level 0 holds
    /// the footprint `voxel_size / factor`. Call before integrating.
    pub fn set_levels(
        &mut self,
        views: &[PosedView],
        reference_footprint: f64,
        opts: &TsdfOptions,
    ) {
        let projectors: Vec<Projector> = views.iter().map(|v| Projector::new(&v.posed)).collect();
        self.levels = Some(LevelField::new(
            &projectors,
            reference_footprint,
            opts.finest_level,
            opts.coarsest_level,
        ));
    }

    /// The level field, where the voxel size follows the depth.
    pub fn levels(&self) -> Option<&LevelField> {
        self.levels.as_ref()
    }

    /// Voxel size of a level.
    pub fn level_voxel_size(&self, level: i8) -> f64 {
        self.voxel_size * scale(level as i32)
    }

    /// The level that owns `p` (0 without levels; `None` where no view sees it).
    pub fn level_at(&self, p: &Point3<f64>) -> Option<i8> {
        match &self.levels {
            None => Some(0),
            Some(f) => f.level(p).map(|l| l as i8),
        }
    }

    /// Allocation samples seen, and those left out as too uncertain (`max_depth_std`).
    pub fn sample_counts(&self) -> (usize, usize) {
        (self.samples, self.samples_uncertain)
    }

    /// Allocated blocks per level, finest first.
    pub fn blocks_per_level(&self) -> Vec<(i8, usize)> {
        let mut m = std::collections::BTreeMap::new();
        for b in &self.blocks {
            *m.entry(b.level).or_insert(0usize) += 1;
        }
        m.into_iter().collect()
    }

    /// Number of allocated blocks.
    pub fn num_blocks(&self) -> usize {
        self.blocks.len()
    }

    /// The allocated blocks.
    pub fn blocks(&self) -> &[Box<Block>] {
        &self.blocks
    }

    /// The level-0 block with key `key`, if allocated.
    pub fn block(&self, key: [i32; 3]) -> Option<&Block> {
        self.block_at(key, 0)
    }

    /// The block with key `key` at `level`, if allocated.
    pub fn block_at(&self, key: [i32; 3], level: i8) -> Option<&Block> {
        self.index.get(&(key, level)).map(|&i| &*self.blocks[i])
    }

    /// Approximate bytes held by the blocks and the index.
    pub fn memory_bytes(&self) -> usize {
        self.blocks.len() * (BLOCK_BYTES + 40)
    }

    /// Integrates one depth map (`view_index` only labels errors): [`Self::allocate`] then
    /// [`Self::update`]. Blocks created by later views miss this view's free-space evidence;
    /// allocate every view first for an order-independent result (as [`crate::fuse_depth_maps`]
    /// does).
    pub fn integrate(&mut self, view: &PosedView, view_index: usize) -> Result<()> {
        self.allocate(view, view_index)?;
        self.update(view, view_index)
    }

    /// Creates the blocks within the truncation band around one view's depths.
    pub fn allocate(&mut self, view: &PosedView, view_index: usize) -> Result<()> {
        let view = Depth::of(view, view_index)?;
        let proj = Projector::new(view.posed);
        self.allocate_blocks(&view, &proj, view_index)
    }

    /// The update pass of one view over every allocated block (see the module documentation).
    pub fn update(&mut self, view: &PosedView, view_index: usize) -> Result<()> {
        let cos = Self::incidence(view, view_index)?;
        self.update_with(view, view_index, &cos)
    }

    /// The per-pixel incidence cosines [`Self::update_with`] needs (in units of `1 / u16::MAX`);
    /// computing them is most of a view's fixed cost, so fusion over tiles keeps them.
    pub fn incidence(view: &PosedView, view_index: usize) -> Result<Vec<u16>> {
        Ok(incidence_map(&Depth::of(view, view_index)?))
    }

    /// [`Self::update`] with the view's incidence cosines ([`Self::incidence`]).
    pub fn update_with(&mut self, view: &PosedView, view_index: usize, cos: &[u16]) -> Result<()> {
        let view = Depth::of(view, view_index)?;
        let proj = Projector::new(view.posed);
        let ctx = UpdateContext {
            view: &view,
            proj: &proj,
            cos,
            vs: self.voxel_size,
            trunc: self.truncation,
            max_w: self.max_weight,
            min_conf: self.min_confidence,
            max_std: self.max_depth_std,
        };
        self.blocks
            .par_iter_mut()
            .for_each(|b| update_block(b, &ctx));
        Ok(())
    }

    /// The blocks one view's depths need (see [`Self::allocate`]), without creating them: the unit
    /// of planning for fusion over spatial tiles. Counts the view's allocation samples.
    pub fn plan(&mut self, view: &PosedView, view_index: usize) -> Result<HashSet<BlockKey>> {
        let view = Depth::of(view, view_index)?;
        let proj = Projector::new(view.posed);
        let (keys, samples, uncertain) = self.collect_keys(&view, &proj, view_index)?;
        self.samples += samples;
        self.samples_uncertain += uncertain;
        Ok(keys)
    }

    /// Replaces the volume's blocks by fresh ones at `keys` (sorted first, so block order is
    /// reproducible). Errors past `max_blocks`, the bound on blocks alive at once.
    pub fn load_blocks(&mut self, keys: &[BlockKey]) -> Result<()> {
        if keys.len() > self.max_blocks {
            return Err(MeshError::TooManyBlocks {
                limit: self.max_blocks,
                bytes_mib: (keys.len() * BLOCK_BYTES) >> 20,
                voxel_size: self.voxel_size,
            });
        }
        let mut keys = keys.to_vec();
        keys.sort_unstable();
        keys.dedup();
        self.index.clear();
        self.blocks.clear();
        for (k, l) in keys {
            self.index.insert((k, l), self.blocks.len());
            self.blocks.push(Box::new(self.new_block(k, l)));
        }
        Ok(())
    }

    /// A fresh block, with the number of views whose frustum holds its centre.
    fn new_block(&self, key: [i32; 3], level: i8) -> Block {
        let mut b = Block::new(key, level);
        if let Some(field) = &self.levels {
            let vs = self.level_voxel_size(level);
            let c = (BLOCK as f64 - 1.0) * 0.5;
            let centre = Point3::new(
                (key[0] as f64 * BLOCK as f64 + c) * vs,
                (key[1] as f64 * BLOCK as f64 + c) * vs,
                (key[2] as f64 * BLOCK as f64 + c) * vs,
            );
            b.views = field.footprint_and_views(&centre).1.min(u16::MAX as usize) as u16;
        }
        b
    }

    /// World-space edge length of a block of `level`.
    pub fn block_side(&self, level: i8) -> f64 {
        self.level_voxel_size(level) * BLOCK as f64
    }

    fn allocate_blocks(&mut self, view: &Depth, proj: &Projector, view_index: usize) -> Result<()> {
        let (keys, samples, uncertain) = self.collect_keys(view, proj, view_index)?;
        self.samples += samples;
        self.samples_uncertain += uncertain;
        let mut new: Vec<BlockKey> = keys
            .into_iter()
            .filter(|k| !self.index.contains_key(k))
            .collect();
        // Sorted, so block order (and everything downstream) is reproducible.
        new.sort_unstable();
        if self.blocks.len() + new.len() > self.max_blocks {
            return Err(MeshError::TooManyBlocks {
                limit: self.max_blocks,
                bytes_mib: ((self.blocks.len() + new.len()) * BLOCK_BYTES) >> 20,
                voxel_size: self.voxel_size,
            });
        }
        for (k, l) in new {
            self.index.insert((k, l), self.blocks.len());
            self.blocks.push(Box::new(self.new_block(k, l)));
        }
        Ok(())
    }

    /// A volume sampled from an analytic signed distance `sdf(p)` (positive outside) over the box
    /// `lo..hi`: blocks within the band are allocated and every voxel gets weight 1 and the maximal
    /// observation count. Meant for tests and synthetic shapes.
    pub fn from_sdf(
        voxel_size: f64,
        truncation_voxels: f64,
        lo: Point3<f64>,
        hi: Point3<f64>,
        sdf: impl Fn(&Point3<f64>) -> f64 + Sync,
    ) -> Result<Self> {
        let opts = TsdfOptions {
            voxel_size: VoxelSize::Absolute(voxel_size),
            truncation_voxels,
            ..TsdfOptions::default()
        };
        let mut vol = Self::new(voxel_size, &opts)?;
        let side = voxel_size * BLOCK as f64;
        let kl = (lo.coords / side).map(|v| v.floor() as i32);
        let kh = (hi.coords / side).map(|v| v.ceil() as i32);
        let reach = vol.truncation + side;
        for kz in kl.z..=kh.z {
            for ky in kl.y..=kh.y {
                for kx in kl.x..=kh.x {
                    let key = [kx, ky, kz];
                    let c = (Vector3::new(kx as f64, ky as f64, kz as f64) + Vector3::repeat(0.5))
                        * side;
                    if sdf(&Point3::from(c)).abs() > reach {
                        continue;
                    }
                    if vol.blocks.len() >= vol.max_blocks {
                        return Err(MeshError::TooManyBlocks {
                            limit: vol.max_blocks,
                            bytes_mib: (vol.blocks.len() * BLOCK_BYTES) >> 20,
                            voxel_size,
                        });
                    }
                    vol.index.insert((key, 0), vol.blocks.len());
                    vol.blocks.push(Box::new(Block::new(key, 0)));
                }
            }
        }
        let trunc = vol.truncation;
        vol.blocks.par_iter_mut().for_each(|b| {
            for i in 0..BLOCK_VOXELS {
                let g = [
                    b.key[0] * BLOCK as i32 + (i % BLOCK) as i32,
                    b.key[1] * BLOCK as i32 + (i / BLOCK % BLOCK) as i32,
                    b.key[2] * BLOCK as i32 + (i / (BLOCK * BLOCK)) as i32,
                ];
                let p = Point3::new(g[0] as f64, g[1] as f64, g[2] as f64) * voxel_size;
                b.tsdf[i] = (sdf(&p) / trunc).clamp(-1.0, 1.0) as f32;
                b.weight[i] = 1.0;
                b.observations[i] = u8::MAX;
            }
        });
        Ok(vol)
    }

    /// Distance (normalised), weight and observation count of the voxel at global index `g`.
    pub fn voxel(&self, g: [i32; 3]) -> Option<(f32, f32, u8)> {
        let b = BLOCK as i32;
        let key = [g[0].div_euclid(b), g[1].div_euclid(b), g[2].div_euclid(b)];
        let blk = self.block(key)?;
        let l = [g[0].rem_euclid(b), g[1].rem_euclid(b), g[2].rem_euclid(b)];
        let i = (l[0] + b * (l[1] + b * l[2])) as usize;
        Some((blk.tsdf[i], blk.weight[i], blk.observations[i]))
    }

    /// World position of the centre of voxel `g`.
    pub fn voxel_center(&self, g: [i32; 3]) -> Point3<f64> {
        Point3::new(g[0] as f64, g[1] as f64, g[2] as f64) * self.voxel_size
    }

    /// Voxels that received any weight.
    pub fn observed_voxels(&self) -> usize {
        self.blocks
            .par_iter()
            .map(|b| b.weight.iter().filter(|&&w| w > 0.0).count())
            .sum()
    }
}
