//! Video correspondences (§2.1 tracking and §3.1 key-frames, footnote 1): KLT tracks over every
//! frame, GRIC key-frames among them, and the key-frame pairs that structure and motion starts from.
//!
//! Every frame becomes a [`Features`] whose keypoints are the tracks alive in it (no descriptors), and
//! [`VideoTracks::ids`] gives each keypoint's stable track id, so that an in-between frame can later
//! be linked to the 3D points its tracks reach. Key-frame pairs are verified exactly like photo pairs
//! (Table 1 through [`verify_pair`]), with the shared tracks as putative matches.

use std::collections::HashMap;

use handheld_core::Progress;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{check, FeatureError};
use crate::keyframes::{select_keyframes, KeyframeOptions, KeyframeReason};
use crate::klt::{KltOptions, KltTracker};
use crate::matching::Match;
use crate::verify::{verify_pair, PairVerificationOptions, VerifiedPair};
use crate::{Descriptors, Features, GrayImage, Keypoint};

/// Options of [`track_video`] and [`keyframe_pairs`].
#[derive(Clone, Debug, PartialEq)]
pub struct VideoTrackingOptions {
    pub klt: KltOptions,
    pub keyframes: KeyframeOptions,
    /// Each key-frame is paired with this many following key-frames (tracks shared with a farther
    /// key-frame give a wider baseline and longer multi-view tracks). Default 3.
    pub keyframe_window: usize,
    /// Fewest shared tracks for a key-frame pair to be verified. Default 30.
    pub min_shared_tracks: usize,
}

impl Default for VideoTrackingOptions {
    fn default() -> Self {
        Self {
            klt: KltOptions {
                target_features: 1000,
                ..Default::default()
            },
            keyframes: KeyframeOptions::default(),
            keyframe_window: 3,
            min_shared_tracks: 30,
        }
    }
}

impl VideoTrackingOptions {
    /// Checks the KLT options, the key-frame window and ratio; the error names the offending option.
    pub fn validate(&self) -> Result<(), FeatureError> {
        self.klt.validate()?;
        check(self.keyframe_window != 0, "keyframe_window", || {
            "must be at least 1".into()
        })?;
        let ratio = self.keyframes.track_ratio;
        check(ratio > 0.0 && ratio <= 1.0, "track_ratio", || {
            format!("the key-frame track ratio must be in (0, 1], got {ratio}")
        })
    }
}

/// The tracks of a whole video, frame by frame.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct VideoTracks {
    /// Per frame: the positions `[x, y]` (pixels) of the tracks alive in it, in order of track id.
    pub points: Vec<Vec<[f32; 2]>>,
    /// Per frame: the stable id of each track in `points`.
    pub ids: Vec<Vec<u64>>,
    /// Key-frames in order, with the reason each was chosen.
    pub keyframes: Vec<(usize, KeyframeReason)>,
}

impl VideoTracks {
    pub fn num_frames(&self) -> usize {
        self.points.len()
    }

    /// Frame `k` as keypoints without descriptors.
    pub fn features(&self, k: usize) -> Features {
        Features {
            keypoints: self.points[k]
                .iter()
                .map(|p| Keypoint {
                    x: p[0],
                    y: p[1],
                    scale: 1.0,
                    orientation: 0.0,
                    response: 0.0,
                })
                .collect(),
            descriptors: Descriptors {
                dim: 0,
                data: Vec::new(),
            },
        }
    }

    /// Tracks shared by frames `a` and `b`, as keypoint-index matches.
    pub fn shared(&self, a: usize, b: usize) -> Vec<Match> {
        let index: HashMap<u64, u32> = self.ids[b]
            .iter()
            .enumerate()
            .map(|(k, id)| (*id, k as u32))
            .collect();
        self.ids[a]
            .iter()
            .enumerate()
            .filter_map(|(k, id)| {
                index.get(id).map(|&j| Match {
                    i: k as u32,
                    j,
                    distance: 0.0,
                })
            })
            .collect()
    }
}

/// The median fraction of a frame's tracks that KLT follows into the next frame, below which
/// tracking is not trusted. KLT assumes small motion between frames (eq. 8 is a linearisation):
/// on a hand-held video it keeps nearly every track from one frame to the next, and loses them
/// only at the borders and at occlusions. When it keeps fewer than half, the frames are too far
/// apart for it (a fast camera, a low frame rate, or frames skipped with a stride): the tracks
/// that remain are short, re-detected ones, key-frames share too few of them, and the sequence
/// breaks into pieces. Descriptor matching between the frames, as for photos, does not depend on
/// the motion being small.
pub const MIN_TRACK_SURVIVAL: f64 = 0.5;

/// The median number of tracks per frame below which KLT is not trusted: key-frames then share a
/// few dozen matches, too few for a well-conditioned epipolar geometry and for resection (an indoor
/// walk past plain walls: 67 per frame, one key-frame, no model), while descriptor matching finds
/// its matches wherever there is texture, at every scale.
pub const MIN_TRACKS_PER_FRAME: usize = 100;

/// Whether KLT tracking held over a video, or why not: too few tracks per frame (see
/// [`MIN_TRACKS_PER_FRAME`]), too few kept from frame to frame (see [`MIN_TRACK_SURVIVAL`]; the
/// median over the video, and at any one frame the tracks it had already followed from the one
/// before),
/// key-frames that stop long before the end, or a key-frame that shares fewer than
/// `min_shared_tracks` tracks with the one before it (the fewest for a key-frame pair to be
/// verified, [`VideoTrackingOptions::min_shared_tracks`]): no pair links the two, and the sequence
/// breaks there into separate models. A corridor walked past plain walls kept a median of 158
/// tracks per frame, but its key-frames shared 1–32 tracks at a dozen places (the turns, a blank
/// stretch of wall), and gave four models of 20–51 frames.
pub fn tracking_verdict(tracks: &VideoTracks, min_shared_tracks: usize) -> Result<(), String> {
    let n = tracks.num_frames();
    if n < 2 {
        return Ok(());
    }
    let mut counts: Vec<usize> = tracks.ids.iter().map(Vec::len).collect();
    counts.sort_unstable();
    let held = counts[counts.len() / 2];
    if held < MIN_TRACKS_PER_FRAME {
        return Err(format!(
            "KLT holds only {held} tracks per frame (median; need {MIN_TRACKS_PER_FRAME}): the frames have too little texture for tracking"
        ));
    }
    let mut survival: Vec<f64> = (0..n - 1)
        .map(|k| {
            let next: std::collections::HashSet<u64> = tracks.ids[k + 1].iter().copied().collect();
            let kept = tracks.ids[k].iter().filter(|id| next.contains(id)).count();
            kept as f64 / tracks.ids[k].len().max(1) as f64
        })
        .collect();
    survival.sort_by(f64::total_cmp);
    let median = survival[survival.len() / 2];
    if median < MIN_TRACK_SURVIVAL {
        return Err(format!(
            "KLT keeps only {:.0} % of its tracks from one frame to the next (median; a steady video keeps over {:.0} %): the frames are too far apart for tracking",
            100.0 * median,
            100.0 * MIN_TRACK_SURVIVAL
        ));
    }
    if let Some((k, kept)) = worst_established_survival(tracks) {
        if kept < MIN_TRACK_SURVIVAL {
            return Err(format!(
                "KLT keeps only {:.0} % of its established tracks from frame {k} to frame {} (a steady video keeps over {:.0} %): where the frames are that far apart the tracks that survive are not trusted (on a repeated pattern they land on copies of themselves)",
                100.0 * kept,
                k + 1,
                100.0 * MIN_TRACK_SURVIVAL
            ));
        }
    }
    let keys: Vec<usize> = tracks.keyframes.iter().map(|k| k.0).collect();
    if keys.len() < 2 {
        // The tracks held and no frame moved far enough from the first: a still camera, which
        // descriptor matching cannot reconstruct either (the tracks stage says so).
        return Ok(());
    }
    let broken: Vec<(usize, usize, usize)> = keys
        .windows(2)
        .map(|w| (w[0], w[1], tracks.shared(w[0], w[1]).len()))
        .filter(|&(_, _, shared)| shared < min_shared_tracks)
        .collect();
    if let Some(&(a, b, shared)) = broken.first() {
        return Err(format!(
            "KLT loses the thread between key-frames at {} place(s), first between frames {a} and {b} ({shared} shared tracks, need {min_shared_tracks} to link them)",
            broken.len()
        ));
    }
    let widest = keys.windows(2).map(|w| w[1] - w[0]).max().unwrap_or(1);
    let last = keys[keys.len() - 1];
    if n - 1 - last > 2 * widest {
        return Err(format!(
            "the key-frames stop at frame {last} of {n}: tracking was lost after it"
        ));
    }
    Ok(())
}

/// The frame `k` whose established tracks (alive in frames `k − 1` and `k`: KLT's churn of corners
/// just detected and lost at once left out) survive least into frame `k + 1`, and the share kept.
/// Where KLT keeps fewer than [`MIN_TRACK_SURVIVAL`] of them, the frames moved beyond its small
/// motion, and the survivors are no better than the lost ones: on a rendered phone orbit before
/// printed wallpaper, 60–71 % of the tracks that survived such frames had landed on a copy of
/// their corner one pattern period (170–530 px) away, agreed with one another, passed the
/// key-frame pairs' verification, and the model's pieces were merged a period apart (0.27–0.31 m)
/// with exact rotations and no warning.
fn worst_established_survival(tracks: &VideoTracks) -> Option<(usize, f64)> {
    let n = tracks.num_frames();
    (1..n.saturating_sub(1))
        .filter_map(|k| {
            let before: std::collections::HashSet<u64> =
                tracks.ids[k - 1].iter().copied().collect();
            let after: std::collections::HashSet<u64> = tracks.ids[k + 1].iter().copied().collect();
            let established: Vec<u64> = tracks.ids[k]
                .iter()
                .copied()
                .filter(|id| before.contains(id))
                .collect();
            (!established.is_empty()).then(|| {
                let kept = established.iter().filter(|id| after.contains(id)).count();
                (k, kept as f64 / established.len() as f64)
            })
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// Tracks features through `frames` (in order) with pyramidal KLT (eq. 8) and selects key-frames by
/// GRIC (§3.1). `frames` yields each frame or the error that stops the run.
pub fn track_video<E>(
    frames: impl Iterator<Item = Result<GrayImage, E>>,
    opts: &VideoTrackingOptions,
    progress: &dyn Progress,
) -> Result<VideoTracks, E>
where
    E: From<String>,
{
    opts.validate().map_err(|e| E::from(e.to_string()))?;
    let mut tracker = KltTracker::new(opts.klt.clone()).map_err(|e| E::from(e.to_string()))?;
    let mut out = VideoTracks::default();
    for frame in frames {
        let frame = frame?;
        let k = tracker.frame_count();
        let tracks = tracker.process(&frame);
        let mut pts = Vec::new();
        let mut ids = Vec::new();
        for t in tracks.iter().filter(|t| t.alive) {
            if let Some(&(f, x, y)) = t.positions.last() {
                if f == k {
                    pts.push([x, y]);
                    ids.push(t.id);
                }
            }
        }
        out.points.push(pts);
        out.ids.push(ids);
        progress.inc(1);
    }
    out.keyframes = select_keyframes(tracker.tracks(), out.num_frames(), &opts.keyframes);
    Ok(out)
}

/// Verifies the key-frame pairs: each key-frame with the next [`VideoTrackingOptions::keyframe_window`]
/// key-frames, when they share enough tracks. Indices in the result are frame indices.
pub fn keyframe_pairs(
    tracks: &VideoTracks,
    opts: &VideoTrackingOptions,
    verification: &PairVerificationOptions,
    progress: &dyn Progress,
) -> Vec<VerifiedPair> {
    let keys: Vec<usize> = tracks.keyframes.iter().map(|k| k.0).collect();
    let mut pairs = Vec::new();
    for (a, &ka) in keys.iter().enumerate() {
        for &kb in keys.iter().skip(a + 1).take(opts.keyframe_window) {
            pairs.push((ka, kb));
        }
    }
    progress.start("verifying key-frame pairs", pairs.len() as u64);
    let v = PairVerificationOptions {
        guided: false,
        ..verification.clone()
    };
    let out = pairs
        .par_iter()
        .filter_map(|&(a, b)| {
            let shared = tracks.shared(a, b);
            progress.inc(1);
            (shared.len() >= opts.min_shared_tracks).then(|| {
                verify_pair(
                    a,
                    b,
                    &tracks.features(a),
                    &tracks.features(b),
                    shared,
                    &v,
                    None,
                )
            })
        })
        .collect();
    progress.finish();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured image shifted by `dx` pixels (a camera translating parallel to a plane).
    fn frame(dx: f32) -> GrayImage {
        let (w, h) = (160usize, 120usize);
        let mut img = GrayImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let u = x as f32 + dx;
                let v = y as f32;
                let val = 0.5
                    + 0.25 * ((u * 0.31).sin() * (v * 0.27).cos())
                    + 0.2 * ((u * 0.093 + v * 0.151).sin() * (u * 0.05 - v * 0.11).cos());
                img.data[y * w + x] = val;
            }
        }
        img
    }

    #[test]
    fn tracks_keep_ids_and_follow_the_shift() {
        let frames: Vec<Result<GrayImage, String>> = (0..5).map(|k| Ok(frame(k as f32))).collect();
        let t = track_video(
            frames.into_iter(),
            &VideoTrackingOptions::default(),
            &handheld_core::NoProgress,
        )
        .unwrap();
        assert_eq!(t.num_frames(), 5);
        assert!(t.points[0].len() > 50, "{} features", t.points[0].len());
        let shared = t.shared(0, 4);
        assert!(shared.len() > 30, "{} shared tracks", shared.len());
        // The content moves left by 1 px per frame: a track's x drops by 4 between frames 0 and 4.
        let mut errs: Vec<f32> = shared
            .iter()
            .map(|m| {
                let (a, b) = (t.points[0][m.i as usize], t.points[4][m.j as usize]);
                ((b[0] - (a[0] - 4.0)).powi(2) + (b[1] - a[1]).powi(2)).sqrt()
            })
            .collect();
        errs.sort_by(f32::total_cmp);
        assert!(
            errs[errs.len() / 2] < 0.1,
            "median error {}",
            errs[errs.len() / 2]
        );
        assert_eq!(t.keyframes.first().map(|k| k.0), Some(0));
    }

    /// `n` frames whose `per_frame` tracks all last the whole video, with key-frames every 3.
    fn steady(n: usize, per_frame: usize) -> VideoTracks {
        VideoTracks {
            points: vec![vec![[1.0, 1.0]; per_frame]; n],
            ids: vec![(0..per_frame as u64).collect(); n],
            keyframes: (0..n)
                .step_by(3)
                .map(|k| (k, KeyframeReason::EpipolarGeometry))
                .collect(),
        }
    }

    #[test]
    fn few_tracks_per_frame_fail_the_verdict_like_lost_ones() {
        assert_eq!(tracking_verdict(&steady(12, 400), 30), Ok(()));
        let e = tracking_verdict(&steady(12, 67), 30).unwrap_err();
        assert!(e.contains("only 67 tracks per frame"), "{e}");
    }

    #[test]
    fn key_frames_that_share_too_few_tracks_fail_the_verdict() {
        // Frame 6's tracks thinned out over three frames, each keeping at least half of the tracks
        // it had followed from the frame before, new ones taking their place: key-frames 6 and 9
        // share 20 tracks.
        let mut t = steady(12, 400);
        let ids = |r: &[std::ops::Range<u64>]| r.iter().cloned().flatten().collect::<Vec<u64>>();
        t.ids[7] = ids(&[0..200, 2000..2200]);
        t.ids[8] = ids(&[0..100, 2000..2200, 3000..3100]);
        for k in 9..12 {
            t.ids[k] = ids(&[0..20, 2000..2200, 4000..4180]);
        }
        let e = tracking_verdict(&t, 30).unwrap_err();
        assert!(
            e.contains("between frames 6 and 9 (20 shared tracks, need 30"),
            "{e}"
        );
        assert_eq!(tracking_verdict(&t, 20), Ok(()));
    }

    #[test]
    fn a_frame_that_loses_most_of_the_tracks_it_followed_fails_the_verdict() {
        // Every track but 20 lost into frame 7 and new ones detected: the median frame keeps all
        // of its tracks, but the 20 that survived frame 7 are not trusted (`worst_established_survival`).
        let mut t = steady(12, 400);
        for k in 7..12 {
            t.ids[k] = (0..400u64)
                .map(|i| if i < 20 { i } else { 1000 + i })
                .collect();
        }
        let e = tracking_verdict(&t, 20).unwrap_err();
        assert!(
            e.contains("only 5 % of its established tracks from frame 6 to frame 7"),
            "{e}"
        );
        // Half of them kept is enough.
        for k in 7..12 {
            t.ids[k] = (0..400u64)
                .map(|i| if i < 200 { i } else { 1000 + i })
                .collect();
        }
        assert_eq!(tracking_verdict(&t, 20), Ok(()));
    }

    #[test]
    fn rejects_bad_options() {
        let o = VideoTrackingOptions {
            keyframe_window: 0,
            ..Default::default()
        };
        assert!(matches!(
            o.validate(),
            Err(FeatureError::InvalidOption {
                option: "keyframe_window",
                ..
            })
        ));
    }
}
