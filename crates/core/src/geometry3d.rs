//! Point clouds and triangle meshes as exchanged with other tools. Positions are `f32`, the precision
//! PLY/OBJ/glTF consumers expect; geometry computations upstream stay in `f64`.

use serde::{Deserialize, Serialize};

/// A point cloud with optional per-point colours and normals.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud {
    pub positions: Vec<[f32; 3]>,
    /// Empty, or one RGB colour per point.
    pub colors: Vec<[u8; 3]>,
    /// Empty, or one unit normal per point.
    pub normals: Vec<[f32; 3]>,
}

impl PointCloud {
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Checks that the optional attributes have one entry per point.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.positions.len();
        if !self.colors.is_empty() && self.colors.len() != n {
            return Err(format!("{} colours for {} points", self.colors.len(), n));
        }
        if !self.normals.is_empty() && self.normals.len() != n {
            return Err(format!("{} normals for {} points", self.normals.len(), n));
        }
        Ok(())
    }
}

/// An indexed triangle mesh with optional per-vertex colours, normals and texture coordinates.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriMesh {
    pub vertices: PointCloud,
    /// Empty, or one `(u, v)` texture coordinate per vertex (v = 0 at the top of the texture).
    pub uvs: Vec<[f32; 2]>,
    /// Counter-clockwise triangles seen from outside.
    pub faces: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Checks attribute counts and face indices.
    pub fn validate(&self) -> Result<(), String> {
        self.vertices.validate()?;
        let n = self.vertices.len();
        if !self.uvs.is_empty() && self.uvs.len() != n {
            return Err(format!(
                "{} texture coordinates for {} vertices",
                self.uvs.len(),
                n
            ));
        }
        if let Some(f) = self
            .faces
            .iter()
            .find(|f| f.iter().any(|&i| i as usize >= n))
        {
            return Err(format!("face {f:?} indexes past the {n} vertices"));
        }
        Ok(())
    }

    /// Area-weighted vertex normals, recomputed from the faces.
    pub fn compute_vertex_normals(&mut self) {
        let n = self.vertices.len();
        let mut acc = vec![[0f64; 3]; n];
        let p = &self.vertices.positions;
        for f in &self.faces {
            let [a, b, c] = f.map(|i| p[i as usize].map(|v| v as f64));
            let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
            let cr = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            for &i in f {
                for k in 0..3 {
                    acc[i as usize][k] += cr[k];
                }
            }
        }
        self.vertices.normals = acc
            .into_iter()
            .map(|v| {
                let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if l > 0.0 {
                    [(v[0] / l) as f32, (v[1] / l) as f32, (v[2] / l) as f32]
                } else {
                    [0.0, 0.0, 0.0]
                }
            })
            .collect();
    }
}
