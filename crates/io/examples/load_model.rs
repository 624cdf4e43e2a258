//! Loads written models back with the reference readers and prints one JSON line per file:
//! `.glb` through the `gltf` crate (which validates the document while importing) and `.obj`
//! through `tobj`. Usage: `load_model FILE...`.
use std::process::ExitCode;

fn glb(path: &str) -> Result<String, String> {
    let (doc, buffers, images) = gltf::import(path).map_err(|e| e.to_string())?;
    let (mut vertices, mut faces) = (0usize, 0usize);
    let (mut uv_lo, mut uv_hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for mesh in doc.meshes() {
        for prim in mesh.primitives() {
            let r = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            vertices += r.read_positions().map_or(0, |p| p.count());
            faces += r.read_indices().map_or(0, |i| i.into_u32().count() / 3);
            if let Some(tc) = r.read_tex_coords(0) {
                for [u, v] in tc.into_f32() {
                    uv_lo = uv_lo.min(u.min(v));
                    uv_hi = uv_hi.max(u.max(v));
                }
            }
        }
    }
    Ok(format!(
        "{{\"file\": \"{path}\", \"reader\": \"gltf\", \"vertices\": {vertices}, \"faces\": {faces}, \"uv_range\": [{uv_lo}, {uv_hi}], \"images\": {}}}",
        images.len()
    ))
}

fn obj(path: &str) -> Result<String, String> {
    let (models, materials) =
        tobj::load_obj(path, &tobj::GPU_LOAD_OPTIONS).map_err(|e| e.to_string())?;
    let materials = materials.map_err(|e| e.to_string())?;
    let faces: usize = models.iter().map(|m| m.mesh.indices.len() / 3).sum();
    let uvs = models.iter().flat_map(|m| m.mesh.texcoords.iter().copied());
    let (lo, hi) = uvs.fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), u| {
        (l.min(u), h.max(u))
    });
    Ok(format!(
        "{{\"file\": \"{path}\", \"reader\": \"tobj\", \"faces\": {faces}, \"uv_range\": [{lo}, {hi}], \"materials\": {}}}",
        materials.len()
    ))
}

fn main() -> ExitCode {
    let mut ok = true;
    for path in std::env::args().skip(1) {
        let r = if path.ends_with(".glb") {
            glb(&path)
        } else {
            obj(&path)
        };
        match r {
            Ok(line) => println!("{line}"),
            Err(e) => {
                eprintln!("{path}: {e}");
                ok = false;
            }
        }
    }
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
