//! Reading glTF 2.0 models (`.glb`, and `.gltf` with its buffers and images beside it) into one
//! [`TriMesh`] with its base-colour texture: the files [`super::write_glb`] writes, and virtual
//! objects made elsewhere (Blender, online model libraries) for augmented video.
//!
//! The `gltf` crate parses and validates the document and decodes the embedded images. Every
//! triangle primitive of the default scene (or of every mesh, without a scene) is merged, its node
//! transforms applied (normals by the inverse transpose). An attribute (normals, colours, texture
//! coordinates) is kept when every primitive has it; texture coordinates missing from some
//! primitives become `(0, 0)`. Only one texture fits a [`TriMesh`]: the first primitive's
//! base-colour texture, converted to 8-bit RGB (alpha dropped); a model whose primitives use
//! different textures is read with that one and a warning.

use std::path::Path;

use handheld_core::{PointCloud, TriMesh};
use image::RgbImage;
use nalgebra::{Matrix3, Matrix4, Vector3, Vector4};

use crate::error::{IoError, Result};

/// One primitive's attributes, already in the model frame.
struct Part {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    colors: Option<Vec<[u8; 3]>>,
    uvs: Option<Vec<[f32; 2]>>,
    faces: Vec<[u32; 3]>,
    /// Index of the base-colour image, with the texture-coordinate set it uses.
    texture: Option<(usize, u32)>,
}

/// Reads a glTF model: positions, faces, and the normals, vertex colours, texture coordinates and
/// base-colour texture when present. Errors name `path`.
pub fn read_glb(path: &Path) -> Result<(TriMesh, Option<RgbImage>)> {
    if !path.exists() {
        return Err(IoError::NotFound {
            path: path.to_path_buf(),
        });
    }
    let bad = |reason: String| IoError::format(path, reason);
    let (doc, buffers, images) = gltf::import(path).map_err(|e| {
        bad(format!(
            "not a readable glTF 2.0 model ({e}); check that the file is a complete .glb or .gltf"
        ))
    })?;
    let mut parts = Vec::new();
    match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(scene) => {
            for node in scene.nodes() {
                collect_node(&node, &Matrix4::identity(), &buffers, &mut parts, path)?;
            }
        }
        None => {
            for mesh in doc.meshes() {
                collect_mesh(&mesh, None, &buffers, &mut parts, path)?;
            }
        }
    }
    let mesh = merge(&parts);
    mesh.validate()
        .map_err(|e| bad(format!("inconsistent mesh: {e}")))?;
    if mesh.faces.is_empty() {
        return Err(bad("the model has no triangle".into()));
    }
    let texture = match parts.iter().find_map(|p| p.texture) {
        Some((index, _)) => {
            let distinct = parts
                .iter()
                .filter_map(|p| p.texture)
                .any(|(i, _)| i != index);
            if distinct {
                tracing::warn!(
                    "{}: the primitives use different textures; only the first is kept",
                    path.display()
                );
            }
            let data = images
                .get(index)
                .ok_or_else(|| bad(format!("texture image {index} is missing")))?;
            Some(to_rgb(data).ok_or_else(|| {
                bad(format!(
                    "texture image {index} has the unsupported pixel format {:?}",
                    data.format
                ))
            })?)
        }
        None => None,
    };
    Ok((mesh, texture))
}

/// Walks a node and its children, composing their transforms.
fn collect_node(
    node: &gltf::Node,
    parent: &Matrix4<f64>,
    buffers: &[gltf::buffer::Data],
    parts: &mut Vec<Part>,
    path: &Path,
) -> Result<()> {
    let local = node.transform().matrix();
    let local = Matrix4::from_fn(|r, c| local[c][r] as f64);
    let world = parent * local;
    if let Some(mesh) = node.mesh() {
        let transform = (world != Matrix4::identity()).then_some(world);
        collect_mesh(&mesh, transform.as_ref(), buffers, parts, path)?;
    }
    for child in node.children() {
        collect_node(&child, &world, buffers, parts, path)?;
    }
    Ok(())
}

/// Reads the triangle primitives of one mesh, transformed by `world` when it is not the identity.
fn collect_mesh(
    mesh: &gltf::Mesh,
    world: Option<&Matrix4<f64>>,
    buffers: &[gltf::buffer::Data],
    parts: &mut Vec<Part>,
    path: &Path,
) -> Result<()> {
    for prim in mesh.primitives() {
        if prim.mode() != gltf::mesh::Mode::Triangles {
            tracing::warn!(
                "{}: a primitive of mode {:?} is skipped (only triangles are read)",
                path.display(),
                prim.mode()
            );
            continue;
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let Some(positions) = reader.read_positions() else {
            continue;
        };
        let mut positions: Vec<[f32; 3]> = positions.collect();
        let mut normals: Option<Vec<[f32; 3]>> = reader.read_normals().map(|n| n.collect());
        let texture = prim
            .material()
            .pbr_metallic_roughness()
            .base_color_texture()
            .map(|info| (info.texture().source().index(), info.tex_coord()));
        let uvs = reader
            .read_tex_coords(texture.map_or(0, |t| t.1))
            .map(|t| t.into_f32().collect());
        let colors = reader.read_colors(0).map(|c| c.into_rgb_u8().collect());
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..positions.len() as u32).collect(),
        };
        if let Some(m) = world {
            transform(m, &mut positions, normals.as_mut());
        }
        parts.push(Part {
            positions,
            normals,
            colors,
            uvs,
            faces: indices
                .chunks_exact(3)
                .map(|f| [f[0], f[1], f[2]])
                .collect(),
            texture,
        });
    }
    Ok(())
}

/// Applies a node transform: `m` to positions, its inverse transpose to normals (renormalised).
fn transform(m: &Matrix4<f64>, positions: &mut [[f32; 3]], normals: Option<&mut Vec<[f32; 3]>>) {
    for p in positions.iter_mut() {
        let q = m * Vector4::new(p[0] as f64, p[1] as f64, p[2] as f64, 1.0);
        *p = [q.x as f32, q.y as f32, q.z as f32];
    }
    let linear: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let normal_matrix = linear
        .try_inverse()
        .map(|i| i.transpose())
        .unwrap_or(linear);
    for n in normals.into_iter().flatten() {
        let v = normal_matrix * Vector3::new(n[0] as f64, n[1] as f64, n[2] as f64);
        let l = v.norm();
        if l > 0.0 {
            *n = [(v.x / l) as f32, (v.y / l) as f32, (v.z / l) as f32];
        }
    }
}

/// Concatenates the parts into one mesh (see the module notes for partial attributes).
fn merge(parts: &[Part]) -> TriMesh {
    let all_normals = parts.iter().all(|p| p.normals.is_some());
    let all_colors = parts.iter().all(|p| p.colors.is_some());
    let any_uvs = parts.iter().any(|p| p.uvs.is_some());
    let mut mesh = TriMesh {
        vertices: PointCloud::default(),
        uvs: Vec::new(),
        faces: Vec::new(),
    };
    for p in parts {
        let base = mesh.vertices.positions.len() as u32;
        mesh.vertices.positions.extend_from_slice(&p.positions);
        if let (true, Some(n)) = (all_normals, &p.normals) {
            mesh.vertices.normals.extend_from_slice(n);
        }
        if let (true, Some(c)) = (all_colors, &p.colors) {
            mesh.vertices.colors.extend_from_slice(c);
        }
        if any_uvs {
            match &p.uvs {
                Some(uv) => mesh.uvs.extend_from_slice(uv),
                None => mesh
                    .uvs
                    .extend(std::iter::repeat_n([0.0, 0.0], p.positions.len())),
            }
        }
        mesh.faces
            .extend(p.faces.iter().map(|f| f.map(|i| i.saturating_add(base))));
    }
    mesh
}

/// Converts a decoded glTF image to 8-bit RGB (grey replicated, alpha dropped, 16 bits shifted,
/// floats clamped to [0, 1]); `None` for a format without red, green and blue.
fn to_rgb(data: &gltf::image::Data) -> Option<RgbImage> {
    use gltf::image::Format;
    let (w, h, px) = (data.width, data.height, &data.pixels);
    let rgb: Vec<u8> = match data.format {
        Format::R8 => px.iter().flat_map(|&g| [g, g, g]).collect(),
        Format::R8G8 => px
            .chunks_exact(2)
            .flat_map(|c| [c[0], c[0], c[0]])
            .collect(),
        Format::R8G8B8 => px.clone(),
        Format::R8G8B8A8 => px
            .chunks_exact(4)
            .flat_map(|c| [c[0], c[1], c[2]])
            .collect(),
        Format::R16 | Format::R16G16 | Format::R16G16B16 | Format::R16G16B16A16 => {
            let channels = match data.format {
                Format::R16 => 1,
                Format::R16G16 => 2,
                Format::R16G16B16 => 3,
                _ => 4,
            };
            // The `gltf` crate stores samples in native byte order; keep the high byte.
            px.chunks_exact(2 * channels)
                .flat_map(|c| {
                    let s = |k: usize| (u16::from_ne_bytes([c[2 * k], c[2 * k + 1]]) >> 8) as u8;
                    if channels < 3 {
                        [s(0), s(0), s(0)]
                    } else {
                        [s(0), s(1), s(2)]
                    }
                })
                .collect()
        }
        Format::R32G32B32FLOAT | Format::R32G32B32A32FLOAT => {
            let channels = if data.format == Format::R32G32B32FLOAT {
                3
            } else {
                4
            };
            px.chunks_exact(4 * channels)
                .flat_map(|c| {
                    let f = |k: usize| {
                        let v = f32::from_ne_bytes([
                            c[4 * k],
                            c[4 * k + 1],
                            c[4 * k + 2],
                            c[4 * k + 3],
                        ]);
                        (v.clamp(0.0, 1.0) * 255.0).round() as u8
                    };
                    [f(0), f(1), f(2)]
                })
                .collect()
        }
    };
    RgbImage::from_raw(w, h, rgb)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::glb::{glb_bytes, write_glb};
    use crate::obj::tests::square;

    #[test]
    fn textured_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.glb");
        let mesh = square();
        let tex = RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 40, y as u8 * 80, 9]));
        write_glb(&path, &mesh, Some(&tex)).unwrap();
        let (back, texture) = read_glb(&path).unwrap();
        assert_eq!(back.vertices.positions, mesh.vertices.positions);
        assert_eq!(back.vertices.normals, mesh.vertices.normals);
        assert_eq!(back.uvs, mesh.uvs);
        assert_eq!(back.faces, mesh.faces);
        assert!(
            back.vertices.colors.is_empty(),
            "the texture replaces vertex colours"
        );
        assert_eq!(texture.as_ref(), Some(&tex));
    }

    #[test]
    fn untextured_round_trip_keeps_vertex_colours() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plain.glb");
        let mut mesh = square();
        mesh.uvs.clear();
        write_glb(&path, &mesh, None).unwrap();
        let (back, texture) = read_glb(&path).unwrap();
        assert!(texture.is_none());
        assert!(back.uvs.is_empty());
        assert_eq!(back.vertices.colors, mesh.vertices.colors);
        assert_eq!(back.faces, mesh.faces);
    }

    #[test]
    fn corrupt_and_missing_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("broken.glb");
        let bytes = glb_bytes(&path, &square(), None).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        let err = read_glb(&path).unwrap_err().to_string();
        assert!(err.contains("broken.glb") && err.contains("glTF"), "{err}");
        std::fs::write(&path, b"not a model at all").unwrap();
        let err = read_glb(&path).unwrap_err().to_string();
        assert!(err.contains("broken.glb"), "{err}");
        let missing = dir.path().join("absent.glb");
        assert!(matches!(
            read_glb(&missing),
            Err(IoError::NotFound { path }) if path == missing
        ));
    }

    #[test]
    fn node_transforms_are_applied() {
        let m = Matrix4::new_translation(&Vector3::new(1.0, 2.0, 3.0))
            * Matrix4::new_nonuniform_scaling(&Vector3::new(2.0, 2.0, 2.0));
        let mut p = vec![[1.0f32, 0.0, 0.0]];
        let mut n = vec![[0.0f32, 0.0, 1.0]];
        transform(&m, &mut p, Some(&mut n));
        assert_eq!(p, vec![[3.0, 2.0, 3.0]]);
        assert_eq!(n, vec![[0.0, 0.0, 1.0]]);
    }
}
