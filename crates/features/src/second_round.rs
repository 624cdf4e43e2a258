//! The second round of pair selection for photo sets matched selectively (retrieval, or the
//! window over the content order plus retrieval): an image whose first round verified fewer pairs
//! than a sequence's window would give is matched with every other image.
//!
//! Retrieval ranks images by a global descriptor (`retrieval.rs`), and where every image shows the
//! same object and ground, the ranking misses whole viewpoints: on a synthetic hemisphere of 48
//! views at an 11° field of view (`handheld demo --path hemisphere --fov 11`, seed 0), the first
//! round proposed 465 of the 1 128 pairs and never paired the lowest ring with the ring above
//! (pairs that verify with up to 386 inliers when every pair is matched). Those views verified 2–7
//! pairs each, against 15–25 for every frame of kitti-seq1, whose proposals verify almost all. A
//! view with few verified pairs is the one whose proposals failed, or one that overlaps few
//! others; either way its full row costs at most `n − 1` pairs and finds what retrieval missed.
//! Images that share verified neighbours (COLMAP's transitive matching) were tried first: that
//! found 194 more pairs on the same hemisphere, none of them between the two rings, and 372 on
//! kitti-seq1, where they only added time.

/// The second round's pairs, and how many weak images it left out for its budget.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SecondRound {
    /// `(lower, higher)`, sorted, without duplicates.
    pub pairs: Vec<(usize, usize)>,
    /// Images with fewer than the minimum of verified pairs whose rows did not fit the budget.
    pub left_out: usize,
}

/// Every pair not yet `tried` of the images (of `n`) with fewer than `min_verified` pairs in
/// `verified`, the fewest verified first, whole rows only while they fit within `budget` pairs: a
/// walk whose every photo overlaps only a few others would otherwise be matched exhaustively.
pub fn weak_image_pairs(
    n: usize,
    verified: &[(usize, usize)],
    tried: &[(usize, usize)],
    min_verified: usize,
    budget: usize,
) -> SecondRound {
    let mut count = vec![0usize; n];
    for &(i, j) in verified {
        if i < n && j < n && i != j {
            count[i] += 1;
            count[j] += 1;
        }
    }
    let mut done: std::collections::HashSet<(usize, usize)> =
        tried.iter().map(|&(a, b)| (a.min(b), a.max(b))).collect();
    let mut weak: Vec<usize> = (0..n).filter(|&a| count[a] < min_verified).collect();
    weak.sort_by_key(|&a| (count[a], a));
    let mut out = SecondRound::default();
    for (k, &a) in weak.iter().enumerate() {
        let row: Vec<(usize, usize)> = (0..n)
            .filter(|&b| b != a)
            .map(|b| (a.min(b), a.max(b)))
            .filter(|p| !done.contains(p))
            .collect();
        if out.pairs.len() + row.len() > budget {
            out.left_out = weak.len() - k;
            break;
        }
        done.extend(row.iter().copied());
        out.pairs.extend(row);
    }
    out.pairs.sort_unstable();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_rows_of_weakly_verified_images_are_added_and_tried_pairs_never() {
        // Five images: 0–1, 1–2, 0–2 and 2–3 verified, 4 verified nothing. With at least two
        // verified pairs needed, 3 and 4 are weak: their rows, without the pairs already tried.
        let verified = [(0, 1), (1, 2), (0, 2), (2, 3)];
        let tried = [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4), (0, 4)];
        let p = weak_image_pairs(5, &verified, &tried, 2, usize::MAX);
        assert_eq!(p.pairs, vec![(0, 3), (1, 3), (1, 4), (2, 4)]);
        assert_eq!(p.left_out, 0);
        // Nothing is weak with no minimum.
        assert!(weak_image_pairs(5, &verified, &tried, 0, usize::MAX)
            .pairs
            .is_empty());
        // Within a budget of three pairs: the weakest image's row (4: 1–4, 2–4) fits, 3's does
        // not.
        let p = weak_image_pairs(5, &verified, &tried, 2, 3);
        assert_eq!(p.pairs, vec![(1, 4), (2, 4)]);
        assert_eq!(p.left_out, 1);
    }
}
