//! End-to-end tests of [`match_rectified`] on a synthetic pair with known disparities.

use super::*;
use crate::options::{HoleFill, SgmPaths};
use crate::synthetic::{bad_percent, render, Scene};

fn opts(method: StereoMethod, max_disparity: i32) -> StereoOptions {
    StereoOptions {
        max_disparity,
        ..StereoOptions::for_method(method)
    }
}

/// Checks accuracy against the truth: dense bad1 over every pixel, the sub-pixel background value,
/// and that the left–right check invalidated the occluded strip left of the box.
fn check(method: StereoMethod, o: &StereoOptions, max_bad1: f64) {
    let scene = Scene::default();
    let pair = render(&scene);
    let d = match_rectified(&pair.left, &pair.right, o).expect("matching runs");
    let w = scene.width;
    assert_eq!((d.width, d.height), (w, scene.height));
    // Dense output (occluded pixels filled with the background) against the truth everywhere.
    let all = bad_percent(&d.data, &pair.truth, |_| true, 1.0);
    assert!(all < max_bad1, "{method:?}: dense bad1 {all:.2}%");
    // Measured pixels alone are nearly all right.
    let measured: Vec<f32> = d
        .data
        .iter()
        .zip(&d.valid)
        .map(|(v, ok)| if *ok { *v } else { f32::NAN })
        .collect();
    let wrong = bad_percent(&measured, &pair.truth, |i| d.valid[i], 1.0);
    assert!(
        wrong < 1.0,
        "{method:?}: {wrong:.2}% of measured pixels off by > 1 px"
    );
    // Sub-pixel: the background plane sits at 7.3, not at the integer 7.
    let mut bg: Vec<f32> = (0..w * scene.height)
        .filter(|&i| d.valid[i] && pair.truth[i] == scene.d_bg)
        .map(|i| d.data[i])
        .collect();
    bg.sort_by(f32::total_cmp);
    let median = bg[bg.len() / 2];
    assert!(
        (median - scene.d_bg).abs() < 0.2,
        "{method:?}: background median {median}"
    );
    // Occluded strip (away from the box's top and bottom edges): flagged, not measured.
    let strip: Vec<usize> = (scene.box_y.0 + 3..scene.box_y.1 - 3)
        .flat_map(|y| (0..w).map(move |x| y * w + x))
        .filter(|&i| pair.occluded[i])
        .collect();
    assert!(strip.len() > 300, "strip of {} pixels", strip.len());
    let flagged = strip.iter().filter(|&&i| !d.valid[i]).count() as f64 / strip.len() as f64;
    assert!(
        flagged > 0.8,
        "{method:?}: only {:.0}% of the occluded strip flagged",
        100.0 * flagged
    );
}

#[test]
fn sgm_recovers_plane_and_box() {
    check(StereoMethod::Sgm, &opts(StereoMethod::Sgm, 31), 2.0);
}

#[test]
fn sgm_with_four_paths_recovers_plane_and_box() {
    let o = StereoOptions {
        sgm_paths: SgmPaths::Four,
        ..opts(StereoMethod::Sgm, 31)
    };
    check(StereoMethod::Sgm, &o, 3.0);
}

#[test]
fn dp_recovers_plane_and_box() {
    check(StereoMethod::Dp, &opts(StereoMethod::Dp, 31), 3.0);
}

#[test]
fn sgm_in_bands_matches_the_truth() {
    // 160 × 24 disparities × 5 bytes = 19 200 bytes per row: 2.1 MB hold 109 rows, so the 120
    // rows are split into ten bands with 48 rows of context around a core of 13 rows.
    let scene = Scene {
        d_fg: 14.0,
        ..Scene::default()
    };
    let pair = render(&scene);
    let mut o = opts(StereoMethod::Sgm, 23);
    let whole = match_rectified(&pair.left, &pair.right, &o).expect("single band");
    o.max_volume_bytes = 2_100_000;
    let banded = match_rectified(&pair.left, &pair.right, &o).expect("banded");
    let bad_whole = bad_percent(&whole.data, &pair.truth, |_| true, 1.0);
    let bad_banded = bad_percent(&banded.data, &pair.truth, |_| true, 1.0);
    assert!(
        bad_banded < 3.0 && bad_whole < 3.0,
        "whole {bad_whole:.2}%, banded {bad_banded:.2}%"
    );
}

#[test]
fn colour_input_and_missing_without_filling() {
    let scene = Scene::default();
    let pair = render(&scene);
    let rgb = |m: &FloatMap| FloatMap {
        width: m.width,
        height: m.height,
        channels: 3,
        data: m.data.iter().flat_map(|v| [*v, *v, *v]).collect(),
    };
    let o = StereoOptions {
        hole_fill: HoleFill::None,
        ..opts(StereoMethod::Sgm, 31)
    };
    let d = match_rectified(&rgb(&pair.left), &rgb(&pair.right), &o).expect("colour input");
    // Without filling, exactly the invalid pixels are missing.
    for (v, ok) in d.data.iter().zip(&d.valid) {
        assert_eq!(v.is_finite(), *ok);
    }
    let bad = bad_percent(
        &d.data,
        &pair.truth,
        |i| !pair.occluded[i] && i % scene.width >= 32,
        1.0,
    );
    assert!(bad < 2.0, "bad1 on visible pixels {bad:.2}%");
}

#[test]
fn reused_matcher_equals_fresh_runs() {
    let small = render(&Scene {
        width: 90,
        height: 60,
        box_x: (40, 70),
        box_y: (20, 40),
        ..Scene::default()
    });
    let large = render(&Scene::default());
    for method in [StereoMethod::Sgm, StereoMethod::Dp] {
        let o = opts(method, 31);
        let mut m = StereoMatcher::new(o.clone()).expect("valid options");
        for pair in [&large, &small, &large] {
            let reused = m.match_pair(&pair.left, &pair.right).expect("reused");
            let fresh = match_rectified(&pair.left, &pair.right, &o).expect("fresh");
            assert_eq!(reused.valid, fresh.valid);
            let same = reused
                .data
                .iter()
                .zip(&fresh.data)
                .all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
            assert!(same, "{method:?}: reused matcher differs");
        }
    }
}

#[test]
fn negative_min_disparity_keeps_the_truth() {
    let scene = Scene::default();
    let pair = render(&scene);
    for method in [StereoMethod::Sgm, StereoMethod::Dp] {
        let o = StereoOptions {
            min_disparity: -8,
            max_disparity: 23,
            ..StereoOptions::for_method(method)
        };
        let d = match_rectified(&pair.left, &pair.right, &o).expect("negative range");
        let bad = bad_percent(
            &d.data,
            &pair.truth,
            |i| !pair.occluded[i] && i % scene.width >= 24,
            1.0,
        );
        assert!(bad < 3.0, "{method:?}: bad1 {bad:.2}% on visible pixels");
    }
}

#[test]
fn tiny_images_do_not_panic() {
    for (w, h) in [(1, 1), (2, 3), (5, 1), (1, 6)] {
        let img = FloatMap {
            width: w,
            height: h,
            channels: 1,
            data: (0..w * h).map(|i| (i * 37 % 255) as f32).collect(),
        };
        for method in [StereoMethod::Sgm, StereoMethod::Dp] {
            let o = StereoOptions {
                max_disparity: 3,
                ..StereoOptions::for_method(method)
            };
            let d = match_rectified(&img, &img, &o).expect("tiny image");
            assert_eq!(d.data.len(), w * h);
        }
    }
    let empty = FloatMap {
        width: 0,
        height: 0,
        channels: 1,
        data: vec![],
    };
    assert!(matches!(
        match_rectified(&empty, &empty, &StereoOptions::default()),
        Err(DenseError::InvalidImage { .. })
    ));
}

#[test]
fn coarse_to_fine_keeps_the_truth_over_a_wide_range() {
    // A 320×240 pair whose box stands 110 px in front of the background, searched over 0..=255:
    // levels of 320, 160 and 80 pixels, the coarsest over the whole (halved) range, the others
    // over 32 disparities per pixel.
    let scene = Scene {
        width: 320,
        height: 240,
        d_bg: 40.3,
        d_fg: 150.0,
        box_x: (170, 280),
        box_y: (60, 180),
    };
    let pair = render(&scene);
    let mut o = opts(StereoMethod::Sgm, 255);
    o.hole_fill = HoleFill::None;
    o.pyramid_min_size = 64;
    o.pyramid_disparities = 32;
    let fine = match_rectified(&pair.left, &pair.right, &o).expect("coarse to fine");
    o.pyramid_disparities = 0;
    let whole = match_rectified(&pair.left, &pair.right, &o).expect("whole range");
    // Pixels seen by both views, measured and right (missing counts as bad).
    let bad = |d: &Disparity| bad_percent(&d.data, &pair.truth, |i| !pair.occluded[i], 1.0);
    let measured_wrong = |d: &Disparity| bad_percent(&d.data, &pair.truth, |i| d.valid[i], 1.0);
    let (bf, bw) = (bad(&fine), bad(&whole));
    // What coarse to fine loses is a band of about 4 px along the box's 110-px depth edges, where
    // a window of 32 cannot hold both sides (measured: 1.2 % of the pixels).
    assert!(bf <= bw + 1.5, "coarse to fine {bf:.2}%, whole {bw:.2}%");
    // Wrong beyond the pixel size it was measured at (values the half-size level kept are
    // half-size measurements). The wrong ones sit in the first rows and columns inside the box,
    // where the coarse level fattened the background by a pixel and the window followed it.
    let wrong_scaled = |d: &Disparity| {
        let n = (0..d.data.len()).filter(|&i| d.valid[i]).count();
        let bad = (0..d.data.len())
            .filter(|&i| d.valid[i])
            .filter(|&i| (d.data[i] - pair.truth[i]).abs() as f64 > d.scale_at(0, i))
            .count();
        100.0 * bad as f64 / n.max(1) as f64
    };
    let (wf, ww) = (wrong_scaled(&fine), measured_wrong(&whole));
    assert!(
        wf < 1.2 && ww < 0.5,
        "measured and wrong: {wf:.2}% vs {ww:.2}%"
    );
    let kept = fine.scale.iter().filter(|s| **s > 1).count();
    assert!(kept > 0, "no half-size value kept");
    // The right map (for linking) is right too, within the pixel size it was measured at.
    let right_ok = fine
        .right
        .iter()
        .enumerate()
        .filter(|(_, r)| r.is_finite())
        .filter(|(i, r)| {
            let (x, y) = (i % scene.width, i / scene.width);
            let xl = (x as f32 + **r).round() as usize;
            xl < scene.width
                && f64::from((pair.truth[y * scene.width + xl] - **r).abs()) <= fine.scale_at(1, *i)
        })
        .count() as f64
        / fine.right.iter().filter(|r| r.is_finite()).count().max(1) as f64;
    // Whole pixels (no sub-pixel fit on the right map); the misses sit along the box's edges.
    assert!(right_ok > 0.97, "right map {:.3} consistent", right_ok);
}
