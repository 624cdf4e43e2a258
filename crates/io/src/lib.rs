//! Handheld's edge with the file system and other tools. Nothing else in the workspace reads or writes
//! files (apart from the CLI's workspace bookkeeping).
//!
//! Split by concept: [`error`] (one error enum naming the path), [`atomic`] (write-then-rename),
//! [`images`] (photo folders, EXIF), [`video`] (ffmpeg subprocess), [`colmap`] (sparse model text and
//! binary), [`ply`] (point clouds and meshes), [`pfm`] (float maps),
//! [`ingest`] (the ingest stage).

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
