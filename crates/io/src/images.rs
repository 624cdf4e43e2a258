//! Photo ingest: list a folder of JPEG/PNG/TIFF images, decode them (8 or 16 bit, grey or colour),
//! apply the EXIF orientation, and read the EXIF focal length as an *optional* prior. Nothing in the
//! pipeline requires EXIF: self-calibration (§3.4) recovers the focal length without it.

use std::fs;
use std::io::{BufReader, Cursor};
use std::path::{Path, PathBuf};

use image::{DynamicImage, ImageDecoder, ImageReader};
use serde::{Deserialize, Serialize};

use crate::error::{IoError, Result};

/// File extensions (lower case) recognised as images.
pub const IMAGE_EXTENSIONS: [&str; 5] = ["jpg", "jpeg", "png", "tif", "tiff"];

/// Options of photo ingest.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ImageIngestOptions {
    /// Smallest accepted width and height, in pixels (default 32): features need some room.
    pub min_dimension: u32,
    /// Fewest images a folder must hold (default 2).
    pub min_images: usize,
    /// Skip unreadable or corrupt image files with a warning instead of failing (default false).
    pub skip_unreadable: bool,
}

impl ImageIngestOptions {
    /// Checks option ranges for ingest; the error names the option. (Listing a folder with
    /// [`list_image_folder`] accepts any `min_images`, 0 included.)
    pub fn validate(&self) -> Result<()> {
        if self.min_images < 2 {
            return Err(IoError::InvalidOption {
                option: "min_images",
                reason: "--min-images must be at least 2: one view cannot be reconstructed".into(),
            });
        }
        Ok(())
    }
}

impl Default for ImageIngestOptions {
    fn default() -> Self {
        Self {
            min_dimension: 32,
            min_images: 2,
            skip_unreadable: false,
        }
    }
}

/// EXIF facts that matter to reconstruction; every field is optional.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ExifInfo {
    pub make: Option<String>,
    pub model: Option<String>,
    /// Focal length in millimetres (`FocalLength`).
    pub focal_length_mm: Option<f64>,
    /// 35 mm-equivalent focal length in millimetres (`FocalLengthIn35mmFilm`).
    pub focal_length_35mm: Option<f64>,
    /// Focal-plane resolution in pixels per millimetre, when the camera records it.
    pub focal_plane_px_per_mm: Option<f64>,
    /// EXIF orientation tag 1–8.
    pub orientation: Option<u32>,
}

impl ExifInfo {
    /// Focal length prior in pixels for an (oriented) image of `width × height`, or `None` when EXIF
    /// cannot tell. Uses the 35 mm equivalent on the diagonal (43.27 mm), else the focal-plane resolution.
    pub fn focal_prior_px(&self, width: u32, height: u32) -> Option<f64> {
        let diag = ((width as f64).powi(2) + (height as f64).powi(2)).sqrt();
        if let Some(f35) = self.focal_length_35mm.filter(|f| *f > 0.0) {
            return Some(f35 / 43.266_615 * diag);
        }
        match (self.focal_length_mm, self.focal_plane_px_per_mm) {
            (Some(f), Some(res)) if f > 0.0 && res > 0.0 => Some(f * res),
            _ => None,
        }
    }

    /// A key telling apart physical cameras and zoom settings, used to split intrinsics groups.
    pub fn camera_key(&self) -> String {
        format!(
            "{}|{}|{}",
            self.make.as_deref().unwrap_or(""),
            self.model.as_deref().unwrap_or(""),
            self.focal_length_mm
                .map(|f| format!("{f:.2}"))
                .unwrap_or_default()
        )
    }
}

/// What ingest learnt about one image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageInfo {
    pub path: PathBuf,
    /// File name inside the input folder (the COLMAP image name).
    pub name: String,
    /// Width and height after the EXIF orientation is applied.
    pub width: u32,
    pub height: u32,
    /// Bits per channel of the file (8 or 16; 32 for float TIFF).
    pub bit_depth: u8,
    /// 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA).
    pub channels: u8,
    pub exif: ExifInfo,
    /// EXIF-derived focal length in pixels, when available (a prior only).
    pub focal_prior_px: Option<f64>,
}

/// A decoded, oriented image and its metadata.
#[derive(Clone, Debug)]
pub struct LoadedImage {
    pub info: ImageInfo,
    pub image: DynamicImage,
}

/// The outcome of listing a folder.
#[derive(Clone, Debug, Default)]
pub struct FolderListing {
    /// Image files, sorted by name.
    pub images: Vec<PathBuf>,
    /// Files that were not taken, with the reason (non-image files, sub-folders are ignored silently).
    pub skipped: Vec<(PathBuf, String)>,
}

/// True when the file name has one of [`IMAGE_EXTENSIONS`].
pub fn has_image_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
        .unwrap_or(false)
}

/// Lists the image files of a folder (not recursive), sorted by name; other files are reported in
/// `skipped`. Fails when the folder does not exist or holds fewer than `min_images` images.
pub fn list_image_folder(dir: &Path, opts: &ImageIngestOptions) -> Result<FolderListing> {
    if !dir.exists() {
        return Err(IoError::NotFound {
            path: dir.to_path_buf(),
        });
    }
    if !dir.is_dir() {
        return Err(IoError::Input {
            path: dir.to_path_buf(),
            reason: "is not a folder of images".into(),
        });
    }
    let mut listing = FolderListing::default();
    let entries = fs::read_dir(dir).map_err(|e| IoError::io(dir, e))?;
    for entry in entries {
        let entry = entry.map_err(|e| IoError::io(dir, e))?;
        let path = entry.path();
        if path.is_dir() {
            continue;
        }
        let hidden = path
            .file_name()
            .and_then(|n| n.to_str())
            .map(|n| n.starts_with('.'))
            .unwrap_or(false);
        if hidden {
            continue;
        }
        if has_image_extension(&path) {
            listing.images.push(path);
        } else {
            listing
                .skipped
                .push((path, "not a JPEG, PNG or TIFF file".into()));
        }
    }
    listing.images.sort();
    listing.skipped.sort();
    if listing.images.len() < opts.min_images {
        let reason = if listing.images.is_empty() {
            format!(
                "contains no images (JPEG, PNG or TIFF); need at least {}",
                opts.min_images
            )
        } else {
            format!(
                "contains only {} image(s); need at least {} views of the scene",
                listing.images.len(),
                opts.min_images
            )
        };
        return Err(IoError::Input {
            path: dir.to_path_buf(),
            reason,
        });
    }
    Ok(listing)
}

/// Reads the EXIF block of a file, if any. Never fails: broken EXIF is simply absent.
pub fn read_exif(path: &Path, bytes: &[u8]) -> ExifInfo {
    let reader = exif::Reader::new();
    let Ok(ex) = reader.read_from_container(&mut Cursor::new(bytes)) else {
        tracing::debug!("{}: no EXIF", path.display());
        return ExifInfo::default();
    };
    let rational = |tag| {
        ex.get_field(tag, exif::In::PRIMARY)
            .and_then(|f| match &f.value {
                exif::Value::Rational(v) => v.first().map(|r| r.to_f64()).filter(|v| v.is_finite()),
                exif::Value::Short(v) => v.first().map(|&s| s as f64),
                exif::Value::Long(v) => v.first().map(|&s| s as f64),
                _ => None,
            })
    };
    let uint = |tag| {
        ex.get_field(tag, exif::In::PRIMARY)
            .and_then(|f| f.value.get_uint(0))
    };
    let ascii = |tag| {
        ex.get_field(tag, exif::In::PRIMARY)
            .and_then(|f| match &f.value {
                exif::Value::Ascii(v) => v
                    .first()
                    .map(|s| String::from_utf8_lossy(s).trim().to_string()),
                _ => None,
            })
    };
    // Focal-plane resolution: unit 2 = inch, 3 = cm, 4 = mm.
    let fp_res = rational(exif::Tag::FocalPlaneXResolution).and_then(|r| {
        let per_mm = match uint(exif::Tag::FocalPlaneResolutionUnit).unwrap_or(2) {
            2 => r / 25.4,
            3 => r / 10.0,
            4 => r,
            _ => return None,
        };
        (per_mm > 0.0).then_some(per_mm)
    });
    ExifInfo {
        make: ascii(exif::Tag::Make),
        model: ascii(exif::Tag::Model),
        focal_length_mm: rational(exif::Tag::FocalLength).filter(|f| *f > 0.0),
        focal_length_35mm: uint(exif::Tag::FocalLengthIn35mmFilm)
            .map(|v| v as f64)
            .filter(|f| *f > 0.0),
        focal_plane_px_per_mm: fp_res,
        orientation: uint(exif::Tag::Orientation),
    }
}

/// A JPEG must end with the end-of-image marker; decoders often paper over truncation with grey.
fn check_jpeg_complete(path: &Path, bytes: &[u8]) -> Result<()> {
    let is_jpeg = bytes.len() >= 2 && bytes[0] == 0xFF && bytes[1] == 0xD8;
    if !is_jpeg {
        return Ok(());
    }
    let tail = &bytes[bytes.len().saturating_sub(64 * 1024)..];
    let has_eoi = tail.windows(2).any(|w| w == [0xFF, 0xD9]);
    if !has_eoi {
        return Err(IoError::Decode {
            path: path.to_path_buf(),
            reason: "truncated JPEG: the end-of-image marker is missing".into(),
        });
    }
    Ok(())
}

/// Decodes one image, applies its EXIF orientation and reads its metadata.
pub fn load_image(path: &Path, opts: &ImageIngestOptions) -> Result<LoadedImage> {
    let bytes = fs::read(path).map_err(|e| IoError::io(path, e))?;
    if bytes.is_empty() {
        return Err(IoError::Decode {
            path: path.to_path_buf(),
            reason: "the file is empty".into(),
        });
    }
    check_jpeg_complete(path, &bytes)?;
    let decode_err = |e: image::ImageError| IoError::Decode {
        path: path.to_path_buf(),
        reason: e.to_string(),
    };
    let reader = ImageReader::new(BufReader::new(Cursor::new(&bytes)))
        .with_guessed_format()
        .map_err(|e| IoError::io(path, e))?;
    let mut decoder = reader.into_decoder().map_err(decode_err)?;
    let orientation = decoder
        .orientation()
        .unwrap_or(image::metadata::Orientation::NoTransforms);
    let color = decoder.color_type();
    let mut image = DynamicImage::from_decoder(decoder).map_err(decode_err)?;
    image.apply_orientation(orientation);
    let (width, height) = (image.width(), image.height());
    if width < opts.min_dimension || height < opts.min_dimension {
        return Err(IoError::Input {
            path: path.to_path_buf(),
            reason: format!(
                "image is only {width}×{height} pixels; at least {0}×{0} is needed to find features",
                opts.min_dimension
            ),
        });
    }
    let exif = read_exif(path, &bytes);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let focal_prior_px = exif.focal_prior_px(width, height);
    let info = ImageInfo {
        path: path.to_path_buf(),
        name,
        width,
        height,
        bit_depth: (color.bits_per_pixel() / color.channel_count() as u16) as u8,
        channels: color.channel_count(),
        exif,
        focal_prior_px,
    };
    Ok(LoadedImage { info, image })
}

#[cfg(test)]
#[path = "images_tests.rs"]
mod tests;
