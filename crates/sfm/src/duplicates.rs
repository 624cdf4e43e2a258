//! Duplicate and near-duplicate shots (the same photo twice, a burst): views that carry no depth
//! against another view of the set. A pair whose matches one homography explains (GRIC, Torr 1998,
//! as in Pollefeys et al. 2002, *Surviving dominant planes*), whose frames nearly coincide and
//! which shares more matches than either view has with any other view has zero baseline.
//!
//! Such a pair fixes no depth, and a projective frame has no angle to test it by. What that costs
//! depends on whether the two are one measurement or two:
//! - **an identical copy** (the same file under another name: the detector finds the same
//!   keypoints, [`Duplicate::identical`]) gives every match twice at the same pixel, so a point
//!   from the two alone has no depth at all (its triangulation is rank-deficient). With four of
//!   bundler-ET's nine photos copied under new names, those points made every upgrade candidate's
//!   metric adjustment remove 45–100 % of the observations, and no model was built. So the
//!   projective stage never makes a new point from an identical copy and its original alone
//!   (`Context::twin`); the copy is still registered, observes the points the other views make,
//!   and is adjusted with them;
//! - **a near-duplicate** (a second exposure from the same place) carries its own noise. Its points
//!   with its twin are weak but harmless, and they tie the two orientations: templeSparseRing's
//!   views 1 and 11 (identical ground-truth poses, 0.2 px apart) lose 0.7 AUC@1 points without
//!   them, and bundler-ET with its four copies re-encoded as JPEG gives 13/13 at 684.6 px with
//!   them (682.3 px without the copies). Such a view is reported and treated as any other.

use handheld_robust::TwoViewConfiguration;

use crate::input::SfmInput;

/// Frames whose matched keypoints moved less than this share of the image diagonal (median) are
/// the same shot. Two photos that coincide this closely and that a homography explains add
/// nothing to each other but noise; a misfire only moves a view to calibrated registration.
pub const MAX_SHIFT_OF_DIAGONAL: f64 = 0.02;

/// A duplicate whose matched keypoints moved less than this (median, pixels) is an identical copy:
/// the detector found the same keypoints (stored as `f32`, whose spacing at 4000 px is 0.0005 px).
pub const IDENTICAL_SHIFT_PX: f64 = 1e-3;

/// One view that repeats another.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Duplicate {
    /// The duplicate (index into the input's images).
    pub image: usize,
    /// The view it repeats.
    pub of: usize,
    /// Median displacement of the pair's matched keypoints, pixels.
    pub shift_px: f64,
}

impl Duplicate {
    /// An identical copy (the same keypoints), from which with its original no point is made.
    pub fn identical(&self) -> bool {
        self.shift_px < IDENTICAL_SHIFT_PX
    }
}

/// The median displacement (pixels) of a pair's matches when the pair carries no depth (a
/// homography explains it) and its frames nearly coincide; `None` otherwise.
fn duplicate_shift(input: &SfmInput, pair: &crate::input::SfmPair) -> Option<f64> {
    if !matches!(
        pair.configuration,
        TwoViewConfiguration::Planar | TwoViewConfiguration::PureRotation
    ) || pair.matches.is_empty()
    {
        return None;
    }
    let (a, b) = (&input.images[pair.a], &input.images[pair.b]);
    if (a.width, a.height) != (b.width, b.height) {
        return None;
    }
    let mut d: Vec<f64> = pair
        .matches
        .iter()
        .map(|&(i, j)| (a.keypoints[i as usize] - b.keypoints[j as usize]).norm())
        .collect();
    let mid = d.len() / 2;
    let shift = *d.select_nth_unstable_by(mid, f64::total_cmp).1;
    let diagonal = f64::from(a.width).hypot(f64::from(a.height));
    (shift <= MAX_SHIFT_OF_DIAGONAL * diagonal).then_some(shift)
}

/// The duplicate shots among the `allowed` views, each with the view it repeats. Views are visited
/// by their total number of verified matches (then by index), and a view is a duplicate only of a
/// view that is not one itself, so a slow pan whose consecutive frames nearly coincide keeps every
/// other frame as an independent one, not only its first. Video input has none: its key-frames were
/// chosen for their baseline (§3.1). At least two views are always independent.
pub(crate) fn find_duplicates(input: &SfmInput, allowed: &[bool]) -> Vec<Duplicate> {
    if input.video {
        return Vec::new();
    }
    let n = input.images.len();
    let mut matches = vec![0usize; n];
    // The two largest match counts of each view's pairs (a pair is compared with the best other).
    let mut best = vec![[0usize; 2]; n];
    let verified = || {
        input
            .pairs
            .iter()
            .filter(|p| p.configuration != TwoViewConfiguration::TooFewInliers)
    };
    for p in verified() {
        let m = p.matches.len();
        matches[p.a] += m;
        matches[p.b] += m;
        for v in [p.a, p.b] {
            if m > best[v][0] {
                best[v] = [m, best[v][0]];
            } else if m > best[v][1] {
                best[v][1] = m;
            }
        }
    }
    // The most matches of `v` with any view but the partner of a pair with `m` matches.
    let best_other = |v: usize, m: usize| {
        if m >= best[v][0] {
            best[v][1]
        } else {
            best[v][0]
        }
    };
    let mut twins: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
    for p in verified() {
        // A duplicate shares more of its content with its twin than with any other view: a pair
        // of a turntable sequence whose few matches lie on the still background (zero shift, one
        // homography) is no duplicate (templeSparseRing 1 and 11: 0.2 px).
        let m = p.matches.len();
        if m < best_other(p.a, m) || m < best_other(p.b, m) {
            continue;
        }
        if let Some(shift) = duplicate_shift(input, p) {
            twins[p.a].push((p.b, shift));
            twins[p.b].push((p.a, shift));
        }
    }
    let mut order: Vec<usize> = (0..n).filter(|&i| allowed[i]).collect();
    order.sort_by(|&x, &y| matches[y].cmp(&matches[x]).then(x.cmp(&y)));
    let mut kept = vec![false; n];
    let mut out = Vec::new();
    for &v in &order {
        let twin = twins[v]
            .iter()
            .filter(|(u, _)| kept[*u])
            .min_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
        match twin {
            Some(&(of, shift_px)) => out.push(Duplicate {
                image: v,
                of,
                shift_px,
            }),
            None => kept[v] = true,
        }
    }
    if kept.iter().filter(|k| **k).count() < 2 {
        return Vec::new();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::input::{SfmImage, SfmPair};
    use handheld_core::ImageId;
    use nalgebra::Vector2;

    fn image(i: u32, shift: f64) -> SfmImage {
        SfmImage {
            id: ImageId(i),
            name: format!("{i}.jpg"),
            width: 640,
            height: 480,
            keypoints: (0..50)
                .map(|k| Vector2::new(10.0 + 11.0 * f64::from(k) + shift, 200.0 + shift))
                .collect(),
            keypoint_scales: Vec::new(),
            camera_key: "cam".into(),
            focal_prior_px: None,
            frame: None,
            track_ids: Vec::new(),
            descriptors: Vec::new(),
            descriptor_dim: 0,
        }
    }

    fn pair(a: usize, b: usize, configuration: TwoViewConfiguration, n: u32) -> SfmPair {
        SfmPair {
            a,
            b,
            matches: (0..n).map(|k| (k, k)).collect(),
            f: None,
            configuration,
            view_distance_px: None,
        }
    }

    #[test]
    fn an_exact_copy_is_identical_a_near_one_is_not_and_a_view_with_depth_is_no_duplicate() {
        use TwoViewConfiguration::*;
        // 0, 1, 2 are distinct views (General pairs); 3 is a copy of 1 (zero shift, H = I).
        let input = SfmInput {
            images: vec![image(0, 0.0), image(1, 0.0), image(2, 0.0), image(3, 0.0)],
            pairs: vec![
                pair(0, 1, General, 40),
                pair(1, 2, General, 40),
                pair(0, 2, General, 30),
                pair(0, 3, General, 40),
                pair(3, 2, General, 40),
                pair(1, 3, PureRotation, 50),
            ],
            video: false,
        };
        let d = find_duplicates(&input, &[true; 4]);
        assert_eq!(
            d,
            vec![Duplicate {
                image: 3,
                of: 1,
                shift_px: 0.0
            }]
        );
        assert!(d[0].identical());
        // A second exposure from the same place: a duplicate, but not the same keypoints.
        let mut near = input;
        near.images[3] = image(3, 0.2);
        let d = find_duplicates(&near, &[true; 4]);
        assert_eq!(d.len(), 1);
        assert!(!d[0].identical(), "{d:?}");
    }

    #[test]
    fn frames_that_moved_are_not_duplicates_and_two_views_are_always_kept() {
        use TwoViewConfiguration::*;
        // A pan: 1 moved 100 px from 0 (more than 2 % of 800 px), a homography explains it.
        let input = SfmInput {
            images: vec![image(0, 0.0), image(1, 100.0)],
            pairs: vec![pair(0, 1, PureRotation, 50)],
            video: false,
        };
        assert!(find_duplicates(&input, &[true; 2]).is_empty());
        // Two copies and nothing else: both are kept (no model can hold fewer than two views).
        let input = SfmInput {
            images: vec![image(0, 0.0), image(1, 0.0)],
            pairs: vec![pair(0, 1, PureRotation, 50)],
            video: false,
        };
        assert!(find_duplicates(&input, &[true; 2]).is_empty());
    }

    #[test]
    fn a_pair_matched_on_a_still_background_only_is_no_duplicate() {
        use TwoViewConfiguration::*;
        // A turntable: 0 and 2 share 12 matches on the still background (zero shift, H = I),
        // far fewer than each shares with its neighbour 1 through the object.
        let input = SfmInput {
            images: vec![image(0, 0.0), image(1, 0.0), image(2, 0.0)],
            pairs: vec![
                pair(0, 1, General, 45),
                pair(1, 2, General, 45),
                pair(0, 2, PureRotation, 12),
            ],
            video: false,
        };
        assert!(find_duplicates(&input, &[true; 3]).is_empty());
    }

    #[test]
    fn a_slow_pan_is_not_collapsed_into_one_view() {
        use TwoViewConfiguration::*;
        // Frames 10 px apart (1.25 % of the diagonal): neighbours coincide, frames two apart not.
        let input = SfmInput {
            images: (0..4).map(|i| image(i, 10.0 * f64::from(i))).collect(),
            pairs: vec![
                pair(0, 1, PureRotation, 50),
                pair(1, 2, PureRotation, 50),
                pair(2, 3, PureRotation, 50),
                pair(0, 2, PureRotation, 30),
                pair(1, 3, PureRotation, 30),
            ],
            video: false,
        };
        let d = find_duplicates(&input, &[true; 4]);
        // 1 and 2 have the most matches, 1 comes first and is kept; 0 and 2 duplicate it; 3
        // duplicates only 2, which
        // is a duplicate itself, so 3 is independent: the chain 0–1–2–3 does not collapse onto 1.
        let held: Vec<(usize, usize)> = d.iter().map(|d| (d.image, d.of)).collect();
        assert_eq!(held, vec![(2, 1), (0, 1)]);
    }
}
