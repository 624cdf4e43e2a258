//! Wavefront OBJ + MTL + PNG texture, the format every modeller opens (Blender, MeshLab).
//!
//! `model.obj` holds `v x y z` (with `r g b` in `[0, 1]` appended when the mesh has vertex colours,
//! the common extension MeshLab and tobj read), `vt u v`, `vn nx ny nz` and 1-based `f a/a/a …`
//! triangles (counter-clockwise seen from outside). OBJ puts `v = 0` at the *bottom* of the image,
//! Handheld at the top, so `v` is flipped on writing. With a texture, `model.mtl` declares one
//! material whose `map_Kd` is `model.png` beside it. Positions are in the sparse model's frame and
//! units. Each file is written atomically, the OBJ last, so it never references a missing file.

use std::path::{Path, PathBuf};

use handheld_core::TriMesh;
use image::{ImageEncoder, RgbImage};

use crate::atomic::{write_atomic, write_bytes_atomic};
use crate::error::{IoError, Result};

/// The files [`write_obj`] created.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ObjFiles {
    pub obj: PathBuf,
    /// The material library and texture, present when a texture was given.
    pub mtl: Option<PathBuf>,
    pub png: Option<PathBuf>,
}

/// Encodes an RGB image as PNG bytes.
pub fn encode_png(path: &Path, image: &RgbImage) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(
            image.as_raw(),
            image.width(),
            image.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| IoError::format(path, format!("cannot encode the texture as PNG: {e}")))?;
    Ok(out)
}

/// Checks that a mesh can be written: valid indices, finite positions, texture coordinates when a
/// texture is given.
pub(crate) fn check_mesh(path: &Path, mesh: &TriMesh, textured: bool) -> Result<()> {
    let input = |reason: String| IoError::Input {
        path: path.to_path_buf(),
        reason,
    };
    mesh.validate().map_err(input)?;
    if mesh.faces.is_empty() {
        return Err(input("the mesh has no face".into()));
    }
    if mesh
        .vertices
        .positions
        .iter()
        .flatten()
        .any(|v| !v.is_finite())
    {
        return Err(input("the mesh has a non-finite vertex position".into()));
    }
    if textured && mesh.uvs.is_empty() {
        return Err(input(
            "a texture was given but the mesh has no texture coordinates".into(),
        ));
    }
    Ok(())
}

/// Writes `path` (an `.obj`), and with a texture also `.mtl` and `.png` siblings of the same stem.
pub fn write_obj(path: &Path, mesh: &TriMesh, texture: Option<&RgbImage>) -> Result<ObjFiles> {
    check_mesh(path, mesh, texture.is_some())?;
    let mut files = ObjFiles {
        obj: path.to_path_buf(),
        mtl: None,
        png: None,
    };
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .filter(|s| !s.is_empty() && !s.contains(char::is_whitespace))
        .ok_or_else(|| IoError::Input {
            path: path.to_path_buf(),
            reason: "the OBJ file name needs a stem without spaces (the MTL refers to it)".into(),
        })?
        .to_string();
    if let Some(img) = texture {
        let png = path.with_extension("png");
        write_bytes_atomic(&png, &encode_png(&png, img)?)?;
        let mtl = path.with_extension("mtl");
        let text = format!(
            "# written by Handheld\nnewmtl material0\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {stem}.png\n"
        );
        write_bytes_atomic(&mtl, text.as_bytes())?;
        files.mtl = Some(mtl);
        files.png = Some(png);
    }
    let v = &mesh.vertices;
    let (has_uv, has_n, has_c) = (
        !mesh.uvs.is_empty(),
        !v.normals.is_empty(),
        !v.colors.is_empty(),
    );
    write_atomic(path, |w| {
        writeln!(
            w,
            "# written by Handheld: {} vertices, {} faces",
            v.len(),
            mesh.faces.len()
        )?;
        if texture.is_some() {
            writeln!(w, "mtllib {stem}.mtl\nusemtl material0")?;
        }
        for (i, p) in v.positions.iter().enumerate() {
            if has_c {
                let c = v.colors[i].map(|x| x as f32 / 255.0);
                writeln!(w, "v {} {} {} {} {} {}", p[0], p[1], p[2], c[0], c[1], c[2])?;
            } else {
                writeln!(w, "v {} {} {}", p[0], p[1], p[2])?;
            }
        }
        if has_uv {
            for t in &mesh.uvs {
                writeln!(w, "vt {} {}", t[0], 1.0 - t[1])?;
            }
        }
        if has_n {
            for n in &v.normals {
                writeln!(w, "vn {} {} {}", n[0], n[1], n[2])?;
            }
        }
        for f in &mesh.faces {
            let [a, b, c] = f.map(|i| i as u64 + 1);
            match (has_uv, has_n) {
                (true, true) => writeln!(w, "f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}")?,
                (true, false) => writeln!(w, "f {a}/{a} {b}/{b} {c}/{c}")?,
                (false, true) => writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}")?,
                (false, false) => writeln!(w, "f {a} {b} {c}")?,
            }
        }
        Ok(())
    })?;
    Ok(files)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use handheld_core::PointCloud;

    /// A unit square of two triangles with normals, colours and texture coordinates.
    pub(crate) fn square() -> TriMesh {
        TriMesh {
            vertices: PointCloud {
                positions: vec![
                    [0.0, 0.0, 0.0],
                    [1.0, 0.0, 0.0],
                    [1.0, 1.0, 0.0],
                    [0.0, 1.0, 0.0],
                ],
                colors: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]],
                normals: vec![[0.0, 0.0, 1.0]; 4],
            },
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            faces: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    #[test]
    fn obj_loads_with_tobj() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.obj");
        let mesh = square();
        let tex = RgbImage::from_fn(8, 4, |x, y| image::Rgb([x as u8 * 30, y as u8 * 60, 7]));
        let files = write_obj(&path, &mesh, Some(&tex)).unwrap();
        assert_eq!(
            files.png.as_deref(),
            Some(dir.path().join("model.png").as_path())
        );
        let (models, materials) = tobj::load_obj(
            &path,
            &tobj::LoadOptions {
                single_index: true,
                triangulate: true,
                ..Default::default()
            },
        )
        .unwrap();
        let materials = materials.unwrap();
        assert_eq!(materials.len(), 1);
        assert_eq!(materials[0].diffuse_texture.as_deref(), Some("model.png"));
        let m = &models[0].mesh;
        assert_eq!(m.indices.len(), 6);
        assert_eq!(m.positions.len(), 12);
        assert_eq!(m.normals.len(), 12);
        assert_eq!(m.vertex_color.len(), 12);
        assert!(m.texcoords.iter().all(|t| (0.0..=1.0).contains(t)));
        // Vertex 2 (1, 1, 0) has uv (1, 1) in Handheld, (1, 0) in OBJ.
        let k = (0..4)
            .find(|&k| m.positions[3 * k..3 * k + 3] == [1.0, 1.0, 0.0])
            .unwrap();
        assert_eq!(&m.texcoords[2 * k..2 * k + 2], &[1.0, 0.0]);
        let png = image::open(dir.path().join("model.png")).unwrap().to_rgb8();
        assert_eq!(png, tex);
    }

    #[test]
    fn untextured_obj_and_bad_meshes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("plain.obj");
        let mut mesh = square();
        mesh.uvs.clear();
        let files = write_obj(&path, &mesh, None).unwrap();
        assert!(files.mtl.is_none() && !dir.path().join("plain.mtl").exists());
        let (models, _) = tobj::load_obj(&path, &tobj::GPU_LOAD_OPTIONS).unwrap();
        assert_eq!(models[0].mesh.indices.len(), 6);
        let tex = RgbImage::new(2, 2);
        assert!(
            write_obj(&path, &mesh, Some(&tex)).is_err(),
            "texture without UVs"
        );
        mesh.faces.push([0, 1, 9]);
        assert!(
            write_obj(&path, &mesh, None).is_err(),
            "index past the vertices"
        );
        mesh.faces.clear();
        assert!(write_obj(&path, &mesh, None).is_err(), "no face");
    }
}
