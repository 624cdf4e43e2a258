//! Fusion streamed over spatial tiles, so that peak memory is set by a tile and not by the scene
//! (the out-of-core scheme of Steinbrücker, Sturm & Cremers, ICRA 2014, and of the tiled TSDFs of
//! large-scale mapping).
//!
//! 1. *Plan*: the allocation pass of every view collects the keys of the blocks the surface
//!    needs ([`TsdfVolume::plan`]) without creating them; a key is 16 bytes, a block 4.6 KB.
//! 2. The keys are grouped into cubic tiles of [`crate::TsdfOptions::tile_blocks`] level-0 blocks
//!    a side, by the position of each block's origin. Tiles are visited in order.
//! 3. Per tile, its blocks and their *halo* (the planned neighbours at `+x`, `+y`, `+z` whose
//!    voxels its cubes read) are created and updated by every view whose frustum meets the
//!    tile; marching cubes meshes the tile's own blocks, and the [`Welder`] joins the triangles
//!    by global grid edge, so the tiles meet without a seam.
//!
//! Every block gets the same update from the same views whichever tile holds it, so the mesh is the
//! one a single volume would give, up to the order of its vertices. A tile is also the unit a
//! distributed fusion would hand to a worker.

use std::collections::{BTreeMap, HashSet};

use handheld_core::{PosedView, Progress};
use nalgebra::Vector3;

use crate::error::Result;
use crate::marching_cubes::{ExtractOptions, Welder};
use crate::tsdf::{BlockKey, TsdfVolume, BLOCK_VOXELS};
use crate::view::Projector;

/// What the tiled pass did.
#[derive(Clone, Debug, Default)]
pub(crate) struct TiledPass {
    /// Blocks of the whole surface (each counted once, halo copies excluded).
    pub blocks: usize,
    pub blocks_per_level: Vec<(i8, usize)>,
    pub tiles: usize,
    /// The most blocks alive at once (a tile and its halo).
    pub peak_blocks: usize,
    pub observed_voxels: usize,
    /// Whether any voxel reached `min_observations`.
    pub seen: bool,
}

/// Plans, integrates and meshes `views` tile by tile into `welder`.
pub(crate) fn fuse_tiled(
    vol: &mut TsdfVolume,
    views: &[(usize, &PosedView)],
    tile_blocks: usize,
    extract: &ExtractOptions,
    welder: &mut Welder,
    progress: &dyn Progress,
) -> Result<TiledPass> {
    progress.start("TSDF fusion: planning", views.len() as u64);
    let mut keys: HashSet<BlockKey> = HashSet::new();
    for &(i, v) in views {
        let k = vol.plan(v, i)?;
        if keys.len() < k.len() {
            keys = k.into_iter().chain(keys).collect();
        } else {
            keys.extend(k);
        }
        progress.inc(1);
    }
    progress.finish();

    // Tiles are counted from the lowest block origin, so one tile of any size holds a scene that
    // fits in it.
    let tile_side = vol.block_side(0) * tile_blocks as f64;
    let origin = |&(k, l): &BlockKey| k.map(|c| c as f64 * vol.block_side(l));
    let low = keys.iter().map(origin).fold([f64::INFINITY; 3], |a, o| {
        [a[0].min(o[0]), a[1].min(o[1]), a[2].min(o[2])]
    });
    let mut tiles: BTreeMap<[i64; 3], Vec<BlockKey>> = BTreeMap::new();
    let mut per_level: BTreeMap<i8, usize> = BTreeMap::new();
    for key in &keys {
        let (o, l) = (origin(key), key.1);
        let t: [i64; 3] = std::array::from_fn(|a| ((o[a] - low[a]) / tile_side).floor() as i64);
        let (k, l) = (key.0, l);
        tiles.entry(t).or_default().push((k, l));
        *per_level.entry(l).or_default() += 1;
    }
    let projectors: Vec<Projector> = views
        .iter()
        .map(|(_, v)| Projector::new(&v.posed))
        .collect();
    let mut pass = TiledPass {
        blocks: keys.len(),
        blocks_per_level: per_level.into_iter().collect(),
        tiles: tiles.len(),
        ..Default::default()
    };
    let min_obs = extract.min_observations as u8;
    // Each view's incidence cosines, computed when a tile first needs the view (2 bytes a pixel).
    let mut incidence: Vec<Option<Vec<u16>>> = vec![None; views.len()];
    progress.start("TSDF fusion", tiles.len() as u64);
    for own in tiles.values() {
        let owned: HashSet<BlockKey> = own.iter().copied().collect();
        let mut load: Vec<BlockKey> = own.clone();
        for &(k, l) in own {
            for n in 1..8usize {
                let nk = (
                    [
                        k[0] + (n & 1) as i32,
                        k[1] + (n >> 1 & 1) as i32,
                        k[2] + (n >> 2 & 1) as i32,
                    ],
                    l,
                );
                if keys.contains(&nk) && !owned.contains(&nk) {
                    load.push(nk);
                }
            }
        }
        vol.load_blocks(&load)?;
        pass.peak_blocks = pass.peak_blocks.max(vol.num_blocks());
        // The world box of the loaded blocks, to skip the views that cannot see the tile.
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for b in vol.blocks() {
            let side = vol.block_side(b.level);
            let o = Vector3::new(b.key[0] as f64, b.key[1] as f64, b.key[2] as f64) * side;
            lo = lo.inf(&o);
            hi = hi.sup(&(o + Vector3::repeat(side)));
        }
        for (j, (&(i, v), proj)) in views.iter().zip(&projectors).enumerate() {
            let corners: [Vector3<f64>; 8] = std::array::from_fn(|c| {
                let p = Vector3::new(
                    if c & 1 == 0 { lo.x } else { hi.x },
                    if c >> 1 & 1 == 0 { lo.y } else { hi.y },
                    if c >> 2 & 1 == 0 { lo.z } else { hi.z },
                );
                proj.rot * p + proj.trans
            });
            if !proj.outside_frustum(&corners) {
                if incidence[j].is_none() {
                    incidence[j] = Some(TsdfVolume::incidence(v, i)?);
                }
                let cos = incidence[j].as_deref().unwrap_or_default();
                vol.update_with(v, i, cos)?;
            }
        }
        for b in vol.blocks() {
            if owned.contains(&(b.key, b.level)) {
                pass.seen |= b.observations.iter().any(|&o| o >= min_obs);
                pass.observed_voxels += (0..BLOCK_VOXELS).filter(|&j| b.weight[j] > 0.0).count();
            }
        }
        welder.add_blocks(vol, extract, |b| owned.contains(&(b.key, b.level)), &|| {});
        progress.inc(1);
    }
    progress.finish();
    vol.load_blocks(&[])?;
    Ok(pass)
}
