//! "Close views" (§3.2): a sequence matched only within a sliding window never links a camera that
//! comes back to a place it saw before, which lets errors accumulate. After the windowed pass, each
//! image is compared with every image outside its window by a cheap vote (mutual ratio-test matches
//! between the strongest few hundred descriptors of each), and its best-scoring partners become extra
//! pairs for full verification. The image-based distance of eq. 14 is then available for every
//! verified pair (`TwoViewGeometry::view_distance_px`), which the SfM stage uses to rank close views.

use rayon::prelude::*;

use crate::detector::{Descriptors, Features};
use crate::matching::{match_descriptors, MatchOptions};

/// Options of [`propose_close_views`].
#[derive(Clone, Debug, PartialEq)]
pub struct CloseViewOptions {
    /// Strongest descriptors per image used for voting (default 256).
    pub sample: usize,
    /// Extra partners proposed per image (default 3).
    pub per_image: usize,
    /// Fewest mutual matches between the samples for a proposal (default 20).
    pub min_votes: usize,
}

impl Default for CloseViewOptions {
    fn default() -> Self {
        Self {
            sample: 256,
            per_image: 3,
            min_votes: 20,
        }
    }
}

fn strongest(f: &Features, n: usize) -> Descriptors {
    let mut idx: Vec<usize> = (0..f.keypoints.len().min(f.descriptors.len())).collect();
    idx.sort_by(|&a, &b| f.keypoints[b].response.total_cmp(&f.keypoints[a].response));
    idx.truncate(n);
    let mut data = Vec::with_capacity(idx.len() * f.descriptors.dim);
    for i in idx {
        data.extend_from_slice(f.descriptors.row(i));
    }
    Descriptors {
        dim: f.descriptors.dim,
        data,
    }
}

/// Pairs `(i, j)`, `i < j`, with `j − i > window`, proposed as close views.
pub fn propose_close_views(
    features: &[Features],
    window: usize,
    opts: &CloseViewOptions,
) -> Vec<(usize, usize)> {
    let n = features.len();
    let samples: Vec<Descriptors> = features
        .par_iter()
        .map(|f| strongest(f, opts.sample))
        .collect();
    let candidates: Vec<(usize, usize)> = (0..n)
        .flat_map(|i| (i + window + 1..n).map(move |j| (i, j)))
        .collect();
    let mopts = MatchOptions::default();
    let votes: Vec<(usize, usize, usize)> = candidates
        .par_iter()
        .map(|&(i, j)| {
            (
                i,
                j,
                match_descriptors(&samples[i], &samples[j], &mopts).len(),
            )
        })
        .collect();
    let mut per: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n];
    for &(i, j, v) in &votes {
        if v >= opts.min_votes {
            per[i].push((v, j));
            per[j].push((v, i));
        }
    }
    let mut out = Vec::new();
    for (i, list) in per.iter_mut().enumerate() {
        list.sort_by_key(|e| std::cmp::Reverse(e.0));
        for &(_, j) in list.iter().take(opts.per_image) {
            out.push((i.min(j), i.max(j)));
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detector::Keypoint;

    /// Images on a loop: image k sees "places" k−1, k, k+1 (mod n), each place with its own
    /// descriptors, so the first and last images share a place although they are far apart in order.
    #[test]
    fn a_loop_closure_is_proposed() {
        let n = 12;
        let dim = 32;
        let mut s = 7u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32) / (1u64 << 24) as f32
        };
        let places: Vec<Vec<Vec<f32>>> = (0..n)
            .map(|_| {
                (0..60)
                    .map(|_| {
                        let v: Vec<f32> = (0..dim).map(|_| rnd()).collect();
                        let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
                        v.iter().map(|x| x / norm).collect()
                    })
                    .collect()
            })
            .collect();
        let features: Vec<Features> = (0..n)
            .map(|k| {
                let mut data = Vec::new();
                let mut keypoints = Vec::new();
                for p in [(k + n - 1) % n, k, (k + 1) % n] {
                    for d in &places[p] {
                        data.extend_from_slice(d);
                        keypoints.push(Keypoint {
                            x: 0.0,
                            y: 0.0,
                            scale: 1.0,
                            orientation: 0.0,
                            response: 1.0,
                        });
                    }
                }
                Features {
                    keypoints,
                    descriptors: Descriptors { dim, data },
                }
            })
            .collect();
        let pairs = propose_close_views(
            &features,
            2,
            &CloseViewOptions {
                sample: 180,
                per_image: 2,
                min_votes: 20,
            },
        );
        assert!(pairs.contains(&(0, n - 1)), "{pairs:?}");
        assert!(pairs.iter().all(|&(i, j)| j - i > 2));
        // Nothing else shares a place outside the window.
        assert!(
            pairs.iter().all(|&(i, j)| (i, j) == (0, n - 1)
                || (i, j) == (0, n - 2)
                || (i, j) == (1, n - 1)),
            "{pairs:?}"
        );
    }
}
