//! The report's binary encodings: JPEG (thumbnails, the mesh atlas) and base64 (the scene's
//! arrays and the atlas's data URI).

use std::path::Path;

use base64::Engine;
use image::RgbImage;

use crate::input::{ReportError, Result};

/// `img` as a JPEG of `quality`; `path` names it in the error.
pub(crate) fn jpeg(img: &RgbImage, quality: u8, path: &Path) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, quality)
        .encode_image(img)
        .map_err(|e| ReportError::Encode {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })?;
    Ok(out)
}

/// `bytes` in standard base64.
pub(crate) fn b64(bytes: &[u8]) -> String {
    base64::engine::general_purpose::STANDARD.encode(bytes)
}
