//! COLMAP's text model: `cameras.txt`, `images.txt` (two lines per image) and `points3D.txt`.
//!
//! Floats are written with Rust's `{}` formatting, the shortest text that parses back to the same
//! bits, so a text round trip is exact. Readers skip comments (`#`) and blank lines (except the
//! keypoint line that follows every image line, which may be empty) and report malformed content as
//! [`IoError::Format`] naming the file and the line.

use std::fmt::Write as _;
use std::fs;
use std::path::Path;
use std::str::FromStr;

use super::{
    check_params, CameraModel, ColmapCamera, ColmapImage, ColmapModel, ColmapPoint2D, ColmapPoint3D,
};
use crate::atomic::write_atomic;
use crate::error::{IoError, Result};

/// Writes `cameras.txt`, `images.txt` and `points3D.txt` into `dir` (created if needed), each atomically.
pub fn write_text(dir: &Path, m: &ColmapModel) -> Result<()> {
    let cam_path = dir.join("cameras.txt");
    for c in m.cameras.values() {
        check_params(c).map_err(|reason| IoError::Input {
            path: cam_path.clone(),
            reason,
        })?;
    }
    let img_path = dir.join("images.txt");
    for im in m.images.values() {
        check_name(&im.name).map_err(|reason| IoError::Input {
            path: img_path.clone(),
            reason: format!("image {}: {reason}", im.id),
        })?;
    }

    write_atomic(&cam_path, |w| {
        writeln!(w, "# Camera list with one line of data per camera:")?;
        writeln!(w, "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]")?;
        writeln!(w, "# Number of cameras: {}", m.cameras.len())?;
        for c in m.cameras.values() {
            let mut line = format!("{} {} {} {}", c.id, c.model.name(), c.width, c.height);
            for p in &c.params {
                let _ = write!(line, " {p}");
            }
            writeln!(w, "{line}")?;
        }
        Ok(())
    })?;

    write_atomic(&img_path, |w| {
        let observations: usize = m
            .images
            .values()
            .map(|im| {
                im.points2d
                    .iter()
                    .filter(|p| p.point3d_id.is_some())
                    .count()
            })
            .sum();
        let mean = if m.images.is_empty() {
            0.0
        } else {
            observations as f64 / m.images.len() as f64
        };
        writeln!(w, "# Image list with two lines of data per image:")?;
        writeln!(
            w,
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME"
        )?;
        writeln!(w, "#   POINTS2D[] as (X, Y, POINT3D_ID)")?;
        writeln!(
            w,
            "# Number of images: {}, mean observations per image: {mean}",
            m.images.len()
        )?;
        let mut line = String::new();
        for im in m.images.values() {
            let [qw, qx, qy, qz] = im.qvec;
            let [tx, ty, tz] = im.tvec;
            writeln!(
                w,
                "{} {qw} {qx} {qy} {qz} {tx} {ty} {tz} {} {}",
                im.id, im.camera_id, im.name
            )?;
            line.clear();
            for (k, p) in im.points2d.iter().enumerate() {
                let sep = if k == 0 { "" } else { " " };
                let _ = match p.point3d_id {
                    Some(id) => write!(line, "{sep}{} {} {id}", p.x, p.y),
                    None => write!(line, "{sep}{} {} -1", p.x, p.y),
                };
            }
            writeln!(w, "{line}")?;
        }
        Ok(())
    })?;

    write_atomic(&dir.join("points3D.txt"), |w| {
        let total: usize = m.points3d.values().map(|p| p.track.len()).sum();
        let mean = if m.points3d.is_empty() {
            0.0
        } else {
            total as f64 / m.points3d.len() as f64
        };
        writeln!(w, "# 3D point list with one line of data per point:")?;
        writeln!(
            w,
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"
        )?;
        writeln!(
            w,
            "# Number of points: {}, mean track length: {mean}",
            m.points3d.len()
        )?;
        let mut line = String::new();
        for p in m.points3d.values() {
            let [x, y, z] = p.xyz;
            let [r, g, b] = p.rgb;
            line.clear();
            let _ = write!(line, "{} {x} {y} {z} {r} {g} {b} {}", p.id, p.error);
            for (img, idx) in &p.track {
                let _ = write!(line, " {img} {idx}");
            }
            writeln!(w, "{line}")?;
        }
        Ok(())
    })
}

/// A name the text format can hold: non-empty, one line, no surrounding whitespace.
fn check_name(name: &str) -> std::result::Result<(), String> {
    if name.is_empty() {
        return Err("empty image name".into());
    }
    if name.contains(['\n', '\r']) || name.trim() != name {
        return Err(format!(
            "image name {name:?} contains a line break or surrounding whitespace"
        ));
    }
    Ok(())
}

/// Reads `cameras.txt`, `images.txt` and `points3D.txt` from `dir`.
pub fn read_text(dir: &Path) -> Result<ColmapModel> {
    Ok(ColmapModel {
        cameras: read_cameras(&dir.join("cameras.txt"))?,
        images: read_images(&dir.join("images.txt"))?,
        points3d: read_points(&dir.join("points3D.txt"))?,
    })
}

/// The tokens of one data line, with enough context to name the file and line in errors.
struct Fields<'a> {
    path: &'a Path,
    line_no: usize,
    tokens: Vec<&'a str>,
    pos: usize,
}

impl<'a> Fields<'a> {
    fn new(path: &'a Path, line_no: usize, line: &'a str) -> Self {
        Self {
            path,
            line_no,
            tokens: line.split_whitespace().collect(),
            pos: 0,
        }
    }

    fn err(&self, reason: impl std::fmt::Display) -> IoError {
        IoError::format(self.path, format!("line {}: {reason}", self.line_no))
    }

    /// The next token parsed as `T`; `what` names the field in the error.
    fn next<T: FromStr>(&mut self, what: &str) -> Result<T> {
        let tok = *self
            .tokens
            .get(self.pos)
            .ok_or_else(|| self.err(format!("missing {what}")))?;
        self.pos += 1;
        tok.parse()
            .map_err(|_| self.err(format!("cannot parse {what} from `{tok}`")))
    }

    fn remaining(&self) -> usize {
        self.tokens.len() - self.pos
    }
}

fn read_file(path: &Path) -> Result<String> {
    fs::read_to_string(path).map_err(|e| IoError::io(path, e))
}

/// True for lines the readers skip.
fn is_skipped(line: &str) -> bool {
    let t = line.trim();
    t.is_empty() || t.starts_with('#')
}

/// Parses a `POINT3D_ID` where `-1` means none.
fn parse_point3d_id(f: &mut Fields<'_>) -> Result<Option<u64>> {
    let tok = *f
        .tokens
        .get(f.pos)
        .ok_or_else(|| f.err("missing POINT3D_ID"))?;
    if tok == "-1" {
        f.pos += 1;
        return Ok(None);
    }
    f.next("POINT3D_ID (an id or -1)").map(Some)
}

fn read_cameras(path: &Path) -> Result<std::collections::BTreeMap<u32, ColmapCamera>> {
    let text = read_file(path)?;
    let mut out = std::collections::BTreeMap::new();
    for (i, line) in text.lines().enumerate() {
        if is_skipped(line) {
            continue;
        }
        let mut f = Fields::new(path, i + 1, line);
        let id: u32 = f.next("CAMERA_ID")?;
        let name: String = f.next("MODEL")?;
        let model = CameraModel::from_name(&name).ok_or_else(|| {
            f.err(format!(
                "camera {id}: unsupported camera model `{name}` (supported: SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV)"
            ))
        })?;
        let width = f.next("WIDTH")?;
        let height = f.next("HEIGHT")?;
        let mut params = Vec::with_capacity(model.num_params());
        while f.remaining() > 0 {
            params.push(f.next::<f64>("camera parameter")?);
        }
        let cam = ColmapCamera {
            id,
            model,
            width,
            height,
            params,
        };
        check_params(&cam).map_err(|e| f.err(e))?;
        if out.insert(id, cam).is_some() {
            return Err(f.err(format!("duplicate CAMERA_ID {id}")));
        }
    }
    Ok(out)
}

/// Splits off the first `n` whitespace-separated tokens; returns them and the trimmed rest.
fn split_tokens(line: &str, n: usize) -> (Vec<&str>, &str) {
    let mut rest = line;
    let mut toks = Vec::with_capacity(n);
    for _ in 0..n {
        rest = rest.trim_start();
        if rest.is_empty() {
            break;
        }
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        toks.push(&rest[..end]);
        rest = &rest[end..];
    }
    (toks, rest.trim())
}

fn read_images(path: &Path) -> Result<std::collections::BTreeMap<u32, ColmapImage>> {
    let text = read_file(path)?;
    let mut out = std::collections::BTreeMap::new();
    let mut lines = text.lines().enumerate();
    while let Some((i, line)) = lines.next() {
        if is_skipped(line) {
            continue;
        }
        let (head, name) = split_tokens(line, 9);
        let mut f = Fields {
            path,
            line_no: i + 1,
            tokens: head,
            pos: 0,
        };
        let id: u32 = f.next("IMAGE_ID")?;
        let mut qvec = [0.0; 4];
        for (q, what) in qvec.iter_mut().zip(["QW", "QX", "QY", "QZ"]) {
            *q = f.next(what)?;
        }
        let mut tvec = [0.0; 3];
        for (t, what) in tvec.iter_mut().zip(["TX", "TY", "TZ"]) {
            *t = f.next(what)?;
        }
        let camera_id = f.next("CAMERA_ID")?;
        if name.is_empty() {
            return Err(f.err(format!("image {id}: missing NAME")));
        }
        // The keypoint line always follows, even when empty.
        let mut points2d = Vec::new();
        if let Some((j, pline)) = lines.next() {
            let mut g = Fields::new(path, j + 1, pline);
            let leftover = g.tokens.len() % 3;
            if leftover > 0 {
                return Err(g.err(format!(
                    "image {id}: keypoint line has {} values, expected triples X Y POINT3D_ID",
                    g.tokens.len()
                )));
            }
            points2d.reserve(g.tokens.len() / 3);
            while g.remaining() > 0 {
                let x = g.next("X")?;
                let y = g.next("Y")?;
                let point3d_id = parse_point3d_id(&mut g)?;
                points2d.push(ColmapPoint2D { x, y, point3d_id });
            }
        }
        let image = ColmapImage {
            id,
            qvec,
            tvec,
            camera_id,
            name: name.to_string(),
            points2d,
        };
        if out.insert(id, image).is_some() {
            return Err(f.err(format!("duplicate IMAGE_ID {id}")));
        }
    }
    Ok(out)
}

fn read_points(path: &Path) -> Result<std::collections::BTreeMap<u64, ColmapPoint3D>> {
    let text = read_file(path)?;
    let mut out = std::collections::BTreeMap::new();
    for (i, line) in text.lines().enumerate() {
        if is_skipped(line) {
            continue;
        }
        let mut f = Fields::new(path, i + 1, line);
        let id: u64 = f.next("POINT3D_ID")?;
        let xyz = [f.next("X")?, f.next("Y")?, f.next("Z")?];
        let rgb = [
            f.next("R (0-255)")?,
            f.next("G (0-255)")?,
            f.next("B (0-255)")?,
        ];
        let error = f.next("ERROR")?;
        let leftover = f.remaining() % 2;
        if leftover > 0 {
            return Err(f.err(format!("point {id}: track has an odd number of values, expected pairs IMAGE_ID POINT2D_IDX")));
        }
        let mut track = Vec::with_capacity(f.remaining() / 2);
        while f.remaining() > 0 {
            track.push((f.next("IMAGE_ID")?, f.next("POINT2D_IDX")?));
        }
        if out
            .insert(
                id,
                ColmapPoint3D {
                    id,
                    xyz,
                    rgb,
                    error,
                    track,
                },
            )
            .is_some()
        {
            return Err(f.err(format!("duplicate POINT3D_ID {id}")));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::testdata::sample_model;
    use super::super::{read_binary, write_binary};
    use super::*;

    #[test]
    fn text_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let m = sample_model();
        write_text(dir.path(), &m).unwrap();
        let back = read_text(dir.path()).unwrap();
        assert_eq!(back, m);
        // Bit-exact, including -0.0 and tiny values.
        let p = &back.cameras[&5].params;
        assert!(p[3] == 0.0 && p[3].is_sign_negative());
        assert_eq!(p[4].to_bits(), 1e-300f64.to_bits());
        assert!(back.images[&3].points2d.is_empty());
    }

    #[test]
    fn text_binary_text_is_identical() {
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        let c = tempfile::tempdir().unwrap();
        write_text(a.path(), &sample_model()).unwrap();
        let m = read_text(a.path()).unwrap();
        write_binary(b.path(), &m).unwrap();
        write_text(c.path(), &read_binary(b.path()).unwrap()).unwrap();
        for f in ["cameras.txt", "images.txt", "points3D.txt"] {
            assert_eq!(
                fs::read(a.path().join(f)).unwrap(),
                fs::read(c.path().join(f)).unwrap(),
                "{f}"
            );
        }
    }

    #[test]
    fn reads_hand_written_files_with_comments_and_blank_lines() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        fs::write(
            d.join("cameras.txt"),
            "# c\n\n  1 SIMPLE_PINHOLE 640 480 500 320 240  \r\n# end\n",
        )
        .unwrap();
        fs::write(
            d.join("images.txt"),
            "# header\n\n1 1 0 0 0 0 0 0 1 my image.png\n\n# next\n2 1 0 0 0 1 2 3 1 b.png\n10.5 20.5 7 1 2 -1\n",
        )
        .unwrap();
        fs::write(d.join("points3D.txt"), "# p\n7 1 2 3 10 20 30 0.5 2 0\n").unwrap();
        let m = read_text(d).unwrap();
        assert_eq!(m.cameras[&1].params, vec![500.0, 320.0, 240.0]);
        assert_eq!(m.images[&1].name, "my image.png");
        assert!(m.images[&1].points2d.is_empty());
        assert_eq!(m.images[&2].points2d[0].point3d_id, Some(7));
        assert_eq!(m.images[&2].points2d[1].point3d_id, None);
        assert_eq!(m.points3d[&7].track, vec![(2, 0)]);
    }

    fn write_valid_rest(d: &Path) {
        fs::write(d.join("images.txt"), "").unwrap();
        fs::write(d.join("points3D.txt"), "").unwrap();
    }

    fn format_error(d: &Path) -> String {
        match read_text(d) {
            Err(e @ IoError::Format { .. }) => e.to_string(),
            other => panic!("expected a format error, got {other:?}"),
        }
    }

    #[test]
    fn too_few_camera_params_names_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        write_valid_rest(dir.path());
        fs::write(
            dir.path().join("cameras.txt"),
            "# x\n1 PINHOLE 640 480 500 500 320 240\n2 PINHOLE 640 480 500 320\n",
        )
        .unwrap();
        let e = format_error(dir.path());
        assert!(
            e.contains("cameras.txt") && e.contains("line 3") && e.contains("needs 4 parameters"),
            "{e}"
        );
    }

    #[test]
    fn malformed_lines_are_errors_not_panics() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let cases: [(&str, &str, &str, usize); 8] = [
            ("cameras.txt", "1 FISHEYE 640 480 1 2 3\n", "FISHEYE", 1),
            ("cameras.txt", "x PINHOLE 640 480 1 2 3 4\n", "CAMERA_ID", 1),
            (
                "cameras.txt",
                "1 PINHOLE 640 480 1 2 3 nan4\n",
                "camera parameter",
                1,
            ),
            ("images.txt", "1 1 0 0 0 0 0 0 1\n\n", "NAME", 1),
            ("images.txt", "1 1 0 0 0 0 0 0 1 a.png\n1 2\n", "triples", 2),
            (
                "images.txt",
                "1 1 0 0 0 0 0 0 1 a.png\n1 2 -2\n",
                "POINT3D_ID",
                2,
            ),
            ("points3D.txt", "1 0 0 0 300 0 0 0.1\n", "R (0-255)", 1),
            ("points3D.txt", "# c\n1 0 0 0 3 0 0 0.1 5\n", "odd", 2),
        ];
        for (file, content, needle, line) in cases {
            fs::write(d.join("cameras.txt"), "").unwrap();
            write_valid_rest(d);
            fs::write(d.join(file), content).unwrap();
            let e = format_error(d);
            assert!(
                e.contains(file) && e.contains(&format!("line {line}:")) && e.contains(needle),
                "{file}: {e}"
            );
        }
    }

    #[test]
    fn missing_file_is_not_found() {
        let dir = tempfile::tempdir().unwrap();
        assert!(matches!(
            read_text(dir.path()),
            Err(IoError::NotFound { .. })
        ));
    }

    #[test]
    fn unwritable_names_are_rejected() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = sample_model();
        m.images.get_mut(&1).unwrap().name = "two\nlines".into();
        assert!(matches!(
            write_text(dir.path(), &m),
            Err(IoError::Input { .. })
        ));
        assert!(!dir.path().join("cameras.txt").exists());
    }
}
