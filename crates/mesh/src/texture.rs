//! Texturing of a fused mesh from the calibrated images (paper §5.1, "the texture can be
//! enhanced…"; view selection after Lempitsky & Ivanov, *Seamless mosaicing of image-based texture
//! maps*, CVPR 2007, and Waechter, Moehrle and Goesele, *Let there be color!*, ECCV 2014, much
//! simplified).
//!
//! 1. *Candidate views per face*: a view is a candidate when the face is in front of it, inside its
//!    image, seen at most [`TextureOptions::max_angle_deg`] off its normal, and not occluded: its
//!    centre and at least two corners are no farther than the mesh's own z-buffer in that view
//!    (rasterised here at [`TextureOptions::zbuffer_scale`]) and than the view's depth map when it
//!    has one, within [`TextureOptions::depth_tolerance`]. The score is the face's projected area in
//!    pixels, which prefers close, frontal, high-resolution views.
//! 2. *Labels*: each face takes its best view, then iterated conditional modes on a Potts energy
//!    (data cost `1 − score/best`, [`TextureOptions::smoothness`] per seam edge) merge the labels into
//!    fewer, larger charts with fewer seams.
//! 3. *Charts* (edge-connected faces with one label) are packed into an atlas and seams are levelled
//!    by per-vertex colour offsets (the private `atlas` and `seams` modules).

use std::time::Instant;

use handheld_core::{PosedView, Progress, TriMesh};
use image::RgbImage;
use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;

use crate::error::{in_range, MeshError, Result};
use crate::topology::face_neighbours;
use crate::view::{check_image_view, Projector};

/// Options of [`texture_mesh`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TextureOptions {
    /// Largest atlas side in texels; charts are scaled down uniformly to fit. Default 8192.
    pub max_atlas_size: u32,
    /// Atlas texels per source pixel before any scaling down. Default 1.
    pub texel_scale: f64,
    /// Largest angle between a face's normal and its line of sight to a view. Default 85°.
    pub max_angle_deg: f64,
    /// Relative depth slack of the occlusion tests. Default 0.01.
    pub depth_tolerance: f64,
    /// Resolution of the occlusion z-buffer relative to the image. Default 0.5.
    pub zbuffer_scale: f64,
    /// Rounds of label smoothing (iterated conditional modes). Default 10.
    pub smoothing_rounds: usize,
    /// Cost of a seam edge relative to using a view with the full best score (see
    /// `select_labels`): higher gives fewer, larger charts at some loss of resolution. Default 0.5.
    pub smoothness: f64,
    /// Empty texels around each chart (against bilinear and mip-map bleeding). Default 2.
    pub padding: u32,
    /// Level the colours across chart seams. Default on.
    pub blend_seams: bool,
    /// Diffusion rounds spreading the seam offsets into the charts. Default 30.
    pub seam_rounds: usize,
}

impl Default for TextureOptions {
    fn default() -> Self {
        Self {
            max_atlas_size: 8192,
            texel_scale: 1.0,
            max_angle_deg: 85.0,
            depth_tolerance: 0.01,
            zbuffer_scale: 0.5,
            smoothing_rounds: 10,
            smoothness: 0.5,
            padding: 2,
            blend_seams: true,
            seam_rounds: 30,
        }
    }
}

impl TextureOptions {
    pub fn validate(&self) -> Result<()> {
        if !(16..=32768).contains(&self.max_atlas_size) {
            return Err(MeshError::InvalidOption {
                option: "max_atlas_size",
                reason: format!("must lie in 16..=32768, got {}", self.max_atlas_size),
            });
        }
        in_range("texel_scale", self.texel_scale, 0.01, 16.0)?;
        in_range("max_angle_deg", self.max_angle_deg, 1.0, 90.0)?;
        in_range("depth_tolerance", self.depth_tolerance, 0.0, 1.0)?;
        in_range("zbuffer_scale", self.zbuffer_scale, 0.05, 2.0)?;
        in_range("smoothness", self.smoothness, 0.0, 10.0)?;
        if self.padding > 64 {
            return Err(MeshError::InvalidOption {
                option: "padding",
                reason: format!("must be at most 64 texels, got {}", self.padding),
            });
        }
        Ok(())
    }
}

/// A mesh whose texture coordinates index one atlas image.
#[derive(Clone, Debug, PartialEq)]
pub struct TexturedMesh {
    /// Vertices are split along chart borders (one copy per chart); every vertex has a texture
    /// coordinate in `[0, 1]` (v = 0 at the top row of `texture`), a normal and a colour.
    pub mesh: TriMesh,
    pub texture: RgbImage,
}

/// What [`texture_mesh`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TextureSummary {
    pub faces: usize,
    /// Faces no view sees (mapped to a grey patch).
    pub untextured_faces: usize,
    pub charts: usize,
    /// Faces labelled with each view.
    pub faces_per_view: Vec<usize>,
    pub atlas_width: u32,
    pub atlas_height: u32,
    /// Atlas texels per source pixel after fitting the atlas.
    pub texel_scale: f64,
    /// Mean colour disagreement between the views meeting at seam vertices, before levelling
    /// (grey levels, mean over channels; levelling makes it zero at the vertices).
    pub seam_step: f64,
    pub seconds: f64,
}

/// Rasterises the mesh's depth into a `w × h` buffer (`scale` × the image) for occlusion tests.
fn zbuffer(
    px: &[Option<(Vector2<f64>, f64)>],
    faces: &[[u32; 3]],
    w: usize,
    h: usize,
    scale: f64,
) -> Vec<f32> {
    let mut zb = vec![f32::INFINITY; w * h];
    for f in faces {
        let (Some(a), Some(b), Some(c)) = (px[f[0] as usize], px[f[1] as usize], px[f[2] as usize])
        else {
            continue;
        };
        let p = [a.0 * scale, b.0 * scale, c.0 * scale];
        let inv_z = [1.0 / a.1, 1.0 / b.1, 1.0 / c.1];
        let area = (p[1] - p[0]).perp(&(p[2] - p[0]));
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = p
            .iter()
            .map(|q| q.x)
            .fold(f64::INFINITY, f64::min)
            .ceil()
            .max(0.0) as usize;
        let y0 = p
            .iter()
            .map(|q| q.y)
            .fold(f64::INFINITY, f64::min)
            .ceil()
            .max(0.0) as usize;
        let x1 = p
            .iter()
            .map(|q| q.x)
            .fold(f64::NEG_INFINITY, f64::max)
            .floor();
        let y1 = p
            .iter()
            .map(|q| q.y)
            .fold(f64::NEG_INFINITY, f64::max)
            .floor();
        if x1 < 0.0 || y1 < 0.0 {
            continue;
        }
        let (x1, y1) = (
            (x1 as usize).min(w.saturating_sub(1)),
            (y1 as usize).min(h.saturating_sub(1)),
        );
        for y in y0..=y1 {
            for x in x0..=x1 {
                let q = Vector2::new(x as f64, y as f64);
                let l0 = (p[2] - p[1]).perp(&(q - p[1])) / area;
                let l1 = (p[0] - p[2]).perp(&(q - p[2])) / area;
                let l2 = 1.0 - l0 - l1;
                if l0 < -1e-9 || l1 < -1e-9 || l2 < -1e-9 {
                    continue;
                }
                let z = (1.0 / (l0 * inv_z[0] + l1 * inv_z[1] + l2 * inv_z[2])) as f32;
                let cell = &mut zb[y * w + x];
                if z < *cell {
                    *cell = z;
                }
            }
        }
    }
    zb
}

/// Largest finite positive value of the 2×2 cells around `q` (cell centres at integers), `None`
/// when there is none (no surface there).
fn max_2x2(data: &[f32], w: usize, h: usize, q: &Vector2<f64>) -> Option<f64> {
    let (x0, y0) = (q.x.floor() as i64, q.y.floor() as i64);
    let mut best: Option<f64> = None;
    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        let (x, y) = (x0 + dx, y0 + dy);
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            continue;
        }
        let v = data[y as usize * w + x as usize];
        if v.is_finite() && v > 0.0 {
            best = Some(best.map_or(v as f64, |b: f64| b.max(v as f64)));
        }
    }
    best
}

/// Projected area of each face in one view, 0 where the view is not a candidate (module docs).
fn view_scores(
    mesh: &TriMesh,
    pos: &[Point3<f64>],
    normals: &[[f32; 3]],
    view: &PosedView,
    opts: &TextureOptions,
) -> Vec<f32> {
    let proj = Projector::new(&view.posed);
    let px: Vec<Option<(Vector2<f64>, f64)>> = pos
        .iter()
        .map(|p| {
            let pc = proj.to_cam(p);
            proj.cam_to_pixel(&pc)
                .filter(|q| proj.posed.camera.contains(q))
                .map(|q| (q, pc.z))
        })
        .collect();
    let s = opts.zbuffer_scale;
    let (zw, zh) = (
        ((view.posed.camera.width as f64 * s).ceil() as usize).max(1),
        ((view.posed.camera.height as f64 * s).ceil() as usize).max(1),
    );
    let zb = zbuffer(&px, &mesh.faces, zw, zh, s);
    let tol = 1.0 + opts.depth_tolerance;
    // Occluded only when every z-buffer (or depth-map) cell around the point holds a nearer
    // surface: the 2×2 maximum keeps grazing surfaces, whose depth changes fast across a cell.
    let visible = |q: &Vector2<f64>, z: f64| -> bool {
        let zq = q * s;
        let front = max_2x2(&zb, zw, zh, &zq).is_none_or(|d| z <= d * tol);
        let depth_ok = view
            .depth
            .as_ref()
            .is_none_or(|d| max_2x2(&d.data, d.width, d.height, q).is_none_or(|dd| z <= dd * tol));
        front && depth_ok
    };
    let cos_max = opts.max_angle_deg.to_radians().cos();
    mesh.faces
        .iter()
        .map(|f| {
            let (Some(a), Some(b), Some(c)) =
                (px[f[0] as usize], px[f[1] as usize], px[f[2] as usize])
            else {
                return 0.0;
            };
            let [pa, pb, pc] = f.map(|i| pos[i as usize]);
            // The smoothed normal (sum of the vertex normals) is steadier than a sliver's own.
            let n = f
                .iter()
                .map(|&i| {
                    let q = normals[i as usize];
                    Vector3::new(q[0] as f64, q[1] as f64, q[2] as f64)
                })
                .sum::<Vector3<f64>>();
            let centroid = Point3::from((pa.coords + pb.coords + pc.coords) / 3.0);
            let sight = proj.center - centroid;
            if n.dot(&sight) < cos_max * n.norm() * sight.norm() || n.norm() == 0.0 {
                return 0.0;
            }
            let Some(qc) = proj.cam_to_pixel(&proj.to_cam(&centroid)) else {
                return 0.0;
            };
            let zc = proj.to_cam(&centroid).z;
            let corners = [a, b, c].iter().filter(|(q, z)| visible(q, *z)).count();
            if !visible(&qc, zc) || corners < 2 {
                return 0.0;
            }
            (0.5 * (b.0 - a.0).perp(&(c.0 - a.0)).abs()) as f32
        })
        .collect()
}

/// Best view per face after label smoothing; `u32::MAX` where no view is a candidate.
///
/// Iterated conditional modes on a Potts energy: face `f` with view `l` costs
/// `1 − score(f, l)/best(f)` plus `smoothness` per edge neighbour with another view; faces are
/// visited in order and take the cheapest of their own and their neighbours' views (only views
/// that see them), which never raises the energy.
fn select_labels(scores: &[Vec<f32>], neighbours: &[[u32; 3]], opts: &TextureOptions) -> Vec<u32> {
    let nf = neighbours.len();
    let best: Vec<(u32, f32)> = (0..nf)
        .map(|f| {
            scores
                .iter()
                .enumerate()
                .map(|(v, s)| (v as u32, s[f]))
                .fold((u32::MAX, 0.0), |acc, x| if x.1 > acc.1 { x } else { acc })
        })
        .collect();
    let mut labels: Vec<u32> = best.iter().map(|b| b.0).collect();
    let lambda = opts.smoothness;
    for _ in 0..opts.smoothing_rounds {
        let mut changed = 0usize;
        for f in 0..nf {
            let own = labels[f];
            if own == u32::MAX {
                continue;
            }
            let cost = |l: u32, labels: &[u32]| -> f64 {
                let data = 1.0 - (scores[l as usize][f] / best[f].1) as f64;
                let disagree = neighbours[f]
                    .iter()
                    .filter(|&&g| labels.get(g as usize).is_some_and(|&m| m != l))
                    .count();
                data + lambda * disagree as f64
            };
            let mut choice = (own, cost(own, &labels));
            for &g in &neighbours[f] {
                let Some(&l) = labels.get(g as usize) else {
                    continue;
                };
                if l == u32::MAX || l == choice.0 || scores[l as usize][f] <= 0.0 {
                    continue;
                }
                let c = cost(l, &labels);
                if c < choice.1 - 1e-12 {
                    choice = (l, c);
                }
            }
            if choice.0 != own {
                labels[f] = choice.0;
                changed += 1;
            }
        }
        if changed == 0 {
            break;
        }
    }
    labels
}

/// Textures `mesh` from the views' images into one atlas (see the module documentation); a view's
/// depth map, where present, also marks what it cannot see. To hold a view out of the texture,
/// leave it out of `views` (e.g. `Vec::remove` it first).
pub fn texture_mesh(
    mesh: &TriMesh,
    views: &[PosedView],
    opts: &TextureOptions,
    progress: &dyn Progress,
) -> Result<(TexturedMesh, TextureSummary)> {
    let t0 = Instant::now();
    opts.validate()?;
    mesh.validate().map_err(MeshError::BadMesh)?;
    if mesh.faces.is_empty() {
        return Err(MeshError::BadMesh("the mesh has no face to texture".into()));
    }
    if views.is_empty() {
        return Err(MeshError::NoViews { what: "images" });
    }
    for (i, v) in views.iter().enumerate() {
        check_image_view(i, v)?;
    }
    let pos: Vec<Point3<f64>> = mesh
        .vertices
        .positions
        .iter()
        .map(|q| Point3::new(q[0] as f64, q[1] as f64, q[2] as f64))
        .collect();
    let normals = if mesh.vertices.normals.len() == mesh.vertices.len() {
        mesh.vertices.normals.clone()
    } else {
        let mut m = mesh.clone();
        m.compute_vertex_normals();
        m.vertices.normals
    };
    progress.start("texture view selection", views.len() as u64);
    let scores: Vec<Vec<f32>> = views
        .par_iter()
        .map(|v| {
            let s = view_scores(mesh, &pos, &normals, v, opts);
            progress.inc(1);
            s
        })
        .collect();
    progress.finish();
    let neighbours = face_neighbours(mesh);
    let labels = select_labels(&scores, &neighbours, opts);
    let mut summary = TextureSummary {
        faces: mesh.faces.len(),
        untextured_faces: labels.iter().filter(|&&l| l == u32::MAX).count(),
        faces_per_view: (0..views.len())
            .map(|v| labels.iter().filter(|&&l| l == v as u32).count())
            .collect(),
        ..Default::default()
    };
    if summary.untextured_faces == mesh.faces.len() {
        return Err(MeshError::EmptyResult {
            stage: "texturing",
            reason: "no face is seen unoccluded by any view (do the images belong to this mesh's frame?)".into(),
        });
    }
    let (textured, stats) =
        crate::atlas::build_atlas(mesh, &pos, &normals, views, &labels, &neighbours, opts)?;
    summary.charts = stats.charts;
    summary.atlas_width = textured.texture.width();
    summary.atlas_height = textured.texture.height();
    summary.texel_scale = stats.texel_scale;
    summary.seam_step = stats.seam_step;
    summary.seconds = t0.elapsed().as_secs_f64();
    Ok((textured, summary))
}
