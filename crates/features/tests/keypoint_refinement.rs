//! Multi-view keypoint refinement on an exactly known warp: image B is image A under an affine map,
//! B's keypoints are the true positions plus noise, and refinement must bring them back.

use handheld_features::refine::{
    refine_track_keypoints, KeypointFrame, KeypointRefinementOptions, PairMatches,
};
use handheld_features::GrayImage;

/// A smooth, non-repetitive texture: a sum of sinusoids at incommensurate frequencies.
fn texture(x: f64, y: f64) -> f32 {
    let waves = [
        (0.213, 0.071, 0.0),
        (-0.097, 0.187, 1.3),
        (0.151, -0.133, 2.1),
        (0.043, 0.311, 0.7),
        (0.271, 0.229, 2.9),
    ];
    let s: f64 = waves
        .iter()
        .map(|(a, b, p)| (a * x + b * y + p).sin())
        .sum();
    (0.5 + 0.09 * s) as f32
}

fn image(w: usize, h: usize, f: impl Fn(f64, f64) -> f32) -> GrayImage {
    let mut img = GrayImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            img.data[y * w + x] = f(x as f64, y as f64);
        }
    }
    img
}

#[test]
fn refinement_recovers_affine_warped_keypoints() {
    let (w, h) = (320usize, 240usize);
    // B(x) = A(M⁻¹(x − c) + c): B sees A rotated by 8°, scaled by 1.1 about the centre, shifted.
    let (th, s, shift) = (8f64.to_radians(), 1.1, (3.3, -2.1));
    let c = (w as f64 / 2.0, h as f64 / 2.0);
    let fwd = |x: f64, y: f64| {
        let (u, v) = (x - c.0, y - c.1);
        (
            c.0 + s * (th.cos() * u - th.sin() * v) + shift.0,
            c.1 + s * (th.sin() * u + th.cos() * v) + shift.1,
        )
    };
    let inv = |x: f64, y: f64| {
        let (u, v) = ((x - shift.0 - c.0) / s, (y - shift.1 - c.1) / s);
        (
            c.0 + th.cos() * u + th.sin() * v,
            c.1 - th.sin() * u + th.cos() * v,
        )
    };
    let a = image(w, h, texture);
    let b = image(w, h, |x, y| {
        let (u, v) = inv(x, y);
        texture(u, v)
    });
    // A grid of keypoints in A; B's are the true positions plus a deterministic 0.4–0.8 px error.
    let mut ka = Vec::new();
    let mut kb = Vec::new();
    let mut truth = Vec::new();
    for (k, (gx, gy)) in (0..6)
        .flat_map(|i| (0..4).map(move |j| (60.0 + 40.0 * i as f64, 60.0 + 40.0 * j as f64)))
        .enumerate()
    {
        let (tx, ty) = fwd(gx, gy);
        let ang = k as f64 * 2.399;
        let r = 0.4 + 0.4 * ((k * 7 % 5) as f64 / 4.0);
        ka.push(KeypointFrame {
            x: gx as f32,
            y: gy as f32,
            scale: 2.0,
            orientation: 0.0,
        });
        kb.push(KeypointFrame {
            x: (tx + r * ang.cos()) as f32,
            y: (ty + r * ang.sin()) as f32,
            scale: 2.2,
            orientation: th as f32,
        });
        truth.push((tx, ty));
    }
    let matches: Vec<(u32, u32)> = (0..ka.len() as u32).map(|i| (i, i)).collect();
    let pairs = [PairMatches {
        a: 0,
        b: 1,
        matches: &matches,
    }];
    let imgs = [a, b];
    let load = |i: usize| -> Result<GrayImage, String> { Ok(imgs[i].clone()) };
    let (out, summary) = refine_track_keypoints(
        &[ka.clone(), kb.clone()],
        &pairs,
        &load,
        &KeypointRefinementOptions::default(),
        &|| {},
    )
    .expect("refinement");
    assert_eq!(summary.tracks, ka.len());
    assert_eq!(summary.moved, ka.len(), "{summary:?}");
    // The references (image A, the finer scale) stay where they were detected.
    for (k, p) in out[0].iter().enumerate() {
        assert_eq!((p[0], p[1]), (ka[k].x, ka[k].y));
    }
    let before: Vec<f64> = kb
        .iter()
        .zip(&truth)
        .map(|(k, t)| (k.x as f64 - t.0).hypot(k.y as f64 - t.1))
        .collect();
    let after: Vec<f64> = out[1]
        .iter()
        .zip(&truth)
        .map(|(p, t)| (p[0] as f64 - t.0).hypot(p[1] as f64 - t.1))
        .collect();
    let max_after = after.iter().cloned().fold(0.0, f64::max);
    let min_before = before.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(min_before >= 0.39, "{min_before}");
    let mut sorted = after.clone();
    sorted.sort_by(f64::total_cmp);
    let median_after = sorted[sorted.len() / 2];
    println!(
        "error before ≥ {min_before:.2} px; after: median {median_after:.3}, max {max_after:.3} px"
    );
    assert!(
        median_after < 0.05,
        "median refined error {median_after} px"
    );
    assert!(
        max_after < 0.1,
        "refined keypoints are up to {max_after} px from the truth"
    );
}
