//! The twin test on a repeated pattern: two portrait views, 36° apart on the phone's orbit, of a
//! wall papered with one motif in a half-drop (`Scene::wallpaper_scene`), with an object on it.
//! Without the test most of the pair's verified matches join copies of the motif a period apart
//! (they agree with one another, and along the epipolar lines the fundamental matrix cannot
//! tell: here four in five); with it, few do, and the right matches stay. A match is correct when the first keypoint, back-projected by an exact
//! ray cast, projects within 1.5 px of the second.

mod common;
use common::{back_project, project_visible};

use handheld_features::extract::{extract_features, ExtractionOptions};
use handheld_features::verify::{match_and_verify, PairVerificationOptions};
use handheld_testkit::{render_sequence_with_scene, PathOptions, Scene, SequenceOptions};
use image::DynamicImage;
use nalgebra::Vector2;

#[test]
fn copies_of_a_repeated_motif_do_not_pass_as_matches() {
    let opts = SequenceOptions {
        seed: 1,
        width: 360,
        height: 640,
        num_frames: 2,
        samples_per_axis: 2,
        focal_px: Some(475.0),
        path: PathOptions {
            sweep: 36.0,
            seed: 1,
            ..PathOptions::wall_orbit(2)
        },
        ..SequenceOptions::default()
    };
    let seq = render_sequence_with_scene(Scene::wallpaper_scene(1), &opts).expect("valid options");
    let feats: Vec<_> = seq
        .images
        .iter()
        .map(|im| {
            extract_features(
                &DynamicImage::ImageRgb8(im.clone()),
                &ExtractionOptions::default(),
            )
        })
        .collect();
    let (f1, f2) = (&feats[0], &feats[1]);
    let run = |twin_test: bool| {
        let v = match_and_verify(
            0,
            1,
            f1,
            f2,
            &PairVerificationOptions {
                twin_test,
                ..Default::default()
            },
        );
        let (mut good, mut scored) = (0, 0);
        for &(a, b) in &v.inliers {
            let (ka, kb) = (&f1.keypoints[a as usize], &f2.keypoints[b as usize]);
            let Some(p) = back_project(&seq, 0, ka.x as f64, ka.y as f64) else {
                continue;
            };
            let Some(gt) = project_visible(&seq, 1, &p) else {
                continue;
            };
            scored += 1;
            good += usize::from((gt - Vector2::new(kb.x as f64, kb.y as f64)).norm() <= 1.5);
        }
        (good, scored)
    };
    let (good_off, scored_off) = run(false);
    let (good_on, scored_on) = run(true);
    println!(
        "{} and {} keypoints; without the twin test {good_off} of {scored_off} verified matches correct, with it {good_on} of {scored_on}",
        f1.keypoints.len(),
        f2.keypoints.len()
    );
    let share = |g: usize, s: usize| g as f64 / s.max(1) as f64;
    // The premise: the pattern's copies do pass without the test.
    assert!(
        share(good_off, scored_off) < 0.8,
        "the scene does not test the copies"
    );
    // Most copies go, and few right matches with them.
    let (wrong_off, wrong_on) = (scored_off - good_off, scored_on - good_on);
    assert!(
        wrong_on * 4 <= wrong_off,
        "{wrong_on} wrong against {wrong_off}"
    );
    assert!(
        good_on * 10 >= good_off * 9,
        "{good_on} right against {good_off}"
    );
    assert!(share(good_on, scored_on) >= 0.8);
}
