//! Harris corners and ZNCC patch matching against exact ground truth (issue #3, paper §2.1):
//! sub-pixel corner accuracy on an analytically anti-aliased checkerboard, and the precision of ZNCC
//! matches between two rendered views with a small baseline, checked by ray casting the scene.

mod common;
use common::{back_project, project_visible};
use std::time::Instant;

use handheld_features::harris::{detect_harris, HarrisOptions, HarrisZncc};
use handheld_features::zncc::{match_zncc, zncc, zncc_patch, ZnccMatchOptions};
use handheld_features::{FeatureDetector, GrayImage};
use nalgebra::Vector2;

/// A checkerboard of `cell`-pixel squares rotated by `angle` about `origin`, box-filtered over each
/// pixel area with `ss²` samples; returns the image and its inner corners (lattice points).
fn checkerboard(
    w: usize,
    h: usize,
    cell: f64,
    angle: f64,
    origin: (f64, f64),
    ss: usize,
) -> (GrayImage, Vec<(f64, f64)>) {
    let (c, s) = (angle.cos(), angle.sin());
    let mut img = GrayImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for j in 0..ss {
                for i in 0..ss {
                    let px = x as f64 - 0.5 + (i as f64 + 0.5) / ss as f64 - origin.0;
                    let py = y as f64 - 0.5 + (j as f64 + 0.5) / ss as f64 - origin.1;
                    let (u, v) = ((c * px + s * py) / cell, (-s * px + c * py) / cell);
                    acc += if (u.floor() + v.floor()) as i64 % 2 == 0 {
                        0.2
                    } else {
                        0.8
                    };
                }
            }
            img.data[y * w + x] = (acc / (ss * ss) as f64) as f32;
        }
    }
    let mut corners = Vec::new();
    for j in -40..40 {
        for i in -40..40 {
            let (u, v) = (i as f64 * cell, j as f64 * cell);
            corners.push((origin.0 + c * u - s * v, origin.1 + s * u + c * v));
        }
    }
    (img, corners)
}

#[test]
fn harris_finds_checkerboard_corners_with_subpixel_accuracy() {
    let (w, h) = (240, 180);
    let mut worst = 0f64;
    let mut all = Vec::new();
    for (k, &(angle, ox, oy)) in [
        (0.3f64, 120.37, 90.81),
        (-0.5, 117.72, 88.15),
        (0.05, 121.5, 90.25),
    ]
    .iter()
    .enumerate()
    {
        let (img, truth) = checkerboard(w, h, 17.0, angle, (ox, oy), 8);
        let kps = detect_harris(&img, &HarrisOptions::default());
        let inner: Vec<_> = truth
            .iter()
            .filter(|&&(x, y)| x > 12.0 && y > 12.0 && x < w as f64 - 13.0 && y < h as f64 - 13.0)
            .collect();
        assert!(inner.len() > 80, "board {k}: {} inner corners", inner.len());
        let mut found = 0;
        for &&(tx, ty) in &inner {
            let best = kps
                .iter()
                .map(|kp| (kp.x as f64 - tx).hypot(kp.y as f64 - ty))
                .fold(f64::INFINITY, f64::min);
            if best < 1.5 {
                found += 1;
                worst = worst.max(best);
                all.push(best);
            }
        }
        // Every detection is a true corner: nothing else in the image has a corner response.
        let spurious = kps
            .iter()
            .filter(|kp| {
                truth
                    .iter()
                    .all(|&(tx, ty)| (kp.x as f64 - tx).hypot(kp.y as f64 - ty) > 1.5)
            })
            .count();
        // One detection per corner.
        for (i, a) in kps.iter().enumerate() {
            assert!(
                kps[i + 1..]
                    .iter()
                    .all(|b| (a.x - b.x).hypot(a.y - b.y) > 3.0),
                "board {k}: duplicate near ({}, {})",
                a.x,
                a.y
            );
        }
        println!(
            "board {k}: {} corners, {found}/{} found, {spurious} spurious",
            kps.len(),
            inner.len()
        );
        assert_eq!(found, inner.len(), "board {k}: missed corners");
        assert_eq!(spurious, 0, "board {k}");
    }
    all.sort_by(f64::total_cmp);
    let mean = all.iter().sum::<f64>() / all.len() as f64;
    println!(
        "harris sub-pixel error: mean {mean:.4} px, median {:.4}, max {worst:.4}",
        all[all.len() / 2]
    );
    assert!(mean < 0.1, "mean error {mean}");
    assert!(worst < 0.2, "max error {worst}");
}

#[test]
fn harris_bucketing_spreads_and_caps_the_corners() {
    let (img, _) = checkerboard(320, 240, 9.0, 0.2, (160.3, 120.6), 4);
    let opts = HarrisOptions {
        max_features: 100,
        cell_size: 80,
        ..HarrisOptions::default()
    };
    let kps = detect_harris(&img, &opts);
    assert_eq!(kps.len(), 100);
    // 4 × 3 cells, quota ⌈100/12⌉ = 9: every cell is populated.
    let mut count = [0usize; 12];
    for kp in &kps {
        count[(kp.y as usize / 80) * 4 + kp.x as usize / 80] += 1;
    }
    assert!(count.iter().all(|&c| c >= 5), "{count:?}");
    assert!(kps.windows(2).all(|p| p[0].response >= p[1].response));
}

#[test]
fn harris_zncc_descriptors_are_normalised_patches() {
    let (img, _) = checkerboard(160, 120, 13.0, 0.4, (80.2, 60.7), 4);
    let det = HarrisZncc::default();
    let f = det.detect(&img);
    assert_eq!(f.descriptors.dim, 49);
    assert_eq!(f.descriptors.len(), f.keypoints.len());
    assert!(!f.keypoints.is_empty());
    for (i, kp) in f.keypoints.iter().enumerate() {
        let d = f.descriptors.row(i);
        let norm: f32 = d.iter().map(|v| v * v).sum();
        let mean: f32 = d.iter().sum::<f32>() / 49.0;
        assert!((norm - 1.0).abs() < 1e-4 && mean.abs() < 1e-5);
        let p = zncc_patch(&img, kp.x, kp.y, 3).expect("textured");
        assert!((zncc(d, &p) - 1.0).abs() < 1e-4);
    }
    // Matching an image with itself pairs every feature with itself.
    let m = match_zncc(
        &f,
        &f,
        &ZnccMatchOptions {
            max_disparity: Some(5.0),
            ..Default::default()
        },
    );
    assert_eq!(m.len(), f.keypoints.len());
    assert!(m.iter().all(|&(i, j, s)| i == j && s > 0.999));
}

#[test]
fn zncc_matches_on_a_small_baseline_pair_are_correct() {
    let t0 = Instant::now();
    let seq = common::orbit_pair(3.0);
    let t_render = t0.elapsed().as_secs_f64();
    let imgs: Vec<GrayImage> = seq.images.iter().map(GrayImage::from_rgb8).collect();
    let t1 = Instant::now();
    let det = HarrisZncc::default();
    let (f0, f1) = (det.detect(&imgs[0]), det.detect(&imgs[1]));
    let t_detect = t1.elapsed().as_secs_f64();
    let t2 = Instant::now();
    let m = match_zncc(
        &f0,
        &f1,
        &ZnccMatchOptions {
            max_disparity: Some(40.0),
            ..Default::default()
        },
    );
    let t_match = t2.elapsed().as_secs_f64();
    let t3 = Instant::now();
    let brute = match_zncc(&f0, &f1, &ZnccMatchOptions::default());
    let t_brute = t3.elapsed().as_secs_f64();
    let (mut good, mut checked) = (0, 0);
    let mut errors = Vec::new();
    for &(i, j, _) in &m {
        let (a, b) = (&f0.keypoints[i as usize], &f1.keypoints[j as usize]);
        let Some(p) = back_project(&seq, 0, a.x as f64, a.y as f64) else {
            continue;
        };
        let Some(q) = project_visible(&seq, 1, &p) else {
            continue;
        };
        let e = (q - Vector2::new(b.x as f64, b.y as f64)).norm();
        checked += 1;
        errors.push(e);
        if e <= 1.5 {
            good += 1;
        }
    }
    errors.sort_by(f64::total_cmp);
    let precision = good as f64 / checked.max(1) as f64;
    println!(
        "render {t_render:.2}s, detect {t_detect:.2}s ({} + {} features), match {t_match:.3}s ({} matches), brute force {t_brute:.2}s ({} matches)",
        f0.keypoints.len(),
        f1.keypoints.len(),
        m.len(),
        brute.len()
    );
    println!("checked {checked}, correct within 1.5 px {good}: precision {precision:.3}, median error {:.3} px", errors[errors.len() / 2]);
    assert!(m.len() > 300, "{} matches", m.len());
    assert!(checked > 200);
    assert!(precision >= 0.9, "precision {precision}");
}
