//! Handheld's edge with the file system and other tools. Nothing else in the workspace reads or writes
//! files (apart from the CLI's workspace bookkeeping).
//!
//! Split by concept: [`error`] (one error enum naming the path), [`atomic`] (write-then-rename),
//! [`images`] (photo folders, EXIF), [`video`] (ffmpeg subprocess), [`colmap`] (sparse model text and
//! binary), [`ply`] (point clouds and meshes), [`pfm`] (float maps),
//! [`ingest`] (the ingest stage).
//!
//! Where each piece lives:
//! - [`images`]: photo ingest (JPEG/PNG/TIFF 8/16-bit, EXIF orientation and focal prior); [`ingest`]: the ingest step;
//! - [`video`]: decoding through the `ffmpeg` program (streamed PPM frames); `video/encode.rs`: H.264 encoding through
//!   `ffmpeg`, from files, from frames in memory, and `VideoWriter` streaming frame by frame with another file's audio;
//! - [`colmap`]: COLMAP text and binary models (COLMAP's pixel convention converted here); [`database`]: COLMAP's
//!   `database.db` (SQLite);
//! - [`ply`], [`pfm`], [`obj`] (OBJ + MTL + PNG); [`glb`]: binary glTF with embedded texture, written and read back
//!   (`glb/read.rs`: the augmented video's objects);
//! - [`track`]: the camera track as an animated glTF camera with the sparse points, and as a Nuke `.chan`;
//! - [`features_file`]: the feature files; [`bal`]: BAL problems; [`gt`]: ground-truth cameras;
//! - [`dense_folder`]: the dense folder's reader and writer (`PosedView`s in, `PosedView`s out).

pub mod atomic;
pub mod bal;
pub mod colmap;
pub mod database;
pub mod dense_folder;
pub mod error;
pub mod features_file;
pub mod glb;
pub mod gt;
pub mod images;
pub mod ingest;
pub mod obj;
pub mod pfm;
pub mod ply;
pub mod track;
pub mod video;

pub use error::{IoError, Result};
