//! Mesh simplification by quadric error metrics (Garland & Heckbert, *Surface simplification using
//! quadric error metrics*, SIGGRAPH 1997), through meshoptimizer's edge-collapse simplifier
//! (`meshopt::simplify`, which accumulates Garland–Heckbert quadrics per vertex). The paper (§5.1)
//! uses a variant of Schroeder et al. 1992; quadric collapses are its modern equivalent.
//!
//! Borders are preserved ([`SimplifyOptions::lock_border`]: vertices on an open boundary never
//! move), so holes left where nothing was observed keep their outline and separately simplified
//! pieces still meet. The result is compacted (unused vertices dropped) and its normals recomputed;
//! per-vertex colours and texture coordinates follow their vertices.

use handheld_core::{PointCloud, TriMesh};

use crate::error::{in_range, MeshError, Result};

/// Options of [`simplify`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SimplifyOptions {
    /// Stop when at most this many triangles remain. Default 500 000.
    pub target_faces: usize,
    /// Stop before the geometric error exceeds this fraction of the mesh's extent (bounding-box
    /// size), even above `target_faces`. Default 0.01.
    pub max_relative_error: f64,
    /// Keep open-boundary vertices in place. Default on.
    pub lock_border: bool,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        Self {
            target_faces: 500_000,
            max_relative_error: 0.01,
            lock_border: true,
        }
    }
}

impl SimplifyOptions {
    pub fn validate(&self) -> Result<()> {
        if self.target_faces == 0 {
            return Err(MeshError::InvalidOption {
                option: "target_faces",
                reason: "must be positive".into(),
            });
        }
        in_range("max_relative_error", self.max_relative_error, 0.0, 1.0)
    }
}

/// What [`simplify`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SimplifySummary {
    pub faces_before: usize,
    pub faces_after: usize,
    /// Geometric error reached, as a fraction of the mesh extent.
    pub relative_error: f64,
}

/// Decimates `mesh` towards `opts.target_faces` triangles.
pub fn simplify(mesh: &TriMesh, opts: &SimplifyOptions) -> Result<(TriMesh, SimplifySummary)> {
    opts.validate()?;
    mesh.validate().map_err(MeshError::BadMesh)?;
    let before = mesh.faces.len();
    if before <= opts.target_faces {
        return Ok((
            mesh.clone(),
            SimplifySummary {
                faces_before: before,
                faces_after: before,
                relative_error: 0.0,
            },
        ));
    }
    let bytes: Vec<u8> = mesh
        .vertices
        .positions
        .iter()
        .flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes()))
        .collect();
    let adapter = meshopt::VertexDataAdapter::new(&bytes, 12, 0)
        .map_err(|e| MeshError::BadMesh(format!("vertex buffer: {e}")))?;
    let indices: Vec<u32> = mesh.faces.iter().flatten().copied().collect();
    let mut flags = meshopt::SimplifyOptions::None;
    if opts.lock_border {
        flags |= meshopt::SimplifyOptions::LockBorder;
    }
    let mut err = 0f32;
    let out = meshopt::simplify(
        &indices,
        &adapter,
        opts.target_faces * 3,
        opts.max_relative_error as f32,
        flags,
        Some(&mut err),
    );
    let faces: Vec<[u32; 3]> = out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let simplified = compact(mesh, &faces);
    let summary = SimplifySummary {
        faces_before: before,
        faces_after: simplified.faces.len(),
        relative_error: err as f64,
    };
    Ok((simplified, summary))
}

/// A mesh holding only the vertices `faces` use (attributes carried over), normals recomputed.
pub(crate) fn compact(mesh: &TriMesh, faces: &[[u32; 3]]) -> TriMesh {
    let mut map = vec![u32::MAX; mesh.vertices.len()];
    let mut out = TriMesh {
        vertices: PointCloud::default(),
        uvs: Vec::new(),
        faces: Vec::with_capacity(faces.len()),
    };
    let v = &mesh.vertices;
    for f in faces {
        let nf = f.map(|i| {
            let i = i as usize;
            if map[i] == u32::MAX {
                map[i] = out.vertices.positions.len() as u32;
                out.vertices.positions.push(v.positions[i]);
                if !v.colors.is_empty() {
                    out.vertices.colors.push(v.colors[i]);
                }
                if !mesh.uvs.is_empty() {
                    out.uvs.push(mesh.uvs[i]);
                }
            }
            map[i]
        });
        out.faces.push(nf);
    }
    out.compute_vertex_normals();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::marching_cubes::{extract_mesh, ExtractOptions};
    use crate::topology::edge_report;
    use crate::tsdf::TsdfVolume;
    use handheld_core::NoProgress;
    use nalgebra::{Point3, Vector3};
    use std::collections::HashSet;

    /// A sphere with its top cut off: an open border to preserve.
    fn open_sphere() -> TriMesh {
        let c = Point3::new(0.1, 0.2, 0.3);
        let vol = TsdfVolume::from_sdf(
            0.03,
            4.0,
            c - Vector3::repeat(1.0),
            c + Vector3::repeat(1.0),
            |p| (p - c).norm() - 0.8,
        )
        .unwrap();
        let opts = ExtractOptions {
            min_observations: 1,
            ..Default::default()
        };
        let m = extract_mesh(&vol, &opts, &NoProgress).unwrap();
        let kept: Vec<[u32; 3]> = m
            .faces
            .iter()
            .filter(|f| f.iter().all(|&i| m.vertices.positions[i as usize][2] < 0.7))
            .copied()
            .collect();
        compact(&m, &kept)
    }

    fn border_positions(m: &TriMesh) -> HashSet<[u32; 3]> {
        let mut directed = HashSet::new();
        for f in &m.faces {
            for k in 0..3 {
                directed.insert((f[k], f[(k + 1) % 3]));
            }
        }
        directed
            .iter()
            .filter(|(a, b)| !directed.contains(&(*b, *a)))
            .flat_map(|(a, b)| [*a, *b])
            .map(|i| m.vertices.positions[i as usize].map(f32::to_bits))
            .collect()
    }

    #[test]
    fn reaches_the_target_and_keeps_the_border() {
        let mesh = open_sphere();
        assert!(edge_report(&mesh).0 > 50, "the cut leaves a border");
        let target = mesh.faces.len() / 10;
        let opts = SimplifyOptions {
            target_faces: target,
            max_relative_error: 1.0,
            lock_border: true,
        };
        let (out, s) = simplify(&mesh, &opts).unwrap();
        out.validate().unwrap();
        assert_eq!(s.faces_before, mesh.faces.len());
        assert!(
            s.faces_after <= target && s.faces_after * 10 >= target * 8,
            "{s:?}"
        );
        assert!(border_positions(&mesh).is_subset(&border_positions(&out)));
        assert_eq!(edge_report(&out).1, 0, "still manifold");
        // Below the target already: unchanged.
        let (same, s2) = simplify(&out, &opts).unwrap();
        assert_eq!(
            (same.faces.len(), s2.relative_error),
            (out.faces.len(), 0.0)
        );
        let bad = SimplifyOptions {
            target_faces: 0,
            ..opts
        };
        assert!(matches!(
            simplify(&mesh, &bad),
            Err(MeshError::InvalidOption { .. })
        ));
    }
}
