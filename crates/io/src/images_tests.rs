//! Ingest tests on files written here: every format and depth the issue names, EXIF orientation and
//! focal length, and each bad-input case with its error message.

use super::*;
use image::{ImageBuffer, Luma, Rgb, RgbImage};

fn gradient(w: u32, h: u32) -> RgbImage {
    ImageBuffer::from_fn(w, h, |x, y| {
        Rgb([
            (x * 255 / w) as u8,
            (y * 255 / h) as u8,
            ((x + y) % 256) as u8,
        ])
    })
}

fn jpeg_bytes(img: &RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95);
    img.write_with_encoder(enc).unwrap();
    out
}

/// A minimal EXIF APP1 segment: orientation 6 (rotate 90° clockwise), FocalLength 5 mm,
/// FocalLengthIn35mmFilm 28 mm.
fn exif_app1() -> Vec<u8> {
    let mut t: Vec<u8> = vec![b'I', b'I', 0x2A, 0, 8, 0, 0, 0];
    t.extend_from_slice(&[2, 0]);
    t.extend_from_slice(&[0x12, 0x01, 3, 0, 1, 0, 0, 0, 6, 0, 0, 0]);
    t.extend_from_slice(&[0x69, 0x87, 4, 0, 1, 0, 0, 0, 38, 0, 0, 0]);
    t.extend_from_slice(&[0, 0, 0, 0]);
    t.extend_from_slice(&[2, 0]);
    t.extend_from_slice(&[0x0A, 0x92, 5, 0, 1, 0, 0, 0, 68, 0, 0, 0]);
    t.extend_from_slice(&[0x05, 0xA4, 3, 0, 1, 0, 0, 0, 28, 0, 0, 0]);
    t.extend_from_slice(&[0, 0, 0, 0]);
    t.extend_from_slice(&[50, 0, 0, 0, 10, 0, 0, 0]);
    let mut seg = vec![0xFF, 0xE1];
    let len = (2 + 6 + t.len()) as u16;
    seg.extend_from_slice(&len.to_be_bytes());
    seg.extend_from_slice(b"Exif\0\0");
    seg.extend_from_slice(&t);
    seg
}

#[test]
fn reads_every_format_and_depth() {
    let dir = tempfile::tempdir().unwrap();
    let rgb = gradient(64, 48);
    rgb.save(dir.path().join("a.png")).unwrap();
    let g16: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_fn(40, 36, |x, y| Luma([(x * 1000 + y) as u16]));
    g16.save(dir.path().join("b.png")).unwrap();
    let rgb16: ImageBuffer<Rgb<u16>, Vec<u16>> =
        ImageBuffer::from_fn(50, 40, |x, y| Rgb([x as u16 * 900, y as u16 * 700, 5]));
    rgb16.save(dir.path().join("c.tif")).unwrap();
    std::fs::write(dir.path().join("d.JPG"), jpeg_bytes(&rgb)).unwrap();
    let gray8 = image::GrayImage::from_fn(33, 33, |x, _| Luma([x as u8]));
    gray8.save(dir.path().join("e.tiff")).unwrap();

    let opts = ImageIngestOptions::default();
    let listing = list_image_folder(dir.path(), &opts).unwrap();
    assert_eq!(listing.images.len(), 5);
    let infos: Vec<_> = listing
        .images
        .iter()
        .map(|p| load_image(p, &opts).unwrap().info)
        .collect();
    let find = |n: &str| infos.iter().find(|i| i.name == n).unwrap();
    assert_eq!((find("a.png").bit_depth, find("a.png").channels), (8, 3));
    assert_eq!(
        (
            find("b.png").bit_depth,
            find("b.png").channels,
            find("b.png").width
        ),
        (16, 1, 40)
    );
    assert_eq!((find("c.tif").bit_depth, find("c.tif").channels), (16, 3));
    assert_eq!((find("d.JPG").width, find("d.JPG").height), (64, 48));
    assert_eq!((find("e.tiff").bit_depth, find("e.tiff").channels), (8, 1));
    assert!(
        infos.iter().all(|i| i.focal_prior_px.is_none()),
        "no EXIF, no prior"
    );
    // 16-bit values survive decoding.
    let b = load_image(&dir.path().join("b.png"), &opts).unwrap();
    assert_eq!(b.image.as_luma16().unwrap().get_pixel(3, 2).0[0], 3002);
}

#[test]
fn exif_orientation_and_focal_prior() {
    let dir = tempfile::tempdir().unwrap();
    // Left half black, right half white; after a 90° clockwise turn the black half is on top.
    let img = ImageBuffer::from_fn(80, 48, |x, _| {
        if x < 40 {
            Rgb([0u8, 0, 0])
        } else {
            Rgb([255u8, 255, 255])
        }
    });
    let jpg = jpeg_bytes(&img);
    let mut with_exif = jpg[..2].to_vec();
    with_exif.extend(exif_app1());
    with_exif.extend_from_slice(&jpg[2..]);
    let p = dir.path().join("rotated.jpg");
    std::fs::write(&p, &with_exif).unwrap();
    let loaded = load_image(&p, &ImageIngestOptions::default()).unwrap();
    assert_eq!(loaded.info.exif.orientation, Some(6));
    assert_eq!((loaded.info.width, loaded.info.height), (48, 80));
    let rgb = loaded.image.to_rgb8();
    assert!(
        rgb.get_pixel(24, 10).0[0] < 40,
        "top should be black after rotation"
    );
    assert!(
        rgb.get_pixel(24, 70).0[0] > 215,
        "bottom should be white after rotation"
    );
    assert_eq!(loaded.info.exif.focal_length_mm, Some(5.0));
    assert_eq!(loaded.info.exif.focal_length_35mm, Some(28.0));
    let diag = (48f64 * 48.0 + 80.0 * 80.0).sqrt();
    let prior = loaded.info.focal_prior_px.unwrap();
    assert!((prior - 28.0 / 43.266_615 * diag).abs() < 1e-9);
}

#[test]
fn truncated_jpeg_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let jpg = jpeg_bytes(&gradient(64, 64));
    let p = dir.path().join("cut.jpg");
    std::fs::write(&p, &jpg[..jpg.len() / 2]).unwrap();
    let err = load_image(&p, &ImageIngestOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("cut.jpg") && err.contains("truncated"),
        "{err}"
    );
}

#[test]
fn garbage_with_image_extension_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("fake.png");
    std::fs::write(&p, b"this is not a png").unwrap();
    let err = load_image(&p, &ImageIngestOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("fake.png") && err.contains("cannot decode"),
        "{err}"
    );
}

#[test]
fn one_pixel_image_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("dot.png");
    gradient(1, 1).save(&p).unwrap();
    let err = load_image(&p, &ImageIngestOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("dot.png") && err.contains("1×1"), "{err}");
}

#[test]
fn folder_errors_name_the_folder() {
    let dir = tempfile::tempdir().unwrap();
    let opts = ImageIngestOptions::default();
    let missing = dir.path().join("nope");
    let err = list_image_folder(&missing, &opts).unwrap_err().to_string();
    assert!(
        err.contains("nope") && err.contains("does not exist"),
        "{err}"
    );
    let err = list_image_folder(dir.path(), &opts)
        .unwrap_err()
        .to_string();
    assert!(err.contains("no images"), "{err}");
    std::fs::write(dir.path().join("notes.txt"), "hello").unwrap();
    gradient(40, 40).save(dir.path().join("1.png")).unwrap();
    assert!(
        list_image_folder(dir.path(), &opts).is_err(),
        "one image is too few"
    );
    gradient(40, 40).save(dir.path().join("2.png")).unwrap();
    let listing = list_image_folder(dir.path(), &opts).unwrap();
    assert_eq!(listing.images.len(), 2);
    assert_eq!(listing.skipped.len(), 1);
    assert!(listing.skipped[0].0.ends_with("notes.txt"));
}
