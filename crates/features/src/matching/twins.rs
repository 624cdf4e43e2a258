//! Each keypoint's **twin**: the nearest descriptor among the other keypoints of its own image.
//!
//! Lowe's ratio test (IJCV 2004, §7.1) asks a match to be clearly nearer than the second-nearest
//! descriptor of the *other* image. A repeated pattern (printed wallpaper, tiles, a facade's
//! windows) defeats it wherever the true partner is missing there (out of view, not detected, or
//! foreshortened more than a copy): the nearest copy is then unique in the other image and passes,
//! though its own image holds look-alikes a period away. Such matches agree with one another (the
//! pattern shifted by a period), so RANSAC keeps them, and along the epipolar lines the fundamental
//! matrix cannot tell them apart: on a synthetic wallpaper orbit (`handheld demo --scene
//! wallpaper`) 9 % of all verified inliers, and 80–86 % of some wide pairs', were copies, and the
//! model placed its cameras up to 0.39 m (a pattern period) off with exact rotations and focal
//! length. The images themselves say which keypoints are ambiguous: a keypoint whose own image
//! holds a descriptor nearer to it than its match is, has a twin that the same match could as well
//! belong to. [`distinct`] keeps a match only when it is nearer than both keypoints' twins: the
//! ratio test at a ratio of 1 with the keypoints' own images as the second-nearest candidates.
//! On the wallpaper orbit the copies fell to 2.3 % of the inliers and the model to its true poses.
//!
//! It costs right matches too: a keypoint on brick or plaster often has a look-alike nearer than
//! its partner across a wide baseline (6–14 % of a fountain-P11 pair's verified inliers, their
//! twins 70–100 keypoint scales away). Taking such matches back once the pair's F was fixed from
//! the distinct ones (when no twin lay on the epipolar line, or when guided matching found them
//! from both sides) let the copies back in as well, through the pairs whose distinct matches
//! already held a copy's F: docs/matches.md has the figures.
//!
//! The search is the matcher's coarse to fine one ([`super::coarse`]) of an image against itself:
//! 32 candidates per keypoint on the coarse codes, ranked on the full descriptors, the keypoint
//! itself and keypoints within [`SAME_PLACE_PX`] of it (the same corner at another orientation or
//! scale) left out.

use rayon::prelude::*;

use super::coarse::candidate_lanes;
use super::{prepare, COARSE_MIN_COLUMNS, ROW_BLOCK};
use crate::detector::Features;
use crate::guided::dist as distance;

/// Keypoints nearer than this (pixels) are the same image structure: not twins.
pub const SAME_PLACE_PX: f32 = 4.0;

/// Below this many keypoints (or for descriptors the coarse pass does not take) every pair is
/// compared; above it without a coarse pass, no twins are looked for.
const BRUTE_MAX: usize = 2048;

/// Every keypoint's twin distance in one image: to the nearest descriptor of another keypoint more
/// than [`SAME_PLACE_PX`] away (`f32::INFINITY` where there is none, or none was looked for).
#[derive(Clone, Debug, Default)]
pub struct Twins {
    pub nearest: Vec<f32>,
}

impl Twins {
    /// The twins of every keypoint of `f` (module notes).
    pub fn of(f: &Features) -> Self {
        let (n, dim) = (f.descriptors.len(), f.descriptors.dim);
        let mut best = vec![f32::INFINITY; n];
        if n >= 2 && dim > 0 && f.keypoints.len() == n {
            let data = &f.descriptors.data;
            let row = |i: usize| &data[i * dim..(i + 1) * dim];
            let kp = &f.keypoints;
            let offer = |i: usize, j: usize, b: &mut f32| {
                if j != i && (kp[i].x - kp[j].x).hypot(kp[i].y - kp[j].y) >= SAME_PLACE_PX {
                    *b = b.min(distance(row(i), row(j)));
                }
            };
            let p = prepare(&f.descriptors);
            match p.coarse.as_deref().filter(|_| n > COARSE_MIN_COLUMNS) {
                Some(coarse) => {
                    best.par_chunks_mut(ROW_BLOCK)
                        .enumerate()
                        .for_each(|(blk, chunk)| {
                            let i0 = blk * ROW_BLOCK;
                            let lanes = candidate_lanes(coarse, coarse, i0, chunk.len());
                            for (r, (ln, b)) in lanes.iter().zip(chunk.iter_mut()).enumerate() {
                                for &j in ln.j1.iter().chain(&ln.j2) {
                                    if j != u32::MAX {
                                        offer(i0 + r, j as usize, b);
                                    }
                                }
                            }
                        });
                }
                None if n <= BRUTE_MAX => {
                    best.par_iter_mut().enumerate().for_each(|(i, b)| {
                        for j in 0..n {
                            offer(i, j, b);
                        }
                    });
                }
                None => {}
            }
        }
        Self { nearest: best }
    }
}

/// Whether the match of keypoint `a` of `f1` with keypoint `b` of `f2` passes the ratio test
/// against both keypoints' twins (`t1`, `t2`: the [`Twins`] of `f1` and `f2`): its distance below
/// `ratio` times each twin's.
#[inline]
pub fn distinct(
    f1: &Features,
    f2: &Features,
    (t1, t2): (&Twins, &Twins),
    ratio: f32,
    a: u32,
    b: u32,
) -> bool {
    let (a, b) = (a as usize, b as usize);
    let (d1, d2) = (&f1.descriptors, &f2.descriptors);
    if d1.dim != d2.dim || a >= t1.nearest.len() || b >= t2.nearest.len() {
        return true;
    }
    let d = distance(
        &d1.data[a * d1.dim..(a + 1) * d1.dim],
        &d2.data[b * d2.dim..(b + 1) * d2.dim],
    );
    d < ratio * t1.nearest[a] && d < ratio * t2.nearest[b]
}

/// Every image's [`Twins`], computed on first use and kept (an image is in many pairs).
pub struct TwinCache(Vec<std::sync::OnceLock<Twins>>);

impl TwinCache {
    /// A cache for `images` images.
    pub fn new(images: usize) -> Self {
        Self((0..images).map(|_| std::sync::OnceLock::new()).collect())
    }

    /// The twins of image `image`, whose features are `f`; `None` past the cache's images.
    pub fn get(&self, image: usize, f: &Features) -> Option<&Twins> {
        Some(self.0.get(image)?.get_or_init(|| Twins::of(f)))
    }

    /// The twins of every image of `pairs` (features `features`), each once and side by side:
    /// found on first use inside the pairs' loop, an image's twins kept the threads that wanted
    /// them waiting.
    pub fn fill(&self, features: &[Features], pairs: &[(usize, usize)]) {
        let mut wanted: Vec<usize> = pairs.iter().flat_map(|&(i, j)| [i, j]).collect();
        wanted.sort_unstable();
        wanted.dedup();
        wanted.par_iter().for_each(|&i| {
            if let Some(f) = features.get(i) {
                self.get(i, f);
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::{Descriptors, Keypoint};

    fn features(points: &[(f32, f32)], rows: &[[f32; 4]]) -> Features {
        Features {
            keypoints: points
                .iter()
                .map(|&(x, y)| Keypoint {
                    x,
                    y,
                    scale: 1.0,
                    orientation: 0.0,
                    response: 1.0,
                })
                .collect(),
            descriptors: Descriptors {
                dim: 4,
                data: rows.iter().flatten().copied().collect(),
            },
        }
    }

    #[test]
    fn a_copy_elsewhere_in_the_image_is_a_twin_and_one_at_the_same_place_is_not() {
        let f = features(
            &[(10.0, 10.0), (11.0, 10.0), (60.0, 10.0), (10.0, 80.0)],
            &[
                [1.0, 0.0, 0.0, 0.0],
                [0.99, 0.1, 0.0, 0.0], // the first keypoint again, 1 px away: not its twin
                [0.9, 0.3, 0.0, 0.0],  // a copy 50 px away: the first one's twin
                [0.0, 0.0, 1.0, 0.0],
            ],
        );
        let t = Twins::of(&f);
        let d02 = distance(&[1.0, 0.0, 0.0, 0.0], &[0.9, 0.3, 0.0, 0.0]);
        assert!((t.nearest[0] - d02).abs() < 1e-6, "{t:?}");
        // The lone keypoint's twin is far.
        assert!(t.nearest[3] > 1.0, "{t:?}");
        // A match nearer than both twins is distinct; one as far as a twin is not.
        let g = features(&[(5.0, 5.0)], &[[0.98, 0.05, 0.0, 0.0]]);
        let tg = Twins::of(&g);
        assert!(distinct(&f, &g, (&t, &tg), 1.0, 0, 0));
        let h = features(&[(5.0, 5.0)], &[[0.8, 0.45, 0.0, 0.0]]);
        let th = Twins::of(&h);
        assert!(!distinct(&f, &h, (&t, &th), 1.0, 0, 0));
    }
}
