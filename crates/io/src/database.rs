//! The matching database in COLMAP's SQLite schema (`database.db`, COLMAP 3.8 layout), so a user can
//! open Handheld's keypoints, matches and verified two-view geometries in COLMAP, and COLMAP's
//! `mapper` can run on them.
//!
//! Conventions at this boundary: keypoint coordinates get COLMAP's +0.5 pixel offset; descriptors are
//! stored as `uint8` (`round(min(255, 512·v))`, COLMAP's own conversion); matrices are `float64`
//! blobs in Eigen's column-major order; a pair is keyed by
//! `pair_id = 2147483647·min(id1, id2) + max(id1, id2)` with the match columns swapped when needed.
//! The database is built in a temporary file and renamed into place by [`Database::finish`].

use std::path::{Path, PathBuf};

use handheld_core::PIXEL_CENTER_OFFSET_COLMAP;
use nalgebra::Matrix3;
use rusqlite::{params, Connection, OptionalExtension};

use crate::atomic::temp_path;
use crate::error::{IoError, Result};

const MAX_IMAGE_ID: u64 = 2_147_483_647;

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS cameras (camera_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, model INTEGER NOT NULL,
  width INTEGER NOT NULL, height INTEGER NOT NULL, params BLOB, prior_focal_length INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS images (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, name TEXT NOT NULL UNIQUE,
  camera_id INTEGER NOT NULL, prior_qw REAL, prior_qx REAL, prior_qy REAL, prior_qz REAL, prior_tx REAL,
  prior_ty REAL, prior_tz REAL, CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647),
  FOREIGN KEY(camera_id) REFERENCES cameras(camera_id));
CREATE UNIQUE INDEX IF NOT EXISTS index_name ON images(name);
CREATE TABLE IF NOT EXISTS keypoints (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS descriptors (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE IF NOT EXISTS matches (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB);
CREATE TABLE IF NOT EXISTS two_view_geometries (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, config INTEGER NOT NULL, F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB);
";

/// COLMAP's `TwoViewGeometry::ConfigurationType`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(i64)]
pub enum TwoViewConfig {
    Undefined = 0,
    Degenerate = 1,
    Calibrated = 2,
    Uncalibrated = 3,
    Planar = 4,
    Panoramic = 5,
    PlanarOrPanoramic = 6,
}

/// A verified two-view geometry as stored in the database.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredTwoViewGeometry {
    pub config: i64,
    /// Inlier matches `(keypoint in image 1, keypoint in image 2)`.
    pub inliers: Vec<(u32, u32)>,
    pub f: Option<Matrix3<f64>>,
    pub h: Option<Matrix3<f64>>,
}

/// COLMAP's pair key (order-independent).
pub fn pair_id(id1: u32, id2: u32) -> u64 {
    let (a, b) = if id1 <= id2 {
        (id1 as u64, id2 as u64)
    } else {
        (id2 as u64, id1 as u64)
    };
    MAX_IMAGE_ID * a + b
}

/// Inverse of [`pair_id`]: `(smaller id, larger id)`.
pub fn ids_from_pair(pair: u64) -> (u32, u32) {
    ((pair / MAX_IMAGE_ID) as u32, (pair % MAX_IMAGE_ID) as u32)
}

/// An open matching database.
pub struct Database {
    conn: Connection,
    path: PathBuf,
    /// Where the file really lives until [`Database::finish`] renames it (`None` when opened in place).
    tmp: Option<PathBuf>,
}

fn sql_err(path: &Path) -> impl Fn(rusqlite::Error) -> IoError + '_ {
    move |e| IoError::format(path, format!("database error: {e}"))
}

fn matrix_blob(m: &Matrix3<f64>) -> Vec<u8> {
    m.as_slice().iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn blob_matrix(b: &[u8]) -> Option<Matrix3<f64>> {
    if b.len() != 72 {
        return None;
    }
    let v: Vec<f64> = b
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    Some(Matrix3::from_column_slice(&v))
}

fn pairs_blob(pairs: &[(u32, u32)], swap: bool) -> Vec<u8> {
    pairs
        .iter()
        .flat_map(|&(a, b)| if swap { [b, a] } else { [a, b] })
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

fn blob_pairs(b: &[u8], swap: bool) -> Vec<(u32, u32)> {
    b.chunks_exact(8)
        .map(|c| {
            let a = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            let d = u32::from_le_bytes([c[4], c[5], c[6], c[7]]);
            if swap {
                (d, a)
            } else {
                (a, d)
            }
        })
        .collect()
}

impl Database {
    /// Starts a new database that will replace `path` when [`Database::finish`] succeeds.
    pub fn create(path: &Path) -> Result<Self> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| IoError::io(dir, e))?;
        }
        let tmp = temp_path(path);
        let _ = std::fs::remove_file(&tmp);
        let conn = Connection::open(&tmp).map_err(sql_err(path))?;
        conn.execute_batch(SCHEMA).map_err(sql_err(path))?;
        conn.execute_batch("PRAGMA journal_mode=OFF; PRAGMA synchronous=OFF; BEGIN;")
            .map_err(sql_err(path))?;
        Ok(Self {
            conn,
            path: path.to_path_buf(),
            tmp: Some(tmp),
        })
    }

    /// Opens an existing database for reading.
    pub fn open(path: &Path) -> Result<Self> {
        if !path.exists() {
            return Err(IoError::NotFound {
                path: path.to_path_buf(),
            });
        }
        let conn = Connection::open_with_flags(path, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
            .map_err(sql_err(path))?;
        Ok(Self {
            conn,
            path: path.to_path_buf(),
            tmp: None,
        })
    }

    /// Commits and renames the database into place.
    pub fn finish(self) -> Result<()> {
        let Some(tmp) = self.tmp.clone() else {
            return Ok(());
        };
        self.conn
            .execute_batch("COMMIT;")
            .map_err(sql_err(&self.path))?;
        self.conn
            .close()
            .map_err(|(_, e)| IoError::format(&tmp, e.to_string()))?;
        std::fs::rename(&tmp, &self.path).map_err(|e| IoError::io(&self.path, e))
    }

    /// Adds an intrinsics group; `model` is COLMAP's model id, `params` its parameter vector.
    pub fn add_camera(
        &self,
        model: i64,
        width: u32,
        height: u32,
        params: &[f64],
        prior_focal_length: bool,
    ) -> Result<u32> {
        let blob: Vec<u8> = params.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.conn
            .execute(
                "INSERT INTO cameras (model, width, height, params, prior_focal_length) VALUES (?1, ?2, ?3, ?4, ?5)",
                params![model, width, height, blob, prior_focal_length as i64],
            )
            .map_err(sql_err(&self.path))?;
        Ok(self.conn.last_insert_rowid() as u32)
    }

    /// Adds an image and returns its id.
    pub fn add_image(&self, name: &str, camera_id: u32) -> Result<u32> {
        self.conn
            .execute(
                "INSERT INTO images (name, camera_id) VALUES (?1, ?2)",
                params![name, camera_id],
            )
            .map_err(sql_err(&self.path))?;
        Ok(self.conn.last_insert_rowid() as u32)
    }

    /// All images as `(image_id, name, camera_id)`, by id.
    pub fn images(&self) -> Result<Vec<(u32, String, u32)>> {
        let mut st = self
            .conn
            .prepare("SELECT image_id, name, camera_id FROM images ORDER BY image_id")
            .map_err(sql_err(&self.path))?;
        let rows = st
            .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)))
            .map_err(sql_err(&self.path))?;
        rows.collect::<std::result::Result<_, _>>()
            .map_err(sql_err(&self.path))
    }

    /// Stores keypoints `(x, y, scale, orientation)` in Handheld's pixel convention.
    pub fn write_keypoints(&self, image_id: u32, keypoints: &[[f32; 4]]) -> Result<()> {
        let off = PIXEL_CENTER_OFFSET_COLMAP as f32;
        let blob: Vec<u8> = keypoints
            .iter()
            .flat_map(|k| [k[0] + off, k[1] + off, k[2], k[3]])
            .flat_map(|v| v.to_le_bytes())
            .collect();
        self.conn
            .execute(
                "INSERT OR REPLACE INTO keypoints VALUES (?1, ?2, 4, ?3)",
                params![image_id, keypoints.len() as i64, blob],
            )
            .map_err(sql_err(&self.path))?;
        Ok(())
    }

    /// Reads keypoints back in Handheld's pixel convention (`scale`, `orientation` are 0 when the
    /// database stores only 2 columns; 6-column affine shapes give their mean scale).
    pub fn read_keypoints(&self, image_id: u32) -> Result<Vec<[f32; 4]>> {
        let row: Option<(i64, i64, Vec<u8>)> = self
            .conn
            .query_row(
                "SELECT rows, cols, data FROM keypoints WHERE image_id = ?1",
                [image_id],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
            )
            .optional()
            .map_err(sql_err(&self.path))?;
        let Some((rows, cols, data)) = row else {
            return Ok(Vec::new());
        };
        let cols = cols as usize;
        if !(cols == 2 || cols == 4 || cols == 6) || data.len() != rows as usize * cols * 4 {
            return Err(IoError::format(
                &self.path,
                format!(
                    "keypoints of image {image_id}: bad blob ({rows}×{cols}, {} bytes)",
                    data.len()
                ),
            ));
        }
        let v: Vec<f32> = data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let off = PIXEL_CENTER_OFFSET_COLMAP as f32;
        Ok(v.chunks_exact(cols)
            .map(|k| match cols {
                4 => [k[0] - off, k[1] - off, k[2], k[3]],
                6 => [
                    k[0] - off,
                    k[1] - off,
                    0.5 * ((k[2] * k[2] + k[4] * k[4]).sqrt() + (k[3] * k[3] + k[5] * k[5]).sqrt()),
                    k[4].atan2(k[2]),
                ],
                _ => [k[0] - off, k[1] - off, 0.0, 0.0],
            })
            .collect())
    }

    /// Stores float descriptors (row-major, `dim` per keypoint) as COLMAP's `uint8`.
    pub fn write_descriptors(&self, image_id: u32, dim: usize, data: &[f32]) -> Result<()> {
        let rows = data.len().checked_div(dim).unwrap_or(0);
        let blob: Vec<u8> = data
            .iter()
            .map(|v| (512.0 * v).round().clamp(0.0, 255.0) as u8)
            .collect();
        self.conn
            .execute(
                "INSERT OR REPLACE INTO descriptors VALUES (?1, ?2, ?3, ?4)",
                params![image_id, rows as i64, dim as i64, blob],
            )
            .map_err(sql_err(&self.path))?;
        Ok(())
    }

    /// Stores the putative matches of a pair (`(keypoint in id1, keypoint in id2)`).
    pub fn write_matches(&self, id1: u32, id2: u32, matches: &[(u32, u32)]) -> Result<()> {
        let blob = pairs_blob(matches, id1 > id2);
        self.conn
            .execute(
                "INSERT OR REPLACE INTO matches VALUES (?1, ?2, 2, ?3)",
                params![pair_id(id1, id2) as i64, matches.len() as i64, blob],
            )
            .map_err(sql_err(&self.path))?;
        Ok(())
    }

    /// Reads the putative matches of a pair, oriented as `(keypoint in id1, keypoint in id2)`.
    pub fn read_matches(&self, id1: u32, id2: u32) -> Result<Vec<(u32, u32)>> {
        let blob: Option<Vec<u8>> = self
            .conn
            .query_row(
                "SELECT data FROM matches WHERE pair_id = ?1",
                [pair_id(id1, id2) as i64],
                |r| r.get(0),
            )
            .optional()
            .map_err(sql_err(&self.path))?;
        Ok(blob.map(|b| blob_pairs(&b, id1 > id2)).unwrap_or_default())
    }

    /// Stores a verified two-view geometry (`F`, `H` as given for `x_id2ᵀ F x_id1 = 0`).
    pub fn write_two_view_geometry(
        &self,
        id1: u32,
        id2: u32,
        g: &StoredTwoViewGeometry,
    ) -> Result<()> {
        let swap = id1 > id2;
        // COLMAP stores F and H for the ordered pair (smaller id first).
        let f = g.f.map(|f| if swap { f.transpose() } else { f });
        let h =
            g.h.and_then(|h| if swap { h.try_inverse() } else { Some(h) });
        let z = Matrix3::<f64>::zeros();
        self.conn
            .execute(
                "INSERT OR REPLACE INTO two_view_geometries VALUES (?1, ?2, 2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)",
                params![
                    pair_id(id1, id2) as i64,
                    g.inliers.len() as i64,
                    pairs_blob(&g.inliers, swap),
                    g.config,
                    matrix_blob(&f.unwrap_or(z)),
                    matrix_blob(&z),
                    matrix_blob(&h.unwrap_or(z)),
                    [1.0f64, 0.0, 0.0, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>(),
                    [0.0f64; 3].iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>(),
                ],
            )
            .map_err(sql_err(&self.path))?;
        Ok(())
    }

    /// Reads a verified geometry, oriented for `(id1, id2)`.
    pub fn read_two_view_geometry(
        &self,
        id1: u32,
        id2: u32,
    ) -> Result<Option<StoredTwoViewGeometry>> {
        // (inlier matches, configuration, F, H) as stored.
        type Row = (Vec<u8>, i64, Vec<u8>, Vec<u8>);
        let row: Option<Row> = self
            .conn
            .query_row(
                "SELECT data, config, F, H FROM two_view_geometries WHERE pair_id = ?1",
                [pair_id(id1, id2) as i64],
                |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
            )
            .optional()
            .map_err(sql_err(&self.path))?;
        let swap = id1 > id2;
        Ok(row.map(|(data, config, f, h)| {
            let nonzero = |m: Option<Matrix3<f64>>| m.filter(|m| m.norm() > 0.0);
            StoredTwoViewGeometry {
                config,
                inliers: blob_pairs(&data, swap),
                f: nonzero(blob_matrix(&f)).map(|f| if swap { f.transpose() } else { f }),
                h: nonzero(blob_matrix(&h))
                    .and_then(|h| if swap { h.try_inverse() } else { Some(h) }),
            }
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_pair_orientation() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("database.db");
        let db = Database::create(&path).unwrap();
        assert!(!path.exists(), "nothing at the final path before finish");
        let cam = db
            .add_camera(2, 640, 480, &[500.0, 320.5, 240.5, 0.0], false)
            .unwrap();
        let a = db.add_image("a.png", cam).unwrap();
        let b = db.add_image("b.png", cam).unwrap();
        db.write_keypoints(a, &[[10.0, 20.0, 1.5, 0.25], [30.0, 40.0, 2.0, -1.0]])
            .unwrap();
        db.write_descriptors(a, 4, &[0.1, 0.2, 0.3, 0.9, 0.0, 0.5, 1.0, 0.25])
            .unwrap();
        db.write_matches(b, a, &[(0, 1), (5, 0)]).unwrap();
        let f = Matrix3::new(0.0, -1e-4, 0.02, 1e-4, 0.0, -0.03, -0.02, 0.03, 1.0);
        let h = Matrix3::new(1.1, 0.01, 3.0, -0.02, 0.95, -4.0, 1e-5, 2e-5, 1.0);
        let g = StoredTwoViewGeometry {
            config: TwoViewConfig::Uncalibrated as i64,
            inliers: vec![(5, 0)],
            f: Some(f),
            h: Some(h),
        };
        db.write_two_view_geometry(b, a, &g).unwrap();
        db.finish().unwrap();

        let db = Database::open(&path).unwrap();
        assert_eq!(
            db.images().unwrap(),
            vec![(a, "a.png".into(), cam), (b, "b.png".into(), cam)]
        );
        assert_eq!(
            db.read_keypoints(a).unwrap(),
            vec![[10.0, 20.0, 1.5, 0.25], [30.0, 40.0, 2.0, -1.0]]
        );
        assert_eq!(db.read_matches(b, a).unwrap(), vec![(0, 1), (5, 0)]);
        assert_eq!(db.read_matches(a, b).unwrap(), vec![(1, 0), (0, 5)]);
        let back = db.read_two_view_geometry(b, a).unwrap().unwrap();
        assert_eq!(back.inliers, vec![(5, 0)]);
        assert!((back.f.unwrap() - f).norm() < 1e-15);
        assert!((back.h.unwrap() - h).norm() < 1e-12);
        let flipped = db.read_two_view_geometry(a, b).unwrap().unwrap();
        assert!((flipped.f.unwrap() - f.transpose()).norm() < 1e-15);
        assert_eq!(ids_from_pair(pair_id(b, a)), (a.min(b), a.max(b)));
        // COLMAP's stored layout: smaller id first, its columns swapped accordingly.
        let conn = Connection::open(&path).unwrap();
        let raw: Vec<u8> = conn
            .query_row("SELECT data FROM matches", [], |r| r.get(0))
            .unwrap();
        assert_eq!(blob_pairs(&raw, false), vec![(1, 0), (0, 5)]);
        let kp: Vec<u8> = conn
            .query_row("SELECT data FROM keypoints", [], |r| r.get(0))
            .unwrap();
        assert_eq!(f32::from_le_bytes([kp[0], kp[1], kp[2], kp[3]]), 10.5);
        let desc: Vec<u8> = conn
            .query_row("SELECT data FROM descriptors", [], |r| r.get(0))
            .unwrap();
        assert_eq!(&desc[..4], &[51, 102, 154, 255]);
    }

    #[test]
    fn missing_database_is_named() {
        let err = Database::open(Path::new("/nonexistent/database.db"))
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("database.db") && err.contains("does not exist"));
    }
}
