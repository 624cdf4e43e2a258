//! Binary glTF 2.0 (`.glb`, Khronos glTF 2.0 specification §4.4): one mesh, one node, positions,
//! unit normals, texture coordinates, `u32` indices and the PNG texture embedded in the binary
//! chunk, ready for web viewers and Blender.
//!
//! The JSON is written with `serde_json`. glTF's texture origin is the top-left corner, the same as
//! Handheld's, so `v` is written as is; glTF's unit is the metre and +Y is up, but the model frame
//! is the sparse model's (its scale and axes are whatever structure from motion fixed), so no
//! conversion is applied. Faces are counter-clockwise seen from outside, glTF's front face.
//! Without a texture the vertex colours (if any) become `COLOR_0`; with one they are left out,
//! because glTF multiplies the texture by `COLOR_0`. The material is marked
//! `KHR_materials_unlit` (photographic textures already contain the lighting), with a
//! non-metallic PBR fallback for viewers without the extension. [`read_glb`] (in [`read`]) reads
//! such files, and glTF models from elsewhere, back.

use std::path::Path;

use handheld_core::TriMesh;
use image::RgbImage;
use serde_json::{json, Value};

use crate::atomic::write_bytes_atomic;
use crate::error::{IoError, Result};
use crate::obj::{check_mesh, encode_png};

pub mod read;
pub use read::read_glb;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_INT: u32 = 5125;

/// The binary chunk under construction and the buffer views and accessors describing it.
#[derive(Default)]
pub(crate) struct Bin {
    pub(crate) bytes: Vec<u8>,
    pub(crate) views: Vec<Value>,
    pub(crate) accessors: Vec<Value>,
}

impl Bin {
    /// Appends a 4-byte-aligned buffer view; returns its index.
    pub(crate) fn view(
        &mut self,
        data: &[u8],
        target: Option<u32>,
        stride: Option<usize>,
    ) -> usize {
        self.bytes.resize(self.bytes.len().next_multiple_of(4), 0);
        let mut v =
            json!({ "buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len() });
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.bytes.extend_from_slice(data);
        self.views.push(v);
        self.views.len() - 1
    }

    /// Adds a float vertex-attribute accessor over `values` (`n` components per element);
    /// returns its index.
    pub(crate) fn floats(&mut self, values: &[f32], n: usize, kind: &str, bounds: bool) -> usize {
        self.floats_for(values, n, kind, bounds, Some(ARRAY_BUFFER))
    }

    /// [`Bin::floats`] with the buffer view's target given (`None` for animation data).
    pub(crate) fn floats_for(
        &mut self,
        values: &[f32],
        n: usize,
        kind: &str,
        bounds: bool,
        target: Option<u32>,
    ) -> usize {
        let bytes: Vec<u8> = values.iter().flat_map(|f| f.to_le_bytes()).collect();
        let view = self.view(&bytes, target, None);
        let mut a = json!({
            "bufferView": view, "componentType": FLOAT, "count": values.len() / n, "type": kind
        });
        if bounds {
            let (mut lo, mut hi) = (vec![f32::INFINITY; n], vec![f32::NEG_INFINITY; n]);
            for chunk in values.chunks_exact(n) {
                for k in 0..n {
                    lo[k] = lo[k].min(chunk[k]);
                    hi[k] = hi[k].max(chunk[k]);
                }
            }
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }
}

/// Unit normals: the mesh's own (normalised) or area-weighted ones; degenerate ones become +z.
fn unit_normals(mesh: &TriMesh) -> Vec<f32> {
    let normals = if mesh.vertices.normals.len() == mesh.vertices.len() {
        mesh.vertices.normals.clone()
    } else {
        let mut m = mesh.clone();
        m.compute_vertex_normals();
        m.vertices.normals
    };
    normals
        .iter()
        .flat_map(|n| {
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if l.is_finite() && l > 1e-6 {
                [n[0] / l, n[1] / l, n[2] / l]
            } else {
                [0.0, 0.0, 1.0]
            }
        })
        .collect()
}

/// The `.glb` bytes of a mesh with an optional embedded texture.
pub fn glb_bytes(path: &Path, mesh: &TriMesh, texture: Option<&RgbImage>) -> Result<Vec<u8>> {
    check_mesh(path, mesh, texture.is_some())?;
    let mut bin = Bin::default();
    let positions: Vec<f32> = mesh.vertices.positions.iter().flatten().copied().collect();
    let mut attributes = json!({ "POSITION": bin.floats(&positions, 3, "VEC3", true) });
    attributes["NORMAL"] = json!(bin.floats(&unit_normals(mesh), 3, "VEC3", false));
    if !mesh.uvs.is_empty() {
        let uv: Vec<f32> = mesh
            .uvs
            .iter()
            .flatten()
            .map(|u| u.clamp(0.0, 1.0))
            .collect();
        attributes["TEXCOORD_0"] = json!(bin.floats(&uv, 2, "VEC2", false));
    }
    if texture.is_none() && !mesh.vertices.colors.is_empty() {
        // Vertex attributes must be 4-byte aligned: RGB bytes padded to a stride of 4.
        let bytes: Vec<u8> = mesh
            .vertices
            .colors
            .iter()
            .flat_map(|c| [c[0], c[1], c[2], 0])
            .collect();
        let view = bin.view(&bytes, Some(ARRAY_BUFFER), Some(4));
        bin.accessors.push(json!({
            "bufferView": view, "componentType": UNSIGNED_BYTE, "normalized": true,
            "count": mesh.vertices.len(), "type": "VEC3"
        }));
        attributes["COLOR_0"] = json!(bin.accessors.len() - 1);
    }
    let indices: Vec<u8> = mesh
        .faces
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let view = bin.view(&indices, Some(ELEMENT_ARRAY_BUFFER), None);
    bin.accessors.push(json!({
        "bufferView": view, "componentType": UNSIGNED_INT, "count": mesh.faces.len() * 3,
        "type": "SCALAR"
    }));
    let index_accessor = bin.accessors.len() - 1;
    let mut pbr = json!({ "metallicFactor": 0.0, "roughnessFactor": 1.0 });
    let mut doc = json!({
        "asset": { "version": "2.0", "generator": "Handheld" },
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0, "name": "model" }],
        "meshes": [{ "primitives": [{
            "attributes": attributes, "indices": index_accessor, "material": 0, "mode": 4
        }] }],
    });
    if let Some(img) = texture {
        let png = encode_png(path, img)?;
        let view = bin.view(&png, None, None);
        pbr["baseColorTexture"] = json!({ "index": 0, "texCoord": 0 });
        doc["images"] = json!([{ "bufferView": view, "mimeType": "image/png" }]);
        doc["samplers"] =
            json!([{ "magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071 }]);
        doc["textures"] = json!([{ "source": 0, "sampler": 0 }]);
    }
    doc["materials"] = json!([{
        "name": "model", "pbrMetallicRoughness": pbr,
        "extensions": { "KHR_materials_unlit": {} }
    }]);
    container(path, doc, bin)
}

/// The `.glb` container (§4.4 of the glTF 2.0 specification): the JSON chunk (`doc`, to which the
/// buffer, its views and accessors are added) and the binary chunk.
pub(crate) fn container(path: &Path, mut doc: Value, mut bin: Bin) -> Result<Vec<u8>> {
    bin.bytes.resize(bin.bytes.len().next_multiple_of(4), 0);
    doc["buffers"] = json!([{ "byteLength": bin.bytes.len() }]);
    doc["bufferViews"] = Value::Array(bin.views);
    doc["accessors"] = Value::Array(bin.accessors);
    let mut text = serde_json::to_vec(&doc)
        .map_err(|e| IoError::format(path, format!("cannot serialise the glTF JSON: {e}")))?;
    text.resize(text.len().next_multiple_of(4), b' ');
    let total = 12 + 8 + text.len() + 8 + bin.bytes.len();
    let total32 = u32::try_from(total).map_err(|_| IoError::Input {
        path: path.to_path_buf(),
        reason: format!("{total} bytes exceed the 4 GiB limit of a .glb file"),
    })?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin.bytes);
    Ok(out)
}

/// Writes a `.glb` file atomically.
pub fn write_glb(path: &Path, mesh: &TriMesh, texture: Option<&RgbImage>) -> Result<()> {
    let bytes = glb_bytes(path, mesh, texture)?;
    write_bytes_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::obj::tests::square;

    #[test]
    fn glb_loads_with_the_gltf_crate() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.glb");
        let mesh = square();
        let tex = RgbImage::from_fn(5, 3, |x, y| image::Rgb([x as u8 * 40, y as u8 * 80, 9]));
        write_glb(&path, &mesh, Some(&tex)).unwrap();
        let (doc, buffers, images) = gltf::import(&path).unwrap();
        assert_eq!(images.len(), 1);
        assert_eq!((images[0].width, images[0].height), (5, 3));
        assert_eq!(&images[0].pixels[..3], &[0, 0, 9]);
        let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
        let reader = prim.reader(|b| Some(&buffers[b.index()]));
        let pos: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
        assert_eq!(pos, mesh.vertices.positions);
        let uv: Vec<[f32; 2]> = reader.read_tex_coords(0).unwrap().into_f32().collect();
        assert_eq!(uv, mesh.uvs);
        let normals: Vec<[f32; 3]> = reader.read_normals().unwrap().collect();
        assert!(normals.iter().all(|n| (n[2] - 1.0).abs() < 1e-6));
        let idx: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
        assert_eq!(idx, vec![0, 1, 2, 0, 2, 3]);
        assert!(
            reader.read_colors(0).is_none(),
            "the texture replaces vertex colours"
        );
        let material = prim.material();
        assert!(material
            .pbr_metallic_roughness()
            .base_color_texture()
            .is_some());
    }

    #[test]
    fn untextured_glb_carries_vertex_colours() {
        let mut mesh = square();
        mesh.uvs.clear();
        mesh.vertices.normals.clear();
        let bytes = glb_bytes(Path::new("x.glb"), &mesh, None).unwrap();
        assert_eq!(bytes.len() % 4, 0);
        let (doc, buffers, images) = gltf::import_slice(&bytes).unwrap();
        assert!(images.is_empty());
        let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
        let reader = prim.reader(|b| Some(&buffers[b.index()]));
        let colors: Vec<[u8; 3]> = reader.read_colors(0).unwrap().into_rgb_u8().collect();
        assert_eq!(colors, mesh.vertices.colors);
        let normals: Vec<[f32; 3]> = reader.read_normals().unwrap().collect();
        assert!(
            normals.iter().all(|n| (n[2] - 1.0).abs() < 1e-6),
            "computed from the faces"
        );
        mesh.faces.clear();
        assert!(glb_bytes(Path::new("x.glb"), &mesh, None).is_err());
    }
}
