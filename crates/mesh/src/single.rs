//! A surface mesh from one depth map (paper §5.1, Fig. 7).
//!
//! A regular grid of triangles is overlaid on the reference image, one vertex every
//! [`SingleMeshOptions::step`] pixels. The depth is first smoothed with a kernel the size of a
//! triangle ("the kernel can be chosen of the same size as the mesh triangles"), each vertex is
//! lifted to 3D through the camera's undistorted ray, and a triangle is dropped when one of its
//! vertices has no depth or too low a confidence, or when it spans a discontinuity: the angle
//! between its normal and the line of sight through its centre exceeds
//! [`SingleMeshOptions::max_angle_deg`] (85° in the paper). The image itself is the texture; the
//! texture coordinates are the vertices' pixel positions normalised to `[0, 1]`.
//!
//! Two small refinements over the paper: the smoothing skips pixels whose depth differs from the
//! vertex's own by more than [`SingleMeshOptions::smooth_max_relative_jump`] (so the kernel does not
//! drag foreground and background together), and each grid square is split along the diagonal with
//! the smaller depth difference (or the one that keeps a triangle when one corner is missing).

use handheld_core::{PosedView, Progress, TriMesh};
use nalgebra::{Point3, Vector2};
use rayon::prelude::*;

use crate::error::{in_range, MeshError, Result};
use crate::view::{check_image_view, sample_rgb, Depth, Projector};

/// Options of [`mesh_from_depth_map`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SingleMeshOptions {
    /// Grid spacing in pixels (the triangles' leg length). Default 4.
    pub step: usize,
    /// Smooth the depth with a box kernel of the triangle's size before lifting. Default on.
    pub smooth: bool,
    /// Pixels whose depth differs from the vertex's own by more than this fraction are left out of
    /// its smoothing kernel. Default 0.05.
    pub smooth_max_relative_jump: f64,
    /// Pixels whose confidence is not above this value count as missing (only with a confidence
    /// map). Default 0.
    pub min_confidence: f64,
    /// Largest angle, in degrees, between a triangle's normal and the line of sight through its
    /// centre; steeper triangles span depth discontinuities and are dropped. Default 85 (§5.1).
    pub max_angle_deg: f64,
}

impl Default for SingleMeshOptions {
    fn default() -> Self {
        Self {
            step: 4,
            smooth: true,
            smooth_max_relative_jump: 0.05,
            min_confidence: 0.0,
            max_angle_deg: 85.0,
        }
    }
}

impl SingleMeshOptions {
    pub fn validate(&self) -> Result<()> {
        if !(1..=256).contains(&self.step) {
            return Err(MeshError::InvalidOption {
                option: "step",
                reason: format!("must lie in 1..=256 pixels, got {}", self.step),
            });
        }
        in_range(
            "smooth_max_relative_jump",
            self.smooth_max_relative_jump,
            0.0,
            10.0,
        )?;
        if !self.min_confidence.is_finite() {
            return Err(MeshError::InvalidOption {
                option: "min_confidence",
                reason: "must be finite".into(),
            });
        }
        in_range("max_angle_deg", self.max_angle_deg, 1.0, 90.0)
    }
}

/// What [`mesh_from_depth_map`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SingleMeshSummary {
    /// Grid vertices with a valid (smoothed) depth.
    pub valid_vertices: usize,
    /// Triangles kept.
    pub faces: usize,
    /// Triangles dropped because a vertex had no depth or too low a confidence.
    pub dropped_missing: usize,
    /// Triangles dropped by the normal / line-of-sight angle test.
    pub dropped_angle: usize,
}

/// Smoothed depth of the grid vertex at pixel `(x, y)`: the mean of the valid depths in a box of
/// side `step + 1` around it that lie within `jump` (relative) of the centre; `None` when the
/// centre itself is missing.
fn vertex_depth(view: &Depth, x: usize, y: usize, opts: &SingleMeshOptions) -> Option<f64> {
    let (w, h) = (view.depth.width, view.depth.height);
    let centre = view.weight(y * w + x, opts.min_confidence);
    if centre <= 0.0 {
        return None;
    }
    let d0 = view.depth.data[y * w + x] as f64;
    if !opts.smooth || opts.step < 2 {
        return Some(d0);
    }
    let r = opts.step / 2;
    let (mut sum, mut n) = (0.0, 0usize);
    for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
        for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
            let i = yy * w + xx;
            if view.weight(i, opts.min_confidence) <= 0.0 {
                continue;
            }
            let d = view.depth.data[i] as f64;
            if (d - d0).abs() <= opts.smooth_max_relative_jump * d0 {
                sum += d;
                n += 1;
            }
        }
    }
    Some(sum / n.max(1) as f64)
}

/// The §5.1 mesh of the view's depth map (and confidence map, where present), in the world frame
/// of `view.cam_from_world`. Texture coordinates are `((x + ½)/w, (y + ½)/h)` of each vertex's
/// pixel (v = 0 at the top), so the view's image is the texture; vertices also get the image's
/// colours unless the image is empty (0×0). Triangles are counter-clockwise seen from the camera.
pub fn mesh_from_depth_map(
    view: &PosedView,
    opts: &SingleMeshOptions,
    progress: &dyn Progress,
) -> Result<(TriMesh, SingleMeshSummary)> {
    opts.validate()?;
    let image = (view.image.width() > 0 || view.image.height() > 0).then_some(&view.image);
    let depth = Depth::of(view, 0)?;
    if image.is_some() {
        check_image_view(0, view)?;
    }
    let view = depth;
    let (w, h) = (view.depth.width, view.depth.height);
    let step = opts.step;
    let (nx, ny) = ((w - 1) / step + 1, (h - 1) / step + 1);
    let proj = Projector::new(view.posed);
    progress.start("single-view mesh", ny as u64);
    // Grid vertices, row by row in parallel.
    let grid: Vec<Option<Point3<f64>>> = (0..ny)
        .into_par_iter()
        .flat_map_iter(|j| {
            let row: Vec<_> = (0..nx)
                .map(|i| {
                    let (x, y) = (i * step, j * step);
                    vertex_depth(&view, x, y, opts).map(|d| proj.lift(x as f64, y as f64, d))
                })
                .collect();
            progress.inc(1);
            row
        })
        .collect();
    progress.finish();
    let mut summary = SingleMeshSummary {
        valid_vertices: grid.iter().filter(|p| p.is_some()).count(),
        ..Default::default()
    };
    if summary.valid_vertices == 0 {
        return Err(MeshError::EmptyDepth { view: 0 });
    }
    let cos_max = opts.max_angle_deg.to_radians().cos();
    let mut index = vec![u32::MAX; grid.len()];
    let mut mesh = TriMesh::default();
    let mut vertex = |g: usize, mesh: &mut TriMesh| -> u32 {
        if index[g] == u32::MAX {
            let p = grid[g].unwrap_or_else(Point3::origin);
            let (x, y) = ((g % nx) * step, (g / nx) * step);
            mesh.vertices
                .positions
                .push([p.x as f32, p.y as f32, p.z as f32]);
            mesh.uvs.push([
                ((x as f64 + 0.5) / w as f64) as f32,
                ((y as f64 + 0.5) / h as f64) as f32,
            ]);
            if let Some(img) = image {
                let c = sample_rgb(img, &Vector2::new(x as f64, y as f64));
                mesh.vertices.colors.push(c.map(|v| v.round() as u8));
            }
            index[g] = (mesh.vertices.positions.len() - 1) as u32;
        }
        index[g]
    };
    for j in 0..ny.saturating_sub(1) {
        for i in 0..nx.saturating_sub(1) {
            let (a, b, c, d) = (
                j * nx + i,
                j * nx + i + 1,
                (j + 1) * nx + i,
                (j + 1) * nx + i + 1,
            );
            // Image-plane corners a b / c d; counter-clockwise seen from the camera is a, c, b.
            let depth = |g: usize| grid[g].map(|p| (p - proj.center).norm());
            let main_diag = match (depth(a), depth(b), depth(c), depth(d)) {
                (Some(da), Some(db), Some(dc), Some(dd)) => (da - dd).abs() <= (db - dc).abs(),
                (None, ..) | (.., None) => false,
                _ => true,
            };
            let tris = if main_diag {
                [[a, c, d], [a, d, b]]
            } else {
                [[a, c, b], [b, c, d]]
            };
            for t in tris {
                let (Some(p0), Some(p1), Some(p2)) = (grid[t[0]], grid[t[1]], grid[t[2]]) else {
                    summary.dropped_missing += 1;
                    continue;
                };
                let n = (p1 - p0).cross(&(p2 - p0));
                let centroid = Point3::from((p0.coords + p1.coords + p2.coords) / 3.0);
                let sight = proj.center - centroid;
                let denom = n.norm() * sight.norm();
                if denom <= 0.0 || n.dot(&sight) < cos_max * denom {
                    summary.dropped_angle += 1;
                    continue;
                }
                let f = [
                    vertex(t[0], &mut mesh),
                    vertex(t[1], &mut mesh),
                    vertex(t[2], &mut mesh),
                ];
                mesh.faces.push(f);
            }
        }
    }
    summary.faces = mesh.faces.len();
    if mesh.faces.is_empty() {
        return Err(MeshError::EmptyResult {
            stage: "single-view mesh",
            reason: format!(
                "all {} triangles were dropped ({} for missing depth, {} steeper than {}°)",
                summary.dropped_missing + summary.dropped_angle,
                summary.dropped_missing,
                summary.dropped_angle,
                opts.max_angle_deg
            ),
        });
    }
    mesh.compute_vertex_normals();
    Ok((mesh, summary))
}
