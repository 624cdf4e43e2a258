//! Key-frame selection for video (§3.1 and its footnote 1). Consecutive video frames are too close
//! for a well-conditioned epipolar geometry, so structure and motion only uses key-frames: the next
//! key-frame is chosen once the fundamental-matrix model explains the tracked features better than
//! a homography (GRIC, Torr 1998), and, "to avoid selecting too many key-frames", at the last frame
//! for which `nᵢ ≥ 0.9·nₑ`, where `nᵢ` is the number of valid tracks shared with the previous
//! key-frame and `nₑ` that number when F first overtook H. In-between frames get their poses later.
//!
//! GRIC alone never fires where a homography explains every pair: a corridor of plain walls and a
//! tiled floor, a phone panning along a wall (dominant planes, Pollefeys et al. 2002). The key-frames
//! must still follow the motion, or the sequence has one key-frame and no model ("the camera hardly
//! moves" of a camera that walked 14.6 m). So a key-frame is also taken when the image content has
//! moved since the last one: the tracks it shares with the last key-frame have moved by a median of
//! [`KeyframeOptions::min_shift`] of the tracked area's diagonal. And when the very next frame
//! already shares too few tracks (a cut, a fast turn), it becomes a key-frame and the sequence goes
//! on from there. (The share of the key-frame's tracks still alive is no measure: KLT re-detects
//! weak features at every frame and loses many of them at once, on a steady orbit as well.)

use handheld_robust::{
    estimate_two_view_geometry, Match2d2d, TwoViewConfiguration, TwoViewOptions,
};
use nalgebra::Vector2;

use crate::klt::Track2d;

/// Options of [`select_keyframes`].
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframeOptions {
    /// The `0.9` of footnote 1.
    pub track_ratio: f64,
    /// Fewest shared tracks for a usable pair; when tracking falls below this before F overtakes H,
    /// the last frame that still had enough tracks becomes a key-frame so the sequence goes on.
    pub min_tracks: usize,
    /// Two-view estimation used for the F-versus-H test (no refinement needed).
    pub two_view: TwoViewOptions,
    /// Before F overtakes H, a frame whose tracks shared with the last key-frame have moved by a
    /// median of this fraction of the tracked area's diagonal is a key-frame: the content moved
    /// that much (a quarter: the frames still overlap by about three quarters).
    pub min_shift: f64,
    /// Fewest of the key-frame's established tracks (those still tracked in the next frame), as a
    /// share, that a later frame must still hold to be paired with it. The median shift above is
    /// measured on the tracks that survive, and those are the ones that moved least: on a fast orbit before a wall (30 portrait frames of H.264)
    /// the tracks shared with the first frame fell from 1000 to 65 while their median shift
    /// stayed near 100 px of a 1441 px diagonal, F overtook H only then, and the two key-frames
    /// (0 and 26) shared 62 verified matches: no model. Half: consecutive key-frames then share
    /// half their tracks, and each key-frame is linked to the next through as many 3D points.
    pub min_alive: f64,
}

impl Default for KeyframeOptions {
    fn default() -> Self {
        Self {
            track_ratio: 0.9,
            min_tracks: 30,
            two_view: TwoViewOptions {
                refine: false,
                f_threshold_px: 1.0,
                h_threshold_px: 2.5,
                ..Default::default()
            },
            min_shift: 0.25,
            min_alive: 0.5,
        }
    }
}

/// Position of a track in `frame`, if it was tracked there.
fn position(t: &Track2d, frame: usize) -> Option<Vector2<f64>> {
    let birth = t.positions.first()?.0;
    let (f, x, y) = *t.positions.get(frame.checked_sub(birth)?)?;
    (f == frame).then(|| Vector2::new(x as f64, y as f64))
}

fn shared(tracks: &[Track2d], a: usize, b: usize) -> Vec<Match2d2d> {
    tracks
        .iter()
        .filter_map(|t| Some(Match2d2d::new(position(t, a)?, position(t, b)?)))
        .collect()
}

/// The diagonal of the bounding box of the tracks in `frame` (the image, where it is textured).
fn tracked_diagonal(tracks: &[Track2d], frame: usize) -> f64 {
    let pts: Vec<Vector2<f64>> = tracks.iter().filter_map(|t| position(t, frame)).collect();
    let (mut lo, mut hi) = (
        Vector2::repeat(f64::INFINITY),
        Vector2::repeat(f64::NEG_INFINITY),
    );
    for p in &pts {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    if pts.len() < 2 {
        return f64::INFINITY;
    }
    (hi - lo).norm()
}

/// The median displacement of matched positions, pixels.
fn median_shift(m: &[Match2d2d]) -> f64 {
    let mut d: Vec<f64> = m.iter().map(|x| (x.x2 - x.x1).norm()).collect();
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Why a key-frame was chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum KeyframeReason {
    /// The first frame.
    First,
    /// F overtook H, then the last frame with `nᵢ ≥ 0.9·nₑ` (footnote 1).
    EpipolarGeometry,
    /// Tracks ran out before F overtook H (e.g. a pure rotation, a cut, or motion fast enough
    /// that most tracks die): the last frame that still shares [`KeyframeOptions::min_tracks`]
    /// and [`KeyframeOptions::min_alive`] of the key-frame's tracks, or the next frame when even
    /// it shares fewer.
    TracksLost,
    /// A homography still explained the tracks, but they had moved by
    /// [`KeyframeOptions::min_shift`] of the image since the last key-frame (a dominant plane, a
    /// pan).
    ContentChanged,
}

/// Selects key-frames among `num_frames` frames from KLT tracks. Returns `(frame, reason)` in order.
pub fn select_keyframes(
    tracks: &[Track2d],
    num_frames: usize,
    opts: &KeyframeOptions,
) -> Vec<(usize, KeyframeReason)> {
    let mut keys = Vec::new();
    if num_frames == 0 {
        return keys;
    }
    keys.push((0, KeyframeReason::First));
    let mut k = 0;
    while k + 1 < num_frames {
        let diagonal = tracked_diagonal(tracks, k);
        // The key-frame's tracks that outlive it by a frame: KLT drops its weakest corners at
        // once (a third of them on a slow synthetic orbit, where the rest then last), and that
        // churn is not the scene leaving the view.
        let established = shared(tracks, k, k + 1).len();
        let needed = opts
            .min_tracks
            .max((opts.min_alive * established as f64).ceil() as usize);
        let mut n_e: Option<usize> = None;
        let mut candidate = None;
        let mut last_enough = None;
        let mut changed = None;
        for i in k + 1..num_frames {
            let m = shared(tracks, k, i);
            tracing::trace!(
                "key-frame {k}: frame {i} shares {} tracks, median shift {:.1} px of a {:.0} px diagonal",
                m.len(),
                median_shift(&m),
                diagonal
            );
            if m.len() < needed {
                break;
            }
            last_enough = Some(i);
            match n_e {
                None => {
                    let general = estimate_two_view_geometry(&m, &opts.two_view)
                        .map(|g| g.configuration == TwoViewConfiguration::General)
                        .unwrap_or(false);
                    if general {
                        n_e = Some(m.len());
                        candidate = Some(i);
                    } else if median_shift(&m) > opts.min_shift * diagonal {
                        changed = Some(i);
                        break;
                    }
                }
                Some(ne) if m.len() as f64 >= opts.track_ratio * ne as f64 => candidate = Some(i),
                Some(_) => break,
            }
        }
        let next = match (candidate, changed, last_enough) {
            (Some(c), _, _) => (c, KeyframeReason::EpipolarGeometry),
            (None, Some(c), _) => (c, KeyframeReason::ContentChanged),
            (None, None, Some(l)) if l + 1 < num_frames => (l, KeyframeReason::TracksLost),
            // Even the next frame shares too few tracks (a cut, a fast turn): it starts anew.
            (None, None, None) => (k + 1, KeyframeReason::TracksLost),
            _ => break,
        };
        keys.push(next);
        k = next.0;
    }
    keys
}
