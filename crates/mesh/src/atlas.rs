//! The texture atlas of [`crate::texture`]: charts, packing, seam levelling and rasterisation.
//!
//! * A *chart* is a set of edge-connected faces with the same view; its texture is the view's image
//!   resampled over the chart's bounding box in that image (plus a gutter of `padding` texels),
//!   so the UV map of a chart is its projection into the view — an affine approximation per
//!   triangle, as in the paper's standard texture mapping (§5.1). Faces no view sees share one grey
//!   patch.
//! * Packing: rectangles sorted by height on shelves of a width near the square root of the total
//!   area; when the atlas would exceed the maximum side, every chart is scaled down alike.
//! * Seams (after Lempitsky & Ivanov 2007's seam levelling, locally): at a vertex shared by charts of
//!   different views, each chart's colour is offset towards the mean of all of them; the offsets are
//!   diffused into the charts by Jacobi rounds (vertices on seams fixed) and interpolated across each
//!   triangle, so exposure and white-balance steps between views fade out instead of showing edges.

use handheld_core::{PointCloud, TriMesh};
use image::RgbImage;
use nalgebra::{Point3, Vector2};
use rayon::prelude::*;

use crate::error::{MeshError, Result};
use crate::texture::{TextureOptions, TexturedMesh};
use crate::view::{sample_rgb, Projector};
use handheld_core::PosedView;

/// Figures of one atlas build.
pub(crate) struct AtlasStats {
    pub charts: usize,
    pub texel_scale: f64,
    pub seam_step: f64,
}

struct Chart {
    /// View index, `u32::MAX` for the grey patch.
    view: u32,
    faces: Vec<u32>,
    /// Original vertex ids and their pixels in the view (grey patch: zero pixels).
    verts: Vec<(u32, Vector2<f64>)>,
    min: Vector2<f64>,
    max: Vector2<f64>,
    /// Placement in the atlas (texels).
    origin: (u32, u32),
    size: (u32, u32),
}

const GREY: u8 = 128;

/// Edge-connected components of equally labelled faces; all unlabelled faces form one chart.
fn make_charts(labels: &[u32], neighbours: &[[u32; 3]]) -> Vec<Chart> {
    let mut chart_of = vec![u32::MAX; labels.len()];
    let mut charts = Vec::new();
    let mut grey = Vec::new();
    for start in 0..labels.len() {
        if labels[start] == u32::MAX {
            grey.push(start as u32);
            continue;
        }
        if chart_of[start] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let mut faces = vec![start as u32];
        chart_of[start] = id;
        let mut k = 0;
        while k < faces.len() {
            let f = faces[k] as usize;
            k += 1;
            for &g in &neighbours[f] {
                let g = g as usize;
                if g < labels.len() && chart_of[g] == u32::MAX && labels[g] == labels[f] {
                    chart_of[g] = id;
                    faces.push(g as u32);
                }
            }
        }
        charts.push(Chart {
            view: labels[start],
            faces,
            verts: Vec::new(),
            min: Vector2::zeros(),
            max: Vector2::zeros(),
            origin: (0, 0),
            size: (0, 0),
        });
    }
    if !grey.is_empty() {
        charts.push(Chart {
            view: u32::MAX,
            faces: grey,
            verts: Vec::new(),
            min: Vector2::zeros(),
            max: Vector2::zeros(),
            origin: (0, 0),
            size: (0, 0),
        });
    }
    charts
}

/// Shelf packing of `sizes` into rows of width `width`; returns origins and the total height.
fn pack(sizes: &[(u32, u32)], width: u32) -> (Vec<(u32, u32)>, u32) {
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse((sizes[i].1, sizes[i].0)));
    let mut origins = vec![(0, 0); sizes.len()];
    let (mut x, mut y, mut row_h) = (0u32, 0u32, 0u32);
    for i in order {
        let (w, h) = sizes[i];
        if x + w > width && x > 0 {
            y += row_h;
            x = 0;
            row_h = 0;
        }
        origins[i] = (x, y);
        x += w;
        row_h = row_h.max(h);
    }
    (origins, y + row_h)
}

/// Rect sizes of every chart at texel scale `s`.
fn chart_sizes(charts: &[Chart], s: f64, pad: u32) -> Vec<(u32, u32)> {
    charts
        .iter()
        .map(|c| {
            if c.view == u32::MAX {
                return (4 + 2 * pad, 4 + 2 * pad);
            }
            let d = (c.max - c.min) * s;
            (
                d.x.ceil() as u32 + 1 + 2 * pad,
                d.y.ceil() as u32 + 1 + 2 * pad,
            )
        })
        .collect()
}

/// Places the charts; returns the atlas size and the texel scale used.
fn place(charts: &mut [Chart], opts: &TextureOptions) -> Result<(u32, u32, f64)> {
    let max = opts.max_atlas_size;
    let mut s = opts.texel_scale;
    for _ in 0..40 {
        let sizes = chart_sizes(charts, s, opts.padding);
        let area: f64 = sizes.iter().map(|&(w, h)| w as f64 * h as f64).sum();
        let widest = sizes.iter().map(|z| z.0).max().unwrap_or(1);
        let width = ((area.sqrt() * 1.1).ceil() as u32).max(widest).min(max);
        if widest <= max {
            let (origins, height) = pack(&sizes, width);
            if height <= max {
                for ((c, o), z) in charts.iter_mut().zip(origins).zip(sizes) {
                    c.origin = o;
                    c.size = z;
                }
                return Ok((width, height.max(1), s));
            }
            s *= (0.95 * (max as f64 * max as f64 / (width as f64 * height as f64)).sqrt())
                .min(0.95);
        } else {
            s *= 0.95 * max as f64 / widest as f64;
        }
    }
    Err(MeshError::EmptyResult {
        stage: "texture atlas",
        reason: format!(
            "{} charts do not fit a {max}×{max} atlas even scaled down",
            charts.len()
        ),
    })
}

/// Colour of a vertex in a view: the mean of five bilinear samples in a one-pixel cross.
fn vertex_colour(img: &RgbImage, px: &Vector2<f64>) -> [f64; 3] {
    let mut acc = [0.0; 3];
    for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)] {
        let c = sample_rgb(img, &(px + Vector2::new(dx, dy)));
        for k in 0..3 {
            acc[k] += c[k] / 5.0;
        }
    }
    acc
}

/// Builds the textured mesh and its atlas (see the module documentation).
pub(crate) fn build_atlas(
    mesh: &TriMesh,
    pos: &[Point3<f64>],
    normals: &[[f32; 3]],
    views: &[PosedView],
    labels: &[u32],
    neighbours: &[[u32; 3]],
    opts: &TextureOptions,
) -> Result<(TexturedMesh, AtlasStats)> {
    let mut charts = make_charts(labels, neighbours);
    chart_vertices(&mut charts, mesh, pos, views);
    let (aw, ah, s) = place(&mut charts, opts)?;
    let pad = opts.padding as f64;
    let atlas_of = |c: &Chart, px: &Vector2<f64>| -> Vector2<f64> {
        if c.view == u32::MAX {
            return Vector2::new(c.origin.0 as f64 + pad + 1.5, c.origin.1 as f64 + pad + 1.5);
        }
        (px - c.min) * s + Vector2::new(c.origin.0 as f64 + pad, c.origin.1 as f64 + pad)
    };
    // New vertices: one per (chart, vertex); base colour per new vertex.
    let mut out = TriMesh {
        vertices: PointCloud::default(),
        uvs: Vec::new(),
        faces: Vec::with_capacity(mesh.faces.len()),
    };
    let mut base: Vec<[f64; 3]> = Vec::new();
    let mut owner: Vec<(u32, u32)> = Vec::new(); // (chart, original vertex) per new vertex
    let mut new_id = vec![u32::MAX; pos.len()];
    let mut face_start = Vec::with_capacity(charts.len());
    for (ci, c) in charts.iter().enumerate() {
        for (v, px) in &c.verts {
            new_id[*v as usize] = out.vertices.positions.len() as u32;
            let a = atlas_of(c, px);
            out.vertices
                .positions
                .push(mesh.vertices.positions[*v as usize]);
            out.vertices.normals.push(normals[*v as usize]);
            out.uvs.push([
                ((a.x + 0.5) / aw as f64).clamp(0.0, 1.0) as f32,
                ((a.y + 0.5) / ah as f64).clamp(0.0, 1.0) as f32,
            ]);
            base.push(if c.view == u32::MAX {
                [GREY as f64; 3]
            } else {
                vertex_colour(&views[c.view as usize].image, px)
            });
            owner.push((ci as u32, *v));
        }
        face_start.push(out.faces.len());
        for &f in &c.faces {
            out.faces
                .push(mesh.faces[f as usize].map(|v| new_id[v as usize]));
        }
    }
    let chart_views: Vec<u32> = charts.iter().map(|c| c.view).collect();
    let (offsets, seam_step) =
        crate::seams::level(&out, &chart_views, &owner, &base, pos.len(), opts);
    out.vertices.colors = base
        .iter()
        .zip(&offsets)
        .map(|(b, o)| std::array::from_fn(|k| (b[k] + o[k]).round().clamp(0.0, 255.0) as u8))
        .collect();
    // Rasterise every chart into its own rectangle, in parallel, then copy into the atlas.
    let tiles: Vec<(usize, Vec<[u8; 3]>, Vec<bool>)> = charts
        .par_iter()
        .enumerate()
        .map(|(ci, c)| {
            let (w, h) = (c.size.0 as usize, c.size.1 as usize);
            if c.view == u32::MAX {
                return (ci, vec![[GREY; 3]; w * h], vec![true; w * h]);
            }
            let img = &views[c.view as usize].image;
            let (mut rgb, mut mask) = (vec![[0u8; 3]; w * h], vec![false; w * h]);
            let o = Vector2::new(c.origin.0 as f64, c.origin.1 as f64);
            for k in 0..c.faces.len() {
                let f = out.faces[face_start[ci] + k];
                let a = f.map(|i| {
                    let uv = out.uvs[i as usize];
                    Vector2::new(
                        uv[0] as f64 * aw as f64 - 0.5,
                        uv[1] as f64 * ah as f64 - 0.5,
                    ) - o
                });
                let off = f.map(|i| offsets[i as usize]);
                raster_triangle(&a, w, h, |x, y, l| {
                    let q = Vector2::new(x as f64, y as f64) + o;
                    let src = (q - Vector2::new(c.origin.0 as f64 + pad, c.origin.1 as f64 + pad))
                        / s
                        + c.min;
                    let col = sample_rgb(img, &src);
                    rgb[y * w + x] = std::array::from_fn(|ch| {
                        let d = l[0] * off[0][ch] + l[1] * off[1][ch] + l[2] * off[2][ch];
                        (col[ch] + d).round().clamp(0.0, 255.0) as u8
                    });
                    mask[y * w + x] = true;
                });
            }
            dilate(&mut rgb, &mut mask, w, h, opts.padding as usize + 1);
            (ci, rgb, mask)
        })
        .collect();
    let atlas = paste_tiles(&charts, tiles, aw, ah);
    let stats = AtlasStats {
        charts: charts.len(),
        texel_scale: s,
        seam_step,
    };
    Ok((
        TexturedMesh {
            mesh: out,
            texture: atlas,
        },
        stats,
    ))
}

/// Lists each chart's vertices with their pixels in the chart's view, and the charts' pixel bounds.
fn chart_vertices(charts: &mut [Chart], mesh: &TriMesh, pos: &[Point3<f64>], views: &[PosedView]) {
    let projectors: Vec<Projector> = views.iter().map(|v| Projector::new(&v.posed)).collect();
    // Chart vertices and their pixels; `slot[v]` marks vertices already listed by the current chart.
    let mut slot = vec![u32::MAX; pos.len()];
    for (ci, c) in charts.iter_mut().enumerate() {
        for &f in &c.faces {
            for &v in &mesh.faces[f as usize] {
                if slot[v as usize] == ci as u32 {
                    continue;
                }
                slot[v as usize] = ci as u32;
                let px = if c.view == u32::MAX {
                    Vector2::zeros()
                } else {
                    let p = &projectors[c.view as usize];
                    p.cam_to_pixel(&p.to_cam(&pos[v as usize]))
                        .unwrap_or_else(Vector2::zeros)
                };
                c.verts.push((v, px));
            }
        }
        if c.view != u32::MAX {
            c.min = c
                .verts
                .iter()
                .fold(Vector2::repeat(f64::INFINITY), |m, v| m.inf(&v.1));
            c.max = c
                .verts
                .iter()
                .fold(Vector2::repeat(f64::NEG_INFINITY), |m, v| m.sup(&v.1));
        }
    }
}

/// Copies the charts' tiles into an `aw × ah` atlas at their origins.
fn paste_tiles(
    charts: &[Chart],
    tiles: Vec<(usize, Vec<[u8; 3]>, Vec<bool>)>,
    aw: u32,
    ah: u32,
) -> RgbImage {
    let mut atlas = RgbImage::new(aw, ah);
    for (ci, rgb, mask) in tiles {
        let c = &charts[ci];
        for y in 0..c.size.1 {
            for x in 0..c.size.0 {
                let i = (y * c.size.0 + x) as usize;
                let (ax, ay) = (c.origin.0 + x, c.origin.1 + y);
                if mask[i] && ax < aw && ay < ah {
                    atlas.put_pixel(ax, ay, image::Rgb(rgb[i]));
                }
            }
        }
    }
    atlas
}

/// Calls `put(x, y, barycentrics)` for every texel centre of a `w × h` tile inside the triangle `a`.
fn raster_triangle(
    a: &[Vector2<f64>; 3],
    w: usize,
    h: usize,
    mut put: impl FnMut(usize, usize, [f64; 3]),
) {
    let area = (a[1] - a[0]).perp(&(a[2] - a[0]));
    if area.abs() < 1e-12 {
        return;
    }
    let lo = a[0].inf(&a[1]).inf(&a[2]);
    let hi = a[0].sup(&a[1]).sup(&a[2]);
    let (x0, y0) = (
        lo.x.floor().max(0.0) as usize,
        lo.y.floor().max(0.0) as usize,
    );
    let (x1, y1) = (
        (hi.x.ceil().max(0.0) as usize).min(w.saturating_sub(1)),
        (hi.y.ceil().max(0.0) as usize).min(h.saturating_sub(1)),
    );
    let eps = 1e-6;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let q = Vector2::new(x as f64, y as f64);
            let l0 = (a[2] - a[1]).perp(&(q - a[1])) / area;
            let l1 = (a[0] - a[2]).perp(&(q - a[2])) / area;
            let l2 = 1.0 - l0 - l1;
            if l0 >= -eps && l1 >= -eps && l2 >= -eps {
                put(x, y, [l0, l1, l2]);
            }
        }
    }
}

/// Grows the filled texels of a tile by `rounds` texels (the gutter against colour bleeding).
fn dilate(rgb: &mut [[u8; 3]], mask: &mut [bool], w: usize, h: usize, rounds: usize) {
    for _ in 0..rounds {
        let snapshot = mask.to_vec();
        for y in 0..h {
            for x in 0..w {
                if snapshot[y * w + x] {
                    continue;
                }
                let mut acc = [0u32; 3];
                let mut n = 0;
                for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                    let (xx, yy) = (x as i64 + dx, y as i64 + dy);
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    let j = yy as usize * w + xx as usize;
                    if snapshot[j] {
                        for k in 0..3 {
                            acc[k] += rgb[j][k] as u32;
                        }
                        n += 1;
                    }
                }
                if n > 0 {
                    rgb[y * w + x] = acc.map(|v| (v / n) as u8);
                    mask[y * w + x] = true;
                }
            }
        }
    }
}
