//! PLY point clouds and triangle meshes, hand-written (no dependency).
//!
//! Writing: `vertex` with `x y z` (float), optional `nx ny nz` (float), `red green blue` (uchar) and,
//! for meshes, `s t` (float) texture coordinates, then a `face` element with
//! `property list uchar int vertex_indices`. Binary little-endian by default, ASCII on request; every
//! file is written atomically.
//!
//! Reading accepts `ascii`, `binary_little_endian` and `binary_big_endian` files from other tools
//! (MeshLab, Open3D, CloudCompare): any scalar type for any property (colours stored as floats are
//! taken to lie in `[0, 1]`), `vertex_indices` or `vertex_index` face lists of any integer type,
//! polygons (fan-triangulated), and unknown properties and elements, which are skipped.

use std::fs;
use std::path::Path;

use handheld_core::{PointCloud, TriMesh};

use crate::atomic::write_atomic;
use crate::error::{IoError, Result};

/// Encoding of a written PLY file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum PlyFormat {
    /// Human-readable text (larger, slower).
    Ascii,
    /// Compact binary, little-endian (the default).
    #[default]
    BinaryLittleEndian,
}

/// Writes a point cloud (colours and normals when present).
pub fn write_point_cloud(path: &Path, cloud: &PointCloud, format: PlyFormat) -> Result<()> {
    cloud.validate().map_err(|reason| IoError::Input {
        path: path.to_path_buf(),
        reason,
    })?;
    write_ply(path, cloud, &[], &[], format)
}

/// Writes a triangle mesh (per-vertex colours, normals and texture coordinates when present).
pub fn write_mesh(path: &Path, mesh: &TriMesh, format: PlyFormat) -> Result<()> {
    mesh.validate().map_err(|reason| IoError::Input {
        path: path.to_path_buf(),
        reason,
    })?;
    if mesh.vertices.len() > i32::MAX as usize {
        return Err(IoError::Input {
            path: path.to_path_buf(),
            reason: "too many vertices for PLY int indices".into(),
        });
    }
    write_ply(path, &mesh.vertices, &mesh.uvs, &mesh.faces, format)
}

/// Reads the `vertex` element of a PLY file as a point cloud (faces, if any, are ignored).
pub fn read_point_cloud(path: &Path) -> Result<PointCloud> {
    Ok(read_ply(path, false)?.vertices)
}

/// Reads a PLY file as a triangle mesh (a file without faces gives a mesh without faces).
pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    read_ply(path, true)
}

fn write_ply(
    path: &Path,
    v: &PointCloud,
    uvs: &[[f32; 2]],
    faces: &[[u32; 3]],
    format: PlyFormat,
) -> Result<()> {
    let (normals, colors, has_uv) = (!v.normals.is_empty(), !v.colors.is_empty(), !uvs.is_empty());
    let is_mesh = has_uv || !faces.is_empty();
    let mut header = String::from("ply\n");
    header += match format {
        PlyFormat::Ascii => "format ascii 1.0\n",
        PlyFormat::BinaryLittleEndian => "format binary_little_endian 1.0\n",
    };
    header += "comment written by Handheld\n";
    header += &format!(
        "element vertex {}\nproperty float x\nproperty float y\nproperty float z\n",
        v.len()
    );
    if normals {
        header += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    if colors {
        header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    if has_uv {
        header += "property float s\nproperty float t\n";
    }
    if is_mesh {
        header += &format!(
            "element face {}\nproperty list uchar int vertex_indices\n",
            faces.len()
        );
    }
    header += "end_header\n";

    write_atomic(path, |w| {
        w.write_all(header.as_bytes())?;
        let mut floats: Vec<f32> = Vec::with_capacity(8);
        for (i, pos) in v.positions.iter().enumerate() {
            floats.clear();
            floats.extend_from_slice(pos);
            if normals {
                floats.extend_from_slice(&v.normals[i]);
            }
            match format {
                PlyFormat::Ascii => {
                    let mut line = floats
                        .iter()
                        .map(|f| f.to_string())
                        .collect::<Vec<_>>()
                        .join(" ");
                    if colors {
                        let [r, g, b] = v.colors[i];
                        line += &format!(" {r} {g} {b}");
                    }
                    if has_uv {
                        line += &format!(" {} {}", uvs[i][0], uvs[i][1]);
                    }
                    writeln!(w, "{line}")?;
                }
                PlyFormat::BinaryLittleEndian => {
                    for f in &floats {
                        w.write_all(&f.to_le_bytes())?;
                    }
                    if colors {
                        w.write_all(&v.colors[i])?;
                    }
                    if has_uv {
                        w.write_all(&uvs[i][0].to_le_bytes())?;
                        w.write_all(&uvs[i][1].to_le_bytes())?;
                    }
                }
            }
        }
        for [a, b, c] in faces {
            match format {
                PlyFormat::Ascii => writeln!(w, "3 {a} {b} {c}")?,
                PlyFormat::BinaryLittleEndian => {
                    w.write_all(&[3])?;
                    for i in [a, b, c] {
                        w.write_all(&(*i as i32).to_le_bytes())?;
                    }
                }
            }
        }
        Ok(())
    })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Encoding {
    Ascii,
    Le,
    Be,
}

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }
}

#[derive(Debug)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// Parses the header; returns the encoding, the elements and the offset of the body.
fn parse_header(path: &Path, bytes: &[u8]) -> Result<(Encoding, Vec<Element>, usize)> {
    let mut pos = 0;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 0;
    loop {
        line_no += 1;
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(IoError::format(
                path,
                "truncated PLY header: no `end_header` line",
            ));
        };
        let line = String::from_utf8_lossy(&bytes[pos..pos + len]);
        pos += len + 1;
        let line = line.trim();
        let err =
            |reason: String| IoError::format(path, format!("header line {line_no}: {reason}"));
        let words: Vec<&str> = line.split_whitespace().collect();
        if line_no == 1 {
            if line != "ply" {
                return Err(err("not a PLY file (first line is not `ply`)".into()));
            }
            continue;
        }
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["end_header"] => break,
            ["format", f, _version] => {
                encoding = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Le,
                    "binary_big_endian" => Encoding::Be,
                    _ => return Err(err(format!("unknown format `{f}`"))),
                });
            }
            ["element", name, count] => {
                let count = count
                    .parse()
                    .map_err(|_| err(format!("bad element count `{count}`")))?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            ["property", "list", count, item, name] => {
                let ty = |t: &str| {
                    Scalar::parse(t).ok_or_else(|| err(format!("unknown property type `{t}`")))
                };
                let prop = Property::List {
                    name: name.to_string(),
                    count: ty(count)?,
                    item: ty(item)?,
                };
                if let Property::List { count: c, .. } = &prop {
                    if c.is_float() {
                        return Err(err("list count must be an integer type".into()));
                    }
                }
                elements
                    .last_mut()
                    .ok_or_else(|| err("property before any element".into()))?
                    .props
                    .push(prop);
            }
            ["property", ty, name] => {
                let ty = Scalar::parse(ty)
                    .ok_or_else(|| err(format!("unknown property type `{ty}`")))?;
                let el = elements
                    .last_mut()
                    .ok_or_else(|| err("property before any element".into()))?;
                el.props.push(Property::Scalar {
                    name: name.to_string(),
                    ty,
                });
            }
            _ => return Err(err(format!("cannot parse `{line}`"))),
        }
    }
    let encoding =
        encoding.ok_or_else(|| IoError::format(path, "PLY header has no `format` line"))?;
    Ok((encoding, elements, pos))
}

/// Reads scalar values from the body in file order.
struct Body<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
    enc: Encoding,
}

impl Body<'_> {
    fn err(&self, reason: &str) -> IoError {
        IoError::format(self.path, format!("byte {}: {reason}", self.pos))
    }

    fn value(&mut self, ty: Scalar) -> Result<f64> {
        if self.enc == Encoding::Ascii {
            while self.pos < self.data.len() && self.data[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            let start = self.pos;
            while self.pos < self.data.len() && !self.data[self.pos].is_ascii_whitespace() {
                self.pos += 1;
            }
            if start == self.pos {
                return Err(self.err("file is truncated (fewer values than the header declares)"));
            }
            let tok = std::str::from_utf8(&self.data[start..self.pos]).unwrap_or("");
            return tok
                .parse::<f64>()
                .map_err(|_| self.err(&format!("cannot parse `{tok}` as a number")));
        }
        let n = ty.size();
        if self.data.len() - self.pos < n {
            return Err(self.err("file is truncated (fewer values than the header declares)"));
        }
        let mut b = [0u8; 8];
        b[..n].copy_from_slice(&self.data[self.pos..self.pos + n]);
        self.pos += n;
        if self.enc == Encoding::Be {
            b[..n].reverse();
        }
        Ok(match ty {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(b),
        })
    }

    /// A list length or index: a non-negative integer.
    fn index(&mut self, ty: Scalar, what: &str) -> Result<u32> {
        let v = self.value(ty)?;
        if v < 0.0 || v.fract() != 0.0 || v > u32::MAX as f64 {
            return Err(self.err(&format!("{what} {v} is not a non-negative integer")));
        }
        Ok(v as u32)
    }
}

/// Vertex properties Handheld understands, by slot.
const SLOTS: [&[&str]; 11] = [
    &["x"],
    &["y"],
    &["z"],
    &["nx"],
    &["ny"],
    &["nz"],
    &["red", "r", "diffuse_red"],
    &["green", "g", "diffuse_green"],
    &["blue", "b", "diffuse_blue"],
    &["s", "u", "texture_u", "texture_s"],
    &["t", "v", "texture_v", "texture_t"],
];

fn read_ply(path: &Path, want_faces: bool) -> Result<TriMesh> {
    let bytes = fs::read(path).map_err(|e| IoError::io(path, e))?;
    let (enc, elements, start) = parse_header(path, &bytes)?;
    let mut body = Body {
        path,
        data: &bytes,
        pos: start,
        enc,
    };
    let mut mesh = TriMesh::default();
    let mut seen_vertex = false;
    let cap = |n: usize| n.min(bytes.len());
    for el in &elements {
        if el.name == "vertex" && !seen_vertex {
            seen_vertex = true;
            read_vertices(&mut body, el, &mut mesh, cap(el.count))?;
        } else if el.name == "face" && want_faces {
            mesh.faces.reserve(cap(el.count));
            let mut poly = Vec::new();
            for _ in 0..el.count {
                for p in &el.props {
                    match p {
                        Property::List { name, count, item }
                            if name == "vertex_indices" || name == "vertex_index" =>
                        {
                            let n = body.index(*count, "face vertex count")?;
                            poly.clear();
                            for _ in 0..n {
                                poly.push(body.index(*item, "face vertex index")?);
                            }
                            for k in 2..poly.len() {
                                mesh.faces.push([poly[0], poly[k - 1], poly[k]]);
                            }
                        }
                        _ => skip_property(&mut body, p)?,
                    }
                }
            }
        } else {
            for _ in 0..el.count {
                for p in &el.props {
                    skip_property(&mut body, p)?;
                }
            }
        }
    }
    if !seen_vertex {
        return Err(IoError::format(path, "PLY file has no `vertex` element"));
    }
    let n = mesh.vertices.len();
    if let Some(f) = mesh
        .faces
        .iter()
        .find(|f| f.iter().any(|&i| i as usize >= n))
    {
        return Err(IoError::format(
            path,
            format!("face {f:?} refers to a vertex past the {n} vertices"),
        ));
    }
    Ok(mesh)
}

fn skip_property(body: &mut Body<'_>, p: &Property) -> Result<()> {
    match p {
        Property::Scalar { ty, .. } => {
            body.value(*ty)?;
        }
        Property::List { count, item, .. } => {
            let n = body.index(*count, "list length")?;
            for _ in 0..n {
                body.value(*item)?;
            }
        }
    }
    Ok(())
}

fn read_vertices(body: &mut Body<'_>, el: &Element, mesh: &mut TriMesh, cap: usize) -> Result<()> {
    // For each property: the slot it fills (if any); for each slot: its type (if present).
    let mut slot_of = Vec::with_capacity(el.props.len());
    let mut types: [Option<Scalar>; 11] = [None; 11];
    for p in &el.props {
        let slot = match p {
            Property::Scalar { name, ty } => SLOTS
                .iter()
                .position(|names| names.contains(&name.as_str()))
                .filter(|&s| {
                    let free = types[s].is_none();
                    if free {
                        types[s] = Some(*ty);
                    }
                    free
                }),
            Property::List { .. } => None,
        };
        slot_of.push(slot);
    }
    if types[..3].iter().any(|t| t.is_none()) {
        return Err(IoError::format(
            body.path,
            "PLY `vertex` element lacks an x, y or z property",
        ));
    }
    let has = |r: std::ops::Range<usize>| types[r].iter().all(|t| t.is_some());
    let (normals, colors, uvs) = (has(3..6), has(6..9), has(9..11));
    let v = &mut mesh.vertices;
    v.positions.reserve(cap);
    let mut vals = [0f64; 11];
    for _ in 0..el.count {
        for (p, slot) in el.props.iter().zip(&slot_of) {
            match (p, slot) {
                (Property::Scalar { ty, .. }, Some(s)) => vals[*s] = body.value(*ty)?,
                _ => skip_property(body, p)?,
            }
        }
        v.positions
            .push([vals[0] as f32, vals[1] as f32, vals[2] as f32]);
        if normals {
            v.normals
                .push([vals[3] as f32, vals[4] as f32, vals[5] as f32]);
        }
        if colors {
            let c = |s: usize| {
                let x = if types[s].is_some_and(Scalar::is_float) {
                    vals[s] * 255.0
                } else {
                    vals[s]
                };
                x.round().clamp(0.0, 255.0) as u8
            };
            v.colors.push([c(6), c(7), c(8)]);
        }
        if uvs {
            mesh.uvs.push([vals[9] as f32, vals[10] as f32]);
        }
    }
    Ok(())
}

#[cfg(test)]
#[path = "ply_tests.rs"]
mod tests;
