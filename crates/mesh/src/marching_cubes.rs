//! Surface extraction from a sparse TSDF by marching cubes (Lorensen & Cline 1987; table in
//! [`crate::mc_tables`]).
//!
//! The cube whose lowest corner is voxel `g` belongs to the block holding `g`; its other corners may
//! sit in the next block along x, y or z, so each block gathers a `(BLOCK + 1)³` padded copy of its
//! voxels from up to seven neighbours. A vertex is identified by its grid edge — the global index of
//! the edge's lower voxel plus the axis — so the blocks' triangles weld into one mesh without
//! cracks, whatever the block boundaries. Vertices sit at the linear zero crossing along the edge.
//!
//! A cube is meshed only where all eight corners are *known*: weight above
//! [`ExtractOptions::min_weight`] and seen within the band by at least
//! [`ExtractOptions::min_observations`] depth maps (Curless & Levoy's unseen/empty/near-surface
//! states). Sign changes that jump by more than [`ExtractOptions::max_jump`] (normalised units)
//! across one voxel edge are not surfaces but the meeting of a band's front and back (e.g. at the
//! edge of a thin object) and are skipped. Triangles are counter-clockwise seen from the positive
//! (free-space, outside) side.

use std::collections::HashMap;

use handheld_core::{Progress, TriMesh};
use rayon::prelude::*;

use crate::error::{in_range, MeshError, Result};
use crate::mc_tables::{triangle_table, EDGE_AXIS, EDGE_CORNER};
use crate::tsdf::{Block, TsdfVolume, BLOCK};

/// Options of [`extract_mesh`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ExtractOptions {
    /// A voxel is known when its accumulated weight is above this. Default 0.
    pub min_weight: f64,
    /// A voxel is known when at least this many depth maps saw it within the truncation band.
    /// Default 2.
    pub min_observations: usize,
    /// Largest normalised-distance difference across one voxel edge that still counts as a
    /// surface crossing (a real surface changes by at most `1/truncation_voxels` per voxel).
    /// Default 0.9.
    pub max_jump: f64,
}

impl Default for ExtractOptions {
    fn default() -> Self {
        Self {
            min_weight: 0.0,
            min_observations: 2,
            max_jump: 0.9,
        }
    }
}

impl ExtractOptions {
    pub fn validate(&self) -> Result<()> {
        in_range("min_weight", self.min_weight, 0.0, 1e12)?;
        in_range("max_jump", self.max_jump, 0.01, 2.0)?;
        if self.min_observations > 255 {
            return Err(MeshError::InvalidOption {
                option: "min_observations",
                reason: format!("must be at most 255, got {}", self.min_observations),
            });
        }
        Ok(())
    }
}

/// Global identity of a grid edge: lower voxel index, axis and level.
type EdgeKey = (i32, i32, i32, u8, i8);

/// Triangles of one block: vertices (edge key, world position) and faces indexing them.
struct BlockMesh {
    vertices: Vec<(EdgeKey, [f64; 3])>,
    faces: Vec<[u32; 3]>,
}

const P: usize = BLOCK + 1;

/// Padded `(BLOCK + 1)³` copy of a block's distances; `NaN` marks unknown voxels.
fn gather(vol: &TsdfVolume, b: &Block, opts: &ExtractOptions) -> Vec<f32> {
    let mut out = vec![f32::NAN; P * P * P];
    let neighbours: [Option<&Block>; 8] = std::array::from_fn(|n| {
        if n == 0 {
            Some(b)
        } else {
            vol.block_at(
                [
                    b.key[0] + (n & 1) as i32,
                    b.key[1] + (n >> 1 & 1) as i32,
                    b.key[2] + (n >> 2 & 1) as i32,
                ],
                b.level,
            )
        }
    });
    let min_w = opts.min_weight as f32;
    let min_obs = opts.min_observations as u8;
    for z in 0..P {
        for y in 0..P {
            for x in 0..P {
                let n = (x / BLOCK) | (y / BLOCK) << 1 | (z / BLOCK) << 2;
                let Some(blk) = neighbours[n] else {
                    continue;
                };
                let i = x % BLOCK + BLOCK * (y % BLOCK + BLOCK * (z % BLOCK));
                if blk.weight[i] > min_w && blk.observations[i] >= min_obs {
                    out[x + P * (y + P * z)] = blk.tsdf[i];
                }
            }
        }
    }
    out
}

fn mesh_block(vol: &TsdfVolume, b: &Block, opts: &ExtractOptions) -> BlockMesh {
    let grid = gather(vol, b, opts);
    let table = triangle_table();
    let vs = vol.level_voxel_size(b.level);
    // Where the voxel size follows the depth, a cube is meshed only where its own level owns space
    // ([`crate::levels`]); a block whose corners all lie in its level's space skips the test.
    let side = vs * BLOCK as f64;
    let origin = [
        b.key[0] as f64 * side,
        b.key[1] as f64 * side,
        b.key[2] as f64 * side,
    ];
    let owned = |p: [f64; 3]| {
        vol.level_at(&nalgebra::Point3::new(p[0], p[1], p[2]))
            .is_none_or(|l| l == b.level)
    };
    let check_owner = vol.levels().is_some()
        && !(0..8).all(|c| {
            owned([
                origin[0] + side * (c & 1) as f64,
                origin[1] + side * (c >> 1 & 1) as f64,
                origin[2] + side * (c >> 2 & 1) as f64,
            ])
        });
    let base = [
        b.key[0] * BLOCK as i32,
        b.key[1] * BLOCK as i32,
        b.key[2] * BLOCK as i32,
    ];
    let mut local: HashMap<EdgeKey, u32> = HashMap::new();
    let mut out = BlockMesh {
        vertices: Vec::new(),
        faces: Vec::new(),
    };
    let max_jump = opts.max_jump as f32;
    for z in 0..BLOCK {
        for y in 0..BLOCK {
            for x in 0..BLOCK {
                let mut val = [0f32; 8];
                let mut case = 0usize;
                let mut known = true;
                for (c, v) in val.iter_mut().enumerate() {
                    let (cx, cy, cz) = (x + (c & 1), y + (c >> 1 & 1), z + (c >> 2 & 1));
                    *v = grid[cx + P * (cy + P * cz)];
                    if v.is_nan() {
                        known = false;
                        break;
                    }
                    if *v < 0.0 {
                        case |= 1 << c;
                    }
                }
                if !known || case == 0 || case == 255 {
                    continue;
                }
                let jump = (0..12).any(|e| {
                    let a = EDGE_CORNER[e];
                    let bb = a | 1 << EDGE_AXIS[e];
                    (case >> a & 1) != (case >> bb & 1) && (val[a] - val[bb]).abs() > max_jump
                });
                if jump {
                    continue;
                }
                if check_owner
                    && !owned([
                        origin[0] + vs * (x as f64 + 0.5),
                        origin[1] + vs * (y as f64 + 0.5),
                        origin[2] + vs * (z as f64 + 0.5),
                    ])
                {
                    continue;
                }
                let mut id = [0u32; 12];
                let mut have = 0u16;
                for tri in &table[case] {
                    let mut f = [0u32; 3];
                    for (k, &e) in tri.iter().enumerate() {
                        let e = e as usize;
                        if have >> e & 1 == 0 {
                            let a = EDGE_CORNER[e];
                            let axis = EDGE_AXIS[e];
                            let g = [
                                base[0] + (x + (a & 1)) as i32,
                                base[1] + (y + (a >> 1 & 1)) as i32,
                                base[2] + (z + (a >> 2 & 1)) as i32,
                            ];
                            let key = (g[0], g[1], g[2], axis as u8, b.level);
                            id[e] = *local.entry(key).or_insert_with(|| {
                                let (v0, v1) = (val[a] as f64, val[a | 1 << axis] as f64);
                                let t = (v0 / (v0 - v1)).clamp(0.0, 1.0);
                                let mut p = [g[0] as f64 * vs, g[1] as f64 * vs, g[2] as f64 * vs];
                                p[axis] += t * vs;
                                out.vertices.push((key, p));
                                (out.vertices.len() - 1) as u32
                            });
                            have |= 1 << e;
                        }
                        f[k] = id[e];
                    }
                    out.faces.push(f);
                }
            }
        }
    }
    out
}

/// Extracts the zero level set of the TSDF as one welded mesh with area-weighted vertex normals.
/// An empty result is an error ([`MeshError::EmptyResult`]), never a silent empty mesh.
pub fn extract_mesh(
    vol: &TsdfVolume,
    opts: &ExtractOptions,
    progress: &dyn Progress,
) -> Result<TriMesh> {
    opts.validate()?;
    progress.start("marching cubes", vol.num_blocks() as u64);
    let mut welder = Welder::default();
    welder.add_blocks(vol, opts, |_| true, &|| progress.inc(1));
    progress.finish();
    welder.finish(opts)
}

/// Welds the triangles of blocks extracted from one or more volumes (the tiles of a fusion over
/// space) into one mesh: a vertex is identified by its global grid edge, so a tile's triangles
/// meet its neighbours' exactly when both hold the voxels of their shared cubes.
#[derive(Default)]
pub struct Welder {
    mesh: TriMesh,
    global: HashMap<EdgeKey, u32>,
    blocks: usize,
}

impl Welder {
    /// Meshes the blocks of `vol` for which `own` holds (their cubes may read voxels of the other,
    /// halo, blocks) and welds them in. `tick` is called once per block meshed.
    pub fn add_blocks(
        &mut self,
        vol: &TsdfVolume,
        opts: &ExtractOptions,
        own: impl Fn(&Block) -> bool + Sync,
        tick: &(dyn Fn() + Sync),
    ) {
        let parts: Vec<BlockMesh> = vol
            .blocks()
            .par_iter()
            .filter(|b| own(b))
            .map(|b| {
                let m = mesh_block(vol, b, opts);
                tick();
                m
            })
            .collect();
        self.blocks += parts.len();
        let total_faces: usize = parts.iter().map(|p| p.faces.len()).sum();
        self.mesh.faces.reserve(total_faces);
        for part in parts {
            let ids: Vec<u32> = part
                .vertices
                .iter()
                .map(|(key, p)| {
                    *self.global.entry(*key).or_insert_with(|| {
                        self.mesh
                            .vertices
                            .positions
                            .push([p[0] as f32, p[1] as f32, p[2] as f32]);
                        (self.mesh.vertices.positions.len() - 1) as u32
                    })
                })
                .collect();
            self.mesh
                .faces
                .extend(part.faces.iter().map(|f| f.map(|i| ids[i as usize])));
        }
    }

    /// The faces welded so far.
    pub fn faces(&self) -> usize {
        self.mesh.faces.len()
    }

    /// The welded mesh with area-weighted vertex normals; no face at all is an error
    /// ([`MeshError::EmptyResult`]).
    pub fn finish(self, opts: &ExtractOptions) -> Result<TriMesh> {
        if self.mesh.faces.is_empty() {
            return Err(MeshError::EmptyResult {
                stage: "marching cubes",
                reason: format!(
                    "no zero crossing among {} blocks with at least {} observations per voxel",
                    self.blocks, opts.min_observations
                ),
            });
        }
        let mut mesh = self.mesh;
        mesh.compute_vertex_normals();
        Ok(mesh)
    }
}

#[cfg(test)]
#[path = "marching_cubes_tests.rs"]
mod tests;
