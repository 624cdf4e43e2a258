//! Key-frame selection (§3.1, footnote 1) on a rendered hand-held video tracked by KLT: key-frames
//! advance, are spaced more than one frame apart, and each consecutive key-frame pair is explained
//! by F rather than H, while the in-between frames right after a key-frame are not.

use handheld_features::keyframes::{select_keyframes, KeyframeOptions, KeyframeReason};
use handheld_features::klt::{KltOptions, KltTracker};
use handheld_features::GrayImage;
use handheld_robust::{estimate_two_view_geometry, Match2d2d, TwoViewConfiguration};
use handheld_testkit::{render_sequence, PathOptions, SequenceOptions};
use nalgebra::Vector2;

#[test]
fn keyframes_follow_the_f_versus_h_rule() {
    let n = 24;
    let opts = SequenceOptions {
        width: 320,
        height: 240,
        num_frames: n,
        samples_per_axis: 2,
        path: PathOptions {
            sweep: 10.0,
            ..PathOptions::orbit(n)
        },
        ..SequenceOptions::default()
    };
    let seq = render_sequence(&opts).unwrap();
    let mut tracker = KltTracker::new(KltOptions {
        target_features: 400,
        ..Default::default()
    })
    .unwrap();
    for img in &seq.images {
        tracker.process(&GrayImage::from_rgb8(img));
    }
    let tracks = tracker.tracks().to_vec();
    let keys = select_keyframes(&tracks, n, &KeyframeOptions::default());
    eprintln!("key-frames: {keys:?}");
    assert!(
        keys.len() >= 3,
        "expected several key-frames over a 10° orbit: {keys:?}"
    );
    assert_eq!(keys[0], (0, KeyframeReason::First));
    // Consecutive frames are too close (the reason for key-frames): most gaps span several frames.
    let mut gaps: Vec<usize> = keys.windows(2).map(|w| w[1].0 - w[0].0).collect();
    gaps.sort_unstable();
    assert!(
        gaps[gaps.len() / 2] >= 3,
        "key-frames should be spaced: {keys:?}"
    );
    for w in keys.windows(2) {
        assert!(w[1].0 > w[0].0, "{keys:?}");
        assert_eq!(w[1].1, KeyframeReason::EpipolarGeometry, "{keys:?}");
        // The pair is explained by F.
        let m: Vec<Match2d2d> = tracks
            .iter()
            .filter_map(|t| {
                let birth = t.positions.first()?.0;
                let a = t.positions.get(w[0].0.checked_sub(birth)?)?;
                let b = t.positions.get(w[1].0.checked_sub(birth)?)?;
                Some(Match2d2d::new(
                    Vector2::new(a.1 as f64, a.2 as f64),
                    Vector2::new(b.1 as f64, b.2 as f64),
                ))
            })
            .collect();
        let g = estimate_two_view_geometry(&m, &KeyframeOptions::default().two_view).unwrap();
        assert_eq!(
            g.configuration,
            TwoViewConfiguration::General,
            "pair {:?}",
            (w[0].0, w[1].0)
        );
    }
}

/// Tracks of a textured wall seen by a camera sliding along it: every frame moves the image 6 px
/// to the left (a homography explains every pair, so GRIC never prefers F), a track lives while
/// its point is in the 320-px-wide frame, and new points enter on the right. `life` caps a
/// track's length (KLT losing it early).
fn sliding_wall(n: usize, life: usize) -> Vec<handheld_features::klt::Track2d> {
    let mut tracks = Vec::new();
    let mut id = 0;
    // Points at world x = 4 px steps; a point at x is at x − 6f in frame f.
    for p in 0..((320 + 6 * n) / 4) {
        let x0 = 4.0 * p as f32 + 1.0;
        let y = 20.0 + ((p * 37) % 200) as f32;
        let frames: Vec<usize> = (0..n)
            .filter(|&f| {
                let x = x0 - 6.0 * f as f32;
                (0.0..320.0).contains(&x)
            })
            .collect();
        let Some(&birth) = frames.first() else {
            continue;
        };
        let positions: Vec<(usize, f32, f32)> = frames
            .iter()
            .take(life)
            .map(|&f| (f, x0 - 6.0 * f as f32, y))
            .collect();
        tracks.push(handheld_features::klt::Track2d {
            id,
            positions,
            alive: birth.saturating_add(life) >= n,
        });
        id += 1;
    }
    tracks
}

#[test]
fn keyframes_follow_the_motion_when_a_homography_explains_every_pair() {
    let n = 60;
    let tracks = sliding_wall(n, usize::MAX);
    let keys = select_keyframes(&tracks, n, &KeyframeOptions::default());
    // A quarter of the tracked area's diagonal (320 × 200 px: 377 px) is 94 px: 16 frames.
    assert!(keys.len() >= 3, "{keys:?}");
    for w in keys.windows(2) {
        assert_eq!(w[1].1, KeyframeReason::ContentChanged, "{keys:?}");
        let gap = w[1].0 - w[0].0;
        assert!((14..=18).contains(&gap), "{keys:?}");
    }
}

#[test]
fn a_video_whose_tracks_do_not_last_a_frame_is_not_cut_short() {
    // Each track is followed in one frame only: no two frames share 30 tracks, so before the
    // key-frames stopped
    // at the first frame ("the camera hardly moves").
    let n = 12;
    let tracks = sliding_wall(n, 1);
    let keys = select_keyframes(&tracks, n, &KeyframeOptions::default());
    assert_eq!(keys.len(), n, "{keys:?}");
    assert!(keys[1..].iter().all(|k| k.1 == KeyframeReason::TracksLost));
}

/// Tracks of a textured wall that drifts 1 px a frame to the left (a homography explains every
/// pair) while KLT loses its tracks one by one: each frame 400 new tracks start at scattered
/// points, and each lives a geometric number of frames (15 % of the living ones die at each
/// step). The tracks that survive are the ones that moved least, so their median shift stays far
/// below a quarter of the image however many have died.
fn thinning_wall(n: usize) -> Vec<handheld_features::klt::Track2d> {
    let mut tracks = Vec::new();
    let mut id = 0;
    for birth in 0..n {
        for k in 0..400usize {
            let h = (birth * 400 + k).wrapping_mul(2_654_435_761) % 1_000_003;
            let x0 = (h % 300) as f32 + 10.0;
            let y = ((h / 300) % 200) as f32 + 20.0;
            // Survival 0.85 per frame: life ℓ with P(ℓ > t) = 0.85^t.
            let u = ((h % 997) as f64 + 0.5) / 997.0;
            let life = 1 + (u.ln() / 0.85f64.ln()) as usize;
            let positions: Vec<(usize, f32, f32)> = (birth..n.min(birth + life))
                .map(|f| (f, x0 - (f - birth) as f32, y))
                .collect();
            tracks.push(handheld_features::klt::Track2d {
                id,
                alive: birth + life >= n,
                positions,
            });
            id += 1;
        }
    }
    tracks
}

#[test]
fn a_key_frame_is_taken_once_most_of_the_last_ones_tracks_are_gone() {
    let n = 60;
    let tracks = thinning_wall(n);
    let shared = |a: usize, b: usize| {
        tracks
            .iter()
            .filter(|t| {
                let has = |f: usize| t.positions.iter().any(|p| p.0 == f);
                has(a) && has(b)
            })
            .count()
    };
    let keys = select_keyframes(&tracks, n, &KeyframeOptions::default());
    assert!(keys.len() >= 8, "{keys:?}");
    for w in keys.windows(2) {
        let (k, next) = (w[0].0, w[1].0);
        let established = shared(k, k + 1);
        assert!(
            2 * shared(k, next) >= established,
            "key-frames {k} and {next} share {} of {established} established tracks",
            shared(k, next)
        );
    }
    // Without the rule, the survivors' small shift and their count above `min_tracks` keep the
    // first key-frame's partner far away: the pair that broke the chain.
    let loose = select_keyframes(
        &tracks,
        n,
        &KeyframeOptions {
            min_alive: 0.0,
            ..Default::default()
        },
    );
    assert!(loose.get(1).is_none_or(|k| k.0 >= 10), "{loose:?}");
}
