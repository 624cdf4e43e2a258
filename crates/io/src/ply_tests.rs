use super::*;

fn cloud(colors: bool, normals: bool) -> PointCloud {
    let n = 17;
    PointCloud {
        positions: (0..n)
            .map(|i| [i as f32 * 0.1, -(i as f32) / 3.0, 1e-7 * i as f32])
            .collect(),
        colors: if colors {
            (0..n).map(|i| [i as u8, 255 - i as u8, 7]).collect()
        } else {
            vec![]
        },
        normals: if normals {
            (0..n)
                .map(|i| [0.0, (i as f32).sin(), (i as f32).cos()])
                .collect()
        } else {
            vec![]
        },
    }
}

fn mesh(uvs: bool) -> TriMesh {
    let vertices = cloud(true, true);
    let faces = (0..15).map(|i| [i, i + 1, i + 2]).collect();
    let uvs = if uvs {
        (0..17)
            .map(|i| [i as f32 / 16.0, 1.0 - i as f32 / 17.0])
            .collect()
    } else {
        vec![]
    };
    TriMesh {
        vertices,
        uvs,
        faces,
    }
}

#[test]
fn clouds_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian] {
        for (c, n) in [(false, false), (true, false), (false, true), (true, true)] {
            let p = dir.path().join(format!("c_{format:?}_{c}_{n}.ply"));
            let pc = cloud(c, n);
            write_point_cloud(&p, &pc, format).unwrap();
            assert_eq!(
                read_point_cloud(&p).unwrap(),
                pc,
                "{format:?} colors={c} normals={n}"
            );
        }
    }
    let empty = dir.path().join("empty.ply");
    write_point_cloud(&empty, &PointCloud::default(), PlyFormat::default()).unwrap();
    assert!(read_point_cloud(&empty).unwrap().is_empty());
}

#[test]
fn meshes_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian] {
        for uvs in [false, true] {
            let p = dir.path().join(format!("m_{format:?}_{uvs}.ply"));
            let m = mesh(uvs);
            write_mesh(&p, &m, format).unwrap();
            assert_eq!(read_mesh(&p).unwrap(), m, "{format:?} uvs={uvs}");
            assert_eq!(read_point_cloud(&p).unwrap(), m.vertices);
        }
    }
    let mut bad = mesh(false);
    bad.faces.push([0, 1, 99]);
    assert!(matches!(
        write_mesh(&dir.path().join("bad.ply"), &bad, PlyFormat::Ascii),
        Err(IoError::Input { .. })
    ));
}

#[test]
fn reads_foreign_ascii_with_doubles_and_extras() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("foreign.ply");
    let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nobj_info whatever\r\n\
        element vertex 4\r\nproperty double x\r\nproperty double y\r\nproperty double z\r\n\
        property float quality\r\nproperty uchar red\r\nproperty uchar green\r\nproperty uchar blue\r\nproperty uchar alpha\r\n\
        element material 2\r\nproperty list uchar float coeffs\r\nproperty int id\r\n\
        element face 2\r\nproperty uchar flags\r\nproperty list uchar uint vertex_index\r\nproperty list uchar float texcoord\r\n\
        end_header\r\n\
        0.5 1.25 -2 9.9 10 20 30 255\r\n1 0 0 0 1 2 3 4\r\n0 1 0 0 5 6 7 8\r\n1 1 0 0 9 10 11 12\r\n\
        3 0.1 0.2 0.3 7\r\n0 42\r\n\
        0 3 0 1 2 6 0 0 1 0 0 1\r\n1 4 0 1 3 2 0\r\n";
    fs::write(&p, text).unwrap();
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.vertices.positions[0], [0.5, 1.25, -2.0]);
    assert_eq!(m.vertices.colors[3], [9, 10, 11]);
    assert!(m.vertices.normals.is_empty() && m.uvs.is_empty());
    assert_eq!(m.faces, vec![[0, 1, 2], [0, 1, 3], [0, 3, 2]]);
}

#[test]
fn reads_big_endian_binary_with_double_and_float_colors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("be.ply");
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
        property double z\nproperty float red\nproperty float green\nproperty float blue\nproperty short extra\n\
        element face 1\nproperty list int int vertex_indices\nend_header\n"
        .to_vec();
    for i in 0..3 {
        for v in [i as f64, 2.0 * i as f64, -0.5] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        for c in [0.0f32, 0.5, 1.0] {
            b.extend_from_slice(&c.to_be_bytes());
        }
        b.extend_from_slice(&(-3i16).to_be_bytes());
    }
    for v in [3i32, 2, 1, 0] {
        b.extend_from_slice(&v.to_be_bytes());
    }
    fs::write(&p, &b).unwrap();
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.vertices.positions[2], [2.0, 4.0, -0.5]);
    assert_eq!(m.vertices.colors[1], [0, 128, 255]);
    assert_eq!(m.faces, vec![[2, 1, 0]]);
    // Truncation anywhere in the body is an error naming the file.
    for cut in [b.len() - 1, b.len() - 20, b.len() - 60] {
        fs::write(&p, &b[..cut]).unwrap();
        let e = read_mesh(&p).unwrap_err().to_string();
        assert!(e.contains("be.ply") && e.contains("truncated"), "{e}");
    }
}

#[test]
fn malformed_headers_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("h.ply");
    for (text, needle) in [
        ("plx\n", "not a PLY"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "end_header"),
        ("ply\nformat ascii 1.0\nproperty float x\nend_header\n", "before any element"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\nend_header\n", "half"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n", "x, y or z"),
        ("ply\nelement vertex 0\nend_header\n", "format"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 zz\n", "zz"),
        ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n1 2 3\n3 0 0 1\n", "past the 1 vertices"),
    ] {
        fs::write(&p, text).unwrap();
        let e = read_mesh(&p).unwrap_err().to_string();
        assert!(e.contains("h.ply") && e.contains(needle), "{needle}: {e}");
    }
}
