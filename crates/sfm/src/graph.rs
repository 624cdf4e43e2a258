//! The correspondence graph: for every keypoint, the keypoints of other images it was matched to
//! (the union of all verified pairs). Resection reads 2D–3D candidates from it, triangulation the
//! partners of a new point (§3.2, "Updating the Structure and Motion").

use std::collections::HashMap;

use handheld_robust::TwoViewConfiguration;

use crate::input::SfmInput;

/// Keypoint-level adjacency plus per-pair statistics.
pub struct CorrespondenceGraph {
    /// `corr[image][kp]`: `(other image, other keypoint)`.
    corr: Vec<Vec<Vec<(u32, u32)>>>,
    /// Inlier count per unordered pair `(min, max)`.
    pub pair_matches: HashMap<(usize, usize), usize>,
}

impl CorrespondenceGraph {
    pub fn build(input: &SfmInput, min_matches: usize) -> Self {
        let mut corr: Vec<Vec<Vec<(u32, u32)>>> = input
            .images
            .iter()
            .map(|im| vec![Vec::new(); im.keypoints.len()])
            .collect();
        let mut pair_matches = HashMap::new();
        for p in &input.pairs {
            if p.configuration == TwoViewConfiguration::TooFewInliers
                || p.matches.len() < min_matches
            {
                continue;
            }
            pair_matches.insert((p.a.min(p.b), p.a.max(p.b)), p.matches.len());
            for &(i, j) in &p.matches {
                corr[p.a][i as usize].push((p.b as u32, j));
                corr[p.b][j as usize].push((p.a as u32, i));
            }
        }
        Self { corr, pair_matches }
    }

    pub fn correspondences(&self, image: usize, kp: usize) -> &[(u32, u32)] {
        &self.corr[image][kp]
    }

    pub fn num_keypoints(&self, image: usize) -> usize {
        self.corr[image].len()
    }

    pub fn num_matches(&self, a: usize, b: usize) -> usize {
        self.pair_matches
            .get(&(a.min(b), a.max(b)))
            .copied()
            .unwrap_or(0)
    }

    /// Images connected to `image` by a verified pair.
    pub fn neighbours(&self, image: usize) -> Vec<usize> {
        let mut v: Vec<usize> = self
            .pair_matches
            .keys()
            .filter_map(|&(a, b)| {
                if a == image {
                    Some(b)
                } else if b == image {
                    Some(a)
                } else {
                    None
                }
            })
            .collect();
        v.sort_unstable();
        v
    }
}
